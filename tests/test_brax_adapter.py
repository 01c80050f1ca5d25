"""The brax adapter follows brax's conventions: done on termination only, truncation in
info, fresh starts, a start difficulty in the state, float32 observations; it runs inside
``lax.scan`` under brax's training wrappers, and brax's GAE bootstraps at its truncations."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env
from brax.envs.wrappers import training
from brax.training import acting
from brax.training.agents.ppo.losses import compute_gae

import vbl  # noqa: F401
from vbl.agents.ppo_inputs import InputEnv, InputParams
from vbl.envs.brax_adapter import BraxAdapter, get_difficulty, set_difficulty
from vbl.envs.shoot_pass import ShootPassEnv
from vbl.envs.shooting import ShootingEnv

STOP = ShootingEnv().action_labels.index("S")  # both motors stopped: nothing moves


@pytest.fixture(scope="module")
def adapter():
    env = ShootingEnv()
    return BraxAdapter(env, env.default_params.replace(max_steps=4))


def _const_policy(action):
    def policy(obs, key):
        return jnp.full(obs.shape[:-1], action, jnp.int32), {}
    return policy


def test_scan_training_wrappers_truncation_and_gae(adapter):
    """10 steps of 'stop' from random starts with a 4-step limit, in one lax.scan through
    Vmap/Episode/AutoReset: no termination, truncation at steps 4 and 8 (1-based); brax's
    compute_gae then bootstraps the value at the limit: with rewards 0, lambda 1 and a
    constant value c, the target of step t is gamma**(steps to the limit) * c, whereas a
    time limit reported as termination would give 0."""
    assert isinstance(adapter, Env) and adapter.episode_length == 4
    n, T, gamma, c = 3, 10, 0.9, 2.0
    env = training.wrap(adapter, episode_length=adapter.episode_length)

    @jax.jit
    def rollout(key):
        st = env.reset(jax.random.split(key, n))
        return acting.generate_unroll(env, st, _const_policy(STOP), key, T,
                                      extra_fields=("truncation",))

    _, data = rollout(jax.random.PRNGKey(0))
    assert data.observation.dtype == jnp.float32 and data.observation.shape == (T, n, 9)
    trunc = np.asarray(data.extras["state_extras"]["truncation"])
    done = 1.0 - np.asarray(data.discount)
    expect = np.zeros((T, n))
    expect[[3, 7]] = 1.0
    np.testing.assert_array_equal(trunc, expect)
    np.testing.assert_array_equal(done, expect)  # EpisodeWrapper ends the episode there
    termination = done * (1 - trunc)  # brax's PPO loss: termination excludes truncation
    assert not termination.any()

    values = jnp.full((T, n), c)
    boot = jnp.full((n,), c)
    rewards = jnp.asarray(data.reward)
    vs, _ = compute_gae(jnp.asarray(trunc), jnp.asarray(termination), rewards, values, boot,
                        lambda_=1.0, discount=gamma)
    to_limit = np.array([3, 2, 1, 0, 3, 2, 1, 0, 2, 1])  # steps until the next limit/end
    np.testing.assert_allclose(vs[:, 0], c * gamma ** to_limit, rtol=1e-6)
    # the old behaviour (limit reported as termination, no truncation) loses the bootstrap
    vs_term, _ = compute_gae(jnp.zeros((T, n)), jnp.asarray(done), rewards, values, boot,
                             lambda_=1.0, discount=gamma)
    np.testing.assert_allclose(vs_term[:4, 0], 0.0, atol=1e-6)


def test_done_only_on_termination_truncation_in_info(adapter):
    s = adapter.reset(jax.random.PRNGKey(3))
    step = jax.jit(adapter.step)
    for t in range(4):
        s = step(s, jnp.int32(STOP))
        assert float(s.done) == 0.0
        assert float(s.info["truncation"]) == (1.0 if t == 3 else 0.0)
    # a goal is a termination: ball on the goal line in front of the robot, drive forward
    easy = ShootingEnv()
    a = BraxAdapter(easy, easy.default_params.replace(start_difficulty=0.0, max_steps=300))
    s = a.reset(jax.random.PRNGKey(0))
    fwd = jnp.int32(easy.action_labels.index("F"))
    step = jax.jit(a.step)
    for _ in range(200):
        s = step(s, fwd)
        if float(s.done):
            break
    assert float(s.done) == 1.0 and float(s.reward) == 1.0 and float(s.info["truncation"]) == 0


def test_fresh_starts_under_auto_reset():
    """brax's AutoResetWrapper restores the start drawn at reset; with fresh_starts the
    adapter replaces it by a new draw every episode."""
    env = ShootingEnv()
    p = env.default_params.replace(max_steps=2)
    starts = {}
    for fresh in (False, True):
        w = training.wrap(BraxAdapter(env, p, fresh_starts=fresh), episode_length=2)
        st = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(1), 4))
        first = np.asarray(st.pipeline_state.world.robots)
        step = jax.jit(w.step)
        for _ in range(2):
            st = step(st, jnp.full((4,), STOP, jnp.int32))
        starts[fresh] = (first, np.asarray(st.pipeline_state.world.robots))
    np.testing.assert_array_equal(*starts[False])
    assert np.all(np.abs(starts[True][0] - starts[True][1]).max(axis=(1, 2)) > 1e-3)


def test_difficulty_in_state_drives_fresh_starts():
    """Easy starts (difficulty 0) put the robot start.easy_goal_dist (1 m) in front of the
    goal line (x = field length / 2) +- easy_jitter_xy; set_difficulty(0) moves them there."""
    env = ShootingEnv()
    p = env.default_params.replace(max_steps=1, start_difficulty=1.0)
    a = BraxAdapter(env, p)
    w = training.wrap(a, episode_length=1)
    st = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(2), 64))
    np.testing.assert_array_equal(st.info["difficulty"], 1.0)
    st = set_difficulty(st, 0.0)
    st = jax.jit(w.step)(st, jnp.full((64,), STOP, jnp.int32))  # every episode ends: fresh starts
    x = np.asarray(st.pipeline_state.world.robots[:, 0, 0])
    goal_x = p.world.field.length / 2 - p.start.easy_goal_dist
    assert np.all(np.abs(x - goal_x) <= p.start.easy_jitter_xy + 1e-5)
    st0 = a.reset(jax.random.PRNGKey(0))
    no_d = st0.replace(info={k: v for k, v in st0.info.items() if k != "difficulty"})
    with pytest.raises(ValueError, match="no info\\['difficulty'\\]"):
        set_difficulty(no_d, 0.5)


@pytest.mark.slow  # 25 s: the two-robot env under the frame stack, compiled twice
def test_shoot_pass_difficulty_through_input_wrapper():
    """The two-robot task's start difficulty, read through InputEnv's params (``inner``):
    at difficulty 0 a pass start rolls the ball at the slowest speed straight at the
    passer; at the default (1) the starts are the env's own draws."""
    env = ShootPassEnv("pass")
    ienv = InputEnv(env, "stack", frames=2)
    a = BraxAdapter(ienv, InputParams(env.default_params.replace(max_steps=1)))
    assert a.has_difficulty and BraxAdapter(env).has_difficulty
    assert get_difficulty(a.params) == 1.0
    w = training.wrap(a, episode_length=1)
    st = w.reset(jax.random.split(jax.random.PRNGKey(5), 32))
    np.testing.assert_array_equal(st.info["difficulty"], 1.0)
    speed = np.linalg.norm(np.asarray(st.pipeline_state.inner.world.ball_vel), axis=-1)
    assert speed.std() > 0.05  # full draw: speeds spread over [0.4, 0.8]
    st = w.step(set_difficulty(st, 0.0), jnp.zeros((32,), jnp.int32))  # all end: fresh starts
    world = st.pipeline_state.inner.world
    vel = np.asarray(world.ball_vel)
    np.testing.assert_allclose(np.linalg.norm(vel, axis=-1),
                               env.default_params.start.pass_ball_speed_min, rtol=1e-5)
    to_passer = np.asarray(world.robots[:, 1, :2] - world.ball)
    cos = np.sum(vel * to_passer, -1) / np.linalg.norm(vel, axis=-1) / np.linalg.norm(
        to_passer, axis=-1)
    np.testing.assert_allclose(cos, 1.0, atol=1e-5)


