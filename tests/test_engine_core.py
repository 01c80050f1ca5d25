"""Engine tests in-process: overrides, sweeps == separate runs, learner batches, statistics,
checkpoint guards, error exit codes of the CLI entry point."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.engine_helpers import TINY_SETS, toy_experiment
from vbl.engine import Experiment
from vbl.engine.checkpoint import CheckpointError, Checkpoints
from vbl.engine.config import parse_sweep, parse_value, split_values, stack_traced
from vbl.engine.runner import run_experiment
from vbl.engine.sharding import batch_layout
from vbl.params import ParamError


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    yield from toy_experiment(tmp_path_factory.mktemp("exps"))


SWEEP = {"agent.learning_rate": [0.1, 0.5], "env.num_arms": [3, 4]}


@pytest.fixture(scope="module")
def swept(toy, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "sweep"
    sets = {"train.pulls_per_chunk": 5, "train.num_chunks": 3}
    res = run_experiment(toy, sets=sets, sweep=SWEEP, seeds=3, out=out, quiet=True,
                         checkpoint_every=2)
    return res, sets


def test_parse_values():
    assert parse_value("0.5") == 0.5 and isinstance(parse_value("3"), int)
    assert parse_value("true") is True and parse_value("False") is False
    assert parse_value("(1, 2.5)") == (1, 2.5)
    assert parse_value("12", default="a") == "12"  # str fields keep their text
    assert split_values("0.1,(1,2),x") == ["0.1", "(1,2)", "x"]


def test_override_errors_name_the_problem(toy):
    cfg = toy.default_config
    with pytest.raises(ParamError, match=r"valid: \['epsilon', 'initial_value', "):
        parse_sweep("agent.eps=0.1,0.2", cfg)
    with pytest.raises(ParamError, match="out of range: must be <= 1.0"):
        run_experiment(toy, sets={"agent.epsilon": 1.5}, out=None, quiet=True)
    with pytest.raises(ParamError, match="expected int"):
        run_experiment(toy, sets={"env.num_arms": 2.5}, quiet=True)
    with pytest.raises(ParamError, match="must be >= 2"):
        run_experiment(toy, sweep={"env.num_arms": [3, 1]}, quiet=True)


def test_stacked_config_dtypes(toy):
    st = stack_traced([toy.default_config, toy.default_config], repeats=3)
    assert st.agent.learning_rate.shape == (6,) and st.agent.learning_rate.dtype == np.float32
    assert st.env.num_arms == 10  # static fields stay Python values


@pytest.mark.parametrize("n,d,b", [(1, 1, 4096), (5, 4, 4096), (5000, 4, 4096), (12, 2, 5),
                                   (7, 3, 1)])
def test_batch_layout_covers_learners(n, d, b):
    nb, size = batch_layout(n, d, b)
    assert size % d == 0 and nb * size >= n and (nb - 1) * size < n
    assert size <= max(d, b - b % d) or nb == 1


def test_sweep_layout_and_files(swept):
    res, _ = swept
    # 4 points (2 static groups of 2), 3 chunks, 3 seeds
    assert res.curves["success_rate"].shape == (4, 3, 3)
    assert res.final["greedy_is_best"].shape == (4, 3)
    assert [p["env.num_arms"] for p in res.points] == [3, 4, 3, 4]
    files = {p.name for p in res.out_dir.iterdir()}
    assert {"config.json", "metrics.jsonl", "summary.json", "checkpoints",
            "success_rate.png"} <= files
    rows = [json.loads(x) for x in (res.out_dir / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 4 * 3 + 4  # per (chunk, point) + one "final" row per point
    assert sorted({r["step"] for r in rows}) == [1, 2, 3, 4, 5, 6]  # 2 groups x 3 chunks
    # summary statistics agree with the per-seed values (mean and Student-t interval)
    v = np.asarray(rows[0]["metrics"]["regret"]["per_seed"])
    st = rows[0]["metrics"]["regret"]
    assert st["mean"] == pytest.approx(v.mean())
    assert st["ci95"] == pytest.approx(4.302653 * v.std(ddof=1) / np.sqrt(3))


@pytest.mark.parametrize("point", [1, 2])
def test_sweep_equals_separate_runs(toy, swept, point, tmp_path):
    res, sets = swept
    values = res.points[point]
    one = run_experiment(toy, sets={**sets, **values}, seeds=3, out=tmp_path / "one",
                         quiet=True, plots=False)
    for k, a in one.curves.items():
        np.testing.assert_array_equal(a[0], res.curves[k][point], err_msg=k)
    for k, a in one.final.items():
        np.testing.assert_array_equal(a[0], res.final[k][point], err_msg=k)


def test_learner_batches_do_not_change_results(toy, swept, tmp_path):
    res, sets = swept
    small = run_experiment(toy, sets=sets, sweep=SWEEP, seeds=3, out=tmp_path / "b",
                           quiet=True, plots=False, learner_batch=4)
    for k in res.curves:
        np.testing.assert_array_equal(small.curves[k], res.curves[k])


def test_toy_rates_random_and_learning(toy, tmp_path):
    """epsilon = 1: every pull is uniform, so the best arm's share is 1/K whatever was
    learnt (analytic). epsilon = 0.2: the learners find the best arm (chance 1/K)."""
    k, pulls, chunks, seeds = 4, 50, 4, 32
    res = run_experiment(toy, sets={"env.num_arms": k, "train.pulls_per_chunk": pulls,
                                    "train.num_chunks": chunks},
                         sweep={"agent.epsilon": [1.0, 0.2]}, seeds=seeds,
                         out=tmp_path / "r", quiet=True, plots=False)
    share = res.curves["success_rate"][0].mean()
    se = np.sqrt(0.25 * 0.75 / (pulls * chunks * seeds))
    assert abs(share - 1 / k) < 4 * se
    assert np.all(res.curves["episodes"] == pulls)
    sr = res.curves["success_rate"][1].mean(axis=1)
    assert sr[-1] > sr[0] and res.final["greedy_is_best"][1].mean() > 0.6


def test_escape_hatch_run_writes_the_folder(tmp_path, toy):
    def run(ctx):
        for i in range(3):
            ctx.log(i + 1, {"x": float(i) * ctx.config.agent.learning_rate})
        return {"answer": 42, "seeds": ctx.seeds}

    exp = Experiment(name="hatch", description="d", default_config=toy.default_config,
                     run=run, seeds=2)
    res = run_experiment(exp, out=tmp_path / "h", quiet=True)
    assert res.extra == {"answer": 42, "seeds": 2}
    assert json.loads((tmp_path / "h" / "summary.json").read_text())["result"]["answer"] == 42
    assert len((tmp_path / "h" / "metrics.jsonl").read_text().splitlines()) == 3


def test_checkpoint_guards(tmp_path):
    tree = {"q": np.arange(6, dtype=np.float32).reshape(3, 2), "k": np.ones((3, 2), np.uint32)}
    ck = Checkpoints(tmp_path / "ck", fingerprint="aaaa")
    ck.save(4, tree, {"group": 0})
    ck.close()
    back, meta = Checkpoints(tmp_path / "ck", "aaaa").restore(4, tree)
    np.testing.assert_array_equal(back["q"], tree["q"])
    with pytest.raises(CheckpointError, match="another config"):
        Checkpoints(tmp_path / "ck", "bbbb").restore(4, tree)
    with pytest.raises(CheckpointError, match="shape"):
        Checkpoints(tmp_path / "ck", "aaaa").restore(4, {"q": np.zeros((4, 2), np.float32),
                                                         "k": tree["k"]})


def test_a_carry_of_many_leaves_comes_back_in_its_order(tmp_path):
    """12 leaves of one shape and dtype (shape checks cannot tell them apart): each comes
    back from the checkpoint as the leaf it was."""
    tree = {f"x{i:02d}": np.full((3, 2), i, np.float32) for i in range(12)}
    ck = Checkpoints(tmp_path / "ck", fingerprint="aaaa")
    ck.save(1, tree, {"group": 0})
    ck.close()
    back, _ = Checkpoints(tmp_path / "ck", "aaaa").restore(1, tree)
    assert {k: float(v[0, 0]) for k, v in back.items()} == {k: float(i) for i, k in
                                                             enumerate(tree)}


def test_set_fixes_a_path_of_the_default_sweep(toy):
    """A path of the experiment's default sweep that --set fixes leaves the sweep: one
    value, the one set (resolve's documented rule)."""
    import dataclasses

    from vbl.engine.runner import resolve

    exp = dataclasses.replace(toy, sweep={"agent.epsilon": [0.1, 0.2]})
    assert resolve(exp)[1] == {"agent.epsilon": [0.1, 0.2]}
    config, sweep, _, spec = resolve(exp, sets={"agent.epsilon": 0.3})
    assert sweep == {} and spec["sweep"] == {}
    assert config.agent.epsilon == pytest.approx(0.3)


def test_quick_fixes_a_path_of_the_default_sweep_but_a_sweep_of_it_stands(toy):
    """A --quick value of a default-swept path fixes it under --quick only; a --sweep of
    the path still sweeps it, and the full run keeps the default sweep."""
    import dataclasses

    from vbl.engine.runner import describe_sweep, resolve

    exp = dataclasses.replace(toy, sweep={"agent.epsilon": [0.1, 0.2], "env.num_arms": [3, 4]},
                              quick={"agent.epsilon": 0.3})
    assert resolve(exp)[1] == {"agent.epsilon": [0.1, 0.2], "env.num_arms": [3, 4]}
    config, sweep, _, spec = resolve(exp, quick=True)
    assert sweep == {"env.num_arms": [3, 4]} == spec["sweep"]
    assert config.agent.epsilon == pytest.approx(0.3)
    assert describe_sweep(exp, quick=True)[0] == 2
    again = resolve(exp, sweep={"agent.epsilon": [0.4, 0.5]}, quick=True)[1]
    assert again == {"env.num_arms": [3, 4], "agent.epsilon": [0.4, 0.5]}


@pytest.mark.parametrize("span", [(0, 0), (2, 2), (3, 1), (0, 4)])
def test_a_span_of_no_chunks_or_past_the_end_is_refused(toy, tmp_path, span):
    """span (first, last) runs chunks first..last-1 of the 3: an empty or reversed span,
    or one past the last chunk, is refused before any folder is written."""
    with pytest.raises(ParamError, match=r"span .* needs 0 <= first < last <= 3"):
        run_experiment(toy, sets={**TINY_SETS, "train.num_chunks": 3}, seeds=1,
                       out=tmp_path / "r", quiet=True, span=span, start_carry=lambda x: x)
    assert not (tmp_path / "r").exists()


def test_cli_errors_exit_nonzero(toy, tmp_path, capsys):
    from vbl.cli import main

    assert main(["run", "no_such_thing"]) == 2  # bad input
    err = capsys.readouterr().err  # names the registered experiments (others in this
    assert "unknown experiment 'no_such_thing'; valid: [" in err  # process may be too)
    assert "'toy_bandit'" in err
    assert main(["run", "toy_bandit", "--set", "agent.epsilon=-1"]) == 2
    assert "agent.epsilon=-1.0 is out of range" in capsys.readouterr().err
    assert main(["run", "toy_bandit", "--set", "agent.nope=1"]) == 2
    assert "valid: ['epsilon'" in capsys.readouterr().err
    assert main(["run", "toy_bandit", "--set", "agent.epsilon"]) == 2
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["run", "toy_bandit", "--quiet", "--out", str(blocker / "run")]) == 1
    assert "cannot write to output folder" in capsys.readouterr().err
    full = tmp_path / "full"
    full.mkdir()
    (full / "something").write_text("keep me")
    assert main(["run", "toy_bandit", "--quiet", "--out", str(full)]) == 1
    assert "exists and is not empty" in capsys.readouterr().err
    assert main(["run", "toy_bandit", "--quiet", "--overwrite", "--out", str(full)]) == 1
    assert "holds no vbl run" in capsys.readouterr().err
    assert (full / "something").read_text() == "keep me"


