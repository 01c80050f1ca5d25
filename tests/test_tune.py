"""``vbl tune`` (docs/engine.md, "Hyperparameter search"): the SPEC grammar, zipped sweeps,
successive halving that stops learners and equals full runs, the confirmation on fresh
seeds and its command, a killed search that resumes, and bad input in one line."""

from __future__ import annotations

import dataclasses
import json
import shlex
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps

from tests.engine_helpers import (
    REPO,
    TINY_SETS,
    env_for,
    experiments_dir,
    one_error_line,
    run_vbl,
    toy_experiment,
    vbl_cmd,
)
from vbl.engine.errors import EngineError
from vbl.engine.runner import run_experiment
from vbl.engine.sweep import make_plan
from vbl.engine.tune import json_value, parse_space, rungs, tune
from vbl.params import ParamError

optuna = pytest.importorskip("optuna")

SETS = {**TINY_SETS, "train.num_chunks": 9}
SPACE = ["agent.learning_rate=0.02..1:log", "agent.epsilon=0..0.4"]


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    gen = toy_experiment(tmp_path_factory.mktemp("exps"))
    yield next(gen)
    next(gen, None)


def test_space_specs_and_rungs(toy):
    cfg = toy.default_config
    sp = parse_space(["agent.learning_rate=0.01..1:log", "agent.epsilon=0..0.5",
                      "env.num_arms=2..5", "agent.initial_value=0,1.5"], cfg)
    lr, eps, arms, init = sp.values()
    assert (lr.kind, lr.low, lr.high, lr.log) == ("float", 0.01, 1.0, True)
    assert (eps.kind, eps.log) == ("float", False)
    assert (arms.kind, arms.low, arms.high, arms.grid()) == ("int", 2, 5, [2, 3, 4, 5])
    assert init.kind == "choice" and init.choices == (0, 1.5)
    assert parse_space(["agent.epsilon=0..1"], cfg)["agent.epsilon"].kind == "float"
    bad = ["agent.learning_rate", "agent.learning_rate=1..0.5", "agent.learning_rate=0..1:log",
           "agent.learning_rate=0.1..2", "agent.nope=0..1", "agent.epsilon=a..b",
           "agent.epsilon=0..1:lin", "env.num_arms=2..4.5", "agent.epsilon=0.1,0.1"]
    for text in bad:
        with pytest.raises(ParamError):
            parse_space([text], cfg)
    assert rungs(9, 3, 1) == [(0, 1), (1, 3), (3, 9)]
    assert rungs(4, 3, 5) == [(0, 4)]
    with pytest.raises(ParamError, match="LOW > 0"):  # a parameter that may be 0
        parse_space(["agent.epsilon=0..0.4:log"], cfg)


@pytest.mark.parametrize("direction, values, kept", [
    ("maximize", [0.2, 0.9], [1]),                 # fewer trials than eta: the best one
    ("minimize", [0.2, 0.9], [0]),
    ("minimize", [0.5, 0.1, 0.7, 0.3, 0.9, 0.2], [1, 5]),   # 6 // 3 = 2: the 2 lowest
    ("maximize", [0.5, 0.1, 0.7, 0.3, 0.9, 0.2], [2, 4]),
])
def test_a_rung_keeps_the_best_third_and_at_least_one(direction, values, kept):
    """Successive halving's rule: the best max(1, n // eta) of the trials' values at the
    rung go on, the others are told PRUNED."""
    from types import SimpleNamespace

    from vbl.engine.tune import _rung

    study = optuna.create_study(direction=direction)
    trials = [study.ask() for _ in values]
    for tr, v in zip(trials, values, strict=True):
        tr.report(v, 3)
    s = SimpleNamespace(spec={"reduction_factor": 3, "direction": direction},
                        echo=lambda _: None)
    alive = study.get_trials(deepcopy=False)
    keep = _rung(optuna, study, s, alive, 3)
    assert sorted(keep) == [trials[i].number for i in kept]
    pruned = [t.number for t in study.get_trials() if t.state == optuna.trial.TrialState.PRUNED]
    assert sorted(pruned) == sorted(set(t.number for t in trials) - keep)