@pytest.mark.slow  # 31 s: two compilations of the whole adapter
@pytest.mark.parametrize("x64", [False, True])
def test_float32_whatever_x64(x64):
    for env in (ShootingEnv(), ShootPassEnv("pass")):
        with jax.enable_x64(x64):
            a = BraxAdapter(env)
            s = a.step(a.reset(jax.random.PRNGKey(0)), jnp.int32(1))
        for x in (s.obs, s.reward, s.done, s.info["truncation"], s.metrics["success"]):
            assert x.dtype == jnp.float32


def test_index_and_argmax_actions_match_env_step(adapter):
    s0 = adapter.reset(jax.random.PRNGKey(1))
    k_step = jax.random.split(s0.info["rng"], 3)[0]
    obs, st, *_ = adapter.vbl_env.step(k_step, s0.pipeline_state, jnp.int32(8),
                                           adapter.params)
    for action in (jnp.int32(8), jnp.eye(9)[8] * 3.0 - 1.0):
        s1 = adapter.step(s0, action)
        np.testing.assert_allclose(s1.obs, obs)
        np.testing.assert_allclose(s1.pipeline_state.world.robots, st.world.robots)


def test_adapter_errors(adapter):
    s0 = adapter.reset(jax.random.PRNGKey(1))
    with pytest.raises(ValueError, match=r"\(9,\)"):
        adapter.step(s0, jnp.zeros(3))
    with pytest.raises(ValueError, match=r"\[0, 9\)"):
        adapter.step(s0, jnp.int32(9))
    with pytest.raises(TypeError, match="not a vbl env"):
        BraxAdapter(object())