def test_cli_resume_with_another_config_is_refused(toy, swept, capsys):
    from vbl.cli import main

    res, _ = swept
    args = ["run", "toy_bandit", "--quiet", "--resume", "--out", str(res.out_dir),
            "--set", "train.pulls_per_chunk=5", "--set", "train.num_chunks=3", "--seeds", "3",
            "--sweep", "agent.learning_rate=0.1,0.5", "--sweep", "env.num_arms=3,4"]
    assert main(args + ["--set", "agent.epsilon=0.3"]) == 1
    assert "another config (differs in ['agent.epsilon'])" in capsys.readouterr().err
    assert main(args) == 0  # the same options resume (here: nothing left to run)





def test_reproduce_writes_one_report(toy, tmp_path):
    from vbl.engine import ReportSection, register
    from vbl.engine.reproduce import reproduce

    def report(res):
        ours = float(res.final["greedy_is_best"].mean())
        return ReportSection(f"| | paper | ours |\n|---|---|---|\n| best arm | 1.0 | {ours:.2f} |",
                             figures=("success_rate.png",))

    register(Experiment(name="toy_paper", description="toy stand-in for a paper result",
                        default_config=toy.default_config, make_program=toy.make_program,
                        quick={**TINY_SETS, "train.num_chunks": 2}, quick_seeds=2,
                        paper_result=True, paper={"best arm": 1.0}, report=report))
    path, ok = reproduce(tmp_path / "rep", quick=True, quiet=True, names=["toy_paper"])
    text = path.read_text()
    assert ok and "## toy_paper" in text and "| best arm | 1.0 |" in text
    assert "![success_rate](toy_paper/success_rate.png)" in text
    assert (tmp_path / "rep" / "toy_paper" / "success_rate.png").exists()


