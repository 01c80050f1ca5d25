"""The one tabular learner (`vbl.programs.tabular`) on a toy state map, and the
grid_shooting experiment.

* Fast: `make_tabular_program` on a toy map of a chain task with a start difficulty runs
  through the engine (LEM off / on in one compiled group, 2 seeds): metrics are written
  with the right shapes, the epsilon schedule and LEM difficulty follow their definitions,
  the greedy policy solves the chain and the random and near-greedy policies' success
  match exact dynamic-programming values; the grid_shooting report renders from that
  result; trials-to-level against hand-computed values; bad configs fail clearly.
* Slow (`-m slow`, compiles the shooting env, ~1-2 min CPU): the registered grid_shooting
  experiment at tiny size through the engine; its greedy policy beats the random policy
  on easy starts.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import vbl  # noqa: F401
from tests import toy_worlds
from vbl.agents import QRunnerParams
from vbl.engine import Experiment, discover, get, run_experiment
from vbl.params import ParamError, param, section
from vbl.programs.tabular import TabularTrainParams, make_tabular_program
from vbl.stats import first_crossing

# ------------------------------------------------------------------ a chain with a start difficulty
N = 6  # positions 0..5; reaching 5 scores and ends the episode


@struct.dataclass
class ChainParams:
    start_difficulty: float = param(1.0, doc="0: start next to the goal (4), 1: at 0", ge=0.0,
                                    le=1.0)
    max_steps: int = param(8, doc="time limit", static=True, ge=1)


def start_position(d) -> jax.Array:
    """Start N-2 at difficulty 0, 0 at difficulty 1 (rounded down in between)."""
    return jnp.floor((1.0 - jnp.asarray(d, jnp.float32)) * (N - 2)).astype(jnp.int32)


class ChainEnv(toy_worlds.ChainEnv):
    """The chain with a start difficulty; auto-reset."""

    n = N
    default_params = ChainParams()

    def start(self, key, params):
        return start_position(params.start_difficulty)


def random_success_exact(start: int, steps: int, p_right: float = 0.5) -> float:
    """P(reach N-1 within `steps` random moves (right with probability `p_right`) from
    `start`; wall at 0): DP."""
    p = np.zeros(N)
    p[start] = 1.0
    hit = 0.0
    for _ in range(steps):
        q = np.zeros(N)
        for s in range(N - 1):
            q[max(s - 1, 0)] += (1.0 - p_right) * p[s]
            q[s + 1] += p_right * p[s]
        hit += q[N - 1]
        q[N - 1] = 0.0
        p = q
    return hit


@struct.dataclass
class ReportP:
    success_levels: tuple = param((0.5,), doc="levels")
    smooth_chunks: int = param(1, doc="window", ge=1)


def _agent() -> QRunnerParams:
    a = QRunnerParams()
    return a.replace(num_states=N, num_actions=2, discount=0.9,
                     exploration=a.exploration.replace(transition_steps=40.0),
                     macro=a.macro.replace(enabled=False),
                     lem=a.lem.replace(statistic="mean", window=10, threshold=1e-3, step=0.5),
                     num_envs=8, chunk_steps=30)


def _train() -> TabularTrainParams:
    return TabularTrainParams(num_chunks=4, eval_rounds=32)  # 32 x 8 = 256 starts


@struct.dataclass
class ChainConfig:
    env: ChainParams = section(ChainParams)
    agent: QRunnerParams = section(_agent)
    train: TabularTrainParams = section(_train)
    report: ReportP = section(ReportP)


class ChainMap:
    """A toy :class:`~vbl.agents.state_maps.StateMap`: the chain's position, nothing to
    fit."""

    num_states = N
    env = ChainEnv()

    def prepare(self, key, c):
        return ()

    def env_params(self, fitted, env_params):
        return env_params

    def index(self, obs, c):
        return obs[0].astype(jnp.int32)

    def perceived(self, obs, c):
        return self.index(obs, c)

    def describe(self, fitted):
        return {}


def chain_program(cfg):
    return make_tabular_program(ChainMap(), cfg)


CHAIN_EXP = Experiment(
    name="chain_q_test", description="chain test", default_config=ChainConfig(),
    make_program=chain_program,
    sweep={"agent.lem.initial_difficulty": [1.0, 0.0]}, seeds=2)


@pytest.fixture(scope="module")
def chain_result(tmp_path_factory):
    out = tmp_path_factory.mktemp("chain") / "run"
    return run_experiment(CHAIN_EXP, out=out, quiet=True, plots=False)


def test_program_runs_through_engine(chain_result):
    res = chain_result
    lines = [json.loads(x) for x in (Path(res.out_dir) / "metrics.jsonl").read_text()
             .splitlines()]
    assert sum(r["chunk"] != "final" for r in lines) == 4 * 2       # chunks x points
    assert sum(r["chunk"] == "final" for r in lines) == 2
    for name in ("episodes", "successes", "eval_success", "train_success", "difficulty",
                 "epsilon", "td_abs", "lem_raises", "mean_primitives", "decisions",
                 "primitives", "primitives_per_decision"):
        assert res.curves[name].shape == (2, 4, 2), name           # points, chunks, seeds
    assert np.all(res.curves["episodes"] > 0)
    for name in ("eval_success", "train_success"):
        assert np.all((res.curves[name] >= 0) & (res.curves[name] <= 1))
    # epsilon: linear 1 -> 0.1 over 40 steps; the last step of chunk 0 acts at count 29
    np.testing.assert_allclose(res.curves["epsilon"][:, 0], 1 - 0.9 * 29 / 40, atol=1e-6)
    np.testing.assert_allclose(res.curves["epsilon"][:, 1:], 0.1, atol=1e-6)
    # LEM off (initial difficulty 1 = max) stays at 1; on: starts at 0, rises by 0.5 steps
    d = res.curves["difficulty"]
    assert np.all(d[0] == 1.0)
    assert np.all(np.isin(d[1], [0.0, 0.5, 1.0])) and np.all(np.diff(d[1], axis=0) >= 0)
    np.testing.assert_allclose(res.curves["lem_raises"][1], d[1] / 0.5)
    assert np.all(res.final["num_states"] == N)
    # macro actions off: every decision is one primitive
    np.testing.assert_array_equal(res.curves["primitives"], res.curves["decisions"])
    np.testing.assert_array_equal(res.curves["primitives_per_decision"][res.curves["decisions"]
                                                                        > 0], 1.0)


def test_greedy_solves_chain_random_matches_dp(chain_result):
    fin = chain_result.final
    np.testing.assert_array_equal(fin["greedy_success"], 1.0)       # optimal: right x5
    np.testing.assert_allclose(fin["greedy_primitives"], N - 1)
    exact = random_success_exact(0, 8)                              # eval at difficulty 1
    n = 32 * 8                                                      # rounds x envs
    tol = 4 * np.sqrt(exact * (1 - exact) / n)
    assert np.all(np.abs(fin["random_success"] - exact) <= tol), (fin["random_success"], exact)
    # near-greedy (epsilon 0.05, default): the greedy move (right) unless a uniform action
    # is drawn, i.e. right with probability 1 - 0.05 / 2
    near = random_success_exact(0, 8, 1.0 - 0.05 / 2)
    tol = 4 * np.sqrt(near * (1 - near) / n) + 1e-6
    assert np.all(np.abs(fin["near_greedy_success"] - near) <= tol), (
        fin["near_greedy_success"], near)


def test_grid_report_renders(chain_result):
    discover()
    sec = get("grid_shooting").report(chain_result)
    assert "| with LEM |" in sec.markdown and "| without LEM |" in sec.markdown
    assert "| random policy |" in sec.markdown
    assert all(Path(f).exists() for f in sec.figures)


def test_lem_verdict_cases():
    from vbl.programs.curves import lem_verdict

    assert lem_verdict(100.0, 200.0, 300.0).startswith("yes")
    assert lem_verdict(300.0, 200.0, 300.0).startswith("**no**")
    assert lem_verdict(100.0, np.inf, 300.0).startswith("yes")     # never reached in 300
    assert lem_verdict(400.0, np.inf, 300.0).startswith("**not shown**")
    # neither arm reaches the level within the run (a short run): not shown, never "no"
    assert lem_verdict(np.inf, np.inf, 300.0, 700.0) == (
        "**not shown** (neither arm reached it: with LEM not reached in 700, without not "
        "reached in 300)")
    assert lem_verdict(np.inf, 200.0, 300.0).startswith("**no**")  # only without LEM


def test_trials_to_level_hand_computed():
    """Trials until a success level (the reports' crossing): vbl.stats.first_crossing on
    cumulative episodes, by hand."""
    success = np.array([[0.0, 0.1], [0.5, 0.2], [0.2, 0.3], [0.9, 0.4]])   # (chunks, seeds)
    trials = np.cumsum(np.array([[10, 20], [10, 20], [5, 20], [5, 20]]), axis=0)
    np.testing.assert_array_equal(first_crossing(success, trials, 0.5), [20.0, np.nan])
    np.testing.assert_array_equal(first_crossing(success, trials, 0.3), [20.0, 60.0])
    with pytest.raises(ValueError, match="rows, columns"):
        first_crossing(success[:, 0], trials[:, 0], 0.5)
    # window 2: running means seed 0 (0, .25, .35, .55), seed 1 (.1, .15, .25, .35)
    np.testing.assert_array_equal(first_crossing(success, trials, 0.3, window=2), [25.0, 80.0])
    np.testing.assert_array_equal(first_crossing(success, trials, 0.5, window=2),
                                  [30.0, np.nan])
    with pytest.raises(ValueError, match="window"):
        first_crossing(success, trials, 0.5, window=0)


def run_chain_program(train: TabularTrainParams, steps: int, seed: int = 0):
    """The chain's tabular program with ``train``, stepped ``steps`` times outside the engine:
    (program, final carry, per-step metrics as NumPy)."""
    cfg = ChainConfig().replace(train=train)
    prog = chain_program(cfg)
    carry = prog.init(jax.random.PRNGKey(seed), cfg)
    ms = []
    for _ in range(steps):
        carry, m = jax.jit(prog.step)(carry, cfg)
        ms.append(jax.tree.map(np.asarray, m))
    return prog, carry, ms


def test_lr_scale_schedule_sets_the_step_size_per_chunk():
    """train.lr_scale multiplies the agent's learning rate per chunk (hand values of the
    linear schedule); scale 0 leaves the Q-table untouched, scale 1 moves it."""
    from vbl.agents.exploration import ScheduleParams

    def run(scale: ScheduleParams, chunks: int):
        _, carry, ms = run_chain_program(_train().replace(lr_scale=scale), chunks)
        return carry.learner.q, [float(m["learning_rate"]) for m in ms]

    lin = ScheduleParams(schedule="linear", init_value=1.0, end_value=0.2, transition_begin=1.0,
                         transition_steps=2.0)
    _, lrs = run(lin, 4)
    base = ChainConfig().agent.learning_rate                        # 0.25
    np.testing.assert_allclose(lrs, [base, base, 0.6 * base, 0.2 * base], rtol=1e-6)
    q0, lrs0 = run(ScheduleParams(schedule="constant", init_value=0.0), 2)
    assert lrs0 == [0.0, 0.0] and np.all(np.asarray(q0) == 0.0)
    q1, _ = run(ScheduleParams(schedule="constant", init_value=1.0), 2)
    assert np.any(np.asarray(q1) != 0.0)


def test_eval_every_trains_the_same_and_sums_the_chunks():
    """train.eval_every=k: one program step trains k chunks, then evaluates once. Training
    is that of k steps of eval_every=1 (same Q-table, key and LEM state, bit for bit);
    episodes, successes and primitives are the sums over the k chunks, epsilon and the
    difficulty those after the last one."""
    p1, c1, m1 = run_chain_program(_train().replace(eval_every=1), 4, seed=3)
    p2, c2, m2 = run_chain_program(_train().replace(eval_every=2), 2, seed=3)
    assert (p1.num_chunks, p2.num_chunks) == (4, 2)
    for a, b in zip(jax.tree.leaves(c1), jax.tree.leaves(c2), strict=True):
        np.testing.assert_array_equal(a, b)
    for i in range(2):
        pair = m1[2 * i:2 * i + 2]
        for k in ("episodes", "successes"):
            assert m2[i][k] == pair[0][k] + pair[1][k]
        prims = sum(m["mean_primitives"] * max(m["episodes"], 1.0) for m in pair)
        np.testing.assert_allclose(m2[i]["mean_primitives"] * max(m2[i]["episodes"], 1.0),
                                   prims, rtol=1e-5)
        for k in ("epsilon", "difficulty", "lem_raises"):
            assert m2[i][k] == pair[1][k]
    with pytest.raises(ParamError, match="multiple of train.eval_every"):
        chain_program(ChainConfig().replace(train=_train().replace(eval_every=3)))


def test_difficulty_metric_is_the_one_in_effect_with_lem_off():
    """LEM off: episodes start at the env's own start_difficulty, and the difficulty
    metric reports that value (not the curriculum's unused cap)."""
    cfg = ChainConfig()
    cfg = cfg.replace(env=cfg.env.replace(start_difficulty=0.25),
                      agent=cfg.agent.replace(lem=cfg.agent.lem.replace(enabled=False)))
    prog = chain_program(cfg)
    carry = prog.init(jax.random.PRNGKey(0), cfg)
    # the starts really are at that difficulty: position floor((1 - 0.25) * 4) = 3
    np.testing.assert_array_equal(np.asarray(carry.learner.env_state.inner.s), 3)
    # the evaluation's starts are at train.eval_difficulty (1: position 0)
    np.testing.assert_array_equal(np.asarray(carry.starts.env_state.inner.s), 0)
    carry, m = jax.jit(prog.step)(carry, cfg)
    assert float(m["difficulty"]) == 0.25


def test_bad_config_errors():
    @struct.dataclass
    class NoTrain:
        env: ChainParams = section(ChainParams)
        agent: QRunnerParams = section(_agent)

    with pytest.raises(ParamError, match="train"):
        chain_program(NoTrain())
    bad = ChainConfig().replace(train=TabularTrainParams(eval_difficulty=1.5))
    with pytest.raises(ParamError, match="eval_difficulty"):
        chain_program(bad)
    bad = ChainConfig().replace(agent=_agent().replace(num_envs=0))
    with pytest.raises(ParamError, match="num_envs"):
        chain_program(bad)
    # an evaluation shorter than the time limit could not see an episode end
    short = ChainConfig().replace(agent=_agent().replace(chunk_steps=5))
    with pytest.raises(ParamError, match="env.max_steps=8"):
        chain_program(short)


# ------------------------------------------------------------------ the real experiment (slow)

# Both sweep points in one compiled group, 2 seeds, 3 chunks of 80 learner steps (primitives)
# x 32 robots, a curve point after each, training and evaluation on easy starts (robot 1 m
# in front of the goal facing it, ball just ahead; 6 s episodes); LEM never raises within
# its 1000-step window.
TINY = {"agent.num_envs": 32, "agent.chunk_steps": 80, "train.num_chunks": 3,
        "train.eval_every": 1, "train.eval_chunks": 1, "train.eval_rounds": 2,
        "env.max_steps": 60, "train.eval_difficulty": 0.0,
        "agent.exploration.transition_steps": 160.0, "agent.lem.window": 1000}


@pytest.mark.slow
def test_grid_shooting_tiny_run(tmp_path):
    discover()
    res = run_experiment(get("grid_shooting"), sets=TINY, seeds=2, out=tmp_path / "run",
                         quiet=True)
    assert res.curves["eval_success"].shape == (2, 3, 2)
    assert np.all(res.curves["episodes"] > 0)
    assert np.all(res.final["num_states"] == 319)
    # without LEM every episode starts at the task difficulty (the curriculum's cap)
    cap = float(res.config.agent.lem.max_difficulty)
    assert np.allclose(res.curves["difficulty"][0], cap)
    assert np.all(res.curves["difficulty"][1] == 0.0)
    # point 1 trained on easy starts (LEM at difficulty 0) and is evaluated on them
    greedy, rand = res.final["greedy_success"][1], res.final["random_success"][1]
    assert np.all(greedy >= rand + 0.2), (greedy, rand)
    assert (Path(res.out_dir) / "summary.json").exists()


def test_evaluation_mode_leaves_the_table_and_training_unchanged():
    """run_chunk in evaluation mode (traced) does not move the table and acts greedily; with
    the mode off it trains exactly as without a mode (bit for bit)."""
    from vbl.agents.qlearning import Evaluation, make_qlearning_runner

    cfg = ChainConfig()
    agent = cfg.agent.replace(lem=cfg.agent.lem.replace(enabled=False))
    run = make_qlearning_runner(ChainEnv(), lambda o: o[0].astype(jnp.int32), agent)
    c0 = run.init(jax.random.PRNGKey(0), agent, cfg.env)
    q = jnp.zeros((N, 2)).at[:, 1].set(1.0)  # "right" everywhere: the chain's optimum
    c0 = c0.replace(q=q)
    chunk = jax.jit(run.run_chunk)
    plain, m_plain = chunk(c0, agent, cfg.env)
    off, m_off = chunk(c0, agent, cfg.env, Evaluation(jnp.bool_(False), jnp.float32(0.0)))
    for a, b in zip(jax.tree.leaves((plain, m_plain)), jax.tree.leaves((off, m_off)),
                    strict=True):
        np.testing.assert_array_equal(a, b)
    on, m_on = chunk(c0, agent, cfg.env, Evaluation(jnp.bool_(True), jnp.float32(0.0)))
    np.testing.assert_array_equal(on.q, q)
    np.testing.assert_array_equal(m_on["rate"], 0.0)
    # greedy "right" from position 0 scores every episode in N - 1 primitives
    done = np.asarray(m_on["episodes"]).sum()
    assert done > 0 and np.asarray(m_on["successes"]).sum() == done
    np.testing.assert_array_equal(np.asarray(m_on["primitives"]).sum(), (N - 1) * done)
