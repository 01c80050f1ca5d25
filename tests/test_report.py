"""Reports (vbl/engine/report.py): the cells every report shares, the table ``vbl run``
prints, ``report.md`` and its figure links.

Truths: SciPy's Student t interval, hand-counted widths and labels, files on disk."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats as sps

from vbl.engine.report import (
    RATE,
    claim,
    default_section,
    figure_path,
    headline_table,
    rate_cell,
    run_report,
    seeds_cell,
    stat_cell,
    url_path,
)


def _half(x) -> float:
    """SciPy's 95 % Student t half-width of the mean of ``x``."""
    x = np.asarray(x, np.float64)
    return float(sps.t.ppf(0.975, x.size - 1) * sps.sem(x))


def _result(points, seeds=4, **kw):
    return SimpleNamespace(summary={"points": points, "seeds": seeds, **kw}, seeds=seeds,
                           figures=[], out_dir=None)


def _st(values):
    return {"mean": float(np.mean(values)), "per_seed": list(values)}


RATES = [0.4, 0.5, 0.6, 0.5]  # mean 0.5, interval inside [0, 1]


# ------------------------------------------------------------------ cells


def test_cells_scale_the_interval_with_the_mean():
    h = _half(RATES)
    assert seeds_cell(RATES, scale=100.0, fmt=".1f") == f"50.0 ± {100 * h:.1f}"
    assert rate_cell(RATES, 100.0, ".1f") == f"50.0 ± {100 * h:.1f}"
    assert stat_cell({"mean": 0.25, "ci95": 0.05}, scale=100.0, fmt=".1f") == "25.0 ± 5.0"


def test_stat_cell_of_one_value_is_the_mean_alone():
    assert stat_cell({"mean": 0.5, "std": 0.0}, n=1) == "0.5"
    assert stat_cell({"mean": 0.5, "ci95": float("nan")}) == "0.5"
    assert stat_cell({"mean": None}) == "-"


@pytest.mark.parametrize("x, text", [([1.0] * 4, "1 ± 0"), ([0.0] * 4, "0 ± 0")])
def test_a_rate_interval_that_touches_the_range_end_keeps_the_plus_minus_form(x, text):
    """Only an interval that crosses the range is clipped; one ending on it is not."""
    assert seeds_cell(x, bounds=RATE) == text


def test_a_rate_crossing_1_with_three_seeds_has_no_interval():
    assert seeds_cell([1.0, 1.0, 0.7], bounds=RATE) == "0.9 (3 seeds: too few for an interval)"


def test_claim_of_a_negative_difference_inside_its_interval_is_not_resolved():
    a, b = [0.1, 0.9, 0.3, 0.6], [0.5, 0.6, 0.4, 0.7]
    assert claim(a, b).startswith("not resolved at 4 seeds (-")
    assert claim([0.1, 0.2, 0.15], [0.8, 0.9, 0.85]).startswith("**no** (-0.7")


# ------------------------------------------------------------------ report.md's table


def test_default_section_shows_rates_in_percent_and_skips_array_metrics():
    point = {"values": {"agent.epsilon": 0.1},
             "final": {"success_rate": _st(RATES), "score": _st([2.0, 2.0, 2.0, 2.0]),
                       "q_map": {"mean": [1.0, 2.0], "per_seed": [[1.0, 2.0]] * 4}}}
    lines = default_section(_result([point]), percent=True).markdown.splitlines()
    assert lines[0] == "| point | success_rate % (final) | score (final) |"
    assert lines[1] == "|---|---|---|"
    assert lines[2] == f"| agent.epsilon=0.1 | 50.0 ± {100 * _half(RATES):.1f} | 2 ± 0 |"
    assert "q_map" not in "\n".join(lines)


def test_default_section_keeps_a_rate_crossing_1_inside_the_range():
    x = [1.0, 1.0, 1.0, 0.6]
    lo = float(np.mean(x)) - _half(x)
    point = {"values": {}, "last_chunk": {"success": _st(x)}}
    row = default_section(_result([point])).markdown.splitlines()[2]
    assert row == f"| default config | 0.9 [{lo:.3g}, 1] |"


# ------------------------------------------------------------------ vbl run's table


def test_point_labels_keep_full_paths_up_to_40_characters():
    def first_label(path, value):
        point = {"values": {path: value}, "final": {"score": _st([1.0, 1.0])}}
        return headline_table(_result([point], seeds=2)).splitlines()[2].split(" | ")[0]

    forty = "a" * 32 + ".b.c=0.5"  # "<path>=0.5" is 40 characters
    assert len(forty) == 40
    assert first_label(forty[:-4], 0.5) == forty
    assert first_label("x" + forty[:-4], 0.5) == "c=0.5"


