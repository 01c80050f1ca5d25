"""ShootingEnv: reference agreement (world + camera), auto-reset, starts, jit/vmap, errors."""

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from tests.reference import world_np
from tests.reference.camera_np import section2_features_np
from vbl.envs.shooting import ShootingEnv, ShootingParams, ShootingState
from vbl.params import ParamError
from vbl.world import make_state

# 1e-4 of each feature's range (px features over the image width/height, x5 over 2)
OBS_TOL = np.array([512, 512, 480, 512, 2, 1, 1, 1, 1]) * 1e-4


@pytest.fixture(scope="module")
def env():
    return ShootingEnv()


@pytest.fixture(scope="module")
def short(env):
    """Params with a 10-primitive time limit (episodes end inside short tests)."""
    return env.default_params.replace(max_steps=10)


@pytest.fixture(scope="module")
def jitted(env):
    """One compilation of each entry point for the module; ``step`` may be traced once
    (checked by test_step_compiles_once: every test calls it with the same static params)."""
    return dict(reset=jax.jit(env.reset), step=jax.jit(chex.assert_max_traces(env.step, n=1)),
                step_env=jax.jit(env.step_env))


def _np_state(world):
    return dict(robots=np.asarray(world.robots, float).tolist(),
                ball=np.asarray(world.ball, float).tolist(),
                vel=np.asarray(world.ball_vel, float).tolist(),
                scored=bool(world.scored), out=bool(world.ball_out))


def _rollout_env(env, params, state, actions):
    """step_env (no reset) over actions (T,) -> per-step obs, states, rewards, flags."""

    def body(s, a):
        o, s, r, te, tr, _ = env.step_env(jax.random.key(0), s, a, params)
        return s, (o, s, r, te, tr)

    return jax.lax.scan(body, state, actions)[1]


# params are a traced argument: episodes with different start_difficulty share one compile
_rollout_env_jit = jax.jit(_rollout_env, static_argnums=0)
_reset_jit = jax.jit(lambda env, key, params: env.reset(key, params), static_argnums=0)


def _episode_vs_reference(env, params, key, n_cam, seed):
    p = params
    obs0, st = _reset_jit(env, key, p)
    rng = np.random.default_rng(seed)
    acts = np.where(rng.random(p.max_steps) < 0.5, 8, rng.integers(0, 9, p.max_steps))
    obs, states, rew, term, trunc = jax.tree_util.tree_map(
        np.asarray, _rollout_env_jit(env, p, st, jnp.asarray(acts, jnp.int32)))
    corners = world_np.goal_corners_np(p.world)

    def cam(s):
        return section2_features_np(np.array(s["robots"][0]), np.array(s["ball"]),
                                    p.world.ball.radius, corners, p.camera)

    np.testing.assert_array_less(np.abs(np.asarray(obs0) - cam(_np_state(st.world))), OBS_TOL)
    ref = world_np.run_episode(_np_state(st.world), acts, p.world, p.max_steps)
    n = len(ref["states"])
    cam_steps = set(np.linspace(0, n - 1, min(n_cam, n)).astype(int))
    for t in range(n):
        s = ref["states"][t]
        np.testing.assert_allclose(states.world.robots[t, 0, :2], s["robots"][0][:2], atol=1e-4)
        dth = np.angle(np.exp(1j * (states.world.robots[t, 0, 2] - s["robots"][0][2])))
        assert abs(dth) < 1e-4
        np.testing.assert_allclose(states.world.ball[t], s["ball"], atol=1e-4)
        assert rew[t] == ref["reward"][t] and term[t] == ref["terminated"][t]
        assert trunc[t] == ref["truncated"][t]
        if t in cam_steps:
            err = np.abs(obs[t] - cam(s))
            assert np.all(err <= OBS_TOL), (t, obs[t], cam(s))
    return ref


