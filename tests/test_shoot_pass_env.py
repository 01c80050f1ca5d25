"""Two-robot shooting/passing env, scripted agents, kicks and the noise model."""

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from tests.reference import world_np
from vbl.envs.noise import NoiseParams, eccentric_centroid, noisy_camera, perturb_ball_velocity
from vbl.envs.other_agents import OtherAgentParams, act, init_memory
from vbl.envs.shoot_pass import (
    EASY_PASS,
    EASY_SHOOT,
    OBS_SLICES,
    START_DRAWS,
    ShootPassEnv,
    ShootPassParams,
    ShootPassState,
    apply_kicks,
)
from vbl.params import ParamError
from vbl.vision.camera import CameraParams
from vbl.vision.section3 import flatten_section3, section3_features
from vbl.world.physics import goal_corners, make_state
from vbl.world.robots import FOUR_WHEEL_LABELS

B = 24
T = 40


@pytest.fixture(scope="module")
def env():
    return ShootPassEnv("shoot")


@pytest.fixture(scope="module")
def step_jit(env):
    @jax.jit
    @chex.assert_max_traces(n=1)
    def step(key, state, action, params):
        return env.step(key, state, action, params)
    return step


@pytest.fixture(scope="module")
def batch_run(env):
    """T steps of B envs, learner stands still (action 0), via jit(vmap(step))."""
    p = env.default_params
    vreset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    vstep = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    obs, st = vreset(jax.random.split(jax.random.PRNGKey(0), B), p)
    keys = jax.random.split(jax.random.PRNGKey(1), T * B).reshape(T, B, 2)
    acts = jax.random.randint(jax.random.PRNGKey(2), (T, B), 0, 7, jnp.int32)
    states, infos, obss = [st], [], [obs]
    for t in range(T):
        obs, st, r, te, tr, info = vstep(keys[t], st, jnp.zeros(B, jnp.int32), p)
        states.append(st)
        infos.append(info)
        obss.append(obs)
    return dict(states=states, infos=infos, obs=obss, keys=keys, acts=acts, vstep=vstep)


def test_reset_shapes_dtypes(env, batch_run):
    obs = batch_run["obs"][0]
    st = batch_run["states"][0]
    assert obs.shape == (B, 26) and obs.dtype == jnp.float32
    assert st.world.robots.shape == (B, 2, 3) and st.world.robots.dtype == jnp.float32
    assert st.step.dtype == jnp.int32 and st.phase.dtype == jnp.float32
    info = batch_run["infos"][0]
    assert info["u"].shape == (B, 2) and info["u"].dtype == jnp.float32
    assert info["success"].dtype == jnp.bool_
    assert env.num_actions == 7 and env.obs_slices == OBS_SLICES
    assert np.all(np.isfinite(np.asarray(batch_run["obs"])))


def test_jit_vmap_equals_loop(env, step_jit, batch_run):
    p = env.default_params
    st0 = batch_run["states"][0]
    keys, acts = batch_run["keys"], batch_run["acts"]
    vstep = batch_run["vstep"]
    st_b = st0
    for t in range(4):
        obs_b, st_b, r_b, *_ = vstep(keys[t], st_b, acts[t], p)
    for i in range(3):
        st = jax.tree_util.tree_map(lambda x, i=i: x[i], st0)
        for t in range(4):
            obs, st, r, *_ = step_jit(keys[t, i], st, acts[t, i], p)
        np.testing.assert_allclose(obs, obs_b[i], rtol=1e-5, atol=1e-3)
        np.testing.assert_allclose(st.world.ball, st_b.world.ball[i], rtol=1e-5, atol=1e-6)


def test_step_compiles_once(env, step_jit, batch_run):
    p = env.default_params
    st = jax.tree_util.tree_map(lambda x: x[5], batch_run["states"][3])
    p2 = p.replace(shooter_kick_speed=1.5, other=p.other.replace(aim_noise_deg=10.0))
    for a in (0, 3):
        step_jit(jax.random.PRNGKey(a), st, jnp.int32(a), p2)  # no retrace (max_traces=1)


def test_obs_equals_section3_features(env, batch_run):
    """The learner's obs is section3_features of the shooter's camera (noise off)."""
    p = env.default_params
    features = jax.jit(lambda *a: flatten_section3(section3_features(*a)))
    for t in (0, 10, 25):
        st = batch_run["states"][t]
        obs = batch_run["obs"][t]
        for i in (0, 7):
            w = jax.tree_util.tree_map(lambda x, i=i: x[i], st.world)
            ref = features(
                w.robots[0], w.ball, p.world.ball.radius, goal_corners(p.world), w.robots[1],
                jnp.array([0.4, 0.4, p.robot_height], jnp.float32), p.shooter_camera)
            np.testing.assert_allclose(obs[i], ref, rtol=1e-5, atol=1e-3)