def test_space_refuses_an_empty_range_a_path_twice_and_no_space(toy):
    cfg = toy.default_config
    for texts in (["agent.epsilon=0.3..0.3"], ["agent.epsilon=0..0.4", "agent.epsilon=0,0.1"],
                  []):
        with pytest.raises(ParamError):
            parse_space(texts, cfg)
    assert rungs(10, 2, 3) == [(0, 3), (3, 6), (6, 10)]
    assert rungs(9, 3, 3) == [(0, 3), (3, 9)]


def test_the_default_metric_is_the_progress_metric_then_the_first_final_one():
    from types import SimpleNamespace

    from vbl.engine.tune import _choose_metric

    prog = SimpleNamespace(progress_metric="rate")
    assert _choose_metric(None, "none", ["loss", "rate"], ["score"], prog) == (
        "rate", False, None)
    none = SimpleNamespace(progress_metric=None)
    assert _choose_metric(None, "none", ["loss"], ["score"], none) == ("score", True, None)
    # a metric logged per chunk and at the end is read at the last chunk
    assert _choose_metric("loss", "halving", ["loss"], ["loss"], none) == (
        "loss", False, "loss")


@pytest.mark.parametrize("kw", [{"eta": 1}, {"confirm_seeds": 1}, {"trials": True},
                                {"seed": 2**31 - 1}, {"direction": "max"}])
def test_search_counts_out_of_range_are_refused(kw):
    from vbl.engine.tune import _check_counts

    args = dict(trials=4, batch=2, sampler="tpe", prune="none", direction="maximize",
                eta=3, min_chunks=None, confirm_seeds=2, seed=2**31 - 2)
    _check_counts(**args)
    with pytest.raises(ParamError):
        _check_counts(**{**args, **kw})


