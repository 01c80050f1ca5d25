"""grid_shooting experiment: the Q-learning program runs through the engine at tiny size and
writes its metrics; the learned grid policy beats the random policy on easy starts; the
report's trials-to-level helper against hand-computed values; bad configs fail clearly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import vbl  # noqa: F401
from vbl.agents import QRunnerParams
from vbl.agents.programs import QTrainParams, make_q_program, trials_to_level
from vbl.engine import discover, get, run_experiment
from vbl.params import ParamError

# Tiny run: both sweep points (LEM off / on) in one compiled group, 2 seeds, 3 chunks of
# 40 learner steps x 16 robots. Training and evaluation start easy (difficulty 0: robot 1 m
# in front of the goal facing it, ball just ahead), so a few thousand macro actions suffice
# to learn "push forward" while a random policy often turns away.
TINY = {"agent.num_envs": 32, "agent.chunk_steps": 40, "train.num_chunks": 3,
        "train.eval_envs": 32, "train.eval_steps": 60, "train.final_eval_rounds": 2,
        "env.max_steps": 60, "env.start_difficulty": 0.0, "train.eval_difficulty": 0.0,
        "agent.agent.exploration.schedule.transition_steps": 60.0,
        "agent.lem.window": 1000}


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    discover()
    out = tmp_path_factory.mktemp("grid_shooting") / "run"
    return run_experiment(get("grid_shooting"), sets=TINY, seeds=2, out=out, quiet=True)


def test_engine_run_writes_metrics(result):
    out = Path(result.out_dir)
    lines = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    chunks = [r for r in lines if r["chunk"] != "final"]
    finals = [r for r in lines if r["chunk"] == "final"]
    assert len(chunks) == 3 * 2 and len(finals) == 2          # 3 chunks x 2 points, 2 finals
    for name in ("episodes", "success_rate", "train_success_rate", "difficulty", "epsilon"):
        assert result.curves[name].shape == (2, 3, 2)          # points, chunks, seeds
    assert np.all(result.curves["episodes"] > 0)
    for name in ("success_rate", "train_success_rate"):
        v = result.curves[name]
        assert np.all((v >= 0) & (v <= 1))
    assert np.all(result.final["num_states"] == 319)
    assert np.all(result.final["states_with_value"] <= 319)
    # LEM off (point 0: initial difficulty 1) keeps the difficulty at 1; LEM on starts at 0
    # and cannot rise within one 1000-step window
    assert np.all(result.curves["difficulty"][0] == 1.0)
    assert np.all(result.curves["difficulty"][1] == 0.0)
    # epsilon: linear 1 -> 0.1 over 60 steps; the last step of chunk 0 acts at count 39
    np.testing.assert_allclose(result.curves["epsilon"][:, 0], 1 - 0.9 * 39 / 60, atol=1e-6)
    np.testing.assert_allclose(result.curves["epsilon"][:, 1:], 0.1, atol=1e-6)
    assert (out / "summary.json").exists()


def test_greedy_beats_random_on_easy_starts(result):
    # point 1 trained on easy starts from the beginning (LEM at difficulty 0)
    greedy = result.final["greedy_success"][1]
    rand = result.final["random_success"][1]
    assert np.all((rand >= 0) & (rand <= 1))
    assert np.all(greedy >= rand + 0.2), (greedy, rand)
    assert np.mean(greedy) >= 0.7, greedy


def test_report(result):
    sec = get("grid_shooting").report(result)
    assert "with LEM" in sec.markdown and "without LEM" in sec.markdown
    assert "random policy" in sec.markdown
    assert all(Path(f).exists() for f in sec.figures)


def test_trials_to_level_hand_computed():
    success = np.array([[0.0, 0.1], [0.5, 0.2], [0.2, 0.3], [0.9, 0.4]])   # (chunks, seeds)
    episodes = np.array([[10, 20], [10, 20], [5, 20], [5, 20]])
    got = trials_to_level(success, episodes, 0.5)
    np.testing.assert_array_equal(got, [20.0, np.nan])         # seed 0 at chunk 1; seed 1 never
    got = trials_to_level(success, episodes, 0.3)
    np.testing.assert_array_equal(got, [20.0, 60.0])


def test_bad_config_errors():
    from flax import struct

    from vbl.envs.shooting import ShootingEnv, ShootingParams
    from vbl.params import section

    @struct.dataclass
    class NoTrain:
        env: ShootingParams = section(ShootingParams)
        agent: QRunnerParams = section(QRunnerParams)

    with pytest.raises(ParamError, match="train"):
        make_q_program(ShootingEnv(), lambda o, c: 0, NoTrain())

    @struct.dataclass
    class Cfg:
        env: ShootingParams = section(ShootingParams)
        agent: QRunnerParams = section(QRunnerParams)
        train: QTrainParams = section(QTrainParams)

    with pytest.raises(ParamError, match="num_states"):
        make_q_program(ShootingEnv(), lambda o, c: 0, Cfg(), num_states=10)
    bad = Cfg().replace(train=QTrainParams(eval_difficulty=1.5))
    with pytest.raises(ParamError, match="eval_difficulty"):
        make_q_program(ShootingEnv(), lambda o, c: 0, bad)