def test_scripted_passer_delivers(batch_run):
    """With the shooter standing still, the passer kicks and the ball comes within 0.45 m of
    the shooter in most first episodes."""
    reached = np.zeros(B, bool)
    kicked = np.zeros(B, bool)
    alive = np.ones(B, bool)
    for st_prev, info in zip(batch_run["states"][:-1], batch_run["infos"], strict=True):
        d = np.linalg.norm(np.asarray(st_prev.world.ball - st_prev.world.robots[:, 0, :2]), axis=1)
        reached |= alive & (d < 0.45)
        kicked |= alive & np.asarray(info["kicked"])
        alive &= ~np.asarray(info["episode_done"])
    assert kicked.mean() >= 0.8
    assert reached.mean() >= 0.8
    # a shooter standing still never scores
    assert not any(np.asarray(i["success"]).any() for i in batch_run["infos"])


def _hand_state(robots, ball, vel, touched):
    w = make_state(robots, ball, vel)
    mem = init_memory(jnp.zeros(2, jnp.float32), OtherAgentParams())
    return ShootPassState(world=w, step=jnp.int32(3), memory=mem.replace(kicked=jnp.bool_(True)),
                          touched=jnp.bool_(touched), kicked=jnp.bool_(True),
                          phase=jnp.float32(0.0))


def test_success_detection_shoot(env, step_jit):
    p = env.default_params
    half = p.world.field.length / 2
    robots = [[0.0, 0.0, 0.0], [-2.0, 1.5, 0.0]]
    ball = [half - 0.05, 0.0]
    for touched in (True, False):
        st = _hand_state(robots, ball, [1.0, 0.0], touched)
        _, _, r, te, tr, info = step_jit(jax.random.PRNGKey(0), st, jnp.int32(0), p)
        assert bool(info["goal"]) and bool(te) and not bool(tr)
        assert bool(info["success"]) == touched and float(r) == float(touched)
    # ball rolling in the field, not touched: no success, not done
    st = _hand_state(robots, [0.0, 1.5], [0.5, 0.0], False)
    _, _, r, te, tr, info = step_jit(jax.random.PRNGKey(0), st, jnp.int32(0), p)
    assert not bool(info["success"]) and not bool(te)


@pytest.mark.slow  # compiles the pass env
def test_success_detection_pass():
    env = ShootPassEnv("pass")
    p = env.default_params
    # ball rolling towards the (waiting) shooter, 0.5 m away at 1 m/s: inside 0.45 m next step
    st = _hand_state([[0.0, 0.0, 0.0], [2.0, 1.0, 3.0]], [0.5, 0.0], [-1.0, 0.0], False)
    _, _, r, te, _, info = env.step_env(jax.random.PRNGKey(0), st, jnp.int32(0), p)
    assert bool(info["success"]) and bool(te) and float(r) == 1.0
    # pass starts: ball rolling, nothing decided at reset
    _, st = env.reset(jax.random.PRNGKey(3), p)
    assert float(jnp.linalg.norm(st.world.ball_vel)) >= p.start.pass_ball_speed_min - 1e-6


