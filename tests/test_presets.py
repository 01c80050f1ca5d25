"""Named presets (`vbl run NAME --preset P`) and renamed parameters of older run folders."""

from __future__ import annotations

import dataclasses

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
    from vbl.engine.report import load_run, run_command

    env = env_for(experiments_dir(tmp_path))
    r = run_vbl(["run", "toy_bandit", "--quick", "--preset", "greedy", *TINY, "--seeds", "2",
                 "--set", "agent.learning_rate=0.3", "--out", str(tmp_path / "run")], env)
    assert r.returncode == 0, r.stderr[-3000:]
    exp, _, spec = load_run(tmp_path / "run")
    assert spec["config"]["agent.epsilon"] == 0.0
    assert spec["config"]["agent.learning_rate"] == pytest.approx(0.3)
    command, _ = run_command(exp, spec)
    assert command.startswith("vbl run toy_bandit --quick --seeds 2 --preset greedy --set ")
    assert "agent.epsilon" not in command and "agent.learning_rate=0.3" in command
    assert all(f"{k}={v}" in command for k, v in TINY_SETS.items())


def test_renamed_parameters_of_older_folders_read_under_the_current_path():
    from vbl.engine import get
    from vbl.engine.config import config_to_dict
    from vbl.engine.report import run_command

    exp = dataclasses.replace(get("toy_bandit"), renamed_params={"agent.eps": "agent.epsilon"})
    cfg = config_to_dict(exp.default_config)
    cfg.pop("agent.epsilon")
    cfg["agent.eps"] = 0.25
    spec = {"experiment": "toy_bandit", "config": cfg, "sweep": {}, "seeds": exp.seeds}
    command, unrecorded = run_command(exp, spec)
    assert command == "vbl run toy_bandit --set agent.epsilon=0.25" and unrecorded == []


def test_a_renamed_section_moves_every_path_under_it_and_names_old_paths():
    """A key ending in '.' renames a section; the longest key wins, an exact one first; an
    old path given to --set is an error that names today's path."""
    from vbl.engine import get
    from vbl.engine.runner import resolve
    from vbl.params import ParamError

    exp = dataclasses.replace(get("toy_bandit"), renamed_params={
        "old.": "agent.", "old.inner.": "agent.", "old.inner.e": "agent.epsilon"})
    assert exp.renamed("old.epsilon") == "agent.epsilon"
    assert exp.renamed("old.inner.epsilon") == "agent.epsilon"
    assert exp.renamed("old.inner.e") == "agent.epsilon" and exp.renamed("x.y") == "x.y"
    with pytest.raises(ParamError, match="old.epsilon is now called agent.epsilon"):
        resolve(exp, {"old.epsilon": 0.1})
    with pytest.raises(ValueError, match="renamed_params"):
        dataclasses.replace(exp, renamed_params={"old.": "nowhere."})


def test_grid_shooting_folders_of_the_nested_layout_rebuild_to_the_defaults():
    """The grid learner's former layout (table parameters at agent.agent, the exploration
    schedule a section with its formula as ``kind``, the rule as the alias trace.enabled +
    trace.kind) reads as today's defaults: the rebuilt command has no --set."""
    from vbl.engine import get
    from vbl.engine.config import config_to_dict
    from vbl.engine.report import run_command

    exp = get("grid_shooting")
    old = {}
    for path, value in config_to_dict(exp.default_config).items():
        section, _, rest = path.partition(".")
        if path == "agent.update":
            old.update({"agent.agent.update": "q_learning", "agent.agent.trace.enabled": True,
                        "agent.agent.trace.kind": value})
        elif path == "agent.exploration.policy":
            old["agent.agent.exploration.kind"] = value
        elif path == "agent.exploration.schedule":
            old["agent.agent.exploration.schedule.kind"] = value
        elif path.startswith("agent.exploration."):
            old["agent.agent.exploration.schedule." + path.rsplit(".", 1)[1]] = value
        elif section == "agent" and rest.split(".")[0] not in ("macro", "lem", "num_envs",
                                                                 "chunk_steps"):
            old["agent.agent." + rest] = value
        elif path == "train.lr_scale.schedule":
            old["train.lr_scale.kind"] = value
        else:
            old[path] = value
    assert old["agent.agent.trace.kind"] == "peng" and "agent.agent.learning_rate" in old
    spec = {"experiment": exp.name, "config": old, "sweep": dict(exp.sweep), "seeds": exp.seeds}
    assert run_command(exp, spec) == ("vbl run grid_shooting", [])


def test_removed_parameters_are_named_unless_they_ran_as_today():
    """A folder that recorded a parameter the experiment no longer has: silent when its
    value is the one under which the run equals today's code, named otherwise (the note
    of `vbl report`; its run folders: tests/test_readme_results.py)."""
    from vbl.engine import get

    exp = dataclasses.replace(get("toy_bandit"), removed_params={"agent.old": 0.0,
                                                                 "gone.": None})
    assert exp.removed_as_today("agent.old", 0.0) and not exp.removed_as_today("agent.old", 1.0)
    assert exp.removed_as_today("gone.x.y", 7) and not exp.removed_as_today("other", 0.0)
    with pytest.raises(ValueError, match="still exists"):
        dataclasses.replace(exp, removed_params={"agent.epsilon": 0.1})


def test_table2_folders_with_the_absolute_lr_schedule_read_as_today():
    """Table 2's step size was an absolute schedule (train.lr_schedule, overriding the
    learning rate); today the learning rate times the factor train.lr_scale. A folder with
    the old schedule rebuilds to the same step sizes."""
    from vbl.engine import get
    from vbl.engine.config import config_to_dict
    from vbl.engine.report import run_command

    exp = get("table2_shoot_pass")
    rec = config_to_dict(exp.default_config)
    for k in [k for k in rec if k.startswith("train.lr_scale.")]:
        rec["train.lr_schedule." + k.rsplit(".", 1)[1]] = rec.pop(k)
    rec.update({"train.lr_schedule.init_value": 0.1, "train.lr_schedule.end_value": 0.01,
                "q.learning_rate": 0.25,  # ignored by the old code
                "q.update": "monte_carlo"})
    spec = {"experiment": exp.name, "config": rec, "sweep": dict(exp.sweep), "seeds": exp.seeds}
    command, unrecorded = run_command(exp, spec)
    assert command == "vbl run table2_shoot_pass --preset monte_carlo" and unrecorded == []
