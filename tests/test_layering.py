"""Imports only go down: base modules -> world -> vision -> envs -> spaces / sysid -> agents
-> programs -> cli, and the generic engine sits beside that chain, below the programs: it
knows no soccer. Checked on the source (every import statement, also inside functions)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "vbl"

LAYERS = {
    "draws": 0, "params": 0, "stats": 0,  # base modules of the package's top level
    "world": 1, "vision": 2, "envs": 3, "spaces": 4, "sysid": 4, "agents": 5, "programs": 7,
    "cli": 8,
    "engine": 6,  # below the programs; test_engine_knows_no_soccer keeps it off the chain
}
SOCCER = ("world", "vision", "envs", "spaces", "sysid", "agents", "programs")


def _layer(module: str) -> str | None:
    """``vbl.x.y`` -> ``x`` (a layer name), None for ``vbl`` itself or outside modules."""
    parts = module.split(".")
    return parts[1] if parts[0] == "vbl" and len(parts) > 1 else None


def _imports(path: Path) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module))
            if node.module == "vbl":  # from vbl import engine
                out += [(node.lineno, f"vbl.{a.name}") for a in node.names]
    return out


def test_every_module_belongs_to_a_layer():
    top = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
           if (p.suffix == ".py" and p.stem != "__init__") or (p / "__init__.py").exists()}
    assert top == set(LAYERS), f"modules without a layer: {sorted(top - set(LAYERS))}"


def test_imports_only_go_down():
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        mine = _layer("vbl." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts))
        if mine not in LAYERS:  # vbl/__init__.py
            continue
        for line, module in _imports(path):
            other = _layer(module)
            same_base = LAYERS.get(other) == LAYERS[mine] == 0  # base modules use each other
            if (other in LAYERS and other != mine and LAYERS[other] >= LAYERS[mine]
                    and not same_base):
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{line} ({mine}) imports "
                           f"{module} ({other})")
    assert not bad, "upward or sideways imports:\n" + "\n".join(bad)


def test_engine_knows_no_soccer():
    """vbl.engine (runs, sweeps, checkpoints, reports) imports none of the soccer layers, so a
    user's own learner runs through it without the paper's code."""
    bad = [f"{path.relative_to(PACKAGE.parent)}:{line} imports {module}"
           for path in sorted((PACKAGE / "engine").rglob("*.py"))
           for line, module in _imports(path) if _layer(module) in SOCCER]
    assert not bad, "the engine imports soccer code:\n" + "\n".join(bad)