def test_kicks_reference():
    w = make_state([[0.0, 0.0, 0.0], [2.0, 2.0, 0.0]], [0.3, 0.0])
    touch = jnp.array([True, False])
    speeds = jnp.array([2.0, 1.0], jnp.float32)
    aim = jnp.array([-1, -1], jnp.int32)
    zero = jnp.zeros(2, jnp.float32)
    k = jnp.zeros(2, jnp.float32)  # aim errors (standard normals; the aim noise is 0 here)
    still = dict(incoming=jnp.zeros(2, jnp.float32), restitution=0.5)  # a resting ball
    w2, kicked = apply_kicks(k, w, touch, jnp.array([1, 0], jnp.int32), speeds, aim, zero, 30.0,
                            **still)
    np.testing.assert_allclose(w2.ball_vel, [2.0, 0.0], atol=1e-6)
    assert kicked.tolist() == [True, False]
    # driving backwards or ball behind: no kick
    w3, kicked = apply_kicks(k, w, touch, jnp.array([4, 0], jnp.int32), speeds, aim, zero, 30.0,
                             **still)
    assert not kicked.any() and np.allclose(w3.ball_vel, 0)
    # aimed kick towards robot 1 at (2, 2) from the ball at (0.3, 0)
    w4, _ = apply_kicks(k, w, touch, jnp.array([1, 0], jnp.int32), speeds,
                        jnp.array([1, -1], jnp.int32), zero, 30.0, **still)
    d = np.array([1.7, 2.0]) / np.linalg.norm([1.7, 2.0])
    np.testing.assert_allclose(w4.ball_vel, 2.0 * d, atol=1e-5)
    # a rolling ball: the heading kick adds to the incoming velocity (the reference's bounce
    # off a moving face), the aimed pass ignores it
    v_in = np.array([-1.0, 0.6], np.float32)
    rolling = dict(incoming=jnp.asarray(v_in), restitution=0.5)
    w5, _ = apply_kicks(k, w, touch, jnp.array([1, 0], jnp.int32), speeds, aim, zero, 30.0,
                        **rolling)
    np.testing.assert_allclose(w5.ball_vel, world_np.kick_np(v_in, 0.0, 2.0, 0.5), atol=1e-6)
    w6, _ = apply_kicks(k, w, touch, jnp.array([1, 0], jnp.int32), speeds,
                        jnp.array([1, -1], jnp.int32), zero, 30.0, **rolling)
    np.testing.assert_allclose(w6.ball_vel, 2.0 * d, atol=1e-5)


def test_scripted_behaviours():
    p = OtherAgentParams(max_delay=0)
    mem = init_memory(jnp.zeros(2, jnp.float32), p)
    k = jnp.full(2, 0.5, jnp.float32)  # uniform draws (used by the random walk only)
    # robot 1 at the origin facing +x; ball ahead / to the left / to the right
    for ball, want in (([1.0, 0.0], 1), ([1.0, 1.0], 2), ([1.0, -1.0], 3)):
        w = make_state([[5.0, 5.0, 0.0], [0.0, 0.0, 0.0]], ball)
        assert int(act("move_to_ball", k, w, mem, 1, p)[0]) == want
        assert int(act("passer", k, w, mem, 1, p)[0]) == want
        assert int(act("passer", k, w, mem.replace(kicked=jnp.bool_(True)), 1, p)[0]) == 0
        assert int(act("stationary", k, w, mem, 1, p)[0]) == 0
    waiting = mem.replace(delay=jnp.int32(5))
    assert int(act("passer", k, w, waiting, 1, p)[0]) == 0
    keep = OtherAgentParams(walk_switch_prob=0.0)
    a, m2 = act("random_walk", k, w, mem.replace(action=jnp.int32(4)), 1, keep)
    assert int(a) == 4 and int(m2.t) == 1
    with pytest.raises(ValueError, match="behaviour"):
        act("dance", k, w, mem, 1, p)


def test_noise_model_pieces():
    obs = jnp.array([10.0, 20.0, 40.0, 30.0], jnp.float32)
    n = NoiseParams(ecc_centroid=0.5)
    out = eccentric_centroid(obs, jnp.float32(1.0), jnp.float32(np.pi / 2), n)
    np.testing.assert_allclose(out, [10.0, 27.5, 40.0, 30.0], atol=1e-5)
    assert np.allclose(eccentric_centroid(obs, jnp.float32(0.0), jnp.float32(1.0), n), obs)
    v = perturb_ball_velocity(jnp.float32(1.3), jnp.array([0.6, 0.8], jnp.float32),
                              jnp.float32(0.1), jnp.float32(0.11), NoiseParams(ecc_turn_std=1.0))
    assert abs(float(jnp.linalg.norm(v)) - 1.0) < 1e-5
    cam = noisy_camera(CameraParams(pixel_noise_std=3.0), NoiseParams(image_std=4.0))
    assert abs(float(cam.pixel_noise_std) - 5.0) < 1e-5


