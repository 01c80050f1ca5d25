"""Named presets (`vbl run NAME --preset P`), published presets and the run-folder format."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from tests.engine_helpers import TINY, TINY_SETS, env_for, experiments_dir, run_vbl


def test_unknown_preset_lists_the_valid_ones(tmp_path):
    r = run_vbl(["run", "toy_bandit", "--preset", "nope", "--out", str(tmp_path / "r")],
                env_for(experiments_dir(tmp_path)))
    assert r.returncode == 2
    assert r.stderr.strip() == ("vbl: error: unknown preset 'nope' for toy_bandit; valid: "
                                "greedy")
    assert not (tmp_path / "r").exists()


def test_presets_are_checked_against_the_config():
    from vbl.engine import get

    exp = dataclasses.replace(get("toy_bandit"), presets={
        "p": {"agent.epsilon": 0.0, "agent.learning_rate": 0.5}})
    assert exp.preset("p") == {"agent.epsilon": 0.0, "agent.learning_rate": 0.5}
    assert exp.preset(None) == {}
    with pytest.raises(ValueError, match=r"presets\['bad'\]"):
        dataclasses.replace(exp, presets={"bad": {"agent.nope": 1}})


def test_a_preset_run_is_recorded_and_rebuilt_with_the_preset(tmp_path):
    from vbl.engine.rebuild import load_run, run_command

    env = env_for(experiments_dir(tmp_path))
    r = run_vbl(["run", "toy_bandit", "--quick", "--preset", "greedy", *TINY, "--seeds", "2",
                 "--set", "agent.learning_rate=0.3", "--out", str(tmp_path / "run")], env)
    assert r.returncode == 0, r.stderr[-3000:]
    exp, _, spec = load_run(tmp_path / "run")
    assert spec["config"]["agent.epsilon"] == 0.0
    assert spec["config"]["agent.learning_rate"] == pytest.approx(0.3)
    command = run_command(exp, spec)
    assert command.startswith("vbl run toy_bandit --quick --preset greedy --seeds 2 --set ")
    assert "agent.epsilon" not in command and "agent.learning_rate=0.3" in command
    assert all(f"{k}={v}" in command for k, v in TINY_SETS.items())


def test_a_folder_of_another_format_is_refused_with_one_line(tmp_path):
    """vbl reads run folders of its own format only; `vbl report` on another names both."""
    import json

    env = env_for(experiments_dir(tmp_path))
    r = run_vbl(["run", "toy_bandit", "--quick", *TINY, "--seeds", "2", "--out",
                 str(tmp_path / "run")], env)
    assert r.returncode == 0, r.stderr[-3000:]
    spec = json.loads((tmp_path / "run" / "config.json").read_text())
    from vbl.engine.runfolder import RUN_FORMAT

    assert spec["format"] == RUN_FORMAT and spec["preset"] is None and spec["quick"] is True
    spec["format"] = RUN_FORMAT - 1
    (tmp_path / "run" / "config.json").write_text(json.dumps(spec))
    r = run_vbl(["report", str(tmp_path / "run")], env)
    assert r.returncode != 0
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"format {RUN_FORMAT - 1}" in lines[0], r.stderr
    assert f"format {RUN_FORMAT} only" in lines[0]


def test_published_presets_must_be_presets():
    from vbl.engine import get

    exp = get("toy_bandit")
    with pytest.raises(ValueError, match="published_presets"):
        dataclasses.replace(exp, published_presets=("nope",))


def test_reproduce_runs_every_published_preset_beside_the_default():
    """Every result the README publishes is a default or a named preset, and `vbl
    reproduce` runs each of them."""
    from vbl.engine.reproduce import paper_experiments, reproduce_jobs

    exps = paper_experiments()
    jobs = reproduce_jobs(exps)
    assert {j.name for j in jobs if j.preset is None} == set(exps)
    assert {(j.name, j.preset) for j in jobs if j.preset} == {
        (n, p) for n, e in exps.items() for p in e.published_presets}
    assert len({j.folder for j in jobs}) == len(jobs)


@pytest.mark.parametrize("quick", [False, True])
def test_every_reproduce_run_has_a_committed_time(quick):
    """The scheduler orders today's runs by the committed run's seconds at that scale: every
    job has one (the committed runs are today's jobs, tests/test_readme_results.py)."""
    from tests.engine_helpers import REPO
    from vbl.engine.registry import source_file
    from vbl.engine.reproduce import committed_seconds, paper_experiments, reproduce_jobs

    builtin = (REPO / "experiments").resolve()  # other tests register paper toys
    exps = {n: e for n, e in paper_experiments().items()
            if source_file(n) and Path(source_file(n)).resolve().parent == builtin}
    seconds = committed_seconds(quick)
    jobs = reproduce_jobs(exps, quick)
    assert jobs and all(seconds.get(j.folder, 0) > 0 for j in jobs), (seconds, jobs)


def test_the_table2_preset_folder_rebuilds_to_its_preset_command():
    from vbl.engine import get
    from vbl.engine.rebuild import run_command
    from vbl.engine.runner import resolve

    exp = get("table2_shoot_pass")
    *_, spec = resolve(exp, preset="monte_carlo")
    assert run_command(exp, spec) == "vbl run table2_shoot_pass --preset monte_carlo"
    *_, spec = resolve(exp, quick=True, preset="monte_carlo")
    assert run_command(exp, spec) == "vbl run table2_shoot_pass --quick --preset monte_carlo"


def test_a_quick_run_without_the_control_rebuilds_to_the_plain_quick_command():
    """--quick fixes Table 2's velocity control: its run folder rebuilds to `--quick`
    alone, and a quick run that sweeps the control again says so with --sweep."""
    from vbl.engine import get
    from vbl.engine.rebuild import run_command
    from vbl.engine.runner import resolve

    exp = get("table2_shoot_pass")
    *_, spec = resolve(exp, quick=True)
    assert run_command(exp, spec) == "vbl run table2_shoot_pass --quick"
    *_, spec = resolve(exp, quick=True, sweep={"ball_velocity": [False, True]})
    assert run_command(exp, spec) == ("vbl run table2_shoot_pass --quick "
                                      "--sweep ball_velocity=false,true")