def test_the_planned_search_defaults(toy):
    """First rung at num_chunks // eta**2 chunks, confirmation on max(seeds, 8) seeds,
    tuples written as JSON lists."""
    from vbl.engine.tune import _plan_search

    spec, _, _, (metric, is_final, rung, chunks) = _plan_search(
        toy, ["agent.epsilon=0..0.4"], trials=4, batch=2, seeds=3, metric=None,
        direction="maximize", sampler="random", prune="halving", reduction_factor=2,
        min_chunks=None, sets={**TINY_SETS, "train.num_chunks": 13}, seed=0,
        confirm_seeds=None, quick=False, preset=None)
    assert (spec["min_chunks"], spec["reduction_factor"], chunks) == (13 // 4, 2, 13)
    assert spec["confirm_seeds"] == 8 and (metric, is_final, rung) == (
        "success_rate", False, "success_rate")
    assert json_value((1, 2)) == [1, 2] and json_value(0.5) == 0.5


def test_a_grid_search_may_ask_for_every_point_but_no_more(toy):
    from vbl.engine.tune import _plan_search

    kw = dict(batch=2, seeds=2, metric=None, direction="maximize", sampler="grid",
              prune="none", reduction_factor=None, min_chunks=None, sets=TINY_SETS, seed=0,
              confirm_seeds=None, quick=False, preset=None)
    space = ["agent.epsilon=0,0.2,0.4", "agent.initial_value=0,1"]  # 3 x 2 points
    assert _plan_search(toy, space, trials=6, **kw)[0]["trials"] == 6
    with pytest.raises(ParamError, match="more than the grid's 6 points"):
        _plan_search(toy, space, trials=7, **kw)


def test_resume_accepts_only_more_trials_or_confirmation_seeds(tmp_path):
    from vbl.engine.tune import _start_spec

    spec = {"format": 1, "seeds": 3, "trials": 4, "confirm_seeds": 8}
    _start_spec(tmp_path, spec, resume=False)
    _start_spec(tmp_path, {**spec, "trials": 6, "confirm_seeds": 10}, resume=True)
    assert json.loads((tmp_path / "tune.json").read_text())["trials"] == 6
    with pytest.raises(EngineError, match=r"other settings \(seeds\)"):
        _start_spec(tmp_path, {**spec, "trials": 6, "seeds": 4}, resume=True)


def test_each_batch_has_its_own_sampler_seed():
    from types import SimpleNamespace

    from vbl.engine.tune import _sampler

    space = {"x": SimpleNamespace()}

    def first_value(k):
        s = SimpleNamespace(spec={"seed": 0, "sampler": "random"}, space=space)
        study = optuna.create_study(sampler=_sampler(optuna, s, k))
        return study.ask({"x": optuna.distributions.FloatDistribution(0, 1)}).params["x"]

    assert first_value(1) == first_value(1) != first_value(0)


def test_a_chunk_objective_is_read_at_the_last_logged_chunk():
    from types import SimpleNamespace

    from vbl.engine.tune import _objective

    curve = np.array([[[0.1, 0.2], [0.3, 0.4], [np.nan, np.nan]]])  # (points, chunks, seeds)
    s = SimpleNamespace(is_final=False, metric="m")
    np.testing.assert_array_equal(_objective(s, SimpleNamespace(curves={"m": curve}), 0),
                                  [0.3, 0.4])


def _metrics_file(path: Path, seeds_per_row: list[int]) -> None:
    path.mkdir(parents=True)
    rows = [{"step": i + 1, "chunk": i, "point": 0,
             "metrics": {"m": {"per_seed": [0.0] * n}}} for i, n in enumerate(seeds_per_row)]
    rows.append({"step": 9, "chunk": "final", "point": 0,
                 "metrics": {"m": {"per_seed": [0.0] * 5}}})
    (path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_compute_counts_the_learner_chunks_of_every_batch_and_rung(tmp_path):
    from types import SimpleNamespace

    from vbl.engine.tune import learner_chunks
    from vbl.engine.tune_report import _compute

    _metrics_file(tmp_path / "batch-0", [3, 3])
    _metrics_file(tmp_path / "batch-1" / "rung-1", [2])
    assert learner_chunks(tmp_path / "batch-0") == 6
    s = SimpleNamespace(out=tmp_path, seeds=3, num_chunks=4, rungs=[(0, 1), (1, 4)])
    comp = _compute(s, trials=[0, 1])
    assert comp == {"learner_chunks": 8, "full_grid_learner_chunks": 24,
                    "saved": pytest.approx(2 / 3), "rungs": [[0, 1], [1, 4]]}


def test_a_rates_interval_stays_in_0_1_and_keeps_the_seed_order():
    from vbl.engine.tune_report import interval

    x = [1.0, 0.6, 1.0, 1.0]
    iv = interval(x, "success_rate")
    half = sps.t.ppf(0.975, 3) * sps.sem(x)
    assert iv["upper"] == 1.0 and iv["lower"] == pytest.approx(0.9 - half)
    assert iv["per_seed"] == x and iv["seeds"] == 4
    assert interval(x, "score")["upper"] == pytest.approx(0.9 + half)


def test_the_confirmation_command_sets_every_value_on_fresh_seeds():
    from types import SimpleNamespace

    from vbl.engine.tune_report import confirm_command

    s = SimpleNamespace(command_name=None, experiment=SimpleNamespace(name="toy"),
                        sets={"env.flag": True, "env.size": (1, 2)},
                        spec={"quick": True, "preset": "small", "confirm_seeds": 8,
                              "seed": 4})
    assert confirm_command(s, {"agent.epsilon": 0.25}) == (
        "vbl run toy --quick --preset small --set agent.epsilon=0.25 --set env.flag=true "
        "--set 'env.size=(1,2)' --seeds 8 --seed 5")


def test_tune_report_lists_complete_trials_best_first(tmp_path):
    from types import SimpleNamespace

    from vbl.engine.results import nan_to_null
    from vbl.engine.tune_report import _markdown

    iv = {"mean": 0.5, "ci95": float("nan"), "lower": 0.5, "upper": 0.5, "seeds": 1,
          "base_seed": 1, "run": "r", "command": "vbl run toy", "params": {"x": 0.1}}
    hist = [{"trial": 0, "state": "COMPLETE", "value": 0.2, "params": {"x": 0.1},
             "batch": 0, "last_chunk": 3},
            {"trial": 1, "state": "PRUNED", "value": None, "params": {"x": 0.2},
             "batch": 0, "last_chunk": 1},
            {"trial": 2, "state": "COMPLETE", "value": 0.7, "params": {"x": 0.3},
             "batch": 0, "last_chunk": 3}]
    sm = {"confirmation": iv, "defaults": iv, "search": {**iv, "point": 0},
          "compute": {"learner_chunks": 30, "full_grid_learner_chunks": 40, "saved": 0.25,
                      "rungs": [[0, 3]]}, "params": {"x": 0.3},
          "search_minus_confirmation": {"diff": 0.1, "ci95": 0.2},
          "confirmation_minus_defaults": {"diff": 0.0, "ci95": 0.1},
          "trials": {"ran": 3, "complete": 2, "pruned": 1, "failed": 0}, "best_trial": 2,
          "importances": {}, "importances_note": None, "wall_time_s": 1.0, "history": hist}
    s = SimpleNamespace(experiment=SimpleNamespace(name="toy"), seeds=1, metric="m",
                        is_final=False, spec={"batch": 3, "sampler": "tpe", "prune": "none",
                                              "direction": "maximize", "space": {"x": "0..1"}})
    text = _markdown(s, sm, [])
    assert "(25.0 % saved;" in text and "0.5 (one seed, no interval)" in text
    rows = [line.split(" | ")[0] for line in text.splitlines() if line.startswith("| ")
            and line.split(" | ")[0][2:].isdigit()]
    assert rows == ["| 2", "| 0", "| 1"]
    assert nan_to_null({"a": [float("inf"), 1.0], "b": float("nan")}) == {
        "a": [None, 1.0], "b": None}


def test_zipped_plan_takes_points_side_by_side(toy):
    sweep = {"agent.epsilon": [0.1, 0.2, 0.1], "env.num_arms": [3, 3, 4]}
    plan = make_plan(toy, toy.default_config, sweep, 2, zipped=True)
    assert plan.points == [{"agent.epsilon": 0.1, "env.num_arms": 3},
                           {"agent.epsilon": 0.2, "env.num_arms": 3},
                           {"agent.epsilon": 0.1, "env.num_arms": 4}]
    assert [g.point_ids for g in plan.groups] == [[0, 1], [2]]  # static values: groups
    with pytest.raises(ParamError, match="zipped"):
        make_plan(toy, toy.default_config, {"agent.epsilon": [0.1], "env.num_arms": [3, 4]},
                  2, zipped=True)


def test_span_is_checked(toy, tmp_path):
    """``run_experiment(span=...)``: chunks within the program, one compile group, and
    ``start_carry`` when the span starts after chunk 0; refused before a folder exists."""
    out = tmp_path / "span"
    for kw in ({"span": (0, 10)}, {"span": (2, 2)}, {"span": (1, 3)},
               {"span": (0, 2), "sweep": {"env.num_arms": [3, 4]}}):
        with pytest.raises(ParamError):
            run_experiment(toy, sets={"train.num_chunks": 3},
                           **{"sweep": None, **kw}, seeds=2, out=out, quiet=True)
    assert not out.exists()


@pytest.fixture(scope="module")
def halving(toy, tmp_path_factory):
    out = tmp_path_factory.mktemp("tune") / "halving"
    res = tune(toy, SPACE, trials=6, batch=3, seeds=3, sets=SETS, sampler="random",
               prune="halving", min_chunks=1, out=out, confirm_seeds=4)
    return res


def test_halving_stops_learners_and_equals_full_runs(toy, halving):
    states = optuna.trial.TrialState
    trials = halving.study.get_trials()
    assert len(trials) == 6 and {t.user_attrs["batch"] for t in trials} == {0, 1}
    assert any(t.state == states.PRUNED for t in trials)
    done = [t for t in trials if t.state == states.COMPLETE]
    # learner-chunks: counted from what the runs logged, as the rungs imply
    expect = 0
    for t in trials:
        last = 9 if t.state == states.COMPLETE else t.last_step
        expect += 3 * last
    comp = halving.summary["compute"]
    assert comp["learner_chunks"] == expect < comp["full_grid_learner_chunks"] == 6 * 3 * 9
    # a trial that survived every rung got what a plain run of its values gets
    t = done[0]
    plain = run_experiment(toy, sets={**SETS, **t.params}, seeds=3, out=halving.out_dir.parent
                           / "plain", quiet=True, plots=False)
    np.testing.assert_allclose(t.user_attrs["per_seed"],
                               plain.curves["success_rate"][0, -1], rtol=1e-6)
    # every trial reported its metric to Optuna at every chunk it ran (step = chunks done)
    for t in trials:
        assert sorted(t.intermediate_values) == list(range(1, t.last_step + 1))
        assert t.state == states.PRUNED or t.last_step == 9


def test_report_and_confirmation_command(toy, halving, tmp_path):
    from vbl.cli import _run, build_parser

    sm = halving.summary
    assert sm["confirmation"]["base_seed"] == 1 and sm["search"]["base_seed"] == 0
    assert sm["search_minus_confirmation"]["diff"] == pytest.approx(
        np.mean(sm["search"]["per_seed"]) - np.mean(sm["confirmation"]["per_seed"]))
    states = [t.state.name for t in halving.study.get_trials()]
    assert sm["trials"] == {"ran": 6, "complete": states.count("COMPLETE"),
                            "pruned": states.count("PRUNED"), "failed": states.count("FAIL")}
    assert sm["confirmation"]["seeds"] == 4 and sm["search"]["seeds"] == 3
    text = halving.report.read_text()
    for want in ("the winner's curse", "confirmation on fresh seeds", "history.png",
                 "learner-chunks run", sm["confirmation"]["command"]):
        assert want in text
    assert (halving.out_dir / "history.png").stat().st_size > 1000
    on_disk = json.loads((halving.out_dir / "summary.json").read_text(),
                         parse_constant=lambda c: pytest.fail(f"{c} in summary.json"))
    assert on_disk["compute"] == sm["compute"] and on_disk["params"] == halving.params
    argv = shlex.split(sm["confirmation"]["command"])[1:] + ["--out", str(tmp_path / "again"),
                                                             "--quiet"]
    assert _run(toy, build_parser().parse_args(argv)) == 0
    rows = [json.loads(x) for x in (tmp_path / "again" / "metrics.jsonl").read_text()
            .splitlines()]
    last = [r for r in rows if r["chunk"] == 8][0]
    assert last["metrics"]["success_rate"]["per_seed"] == sm["confirmation"]["per_seed"]


def test_the_defaults_run_on_the_confirmation_seeds(toy, halving):
    """The config's values of the searched parameters run on the confirmation's fresh seeds:
    what a plain run of the defaults on those seeds gives, and the gain against it is the
    difference of the two runs' means."""
    from vbl.engine.runner import resolve
    from vbl.params import get_path

    sm = halving.summary
    base, conf = sm["defaults"], sm["confirmation"]
    config = resolve(toy, SETS, None, 4, 1, False, None)[0]
    assert base["params"] == {p: get_path(config, p) for p in
                              ("agent.learning_rate", "agent.epsilon")}
    assert base["seeds"] == conf["seeds"] == 4 and base["base_seed"] == conf["base_seed"] == 1
    assert "--set agent.learning_rate" not in base["command"]
    plain = run_experiment(toy, sets=SETS, seeds=4, base_seed=1, quiet=True, plots=False,
                           out=halving.out_dir.parent / "plain-defaults")
    np.testing.assert_allclose(base["per_seed"], plain.curves["success_rate"][0, -1],
                               rtol=1e-6)
    gain = sm["confirmation_minus_defaults"]["diff"]
    assert gain == pytest.approx(np.mean(conf["per_seed"]) - np.mean(base["per_seed"]))
    assert "on the same fresh seeds" in halving.report.read_text()


def test_grid_over_static_and_traced_values_with_a_final_metric(toy, tmp_path):
    """The grid sampler visits every point once, batch after batch; a static parameter
    splits a batch into compile groups; a final metric, minimised; the experiment's default
    sweep is fixed at the config's value."""
    swept = dataclasses.replace(toy, sweep={"agent.initial_value": [1.0, 0.0]})
    said: list[str] = []
    res = tune(swept, ["agent.epsilon=0,0.3", "env.num_arms=3..4"], trials=4, batch=3,
               seeds=2, sets={"train.pulls_per_chunk": 5, "train.num_chunks": 2},
               sampler="grid", metric="value_error", direction="minimize", confirm_seeds=2,
               out=tmp_path / "grid", echo=said.append)
    assert said[0].startswith("toy_bandit: 4 trials in batches of 3 x 2 seeds")
    assert "agent.initial_value=0.0" in said[1]  # the default sweep, fixed and said so
    assert "--set agent.initial_value=0.0" in res.summary["confirmation"]["command"]
    hist = res.summary["history"]
    assert sorted((h["params"]["agent.epsilon"], h["params"]["env.num_arms"]) for h in hist) \
        == [(0, 3), (0, 4), (0.3, 3), (0.3, 4)]
    assert res.summary["best_trial"] == min(hist, key=lambda h: h["value"])["trial"]
    cfg = json.loads((res.out_dir / "batch-0" / "config.json").read_text())
    assert cfg["zipped"] is True and len(cfg["sweep"]["env.num_arms"]) == 3


def test_bad_input_is_one_line(toy, tmp_path):
    from vbl.cli import _cmd_tune, build_parser

    out = tmp_path / "x"
    base = ["tune", "toy_bandit", "--trials", "2", "--batch", "2", "--out", str(out)]
    for extra in (["--space", "agent.nope=0..1"],
                  ["--space", "agent.epsilon=0..1", "--metric", "nope"],
                  ["--space", "env.num_arms=2..4", "--prune", "halving"],
                  ["--space", "agent.epsilon=0..1", "--sampler", "grid"],
                  ["--space", "agent.epsilon=0,1", "--set", "agent.epsilon=0.5"],
                  ["--space", "agent.epsilon=0..1", "--confirm-seeds", "1"]):
        with pytest.raises(ParamError):  # the command's exit 2
            _cmd_tune(build_parser().parse_args(base + extra))
    assert not out.exists()
    env = env_for(experiments_dir(tmp_path))
    r = run_vbl(base + ["--space", "agent.learning_rate=2..1"], env)
    assert r.returncode == 2 and "LOW must be below HIGH" in one_error_line(r.stderr)
    blocker = tmp_path / "no_optuna" / "optuna"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text("raise ImportError('optuna is not installed')\n")
    r = run_vbl(base + ["--space", "agent.epsilon=0..1"],
                dict(env, PYTHONPATH=str(tmp_path / "no_optuna")))
    assert r.returncode == 1 and "pip install 'vbl[tune]'" in one_error_line(r.stderr)
    assert not out.exists()


def test_cli_names_a_script_by_its_path(tmp_path, capsys):
    from vbl.cli import _cmd_tune, build_parser

    script = str(experiments_dir(tmp_path) / "toy_bandit.py")
    argv = ["tune", script, "--space", "agent.epsilon=0..0.4", "--trials", "1", "--batch", "1",
            "--seeds", "2", "--confirm-seeds", "2", "--set", "train.num_chunks=1", "--quiet",
            "--out", str(tmp_path / "s")]
    assert _cmd_tune(build_parser().parse_args(argv)) == 0
    out = capsys.readouterr().out
    assert f"reproduce the confirmation: vbl run {script} --set agent.epsilon=" in out
    assert "(2 fresh seeds)" in out


def _history(out: Path) -> list[tuple]:
    sm = json.loads((out / "summary.json").read_text())
    return [(h["trial"], h["state"], h["value"], h["params"]) for h in sm["history"]]


def _kill_when_written(proc: subprocess.Popen, metrics: Path, lines: int, timeout: float,
                       poll: float) -> None:
    """SIGKILL ``proc`` once ``metrics`` holds ``lines`` lines (polled every ``poll`` s);
    fail if it ends first."""
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and proc.poll() is None:
            if metrics.exists() and len(metrics.read_text().splitlines()) >= lines:
                break
            time.sleep(poll)
        assert proc.poll() is None, "the search ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()


def test_killed_search_resumes(toy, tmp_path):
    """SIGKILL in the middle of the second batch, then --resume: the same trials, each
    told once, the same values as a search never stopped."""
    env = env_for(experiments_dir(tmp_path))
    sets = {**TINY_SETS, "train.num_chunks": 80}
    args = ["tune", "toy_bandit", "--space", SPACE[1], "--trials", "4", "--batch", "2",
            "--seeds", "2", "--sampler", "random", "--checkpoint-every", "10",
            "--confirm-seeds", "2", "--quiet"]
    for k, v in sets.items():
        args += ["--set", f"{k}={v}"]
    out = tmp_path / "killed"
    proc = subprocess.Popen(vbl_cmd(*args, "--out", str(out)), env=env, cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    metrics = out / "batch-1" / "metrics.jsonl"
    _kill_when_written(proc, metrics, 30, timeout=120, poll=0.02)
    assert len(metrics.read_text().splitlines()) < 160
    with pytest.raises(EngineError, match="no search"):  # a run folder is not a search
        tune(toy, [SPACE[1]], trials=4, batch=2, seeds=2, sets=sets, out=out / "batch-0",
             resume=True)
    with pytest.raises(EngineError, match="--resume"):  # a taken folder: never overwritten
        tune(toy, [SPACE[1]], trials=4, batch=2, seeds=2, sampler="random", sets=sets,
             out=out)
    r = run_vbl(args + ["--out", str(out), "--resume"], env)
    assert r.returncode == 0, r.stderr[-3000:]
    ref = tmp_path / "whole"
    tune(toy, [SPACE[1]], trials=4, batch=2, seeds=2, sampler="random", sets=sets,
         confirm_seeds=2, out=ref, checkpoint_every=10)
    assert _history(out) == _history(ref)
    with pytest.raises(EngineError, match="other settings"):  # another search's options
        tune(toy, [SPACE[1]], trials=4, batch=2, seeds=3, sampler="random", sets=sets,
             out=out, resume=True)
    study = optuna.load_study(study_name="vbl-tune", storage=f"sqlite:///{out / 'study.db'}")
    assert sorted(t.number for t in study.trials) == [0, 1, 2, 3]
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials)
    rows = [json.loads(x) for x in metrics.read_text().splitlines()]
    steps = [(r["point"], r["chunk"]) for r in rows if r["chunk"] != "final"]
    assert sorted(steps) == [(p, c) for p in range(2) for c in range(80)]


@pytest.mark.slow
def test_killed_halving_search_resumes_mid_rung(toy, tmp_path):
    """SIGKILL while a rung's survivors run (their carries restored from the rung
    before), then --resume: the history and learner-chunks of a search never stopped."""
    env = env_for(experiments_dir(tmp_path))
    args = ["tune", "toy_bandit", "--space", SPACE[0], "--space", SPACE[1], "--trials", "8",
            "--batch", "4", "--seeds", "2", "--sampler", "random", "--prune", "halving",
            "--reduction-factor", "2", "--min-chunks", "10", "--checkpoint-every", "5",
            "--quiet", "--set", "env.num_arms=3", "--set", "train.pulls_per_chunk=5",
            "--set", "train.num_chunks=80"]
    out, ref = tmp_path / "killed", tmp_path / "whole"
    proc = subprocess.Popen(vbl_cmd(*args, "--out", str(out)), env=env, cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    metrics = out / "batch-0" / "rung-1" / "metrics.jsonl"
    _kill_when_written(proc, metrics, 6, timeout=300, poll=0.01)
    r = run_vbl(args + ["--out", str(out), "--resume"], env)
    assert r.returncode == 0, r.stderr[-3000:]
    r = run_vbl(args + ["--out", str(ref)], env)
    assert r.returncode == 0, r.stderr[-3000:]
    assert _history(out) == _history(ref)
    comp = [json.loads((d / "summary.json").read_text())["compute"] for d in (out, ref)]
    assert comp[0] == comp[1] and comp[0]["learner_chunks"] < comp[0]["full_grid_learner_chunks"]