def test_matches_reference_world_and_camera(env):
    """A whole episode (to goal or time limit) at easy and full starts, world every step,
    camera features at evenly spread steps (the NumPy camera reference is slow)."""
    p = env.default_params
    ends = []
    for i, d in enumerate([0.0, 1.0]):
        ref = _episode_vs_reference(env, p.replace(start_difficulty=d), jax.random.key(10 + i),
                                    n_cam=8, seed=i)
        ends.append(len(ref["states"]))
    assert min(ends) >= 1


@pytest.mark.slow
def test_matches_reference_camera_every_step(env):
    p = env.default_params
    for i in range(3):
        _episode_vs_reference(env, p.replace(start_difficulty=0.3 * i), jax.random.key(20 + i),
                              n_cam=10**6, seed=20 + i)


def test_reset_step_shapes_dtypes(env, short, jitted):
    p = short
    obs, st = jitted["reset"](jax.random.key(0), p)
    assert obs.shape == (9,) and obs.dtype == jnp.float32
    assert st.world.robots.shape == (1, 3) and st.world.robots.dtype == jnp.float32
    assert st.step.dtype == jnp.int32
    obs, st2, r, te, tr, info = jitted["step"](jax.random.key(1), st, jnp.int32(8), p)
    assert obs.shape == (9,) and obs.dtype == jnp.float32 and r.dtype == jnp.float32
    assert te.dtype == jnp.bool_ and tr.dtype == jnp.bool_
    assert set(info) >= {"success", "episode_done", "episode_length"}
    assert int(st2.step) == 1 and int(info["episode_length"]) == 1


def test_split_observation_equals_reset_and_step(env, short, jitted):
    """A loop that observes inside its body (``reset_state`` / ``step_state`` carried,
    ``get_obs`` of the carried state) sees the obs, states and rewards of a plain loop over
    ``reset`` / ``step`` with the same keys, across auto-resets and with pixel noise on (its
    draws follow the state through the loop)."""
    p = short.replace(camera=short.camera.replace(pixel_noise_std=2.0),
                      noise_on=short.noise_on.replace(pixel=True))
    n = 32
    k_reset, k_run = jax.random.split(jax.random.key(3))
    keys = jax.random.split(k_run, n)
    acts = jnp.asarray(np.random.default_rng(0).integers(0, 9, n), jnp.int32)

    @jax.jit
    def split_loop(k_reset, keys, acts):
        def body(c, x):
            st, eps = c
            k, a = x
            obs = env.get_obs(st, p, eps)
            st2, eps2, r, te, tr, _ = env.step_state(k, st, a, p)
            return (st2, eps2), (obs, st, r, te | tr)

        return jax.lax.scan(body, env.reset_state(k_reset, p), (keys, acts))[1]

    obs, states, rew, done = split_loop(k_reset, keys, acts)
    o, st = jax.jit(env.reset)(k_reset, p)
    step = jax.jit(env.step)
    for t in range(n):
        np.testing.assert_array_less(np.abs(np.asarray(obs[t]) - np.asarray(o)), OBS_TOL)
        jax.tree.map(lambda a, b, t=t: np.testing.assert_allclose(a[t], b, rtol=1e-6, atol=1e-6),
                     states, st)
        o, st, r, te, tr, _ = step(keys[t], st, acts[t], p)
        assert float(rew[t]) == float(r) and bool(done[t]) == bool(te | tr)
    assert int(np.sum(np.asarray(done))) >= 2  # the loop crossed auto-resets


def test_vmapped_batch_equals_loop_of_single_episodes(env, short, jitted):
    n, T = 4, 25
    keys = jax.random.split(jax.random.key(5), n)
    acts = jax.random.randint(jax.random.key(6), (T, n), 0, 9, jnp.int32)
    step_keys = jax.random.split(jax.random.key(7), (T, n))

    @jax.jit
    def batch(keys, acts, step_keys):
        obs, st = jax.vmap(env.reset, (0, None))(keys, short)

        def body(st, xs):
            a, k = xs
            o, st, r, te, tr, info = jax.vmap(env.step, (0, 0, 0, None))(k, st, a, short)
            return st, (o, r, info["episode_done"], st.world.ball)

        return jax.lax.scan(body, st, (acts, step_keys))[1]

    b_obs, b_r, b_done, b_ball = batch(keys, acts, step_keys)
    assert np.asarray(b_done).sum() >= n * 2  # 10-step limit: every env reset twice
    for i in range(n):
        _, st = jitted["reset"](keys[i], short)
        for t in range(T):
            o, st, r, te, tr, info = jitted["step"](step_keys[t, i], st, acts[t, i], short)
            np.testing.assert_allclose(o, b_obs[t, i], rtol=1e-5, atol=1e-4)
            np.testing.assert_allclose(st.world.ball, b_ball[t, i], atol=1e-6)
            assert bool(info["episode_done"]) == bool(b_done[t, i]) and r == b_r[t, i]