def test_point_labels_shorten_every_point_when_one_is_long():
    points = [{"values": {"agent.deep.epsilon": v}, "final": {"score": _st([1.0, 1.0])}}
              for v in ("0.1", "x" * 40)]
    rows = headline_table(_result(points, seeds=2)).splitlines()[2:4]
    assert [r.split(" | ")[0].strip() for r in rows] == ["epsilon=0.1", "epsilon=" + "x" * 40]


def test_headline_note_counts_the_left_out_metrics_and_the_summary_seeds():
    st = _st([1.0, 1.0])
    wide = {"a_" + "w" * 90: st, "b_" + "w" * 90: st}
    res = _result([{"values": {}, "final": {"s": st, **dict(list(wide.items())[:1])}}],
                  seeds=5)
    res.seeds = 2  # summary.json's count (e.g. a merged run's) is the one shown
    one = headline_table(res)
    assert one.splitlines()[-1] == ("mean ± 95% interval over 5 seeds; 1 more metric in "
                                    "summary.json")
    two = headline_table(_result([{"values": {}, "final": {"s": st, **wide}}]), width=40)
    assert two.splitlines()[-1].endswith("; 2 more metrics in summary.json")


def test_headline_fits_a_narrow_metric_after_one_too_wide():
    st = _st([1.0, 1.0])
    point = {"values": {}, "final": {"w" * 90: st, "narrow": st}}
    table = headline_table(_result([point]), width=40)
    assert [h.strip() for h in table.splitlines()[0].split(" | ")] == ["point", "narrow"]
    assert table.endswith("1 more metric in summary.json")


def test_headline_lines_have_no_trailing_spaces():
    points = [{"values": {"lr": v}, "final": {"a_long_score_name": _st([1.0, 1.0])}}
              for v in ("0.1", "0.001")]
    lines = headline_table(_result(points)).splitlines()
    assert lines[2] == "lr=0.1   | 1 ± 0"  # the last cell is narrower than its heading
    for line in lines:
        assert line == line.rstrip()


def test_headline_leaves_out_episodes_and_array_headline_metrics():
    st = _st([1.0, 1.0])
    point = {"values": {}, "last_chunk": {"episodes": st, "score": st,
                                          "curve": {"mean": [1.0, 2.0]}}}
    assert headline_table(_result([point])).splitlines()[0] == "point          | score"
    exp = SimpleNamespace(headline=("curve", "score"), percent=False)
    assert headline_table(_result([point]), exp).splitlines()[0].split(" | ")[1] == "score"


def test_headline_of_a_run_without_points_is_its_result_cut_to_the_width():
    res = SimpleNamespace(summary={"result": {"alpha": 1, "beta": 2}}, seeds=1)
    assert headline_table(res) == "result keys: alpha, beta"
    text = "result: " + "x" * 32  # 40 characters: fits exactly
    res = SimpleNamespace(summary={"result": "x" * 32}, seeds=1)
    assert headline_table(res, width=40) == text
    cut = headline_table(res, width=20)
    assert len(cut) == 20 and cut == text[:17] + "..."


# ------------------------------------------------------------------ report.md


def test_url_path_encodes_what_would_break_a_markdown_link():
    assert url_path("my run (2)/fig #1.png") == "my%20run%20%282%29/fig%20%231.png"


def test_figure_path_prefers_the_working_directory_then_the_run_folder(tmp_path,
                                                                        monkeypatch):
    cwd, out = tmp_path / "cwd", tmp_path / "run"
    cwd.mkdir()
    out.mkdir()
    (cwd / "here.png").write_bytes(b"x")
    monkeypatch.chdir(cwd)
    assert figure_path("here.png", out) == cwd / "here.png"
    assert figure_path("there.png", out) == out / "there.png"
    assert figure_path(out / "abs.png", tmp_path) == out / "abs.png"


def test_run_report_writes_the_description_and_records_only_its_own_files(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / ".vbl-run").write_text(json.dumps({"vbl_run": 1, "experiment": "x",
                                              "files": [".vbl-lock", ".vbl-run"]}))
    (out / "notes.txt").write_text("the user's")

    def report(result):
        (out / "fig a.png").write_bytes(b"png")
        return SimpleNamespace(markdown="the table", figures=("fig a.png",))

    exp = SimpleNamespace(name="demo", description="What demo shows.", report=report,
                          percent=False)
    section, path = run_report(exp, SimpleNamespace(out_dir=out))
    assert path.read_text() == ("# demo\n\nWhat demo shows.\n\nthe table\n\n"
                                "![fig a](fig%20a.png)\n\n")
    assert section.figures == (out.absolute() / "fig a.png",)
    files = json.loads((out / ".vbl-run").read_text())["files"]
    assert files == [".vbl-lock", ".vbl-run", "fig a.png", "report.md"]
