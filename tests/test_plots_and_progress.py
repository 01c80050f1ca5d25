"""Plots and the progress bar as a user sees them: rate bands inside [0, 1], every sweep
point's line visible, a sane bar width when the terminal reports none."""

from __future__ import annotations

import os

import numpy as np
import pytest
from scipy import stats

from vbl.engine.plots import band, plot_curves
from vbl.engine.progress import DEFAULT_COLUMNS, bar_width


def test_rate_band_is_the_t_interval_clipped_to_the_unit_interval():
    # 2 seeds at 0 and 1: the t interval of the mean is 0.5 +- 12.7 * 0.5
    y = np.array([[0.0, 1.0], [0.5, 0.5]])
    m, lo, hi = band("success_rate", y)
    np.testing.assert_allclose(m, [0.5, 0.5])
    np.testing.assert_allclose(lo, [0.0, 0.5])
    np.testing.assert_allclose(hi, [1.0, 0.5])
    # not a rate: the plain interval (scipy's t quantile)
    h = stats.t.ppf(0.975, 1) * np.std([0.0, 1.0], ddof=1) / np.sqrt(2)
    _, lo, hi = band("td_abs", y)
    np.testing.assert_allclose([lo[0], hi[0]], [0.5 - h, 0.5 + h], rtol=1e-6)