def test_reproduce_builds_a_report_again_once_the_runs_it_reads_have_finished(toy, tmp_path):
    """A report that reads a later run (``report_reads``) shows that run's numbers in the
    reproduce's report.md and in its own, though its run ended first; its engine figures
    and curves survive the second build."""
    from vbl.engine import ReportSection, register
    from vbl.engine.rebuild import load_run, sibling_result
    from vbl.engine.reproduce import reproduce

    def reader(res):
        other = sibling_result(res, "toy_read_b")
        seen = "none" if other is None else f"{np.mean(other.final['greedy_is_best']):.3f}"
        chunks = next(iter(res.curves.values())).shape[1] if res.curves else 0
        return ReportSection(f"b says {seen}; {chunks} chunks", figures=tuple(res.figures))

    common = dict(default_config=toy.default_config, make_program=toy.make_program,
                  quick={**TINY_SETS, "train.num_chunks": 2}, quick_seeds=2, paper_result=True)
    register(Experiment(name="toy_read_a", description="reads b", report=reader,
                        report_reads=("toy_read_b",), **common))
    register(Experiment(name="toy_read_b", description="read by a", **common))
    path, ok = reproduce(tmp_path / "rep", quick=True, quiet=True,
                         names=["toy_read_a", "toy_read_b"])
    _, b, _ = load_run(tmp_path / "rep" / "toy_read_b")
    want = f"b says {np.mean(b.final['greedy_is_best']):.3f}; 2 chunks"
    own = (tmp_path / "rep" / "toy_read_a" / "report.md").read_text()
    assert ok and want in path.read_text() and want in own, own
    assert "![success_rate](toy_read_a/success_rate.png)" in path.read_text()