def test_step_compiles_once(env, short, jitted):
    step = jitted["step"]  # jit(chex.assert_max_traces(env.step, n=1)), shared by the module
    _, st = jitted["reset"](jax.random.key(0), short)
    for i, d in enumerate([0.0, 0.5, 1.0]):
        p = short.replace(start_difficulty=d)
        out = step(jax.random.key(i), st, jnp.int32(i), p)
        st = out[1]
    # a new static value (time limit) is a new program: that retrace is expected to fail
    with pytest.raises(AssertionError):
        step(jax.random.key(9), st, jnp.int32(0), short.replace(max_steps=11))


def test_auto_reset_draws_fresh_start(env, short, jitted):
    _, st = jitted["reset"](jax.random.key(3), short)
    starts = [np.asarray(st.world.robots)]
    for t in range(30):
        _, st, r, te, tr, info = jitted["step"](jax.random.key(100 + t), st, jnp.int32(4), short)
        if (t + 1) % 10 == 0:
            assert bool(info["episode_done"]) and bool(tr) and not bool(te)
            assert int(info["episode_length"]) == 10 and int(st.step) == 0
            starts.append(np.asarray(st.world.robots))
        else:
            assert not bool(info["episode_done"]) and int(st.step) == (t + 1) % 10
    starts = np.array(starts)
    assert len({tuple(s.ravel().round(5)) for s in starts}) == len(starts)  # all different


def test_goal_gives_reward_and_ends_episode(short, jitted):
    p = short
    world = make_state([[3.0, 1.0, 0.0]], [3.95, 0.0], [2.0, 0.0])
    st = ShootingState(world=world, step=jnp.int32(5))
    _, st1, r, te, tr, info = jitted["step_env"](jax.random.key(0), st, jnp.int32(4), p)
    assert float(r) == 1.0 and bool(te) and not bool(tr) and bool(info["success"])
    _, st2, r, te, tr, info = jitted["step"](jax.random.key(0), st, jnp.int32(4), p)
    assert float(r) == 1.0 and bool(info["episode_done"]) and int(info["episode_length"]) == 6
    assert int(st2.step) == 0 and not bool(st2.world.scored)


def test_ball_leaving_the_field_ends_episode_without_reward():
    env = ShootingEnv()
    p = env.default_params
    p = p.replace(world=p.world.replace(field=p.world.field.replace(walls=False)))
    world = make_state([[0.0, 0.0, 0.0]], [4.05, 1.5], [2.0, 0.0])
    st = ShootingState(world=world, step=jnp.int32(0))
    _, _, r, te, tr, info = jax.jit(env.step_env)(jax.random.key(0), st, jnp.int32(4), p)
    assert float(r) == 0.0 and bool(te) and bool(info["ball_out"]) and not bool(info["success"])


