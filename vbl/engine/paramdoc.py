"""Generated parameter tables in the Markdown docs.

A doc marks a table it wants generated with a pair of comments::

    <!-- params:EXPERIMENT PREFIX[,PREFIX...] -->
    | parameter | default | ... |        (generated)
    <!-- /params -->

The table is ``vbl params EXPERIMENT``'s parameter table without its run notes
(:func:`vbl.params.markdown_table` of the experiment's default config), or, for
``EXPERIMENT`` written ``module:Class`` (e.g. ``vbl.vision.camera:CameraParams``), the
table of that parameter class's defaults,
restricted to the rows whose path equals a ``PREFIX`` or starts with
``PREFIX.`` (``learner`` selects the whole ``learner`` section, ``task`` the one field).
``tests/test_docs.py`` checks every region against :func:`render`;
``python -m vbl.engine.paramdoc FILE.md ...`` rewrites the regions in place.
"""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

from vbl.engine.registry import get
from vbl.params import markdown_table

__all__ = ["REGION", "table", "experiment_page", "regions", "render", "main"]

REGION = re.compile(
    r"(?P<open><!-- params:(?P<exp>[\w.:-]+)(?: (?P<prefixes>[\w.,-]+))? -->\n)"
    r"(?P<body>.*?)"
    r"(?P<close><!-- /params -->)", re.S)


def _selected(path: str, prefixes: list[str]) -> bool:
    return not prefixes or any(path == p or path.startswith(p + ".") for p in prefixes)


def table(experiment: str, prefixes: list[str] | tuple[str, ...] = ()) -> str:
    """The rows of ``vbl params experiment`` whose path is under one of ``prefixes`` (all
    rows when empty), with the table's header."""
    if ":" in experiment:  # a parameter class: module:Class
        module, name = experiment.split(":")
        source = getattr(importlib.import_module(module), name)
    else:
        source = get(experiment).default_config
    lines = markdown_table(source).splitlines()
    head, rows = lines[:2], lines[2:]
    keep = [r for r in rows if _selected(r.split("`")[1], list(prefixes))]
    if not keep:
        raise ValueError(f"no parameter of {experiment!r} is under {list(prefixes)}")
    return "\n".join(head + keep)


def _values(values) -> str:
    return ", ".join(str(v) for v in values)


def experiment_page(exp) -> str:
    """``vbl params EXPERIMENT``: what a run of ``exp`` uses, as Markdown. The seeds and the
    default sweep (with and without ``--quick``), what ``--quick`` and each preset set, then
    the parameter table, whose ``default`` cell also names every sweep, ``--quick`` or
    preset value that replaces the default in a run."""
    quick_seeds = exp.quick_seeds or exp.seeds
    sweep = (" x ".join(f"`{k}` in [{_values(v)}]" for k, v in exp.sweep.items())
             if exp.sweep else "none (one point)")
    lines = [f"# {exp.name}: {exp.description}", "",
             f"* seeds: {exp.seeds} (`--quick`: {quick_seeds}; `--seeds N` sets them)",
             f"* default sweep: {sweep}; a `--set` (or a `--quick` value) of a swept path "
             "fixes it, `--sweep` replaces its values"]
    if exp.paper_result and not exp.in_quick_reproduce:
        lines.append("* `vbl reproduce --quick` leaves it out: the full reproduce runs it")
    if exp.quick:
        lines.append("* `--quick` sets: " + ", ".join(f"`{k}={v}`" for k, v in
                                                       exp.quick.items()))
    for name, values in sorted(exp.presets.items()):
        sets = ", ".join(f"`{k}={v}`" for k, v in values.items())
        lines.append(f"* preset `{name}` (`--preset {name}`): {sets}")
    notes: dict[str, list[str]] = {}
    for k, v in exp.sweep.items():
        notes.setdefault(k, []).append(f"swept: {_values(v)}")
    for k, v in exp.quick.items():
        notes.setdefault(k, []).append(f"--quick: {v}")
    for name, values in sorted(exp.presets.items()):
        for k, v in values.items():
            notes.setdefault(k, []).append(f"preset {name}: {v}")
    table = markdown_table(exp.default_config,
                           notes={k: "; ".join(v) for k, v in notes.items()})
    return "\n".join([*lines, "", table])


def regions(text: str) -> list[tuple[str, list[str], str]]:
    """``(experiment, prefixes, body)`` of every generated region of ``text``."""
    return [(m["exp"], [p for p in (m["prefixes"] or "").split(",") if p], m["body"])
            for m in REGION.finditer(text)]


def render(text: str) -> str:
    """``text`` with every generated region's body replaced by the current table."""
    def sub(m: re.Match) -> str:
        prefixes = [p for p in (m["prefixes"] or "").split(",") if p]
        return m["open"] + table(m["exp"], prefixes) + "\n" + m["close"]

    return REGION.sub(sub, text)


def main(argv: list[str] | None = None) -> int:
    """Rewrite the generated regions of the given Markdown files; print the changed ones."""
    for name in (sys.argv[1:] if argv is None else argv):
        path = Path(name)
        old = path.read_text()
        new = render(old)
        if new != old:
            path.write_text(new)
            print(f"updated {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