def test_reproduce_in_worker_processes_equals_in_process(tmp_path, monkeypatch):
    """--jobs 2 runs experiments in spawned workers; the report's numbers are the same."""
    import re

    from tests.engine_helpers import write_paper_toy
    from vbl.engine import registry
    from vbl.engine.reproduce import reproduce

    d = tmp_path / "exps"
    d.mkdir()
    for name in ("paper_a", "paper_b"):
        write_paper_toy(d, name, chunks=2)
    monkeypatch.setenv("VBL_EXPERIMENTS_DIR", str(d))  # inherited by the workers
    monkeypatch.setattr(registry, "_DISCOVERED", set())
    reports = {}
    for jobs in (1, 2):
        path, ok = reproduce(tmp_path / f"rep{jobs}", quick=True, quiet=True, jobs=jobs,
                             names=["paper_a", "paper_b"])
        assert ok, path.read_text()
        text = path.read_text()
        assert "## paper_a" in text and "## paper_b" in text
        reports[jobs] = re.sub(r"^[0-9]+ s wall .*|\| [0-9.]+ \|\n", "", text, flags=re.M)
        manifest = json.loads((tmp_path / f"rep{jobs}" / "reproduce.json").read_text())
        assert [r["folder"] for r in manifest["runs"]] == ["paper_a", "paper_b"]
        assert manifest["workers"] == jobs and manifest["quick"] is True
        assert all(r["status"] == "ok" and r["peak_rss_mb"] > 0 and 0 < r["cpu_s"] for r in
                   manifest["runs"])
    assert f"{jobs} worker processes" in path.read_text()
    assert reports[1] == reports[2]
    # the workers' execution lock (they take turns at running programs) is gone after
    import os

    from vbl.engine.jax_setup import EXECUTION_LOCK_ENV
    assert EXECUTION_LOCK_ENV not in os.environ
    # a --resume of the finished reproduce runs nothing: its runs keep their recorded
    # times in the manifest (the runs table and the scheduler read them)
    before = json.loads((tmp_path / "rep1" / "reproduce.json").read_text())["runs"]
    summaries = {r["folder"]: (tmp_path / "rep1" / r["folder"] / "summary.json").read_bytes()
                 for r in before}
    _, ok = reproduce(tmp_path / "rep1", quick=True, quiet=True, jobs=1, resume=True,
                      names=["paper_a", "paper_b"])
    after = json.loads((tmp_path / "rep1" / "reproduce.json").read_text())["runs"]
    assert ok and after == before
    assert all((tmp_path / "rep1" / f / "summary.json").read_bytes() == b
               for f, b in summaries.items())