def test_start_difficulty_moves_starts_outward(env):
    p = env.default_params
    wp = p.world
    L2, W2 = wp.field.length / 2, wp.field.width / 2
    rr, rb = wp.robot.radius, wp.ball.radius
    keys = jax.random.split(jax.random.key(11), 512)
    draw = jax.jit(jax.vmap(env.sample_start, (0, None)))
    mean_dist = []
    for d in [0.0, 0.5, 1.0]:
        w = jax.tree_util.tree_map(np.asarray, draw(keys, p.replace(start_difficulty=d)))
        r, b = w.robots[:, 0], w.ball
        assert np.all(np.linalg.norm(b - r[:, :2], axis=1) >= rr + rb)
        assert np.all(np.abs(r[:, 0]) <= L2 - rr) and np.all(np.abs(r[:, 1]) <= W2 - rr)
        assert np.all(np.abs(b[:, 0]) <= L2 - rb) and np.all(np.abs(b[:, 1]) <= W2 - rb)
        mean_dist.append(np.mean(np.hypot(L2 - r[:, 0], r[:, 1])))
        if d == 0.0:
            sp = p.start
            assert np.all(np.abs(r[:, 0] - (L2 - sp.easy_goal_dist)) <= sp.easy_jitter_xy + 1e-6)
            assert np.all(np.abs(r[:, 2]) <= np.deg2rad(sp.easy_jitter_deg) + 1e-6)
            rel = b - r[:, :2]
            assert np.all(rel[:, 0] > 0.25)  # ball in front
        if d == 1.0:
            assert np.std(r[:, 2]) > 1.5  # headings spread over the circle
    assert mean_dist[0] < mean_dist[1] < mean_dist[2]


def test_easy_starts_are_easy(env):
    """Driving straight forward scores from most easy starts, rarely from full starts."""
    p = env.default_params.replace(max_steps=60)
    n = 64

    @jax.jit
    def rate(p, keys):
        def one(k):
            _, st = env.reset(k, p)
            acts = jnp.full((60,), 8, jnp.int32)
            return jnp.sum(_rollout_env(env, p, st, acts)[2])
        return jnp.mean(jax.vmap(one)(keys))

    keys = jax.random.split(jax.random.key(1), n)
    easy = float(rate(p.replace(start_difficulty=0.0), keys))
    full = float(rate(p.replace(start_difficulty=1.0), keys))
    assert easy > 0.7 and full < 0.3, (easy, full)


def test_bad_inputs_raise_clear_errors(env, short, jitted):
    p = env.default_params
    _, st = jitted["reset"](jax.random.key(0), short)  # a valid state (jitted: fast)
    k = jax.random.key(1)
    with pytest.raises(ValueError, match=r"out of range.*\[0, 8\]"):
        env.step(k, st, 9, p)
    with pytest.raises(ValueError, match="out of range"):
        env.step(k, st, jnp.int32(-1), p)
    with pytest.raises(ValueError, match="integer"):
        env.step(k, st, 1.0, p)
    with pytest.raises(ValueError, match="shape"):
        env.step(k, st, jnp.array([1, 2], jnp.int32), p)
    with pytest.raises(ValueError, match="expected"):
        env.step(k, st.replace(world=st.world.replace(ball=jnp.zeros(3, jnp.float32))), 1, p)
    bad = p.replace(world=p.world.replace(ball=p.world.ball.replace(radius=-0.11)))
    with pytest.raises(ParamError, match="radius"):
        env.step(k, st, 1, bad)
    with pytest.raises(ParamError, match="radius"):
        ShootingEnv(params=bad)
    with pytest.raises(ParamError, match="start_difficulty"):
        env.reset(k, p.replace(start_difficulty=1.5))
    with pytest.raises(ParamError, match="robot_kinds"):
        env.validate(p.replace(world=p.world.replace(robot_kinds=("four_wheel",))))
    with pytest.raises(ParamError, match="ShootingParams"):
        env.validate(p.world)
    with pytest.raises(ValueError, match="robot_kind"):
        ShootingEnv("tank")


def test_four_wheel_robot_env():
    env = ShootingEnv("four_wheel")
    assert env.num_actions == 7 and env.action_labels[1] == "F"
    assert isinstance(env.default_params, ShootingParams)
    obs, st = env.reset(jax.random.key(0))
    obs, st, *_ = env.step(jax.random.key(1), st, 6)
    assert obs.shape == (9,)
    with pytest.raises(ValueError, match=r"\[0, 6\]"):
        env.step(jax.random.key(1), st, 7)