def test_bad_inputs(env, batch_run):
    with pytest.raises(ValueError, match="task"):
        ShootPassEnv("dribble")
    p = env.default_params
    with pytest.raises(ParamError, match="shooter_x_min"):
        env.validate(p.replace(start=p.start.replace(shooter_x_min=3.0)))
    with pytest.raises(ParamError, match="receive_distance"):
        ShootPassEnv("pass", p.replace(receive_distance=1.0))
    with pytest.raises(ParamError):
        env.validate(p.replace(kick_cone_deg=-1.0))
    st = jax.tree_util.tree_map(lambda x: x[0], batch_run["states"][0])
    k = jax.random.PRNGKey(0)
    for bad, msg in ((7, "out of range"), (-1, "out of range"), (1.0, "integer"),
                     (np.array([1, 2]), "scalar")):
        with pytest.raises(ValueError, match=msg):
            env.step(k, st, bad, p)
    with pytest.raises(ValueError, match="vmap"):
        env.step(k, batch_run["states"][0], 0, p)


@pytest.mark.slow  # compiles the fixed pass env and the select env
def test_select_task_matches_fixed_tasks():
    """ShootPassEnv("select") with the traced task_pass reproduces the fixed-task envs: from
    the states of a fixed-task rollout, one step of each env with the same key and action
    gives the same observation, reward and ends (one-step comparison: float32 rounding
    differs slightly, and a whole rollout would amplify it). One compilation serves both
    roles."""
    sel = ShootPassEnv("select")
    n, steps = 8, 40
    acts = jax.random.randint(jax.random.PRNGKey(5), (steps, n), 0, 7, jnp.int32)
    keys = jax.random.split(jax.random.PRNGKey(6), steps * n).reshape(steps, n, 2)

    def one_step(e, p, states):
        o, _, r, te, tr, info = jax.vmap(jax.vmap(
            lambda k, s, a: e.step(k, s, a, p)))(keys, states, acts)
        return o, r, te, tr, info["success"], info["u"]

    sel_step = jax.jit(chex.assert_max_traces(n=1)(lambda p, s: one_step(sel, p, s)))
    for task, flag in (("shoot", False), ("pass", True)):
        fixed = ShootPassEnv(task)
        p = fixed.default_params

        @jax.jit
        def rollout(p, fixed=fixed):
            _, st = jax.vmap(fixed.reset, in_axes=(0, None))(
                jax.random.split(jax.random.PRNGKey(4), n), p)

            def body(st, x):
                k, a = x
                st2 = jax.vmap(fixed.step, in_axes=(0, 0, 0, None))(k, st, a, p)[1]
                return st2, st

            return jax.lax.scan(body, st, (keys, acts))[1]

        states = rollout(p)
        ref = jax.jit(lambda p, s, fixed=fixed: one_step(fixed, p, s))(p, states)
        got = sel_step(sel.default_params.replace(task_pass=jnp.asarray(flag)), states)
        for a, b in zip(ref[1:], got[1:], strict=True):  # reward, ends, success, u: exact
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_allclose(np.asarray(ref[0]), np.asarray(got[0]), rtol=1e-4, atol=0.05)


# Starts of jax.vmap(env.reset)(split(PRNGKey(7), 3)) at the default params, recorded from
# the code before start_difficulty existed: the default (1.0) must reproduce them exactly.
GOLDEN_ROBOTS = {
    "shoot": [[[1.6275815963745117, 0.06757724285125732, -0.2607390880584717],
               [3.7319188117980957, -0.5576218962669373, 2.8283445835113525]],
              [[1.377673625946045, 0.3914117217063904, -0.27698230743408203],
               [2.9478139877319336, -0.32470792531967163, 2.818192720413208]],
              [[0.7677973508834839, -0.28987041115760803, -0.13135719299316406],
               [2.3773584365844727, -0.8671877384185791, 2.7143216133117676]]],
    "pass": [[[1.6275815963745117, 0.06757724285125732, -0.2607390880584717],
              [3.7319188117980957, -0.5576218962669373, 2.706075429916382]],
             [[1.377673625946045, 0.3914117217063904, -0.27698230743408203],
              [2.9478139877319336, -0.32470792531967163, -2.9424736499786377]],
             [[0.7677973508834839, -0.28987041115760803, -0.13135719299316406],
              [2.3773584365844727, -0.8671877384185791, 2.2998993396759033]]]}
GOLDEN_BALL = {
    "shoot": [[3.257368564605713, -0.4166329503059387], [2.3594512939453125, -0.05636373162269592],
              [1.748168706893921, -0.641510009765625]],
    "pass": [[2.989389419555664, -0.409157931804657], [2.0561165809631348, -0.02419654279947281],
             [1.4997674226760864, -0.46417486667633057]]}
GOLDEN_VEL_PASS = [[0.3449153006076813, -0.28453195095062256],
                   [0.29525256156921387, -0.29437196254730225],
                   [0.4056597650051117, -0.07632317394018173]]