_DYING_TOY = """
import multiprocessing, os
from vbl.engine.registry import load_script
toy = load_script({toy!r})
from vbl.engine import Experiment, register

def make_program(cfg):
    if multiprocessing.parent_process() is not None:  # in a reproduce worker: killed
        os._exit(9)
    return toy.make_program(cfg)

register(Experiment(name="paper_dies", description="a run whose worker is killed",
                    default_config=toy.BanditConfig(), make_program=make_program,
                    quick={quick!r}, quick_seeds=2, paper_result=True))
"""


def test_reproduce_keeps_the_other_runs_when_a_worker_dies(tmp_path, monkeypatch):
    """A worker killed mid-run (out of memory, a signal) breaks the pool, which stops the
    other worker too: the command still ends with the report and the manifest (a dead
    run's costs null, a run that had finished kept) and a non-zero status."""
    from tests.engine_helpers import TINY_SETS, TOY, write_paper_toy
    from vbl.engine import registry
    from vbl.engine.reproduce import reproduce

    d = tmp_path / "exps"
    d.mkdir()
    write_paper_toy(d, "paper_a", chunks=2)
    (d / "paper_dies.py").write_text(_DYING_TOY.format(
        toy=str(TOY), quick={**TINY_SETS, "train.num_chunks": 2}))
    monkeypatch.setenv("VBL_EXPERIMENTS_DIR", str(d))
    monkeypatch.setattr(registry, "_DISCOVERED", set())
    path, ok = reproduce(tmp_path / "rep", quick=True, quiet=True, jobs=2,
                         names=["paper_a", "paper_dies"])
    assert not ok
    runs = {r["folder"]: r for r in
            json.loads((tmp_path / "rep" / "reproduce.json").read_text())["runs"]}
    died = "failed: worker process died"
    assert runs["paper_a"]["status"] == "ok" or runs["paper_a"]["status"].startswith(died)
    for r in runs.values():
        if r["status"].startswith(died):
            assert r["seconds"] is None and r["cpu_s"] is None and r["peak_rss_mb"] is None
        else:
            assert r["cpu_s"] > 0
    assert runs["paper_dies"]["status"].startswith(died)
    text = path.read_text()
    assert "## paper_a" in text and "| paper_dies |" in text and "nan" not in text.lower()


