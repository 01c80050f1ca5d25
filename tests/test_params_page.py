"""``vbl params EXPERIMENT`` tells the whole configuration of a run: seeds, the default
sweep, what ``--quick`` and each preset set, and, in the table, every default a run
replaces (checked against the configs the engine resolves, not against the page's code)."""

from __future__ import annotations

import re

import pytest

from vbl.engine.paramdoc import experiment_page
from vbl.engine.reproduce import paper_experiments
from vbl.engine.runner import resolve
from vbl.params import get_path


def _default_cells(page: str) -> dict[str, str]:
    return {m[1]: m[2] for m in re.finditer(r"^\| `([\w.]+)` \| (.*?) \| ", page, re.M)}


@pytest.mark.parametrize("name", sorted(paper_experiments()))
def test_params_page_names_what_a_run_replaces(name):
    exp = paper_experiments()[name]
    page = experiment_page(exp)
    cells = _default_cells(page)
    assert f"seeds: {exp.seeds} (`--quick`: " in page
    _, _, quick_seeds, _ = resolve(exp, quick=True)
    assert f"(`--quick`: {quick_seeds};" in page
    quick_config, *_ = resolve(exp, quick=True)
    for path in exp.quick:  # the value a --quick run uses, as the engine resolves it
        assert f"--quick: {get_path(quick_config, path)}" in cells[path], path
    for path, values in exp.sweep.items():
        assert f"swept: {', '.join(map(str, values))}" in cells[path], path
    for preset in exp.presets:
        config, *_ = resolve(exp, preset=preset)
        for path in exp.presets[preset]:
            assert f"preset {preset}: {get_path(config, path)}" in cells[path], (preset, path)
    config, *_ = resolve(exp)
    for path, cell in cells.items():  # a row without a note shows the value a run uses
        if "(" not in cell and path not in exp.sweep:
            value = get_path(config, path)
            shown = f"{value:g}" if isinstance(value, float) else str(value)
            assert cell == shown, path


def test_vbl_params_prints_the_page(capsys):
    from vbl.cli import main

    assert main(["params", "grid_shooting"]) == 0
    out = capsys.readouterr().out
    assert "default sweep: `agent.lem.initial_difficulty` in [" in out
    assert "(swept: " in _default_cells(out)["agent.lem.initial_difficulty"]