@pytest.mark.parametrize("task", ["shoot", "pass"])
def test_default_start_difficulty_is_the_full_draw_bit_for_bit(task):
    e = ShootPassEnv(task)
    p = e.default_params
    assert p.start_difficulty == 1.0
    # reset's state, without its observation (the camera, op by op, took 10 s)
    st, _ = jax.vmap(e.reset_state, (0, None))(jax.random.split(jax.random.PRNGKey(7), 3), p)
    np.testing.assert_array_equal(st.world.robots, np.float32(GOLDEN_ROBOTS[task]))
    np.testing.assert_array_equal(st.world.ball, np.float32(GOLDEN_BALL[task]))
    vel = GOLDEN_VEL_PASS if task == "pass" else np.zeros((3, 2))
    np.testing.assert_array_equal(st.world.ball_vel, np.float32(vel))
    # the start uniforms pass unchanged at difficulty 1, also traced
    u = jax.random.uniform(jax.random.PRNGKey(3), (64, START_DRAWS), jnp.float32)
    u = u.at[0].set(0.0).at[1].set(np.nextafter(np.float32(1), np.float32(0)))
    eased = jax.jit(jax.vmap(e.eased_uniform, (0, None)))(u, p)
    np.testing.assert_array_equal(eased, u)


def test_start_difficulty_interpolates_the_uniforms():
    """Draws with an easy value move to it at difficulty 0, halfway at 0.5; the others
    (nan in EASY_*) keep their draw."""
    u = jax.random.uniform(jax.random.PRNGKey(4), (START_DRAWS,), jnp.float32)
    for task, easy in (("shoot", EASY_SHOOT), ("pass", EASY_PASS)):
        e = ShootPassEnv(task)
        easy = np.asarray(easy, np.float32)
        keep = np.isnan(easy)
        for d in (0.0, 0.5):
            got = np.asarray(e.eased_uniform(u, e.default_params.replace(start_difficulty=d)))
            want = np.where(keep, u, easy + d * (np.asarray(u) - easy))
            np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)
    with pytest.raises(ParamError, match="start_difficulty"):
        ShootPassEnv("shoot").validate(ShootPassParams(start_difficulty=1.5))


def test_easy_starts_are_easier():
    """A learner that only drives forward (action F) from 512 starts per cell, one compiled
    program for both tasks and difficulties ("select" env, traced task and difficulty): it
    scores (shoot) or passes far more often at difficulty 0 than from the full draw."""
    e = ShootPassEnv("select")
    n, steps = 512, 100
    fwd = FOUR_WHEEL_LABELS.index("F")

    def rate(task_pass, d, key):
        p = e.default_params.replace(task_pass=task_pass, start_difficulty=d)
        k0, k1 = jax.random.split(key)
        _, st = jax.vmap(e.reset, (0, None))(jax.random.split(k0, n), p)

        def body(c, k):
            st, done, succ = c
            _, st, _, term, trunc, info = jax.vmap(e.step_env, (0, 0, None, None))(
                jax.random.split(k, n), st, jnp.int32(fwd), p)
            return (st, done | term | trunc, succ | (~done & info["success"])), None

        z = jnp.zeros(n, bool)
        (_, _, succ), _ = jax.lax.scan(body, (st, z, z), jax.random.split(k1, steps))
        return jnp.mean(succ)

    tp = jnp.array([False, False, True, True])
    d = jnp.array([0.0, 1.0, 0.0, 1.0], jnp.float32)
    r = np.asarray(jax.jit(jax.vmap(rate, (0, 0, None)))(tp, d, jax.random.PRNGKey(0)))
    shoot_easy, shoot_full, pass_easy, pass_full = r
    se = np.sqrt(0.25 * 2 / n)  # largest binomial standard error of a difference
    assert shoot_easy - shoot_full > 4 * se, r
    assert pass_easy - pass_full > 4 * se, r


def test_a_shoot_episode_starts_with_a_still_ball_and_no_kick():
    """The shooting task's start: the ball lies still and nobody has kicked yet (the
    scripted passer first drives to the ball)."""
    env = ShootPassEnv("shoot")
    states = jax.jit(jax.vmap(lambda k: env.reset(k, env.default_params)[1]))(
        jax.random.split(jax.random.PRNGKey(5), 64))
    assert float(jnp.abs(states.world.ball_vel).max()) == 0.0
    assert not np.any(np.asarray(states.kicked)) and not np.any(np.asarray(states.memory.kicked))