def test_reproduce_chains_group_experiments_and_start_the_longest(toy, tmp_path):
    """Chains (a group runs in one worker) start longest first by the committed run's
    seconds at that scale; a run without a time counts the mean of the others."""
    from vbl.engine.rebuild import REPRODUCE_MANIFEST
    from vbl.engine.reproduce import Job, _chains, committed_seconds, reproduce_jobs

    def exp(name, group=None, presets=()):
        return Experiment(name=name, description="", default_config=toy.default_config,
                          make_program=toy.make_program, group=group,
                          presets={p: {"agent.epsilon": 0.0} for p in presets},
                          published_presets=tuple(presets))

    exps = {e.name: e for e in (exp("t1", "ident"), exp("grid", presets=("p",)), exp("t2"),
                                exp("t3", "ident"))}
    jobs = reproduce_jobs(exps)
    assert jobs == [Job("t1"), Job("grid"), Job("grid", "p"), Job("t2"), Job("t3")]
    assert reproduce_jobs(exps, quick=True) == [Job("t1"), Job("grid"), Job("t2"), Job("t3")]
    for scale, seconds in (("reproduce", {"t1": 70, "t3": 70, "grid": 10, "grid-p": 500,
                                          "t2": 200}),
                           ("reproduce-quick", {"t1": 70, "t3": 70, "grid": 45, "t2": 90})):
        (tmp_path / scale).mkdir()
        (tmp_path / scale / REPRODUCE_MANIFEST).write_text(json.dumps({"runs": [
            {"folder": f, "seconds": t} for f, t in seconds.items()]}))
    full, quick = committed_seconds(False, tmp_path), committed_seconds(True, tmp_path)
    assert [[j.folder for j in c] for c in _chains(jobs, exps, full)] == [
        ["grid-p"], ["t2"], ["t1", "t3"], ["grid"]]
    assert [[j.folder for j in c] for c in _chains(jobs, exps, quick)] == [
        ["t1", "t3"], ["t2"], ["grid-p"], ["grid"]]  # grid-p: the mean, 68.75 s
    assert committed_seconds(True, tmp_path / "none") == {}  # an installed package
    assert [[j.folder for j in c] for c in _chains(jobs, exps, {})] == [
        ["t1", "t3"], ["grid"], ["grid-p"], ["t2"]]  # no times: the registry's order


def test_report_figure_links_resolve_with_a_relative_out_dir(toy, tmp_path, monkeypatch):
    """Experiments return figure paths under their (relative) run folder; links must resolve."""
    import re

    from vbl.engine import ReportSection, register
    from vbl.engine.reproduce import reproduce

    def report(res):  # a path as experiments build it: run_dir / name, run_dir relative
        return ReportSection("fig", figures=(str(res.out_dir / "success_rate.png"),))

    register(Experiment(name="toy_paper_rel", description="relative figure paths",
                        default_config=toy.default_config, make_program=toy.make_program,
                        quick={**TINY_SETS, "train.num_chunks": 2}, quick_seeds=2,
                        paper_result=True, report=report))
    monkeypatch.chdir(tmp_path)
    path, ok = reproduce(Path("rel"), quick=True, quiet=True, names=["toy_paper_rel"])
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", path.read_text())
    assert ok and links == ["toy_paper_rel/success_rate.png"]
    assert all((path.parent / link).exists() for link in links)


def test_progress_is_quiet_in_ci(monkeypatch, capsys):
    from vbl.engine.progress import Progress, auto_quiet

    monkeypatch.setenv("CI", "true")
    assert auto_quiet()
    p = Progress(2, quiet=False)
    p.update({"episodes": np.full(3, 10.0), "success_rate": np.full(3, 0.5)}, 0.5)
    p.close()
    assert "episodes/s=60" in capsys.readouterr().err  # 3 learners x 10 episodes / 0.5 s


def test_a_resumed_run_says_where_it_goes_on(toy, tmp_path, capsys):
    """A resume names the chunk whose checkpoint it continues after (not quiet)."""
    sets = {**TINY_SETS, "train.num_chunks": 4}
    run_experiment(toy, sets=sets, seeds=2, out=tmp_path / "r", quiet=True,
                   checkpoint_every=2)
    capsys.readouterr()
    run_experiment(toy, sets=sets, seeds=2, out=tmp_path / "r", quiet=False, resume=True,
                   checkpoint_every=2)
    assert f"resuming after chunk 4 (its checkpoint in {tmp_path / 'r'})" in \
        capsys.readouterr().err
