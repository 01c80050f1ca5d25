"""Results as data (docs/engine.md, "Results as data"): a run folder as tables, value for
value its ``metrics.jsonl``; the final table's statistics are ``summary.json``'s; the plot
against a swept value; ``vbl export`` and ``vbl plot`` on bad input; the docs' example."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.engine_helpers import one_error_line, toy_experiment
from vbl.engine.export import final_stats, read_run, swept_path
from vbl.engine.plots import plot_sweep
from vbl.engine.runner import run_experiment
from vbl.params import ParamError

pd = pytest.importorskip("pandas")

REPO = Path(__file__).resolve().parents[1]
SWEEP = {"agent.learning_rate": [0.1, 0.5], "env.num_arms": [3, 4]}  # num_arms: 2 groups


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    gen = toy_experiment(tmp_path_factory.mktemp("exps"))
    toy = next(gen)
    out = tmp_path_factory.mktemp("runs") / "sweep"
    run_experiment(toy, sets={"train.pulls_per_chunk": 5, "train.num_chunks": 3},
                   sweep=SWEEP, seeds=3, out=out, quiet=True, plots=False)
    yield out
    next(gen, None)


def _expected(rows: list[dict]) -> list[tuple]:
    """``(point, lr, arms, seed, chunk, metric, value)`` of every per-seed value of
    ``metrics.jsonl``'s rows, in the file's order."""
    out = []
    for r in rows:
        first = r.get("seeds", [0])[0]
        for k, st in r["metrics"].items():
            for s, v in enumerate(st["per_seed"]):
                out.append((r["point"], r["values"]["agent.learning_rate"],
                            r["values"]["env.num_arms"], first + s,
                            None if r["chunk"] == "final" else r["chunk"], k,
                            np.nan if v is None else v))
    return out


def _actual(df) -> list[tuple]:
    return [(int(p), lr, int(a), int(s), None if c is pd.NA else int(c), m, v)
            for p, lr, a, s, c, m, v in zip(df["point"], df["agent.learning_rate"],
                                            df["env.num_arms"], df["seed"], df["chunk"],
                                            df["metric"], df["value"], strict=True)]


def _rows(run_dir: Path) -> list[dict]:
    return [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]


def test_the_table_is_metrics_jsonl_value_for_value(run_dir, tmp_path):
    """run_table, and its CSV and Parquet files written by `vbl export`, hold every
    per-seed value of metrics.jsonl with its point, swept values, seed and chunk."""
    from vbl.cli import main
    from vbl.engine.export import run_table

    want = _expected(_rows(run_dir))
    df = run_table(run_dir)
    assert list(df.columns) == ["point", "agent.learning_rate", "env.num_arms", "seed",
                                "chunk", "final", "metric", "value"]
    assert _actual(df) == want and len(want) > 100
    assert (df["final"] == df["chunk"].isna()).all()
    assert main(["export", str(run_dir), "--out", str(tmp_path / "t.csv")]) == 0
    assert main(["export", str(run_dir), "--format", "parquet",
                 "--out", str(tmp_path / "t.pq")]) == 0
    csv = pd.read_csv(tmp_path / "t.csv")
    csv["chunk"] = csv["chunk"].astype("Int64")
    assert _actual(csv) == want
    assert _actual(pd.read_parquet(tmp_path / "t.pq")) == want


def test_the_final_table_holds_the_summarys_statistics(run_dir, tmp_path):
    """final_table's mean and 95 % half-width per point are summary.json's, for
    Program.final's metrics and the last chunk's; a rate's interval stays in [0, 1]."""
    from vbl.cli import main
    from vbl.engine.export import final_table

    summary = json.loads((run_dir / "summary.json").read_text())
    ft = final_table(run_dir)
    assert len(ft) == sum(len(p["final"]) + len(p["last_chunk"]) for p in summary["points"])
    for r in ft.itertuples():
        entry = summary["points"][r.point]
        st = entry["final" if r.source == "final" else "last_chunk"][r.metric]
        assert (r.seeds, entry["values"]["agent.learning_rate"]) == (3, r[2])
        np.testing.assert_allclose([r.mean, r.ci95], [st["mean"], st["ci95"]], rtol=1e-12)
        if r.metric == "success_rate" and not np.isnan(r.lower):  # NaN: too few seeds
            assert 0.0 <= r.lower <= r.mean <= r.upper <= 1.0
        elif r.metric == "greedy_is_best":  # not named as a rate: mean -/+ ci95
            np.testing.assert_allclose([r.lower, r.upper], [r.mean - r.ci95, r.mean + r.ci95])
    assert set(ft[ft.source == "last_chunk"]["chunk"]) == {2}
    assert main(["export", str(run_dir), "--final", "--out", str(tmp_path / "f.csv")]) == 0
    assert len(pd.read_csv(tmp_path / "f.csv")) == len(ft)