def test_every_point_gets_its_own_line_style(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    styles = []
    real = plt.Figure.savefig

    def record(fig, *a, **k):
        styles.extend(line.get_linestyle() for line in fig.axes[0].get_lines())
        return real(fig, *a, **k)

    monkeypatch.setattr(plt.Figure, "savefig", record)
    same = np.full((3, 4, 2), 0.5)  # three points with identical curves
    plot_curves({"success_rate": same}, [{"a": 1}, {"a": 2}, {"a": 3}], tmp_path)
    assert len(styles) == 3 and len(set(styles)) == 3
    assert (tmp_path / "success_rate.png").stat().st_size > 1000


@pytest.mark.parametrize("columns, want", [("0", DEFAULT_COLUMNS), ("120", None),
                                           ("40", None), ("39", DEFAULT_COLUMNS)])
def test_bar_width_when_the_terminal_reports_none(monkeypatch, columns, want):
    monkeypatch.setenv("COLUMNS", columns)
    monkeypatch.setenv("LINES", "24")
    assert bar_width() == want
    assert os.environ["COLUMNS"] == columns


def test_progress_shows_the_programs_metric_by_its_name(capsys):
    """The bar shows the metric the program names (Program.progress_metric), mean over the
    learners, and none when the program names none or the chunk lacks it."""
    import numpy as np

    from vbl.engine.progress import Progress

    both = {"eval_success": 0.5, "train_success": 0.25}
    for name, shown in (("eval_success", "eval_success=0.500"),
                        ("train_success", "train_success=0.250"), (None, None),
                        ("greedy_success", None)):
        p = Progress(1, desc="x")
        p.update({"episodes": np.full(2, 5.0), **{k: np.full(2, v) for k, v in both.items()}},
                 0.5, name)
        p.close()
        err = capsys.readouterr().err
        assert "episodes/s=20" in err
        if shown is None:
            assert "success=" not in err
        else:
            assert shown in err and err.count("success=") == 1


def test_every_success_plot_keeps_its_bands_in_the_unit_interval(tmp_path, monkeypatch):
    """The experiment figures (grid LEM curves, PPO curves) as well as the engine's own:
    two seeds at 0 and 1 give a t interval of 0.5 +- 6.4, drawn clipped to [0, 1]."""
    import types

    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.axes

    from vbl.programs import curves, ppo_report

    drawn = []
    real = matplotlib.axes.Axes.fill_between

    def record(ax, x, lo, hi, *a, **k):
        drawn.append(np.concatenate([np.ravel(lo), np.ravel(hi)]))
        return real(ax, x, lo, hi, *a, **k)

    monkeypatch.setattr(matplotlib.axes.Axes, "fill_between", record)
    spread = np.tile([0.0, 1.0], (2, 3, 1))  # (points, chunks, seeds)
    steps = np.cumsum(np.ones_like(spread), axis=1)
    plot_curves({"success_rate": spread}, [{"a": 1}, {"a": 2}], tmp_path)
    res = types.SimpleNamespace(
        curves={"train_success": spread, "episodes": np.ones_like(spread)},
        points=[{"a": 1}, {"a": 2}], final={}, seeds=2,
        config=types.SimpleNamespace(train=types.SimpleNamespace(curve_epsilon=0.0)))
    curves.plot_success_vs_trials(res, 0.5, tmp_path / "lem.png", "grid")
    ppo = {"env_steps": steps, "success_rate": spread}
    ppo_report.plot_success_vs_steps(ppo, ["a", "b"], tmp_path / "ppo.png", "ppo")
    ppo_report.plot_two_robot_curves(ppo, [("shoot", "current", False), ("pass", "cva", True)],
                                     tmp_path / "two.png", "two")
    assert len(drawn) == 2 + 2 + 2 + 2
    for bounds in drawn:
        assert bounds.min() == 0.0 and bounds.max() == 1.0


def test_status_file_phases_and_an_eta_that_leaves_out_the_compiling_chunk(tmp_path,
                                                                          monkeypatch):
    """The first chunk (compilation: 100 s here) does not enter the ETA: after chunks of
    100, 2 and 2 s, 7 chunks left take 7 x 2 s."""
    from vbl.engine import progress

    clock = iter([0.0, 100.0, 100.0, 102.0, 102.0, 104.0, 104.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    p = progress.Progress(10, 0, "t", quiet=True, status_dir=tmp_path)
    assert progress.read_status(tmp_path) == "compiling 0/10 chunks"
    m = {"episodes": np.ones(2)}
    p.update(m)
    assert progress.read_status(tmp_path) == "training 1/10 chunks"
    p.update(m)
    p.update(m)
    assert progress.read_status(tmp_path) == "training 3/10 chunks, ETA 14 s"
    p.close()  # the run no longer runs: no status file is left behind
    assert progress.read_status(tmp_path) == "" and not list(tmp_path.iterdir())


def test_a_second_program_compiles_again_and_its_eta_leaves_that_chunk_out(tmp_path,
                                                                            monkeypatch):
    """Chunks of 100, 2 (first program) then 50 (the second program's compiling chunk)
    and 3 s: 6 chunks left take 6 x 3 s, not the mean with the 50 s chunk in it."""
    from vbl.engine import progress

    clock = iter([0.0, 100.0, 102.0, 102.0, 152.0, 155.0, 155.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    p = progress.Progress(10, 0, "t", quiet=True, status_dir=tmp_path)
    m = {"episodes": np.ones(2)}
    p.update(m)
    p.update(m)
    p.compiling()
    assert progress.read_status(tmp_path) == "compiling 2/10 chunks"
    p.update(m)
    p.update(m)
    assert progress.read_status(tmp_path) == "training 4/10 chunks, ETA 18 s"
    p.close()


@pytest.mark.parametrize("elapsed, shown", [(1799.6, "30 min 00 s"), (59.4, "0 min 59 s"),
                                            (61.0, "1 min 01 s")])
def test_reproduce_progress_line_rounds_to_whole_seconds(tmp_path, monkeypatch, elapsed, shown):
    """The elapsed time reads as minutes and seconds 00-59 (never "29 min 60 s")."""
    from vbl.engine import reproduce

    monkeypatch.setattr(reproduce.time, "perf_counter", lambda: 100.0 + elapsed)
    line = reproduce._progress_line(tmp_path, [], 3, 10, 100.0)
    assert line == f"vbl reproduce [3/10 done, {shown}] finishing"


def _recorded_lines(monkeypatch) -> list:
    """``[(ylabel, [(x, y) of each line])]`` of every figure saved from now on."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    saved = []
    real = plt.Figure.savefig

    def record(fig, *a, **k):
        ax = fig.axes[0]
        saved.append((ax.get_ylabel(), [(ln.get_xdata(), ln.get_ydata())
                                        for ln in ax.get_lines()]))
        return real(fig, *a, **k)

    monkeypatch.setattr(plt.Figure, "savefig", record)
    return saved


def test_one_seed_has_a_band_of_its_value():
    m, lo, hi = band("score", np.array([[0.3], [0.7]]))
    np.testing.assert_array_equal([m, lo, hi], [[0.3, 0.7]] * 3)


def test_curves_against_cumulative_episodes_with_rates_in_percent(tmp_path, monkeypatch):
    from vbl.engine.plots import plot_names

    saved = _recorded_lines(monkeypatch)
    curves = {"success_rate": np.array([[[0.2, 0.4], [0.5, 0.5]]]),
              "episodes": np.array([[[4.0, 6.0], [10.0, 10.0]]]),
              "q_map": np.zeros((1, 2, 2, 3)), "a/b c": np.zeros((1, 2, 2))}
    assert plot_names(curves) == ["success_rate.png", "a_b_c.png"]
    paths = plot_curves(curves, [{}], tmp_path, percent=True)
    assert [p.name for p in paths] == plot_names(curves)
    ylabel, [(x, y)] = saved[0]
    assert ylabel == "success_rate (%)"
    np.testing.assert_allclose(x, [5.0, 15.0])  # mean episodes per chunk, summed
    np.testing.assert_allclose(y, [30.0, 50.0])
    assert saved[1][0] == "a/b c"  # not a rate: as it is


def test_point_labels_name_the_last_part_of_each_path():
    from vbl.engine.plots import point_label

    assert point_label({"agent.learning_rate": 0.1, "env.num_arms": 3}) == \
        "learning_rate=0.1, num_arms=3"
    assert point_label({}) == "run"


def test_sweep_lines_sort_numbers_and_keep_words_in_their_order():
    from vbl.engine.plots import _sweep_lines

    recs = [{"x": 0.5, "k": 1}, {"x": 0.1, "k": 1}, {"x": 0.3, "k": 2}]
    lines, ticks = _sweep_lines(recs, "x", ["k"])
    assert ticks == {} and list(lines) == ["k=1", "k=2"]
    assert [r["x"] for r in lines["k=1"]] == [0.1, 0.5]
    words = [{"x": "tpe"}, {"x": "grid"}, {"x": "tpe"}]
    lines, ticks = _sweep_lines(words, "x", [])
    assert ticks == {"tpe": 0, "grid": 1} and list(lines) == [""]


def _sweep_run(folder, rows):
    import json

    folder.mkdir()
    (folder / "config.json").write_text(json.dumps(
        {"format": 2, "experiment": "demo", "sweep": {"agent.lr": [0.1, 0.5]}, "seeds": 2}))
    (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return folder


def test_a_sweep_plot_prefers_the_final_metric_and_names_its_file(tmp_path, monkeypatch):
    from vbl.engine.export import read_run
    from vbl.engine.plots import _metric_records, plot_sweep
    from vbl.params import ParamError

    def row(step, chunk, p, m):
        return {"step": step, "chunk": chunk, "point": p, "values": {"agent.lr": [0.1, 0.5][p]},
                "metrics": {k: {"per_seed": v} for k, v in m.items()}}

    run = read_run(_sweep_run(tmp_path / "r", [
        row(1, 0, 0, {"s": [1.0, 1.0], "c": [0.0, 2.0]}), row(2, 0, 1, {"s": [2.0, 2.0]}),
        row(3, "final", 0, {"s": [5.0, 7.0]}), row(4, "final", 1, {"s": [3.0, 3.0]})]))
    assert [(r["source"], r["mean"]) for r in _metric_records(run, "s")] == [
        ("final", 6.0), ("final", 3.0)]
    assert [r["source"] for r in _metric_records(run, "c")] == ["last_chunk"]
    with pytest.raises(ParamError, match="metrics: c, s"):
        _metric_records(run, "nope")
    monkeypatch.chdir(tmp_path)
    saved = _recorded_lines(monkeypatch)
    assert plot_sweep(run, "lr", "s").name == "s_vs_agent.lr.png"
    assert saved[0][0] == "s (final)"
    assert plot_sweep(run, "lr", "c", tmp_path / "c.PNG").exists()
    with pytest.raises(ParamError, match=".png or .svg"):
        plot_sweep(run, "lr", "s", tmp_path / "c.jpg")


def test_eta_text_shows_seconds_below_90_s_and_whole_minutes_above():
    from vbl.engine.progress import eta_text

    assert [eta_text(s) for s in (0, 42, 89)] == ["0 s", "42 s", "89 s"]
    assert [eta_text(s) for s in (90, 180, 600, 3570)] == ["2 min", "3 min", "10 min",
                                                           "60 min"]


def test_a_long_eta_is_shown_in_minutes_in_the_status_and_the_bar(tmp_path, monkeypatch,
                                                                  capsys):
    """Chunks of 30 s after a compiling chunk: 2 done of 22 leaves 20 x 30 s = 10 min."""
    from vbl.engine import progress

    clock = iter([0.0, 100.0, 130.0, 130.0, 130.0, 130.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    p = progress.Progress(22, 0, "t", quiet=False, status_dir=tmp_path)
    p.update({}, 100.0)
    p.update({}, 30.0)
    assert p.eta() == 600.0
    assert progress.read_status(tmp_path) == "training 2/22 chunks, ETA 10 min"
    p._bar.refresh()
    assert "ETA=10 min" in capsys.readouterr().err
    p.close()


@pytest.mark.parametrize("ci, tty, kernel, quiet", [
    ("1", True, False, True), ("true", True, False, True), (" YES ", True, False, True),
    ("0", True, False, False), ("", True, False, False), ("", False, False, True),
    ("", False, True, False), ("false", False, True, False)])
def test_the_bar_is_quiet_under_ci_or_without_a_terminal_or_notebook(monkeypatch, ci, tty,
                                                                     kernel, quiet):
    import types

    from vbl.engine import progress

    monkeypatch.setenv("CI", ci)
    monkeypatch.setattr(progress.sys, "stderr", types.SimpleNamespace(isatty=lambda: tty))
    monkeypatch.setattr(progress, "_in_kernel", lambda: kernel)
    assert progress.auto_quiet() is quiet


def test_only_a_jupyter_kernel_counts_as_a_notebook(monkeypatch):
    """IPython in a terminal is no kernel; one whose config names IPKernelApp is; a broken
    IPython is none."""
    import sys
    import types

    from vbl.engine import progress

    def ipython(shell=None, broken=False):
        def get():
            if broken:
                raise RuntimeError("broken")
            return shell
        return types.SimpleNamespace(get_ipython=get)

    for module, want in ((None, False), (ipython(None), False),
                         (ipython(types.SimpleNamespace(config={"TerminalIPythonApp": {}})),
                          False),
                         (ipython(types.SimpleNamespace(config={"IPKernelApp": {}})), True),
                         (ipython(broken=True), False)):
        monkeypatch.setitem(sys.modules, "IPython", module)
        assert progress._in_kernel() is want


def test_a_status_file_is_read_as_one_line_even_at_zero_eta(tmp_path):
    """The last chunk's ETA is 0 s and is shown; no ETA (compiling) shows none; no file or
    a broken one reads as ""."""
    import json

    from vbl.engine.progress import STATUS_FILE, read_status

    assert read_status(tmp_path) == ""
    status = tmp_path / STATUS_FILE
    for eta, want in ((0.0, "training 9/10 chunks, ETA 0 s"), (None, "training 9/10 chunks"),
                      (3600, "training 9/10 chunks, ETA 60 min")):
        status.write_text(json.dumps({"phase": "training", "done": 9, "total": 10,
                                      "eta_s": eta}))
        assert read_status(tmp_path) == want
    status.write_text("{broken")
    assert read_status(tmp_path) == ""


def test_the_last_chunk_done_is_the_finishing_phase(tmp_path, monkeypatch):
    from vbl.engine import progress

    clock = iter([0.0, 10.0, 20.0, 20.0, 20.0, 20.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    p = progress.Progress(2, 0, "t", quiet=True, status_dir=tmp_path)
    p.update({}, 10.0)
    assert progress.read_status(tmp_path) == "training 1/2 chunks"
    p.update({}, 10.0)
    assert progress.read_status(tmp_path).startswith("finishing 2/2 chunks")
    p.close()
