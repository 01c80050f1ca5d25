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


CAMERA = "vbl.vision.camera:CameraParams"


def test_a_generated_table_keeps_the_rows_under_its_prefixes():
    from vbl.engine.paramdoc import table
    from vbl.params import markdown_table
    from vbl.vision.camera import CameraParams

    rows = table(CAMERA, ["image_width", "height"]).splitlines()
    assert rows[:2] == markdown_table(CameraParams).splitlines()[:2]
    assert [r.split("`")[1] for r in rows[2:]] == ["height", "image_width"]
    with pytest.raises(ValueError, match="no parameter"):
        table(CAMERA, ["image"])  # a prefix is a whole path part, not the start of a name
    lem = [r.split("`")[1] for r in table("grid_shooting", ["agent.lem"]).splitlines()[2:]]
    assert lem and all(p.startswith("agent.lem.") for p in lem)


def test_render_rewrites_each_regions_body_and_nothing_else(tmp_path, capsys):
    from vbl.engine.paramdoc import main, regions, render, table

    text = (f"intro\n<!-- params:{CAMERA} height -->\nstale\n<!-- /params -->\nmiddle\n"
            f"<!-- params:{CAMERA} hfov_deg,vfov_deg -->\n<!-- /params -->\nend\n")
    assert regions(text) == [(CAMERA, ["height"], "stale\n"),
                             (CAMERA, ["hfov_deg", "vfov_deg"], "")]
    new = render(text)
    assert [body for *_, body in regions(new)] == [
        table(CAMERA, ["height"]) + "\n", table(CAMERA, ["hfov_deg", "vfov_deg"]) + "\n"]
    assert new.startswith("intro\n<!-- params:") and new.endswith("<!-- /params -->\nend\n")
    assert "\nmiddle\n" in new and "stale" not in new
    doc = tmp_path / "doc.md"
    doc.write_text(text)
    assert main([str(doc)]) == 0 and doc.read_text() == new
    assert capsys.readouterr().out == f"updated {doc}\n"
    main([str(doc)])
    assert capsys.readouterr().out == ""


def test_params_page_of_an_experiment_without_quick_seeds_or_sweep():
    import dataclasses

    from vbl.engine import get

    exp = get("fig9_incremental")  # several presets
    exp = dataclasses.replace(exp, quick_seeds=None, seeds=5, sweep={})
    page = experiment_page(exp)
    assert "* seeds: 5 (`--quick`: 5;" in page and "default sweep: none (one point)" in page
    presets = re.findall(r"^\* preset `([\w-]+)`", page, re.M)
    assert len(presets) > 1 and presets == sorted(exp.presets)