def test_a_running_run_and_a_shard_read_as_far_as_they_went(run_dir, tmp_path):
    """A folder with the first rows of metrics.jsonl (a run still going) gives those rows,
    and its last chunk so far; a shard's rows give their seeds' indices in the whole run."""
    from vbl.engine.export import run_table

    rows = _rows(run_dir)
    part = tmp_path / "running"
    part.mkdir()
    shutil.copy(run_dir / "config.json", part)
    head = [r for r in rows if r["chunk"] in (0, 1)]
    for r in head:
        r["seeds"] = [3, 6]
    (part / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in head))
    df = run_table(part)
    assert _actual(df) == _expected(head) and set(df["seed"]) == {3, 4, 5}
    last = {r["chunk"] for r in final_stats(part)}
    assert last == {1}


def test_the_plot_against_a_swept_value(run_dir, tmp_path):
    """PNG and SVG; x by its path or its last part; bad x, y or file type: ParamError."""
    png = plot_sweep(run_dir, "learning_rate", "greedy_is_best", tmp_path / "a.png")
    svg = plot_sweep(read_run(run_dir), "env.num_arms", "success_rate", tmp_path / "a.svg")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert b"<svg" in svg.read_bytes()[:2000]
    assert swept_path(run_dir, "num_arms") == "env.num_arms"
    with pytest.raises(ParamError, match="not a swept parameter.*swept: agent.learning_rate"):
        plot_sweep(run_dir, "epsilon", "greedy_is_best", tmp_path / "b.png")
    with pytest.raises(ParamError, match="not a metric.*greedy_is_best"):
        plot_sweep(run_dir, "learning_rate", "nope", tmp_path / "b.png")
    with pytest.raises(ParamError, match=".png or .svg"):
        plot_sweep(run_dir, "learning_rate", "greedy_is_best", tmp_path / "b.jpg")


@pytest.mark.parametrize("case", ["no_folder", "not_a_run", "own_loop", "bad_x", "bad_y",
                                  "bad_format"])
def test_bad_input_is_one_line_exit_2(case, run_dir, tmp_path, capsys):
    from vbl.cli import main

    folder = {"no_folder": tmp_path / "missing", "not_a_run": tmp_path}.get(case, run_dir)
    if case == "own_loop":
        folder = tmp_path / "own"
        folder.mkdir()
        shutil.copy(run_dir / "config.json", folder)
        (folder / "metrics.jsonl").write_text('{"step": 1, "metrics": {"x": 1.0}}\n')
    argv = {"bad_x": ["plot", str(folder), "--x", "nope", "--y", "success_rate"],
            "bad_y": ["plot", str(folder), "--x", "num_arms", "--y", "nope"],
            "bad_format": ["export", str(folder), "--format", "xlsx"]}.get(
        case, ["export", str(folder), "--out", str(tmp_path / "t.csv")])
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's own check (--format's choices)
        code = e.code
    line = one_error_line(capsys.readouterr().err)
    assert code == 2, line
    want = {"no_folder": "is not a run folder (no such folder)",
            "not_a_run": "is not a run folder (no config.json)",
            "own_loop": "not a sweep point's metrics row", "bad_x": "not a swept parameter",
            "bad_y": "not a metric", "bad_format": "invalid choice"}[case]
    assert want in line, line


def _docs_example() -> str:
    text = (REPO / "docs" / "engine.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    return next(b for b in blocks if "plot_sweep(" in b)


def test_the_docs_example_runs_at_a_tiny_size(tmp_path, monkeypatch):
    """docs/engine.md's discount sweep (at most 10 lines) runs as written, at a tiny size
    (run_experiment given the tiny overrides of tests/test_guards.py and 2 seeds): its table
    has a row per sweep point (3 discounts x LEM off/on) and its plot is written."""
    from vbl.engine import runner
    from vbl.engine.registry import load_script

    load_script(REPO / "experiments" / "grid_shooting.py")  # registers it beside the toy
    code = _docs_example()
    assert len(code.strip().splitlines()) <= 10, code
    tiny = {"agent.num_envs": 4, "agent.chunk_steps": 3, "train.num_chunks": 2,
            "train.eval_every": 1, "train.eval_chunks": 7, "train.eval_rounds": 1,
            "train.eval_curve": False, "env.max_steps": 20}
    real = runner.run_experiment

    def tiny_run(experiment, **kw):
        return real(experiment, sets=tiny, seeds=2, quiet=True, plots=False, **kw)

    monkeypatch.setattr(runner, "run_experiment", tiny_run)
    monkeypatch.chdir(tmp_path)
    printed: list = []
    exec(compile(code, "docs/engine.md", "exec"), {"print": printed.append})
    table = printed[0]
    assert len(table) == 6 and set(table["metric"]) == {"greedy_success"}
    assert (tmp_path / "discount.png").stat().st_size > 1000
    stats = [r for r in final_stats(tmp_path / "runs" / "discount")
             if r["metric"] == "greedy_success"]
    assert sorted({r["agent.discount"] for r in stats}) == [0.9, 0.95, 0.98]


def _hand_run(folder: Path, sweep: dict, rows: list[dict], seeds: int = 2) -> Path:
    """A run folder written by hand: config.json and metrics.jsonl."""
    folder.mkdir()
    (folder / "config.json").write_text(json.dumps(
        {"format": 2, "experiment": "demo", "sweep": sweep, "seeds": seeds}))
    (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return folder


def _mrow(step, chunk, point, values, metrics):
    return {"step": step, "chunk": chunk, "point": point, "values": values,
            "metrics": {k: {"per_seed": v} for k, v in metrics.items()}}


def test_array_metrics_and_columns_named_like_the_tables_own(tmp_path):
    """An array metric's elements are name[i,j] in row-major order; a swept parameter
    named like a column is "NAME (swept)"; a tuple value is its text."""
    from vbl.engine.export import long_columns

    q = [[[1, 2, 3], [4, 5, 6]], [[7, 8, 9], [10, 11, 12]]]  # (seeds, 2, 3)
    run = _hand_run(tmp_path / "r", {"seed": [[1, 2]]},
                    [_mrow(1, 0, 0, {"seed": [1, 2]}, {"q": q}),
                     _mrow(2, "final", 0, {"seed": [1, 2]}, {"s": [0.5, 1.5]})])
    cols = long_columns(run)
    assert list(cols) == ["point", "seed (swept)", "seed", "chunk", "final", "metric",
                          "value"]
    at = cols["metric"] == "q[1,0]"
    assert cols["value"][at].tolist() == [4.0, 10.0] and cols["seed"][at].tolist() == [0, 1]
    assert sorted(set(cols["metric"])) == sorted(
        [f"q[{i},{j}]" for i in range(2) for j in range(3)] + ["s"])
    assert set(cols["seed (swept)"]) == {"(1, 2)"}
    assert cols["chunk"][cols["final"]].tolist() == [-1, -1]


def test_final_stats_take_each_points_latest_chunk_in_point_order(tmp_path):
    rows = [_mrow(1, 0, 1, {"a.lr": 0.5}, {"success": [0.0, 0.0, 0.0, 0.0]}),
            _mrow(5, 2, 1, {"a.lr": 0.5}, {"success": [1.0, 1.0, 1.0, 0.6]}),
            _mrow(3, 1, 1, {"a.lr": 0.5}, {"success": [0.5, 0.5, 0.5, 0.5]}),  # merged late
            _mrow(2, 0, 0, {"a.lr": 0.1}, {"success": [0.2, 0.4, 0.6, 0.8]}),
            _mrow(4, "final", 0, {"a.lr": 0.1}, {"score": [1.0, 3.0, 5.0, 7.0]})]
    recs = final_stats(_hand_run(tmp_path / "r", {"a.lr": [0.1, 0.5]}, rows, seeds=4))
    assert [(r["point"], r["source"], r["chunk"], r["metric"]) for r in recs] == [
        (0, "final", None, "score"), (0, "last_chunk", 0, "success"),
        (1, "last_chunk", 2, "success")]
    score, _, late = recs
    assert score["std"] == pytest.approx(np.std([1, 3, 5, 7], ddof=1))
    assert score["lower"] == pytest.approx(4.0 - score["ci95"])
    assert late["mean"] == pytest.approx(0.9) and late["upper"] == 1.0  # a rate: clipped
    assert late["lower"] == pytest.approx(0.9 - late["ci95"])


def test_a_swept_name_must_name_one_path(tmp_path):
    run = _hand_run(tmp_path / "r", {"agent.lr": [0.1], "env.lr": [1], "env.arms": [3]}, [])
    assert swept_path(run, "arms") == "env.arms" and swept_path(run, "env.lr") == "env.lr"
    with pytest.raises(ParamError, match="not a swept parameter"):
        swept_path(run, "lr")


def test_export_names_its_file_and_format(tmp_path, monkeypatch):
    from vbl.engine.export import export_run

    run = _hand_run(tmp_path / "r", {}, [_mrow(1, 0, 0, {}, {"m": [1.0, 2.0]}),
                                         _mrow(2, "final", 0, {}, {"m": [1.0, 2.0]})])
    monkeypatch.chdir(tmp_path)
    path, n = export_run(run, final=True)
    assert (path, n) == (Path("r-final.csv"), 2)  # the final and the last chunk's
    path, n = export_run(run, tmp_path / "all.CSV")
    assert n == 4 and pd.read_csv(path)["value"].tolist() == [1.0, 2.0, 1.0, 2.0]
    assert export_run(run)[0] == Path("r.csv")
