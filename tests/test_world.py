"""Soccer-world physics: NumPy reference agreement, analytic kinematics, invariants, errors."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401  (enables x64; the world must stay float32 anyway)
from tests.reference import world_np
from vbl.params import ParamError, validate
from vbl.world import (
    FOUR_WHEEL_U,
    TWO_MOTOR_LABELS,
    TWO_MOTOR_MOTORS,
    WorldParams,
    check_actions,
    goal_corners,
    kick_velocity,
    make_state,
    num_actions,
    world_step,
)

P = WorldParams()
L2, W2, G2 = P.field.length / 2, P.field.width / 2, P.goal.width / 2
RB, RR = P.ball.radius, P.robot.radius


def _with(p, **kw):
    """Replace nested fields: _with(p, ball__drag=0.0, substeps=2)."""
    for k, v in kw.items():
        parts = k.split("__")
        if len(parts) == 1:
            p = p.replace(**{k: v})
        else:
            p = p.replace(**{parts[0]: getattr(p, parts[0]).replace(**{parts[1]: v})})
    return validate(p)


def rollout(params, state, actions, key):
    """JAX trajectory of T primitives: actions (T, R) -> stacked states and events."""

    def body(s, xs):
        k, a = xs
        eps = jax.random.normal(k, (len(params.robot_kinds), 2), jnp.float32)
        s, ev = world_step(s, a, params, slip_eps=eps)
        return s, (s, ev)

    keys = jax.random.split(key, actions.shape[0])
    return jax.lax.scan(body, state, (keys, jnp.asarray(actions, jnp.int32)))[1]


_rollout_jit = jax.jit(rollout)
T_STD = 60  # one trace length for the short tests, so they share compilations


def _rollout(params, state, actions, key=None):
    """Jitted rollout padded to T_STD primitives (extra steps: stop); numpy outputs."""
    actions = np.asarray(actions, np.int32)
    T = actions.shape[0]
    if T < T_STD:
        stop = np.array([4 if k == "two_motor" else 0 for k in params.robot_kinds], np.int32)
        actions = np.concatenate([actions, np.tile(stop, (T_STD - T, 1))])
    key = jax.random.key(0) if key is None else key
    out = _rollout_jit(params, state, actions, key)
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[:T], out)


def _np_state(robots, ball, vel=(0.0, 0.0)):
    return dict(robots=[list(map(float, r)) for r in robots], ball=list(map(float, ball)),
                vel=list(map(float, vel)), scored=False, out=False)


def _biased_actions(rng, T, kinds):
    """Random actions, mostly straight forward so the ball gets pushed about."""
    cols = []
    for kind in kinds:
        fwd = 8 if kind == "two_motor" else 1
        a = rng.integers(0, num_actions(kind), T)
        cols.append(np.where(rng.random(T) < 0.5, fwd, a))
    return np.stack(cols, axis=1).astype(np.int32)


CONFIGS = {
    "one_two_motor": dict(robot_kinds=("two_motor",)),
    "two_robots_mixed": dict(robot_kinds=("two_motor", "four_wheel")),
    "walls_off": dict(robot_kinds=("two_motor",), field__walls=False),
}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_matches_numpy_reference_step_by_step(name):
    params = _with(P, **CONFIGS[name])
    kinds = params.robot_kinds
    rng = np.random.default_rng(len(name))
    T, n_ep = 300, 4
    for ep in range(n_ep):
        r0 = [[rng.uniform(1.0, 3.5), rng.uniform(-1.5, 1.5), rng.uniform(-np.pi, np.pi)]
              for _ in kinds]
        # ball close to the first robot so contacts happen
        ang = rng.uniform(-0.6, 0.6) + r0[0][2]
        ball = [r0[0][0] + 0.4 * math.cos(ang), r0[0][1] + 0.4 * math.sin(ang)]
        if len(kinds) > 1:
            r0[1] = [r0[0][0] - 0.6, r0[0][1] + 0.2, r0[0][2]]
        vel = rng.normal(0, 1.0, 2) if ep % 2 else np.zeros(2)
        acts = _biased_actions(rng, T, kinds)
        traj, ev = _rollout(params, make_state(r0, ball, vel), acts)
        assert traj.robots.dtype == jnp.float32 and traj.ball.dtype == jnp.float32
        s = _np_state(r0, ball, vel)
        for t in range(T):
            s, e = world_np.step_world(s, acts[t], params)
            dth = np.angle(np.exp(1j * (np.array(s["robots"])[:, 2] - traj.robots[t, :, 2])))
            np.testing.assert_allclose(traj.robots[t, :, :2], np.array(s["robots"])[:, :2],
                                       atol=1e-4, err_msg=f"{name} ep {ep} step {t}")
            assert np.max(np.abs(dth)) < 1e-4
            np.testing.assert_allclose(traj.ball[t], s["ball"], atol=1e-4,
                                       err_msg=f"{name} ep {ep} step {t}")
            np.testing.assert_allclose(traj.ball_vel[t], s["vel"], atol=1e-4)
            assert bool(ev.goal[t]) == e["goal"] and bool(ev.ball_out[t]) == e["ball_out"]
            assert list(np.asarray(ev.touch[t])) == e["touch"]


def test_action_tables_and_labels():
    assert TWO_MOTOR_MOTORS.shape == (9, 2) and len(set(map(tuple, TWO_MOTOR_MOTORS))) == 9
    for a, (lm, rm) in enumerate(TWO_MOTOR_MOTORS):
        assert a == 3 * (lm + 1) + (rm + 1)
    assert TWO_MOTOR_LABELS[8] == "F" and TWO_MOTOR_LABELS[0] == "B"
    assert TWO_MOTOR_LABELS[4] == "S"
    assert FOUR_WHEEL_U.shape == (7, 2) and len(set(map(tuple, FOUR_WHEEL_U))) == 7
    assert tuple(FOUR_WHEEL_U[0]) == (0, 0)
    assert all(u[0] != 0 for u in FOUR_WHEEL_U[1:])  # steering only matters when moving


def test_kinematics_analytic():
    params = _with(P, robot_kinds=("two_motor", "two_motor", "four_wheel"))
    # far apart, no ball contact
    r0 = [[-3.0, -1.5, 0.0], [0.0, 1.5, 0.3], [2.5, 0.0, 0.0]]
    st = make_state(r0, [-3.5, 1.8])
    T = 20
    acts = np.tile(np.array([[8, 2, 2]], np.int32), (T, 1))  # F, spin left, four-wheel FL
    traj, _ = _rollout(params, st, acts)
    dt = P.action_dt
    v = P.two_motor.wheel_speed
    np.testing.assert_allclose(traj.robots[-1, 0], [-3.0 + v * dt * T, -1.5, 0.0], atol=1e-5)
    w = 2 * v / P.two_motor.track
    expect = (0.3 + w * dt * T + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(traj.robots[-1, 1, :2], [0.0, 1.5], atol=1e-6)
    assert abs(np.angle(np.exp(1j * (traj.robots[-1, 1, 2] - expect)))) < 1e-4
    # 4WS robot drives on a circle of radius wheelbase / (2 tan delta) to the left
    delta = np.deg2rad(P.four_wheel.max_steer_deg)
    radius = P.four_wheel.wheelbase / (2 * np.tan(delta))
    centre = np.array([2.5, radius])
    d = np.linalg.norm(np.asarray(traj.robots[:, 2, :2]) - centre, axis=1)
    np.testing.assert_allclose(d, radius, rtol=2e-3)
    omega = 2 * P.four_wheel.speed * np.tan(delta) / P.four_wheel.wheelbase
    assert abs(np.angle(np.exp(1j * (traj.robots[-1, 2, 2] - omega * dt * T)))) < 1e-4


def test_free_roll_slows_monotonically_and_analytically():
    # no drag: speed drops by rolling_decel * action_dt per primitive (walls far enough)
    p = _with(P, ball__drag=0.0)
    st = make_state([[-3.8, -2.0, 0.0]], [-2.0, 0.0], [1.5, 0.0])
    traj, _ = _rollout(p, st, np.full((10, 1), 4, np.int32))
    speed = np.linalg.norm(np.asarray(traj.ball_vel), axis=1)
    np.testing.assert_allclose(speed, 1.5 - P.ball.rolling_decel * P.action_dt
                               * np.arange(1, 11), atol=1e-5)
    # drag only: geometric decay (1 - drag h)^substeps per primitive
    p = _with(P, ball__rolling_decel=0.0)
    traj, _ = _rollout(p, st, np.full((10, 1), 4, np.int32))
    speed = np.linalg.norm(np.asarray(traj.ball_vel), axis=1)
    q = (1 - P.ball.drag * P.action_dt / P.substeps) ** P.substeps
    np.testing.assert_allclose(speed, 1.5 * q ** np.arange(1, 11), rtol=1e-5)
    # default friction, with wall bounces: speed never increases and reaches 0
    st = make_state([[-3.8, -2.0, 0.0]], [0.0, 0.0], [1.8, 1.2])
    traj, _ = _rollout(P, st, np.full((60, 1), 4, np.int32))
    speed = np.linalg.norm(np.asarray(traj.ball_vel), axis=1)
    assert np.all(np.diff(speed) <= 1e-7) and speed[-1] == 0.0


def test_kick_impulse_from_robot_velocity():
    p = _with(P, ball__drag=0.0, ball__rolling_decel=0.0)
    gap = 0.01
    st = make_state([[0.0, 0.0, 0.0]], [RR + RB + gap, 0.0])
    traj, ev = _rollout(p, st, np.full((3, 1), 8, np.int32))
    v = P.two_motor.wheel_speed
    np.testing.assert_allclose(traj.ball_vel[-1], [(1 + P.ball.kick_restitution) * v, 0.0],
                               atol=1e-6)
    assert bool(ev.touch[0, 0])


def test_kick_velocity_matches_numpy_reference():
    """The kick law against the reference's bounce off a moving face, on random incoming
    velocities (head-on, across, receding), headings, kick speeds and restitutions."""
    rng = np.random.default_rng(7)
    n = 200
    vel = rng.uniform(-2.0, 2.0, (n, 2)).astype(np.float32)
    th = rng.uniform(-np.pi, np.pi, n).astype(np.float32)
    k = rng.uniform(0.0, 2.5, n).astype(np.float32)
    e = rng.uniform(0.0, 1.0, n).astype(np.float32)
    heading = np.stack([np.cos(th), np.sin(th)], axis=1)
    got = np.asarray(jax.jit(jax.vmap(kick_velocity))(vel, heading, k, e))
    want = np.array([world_np.kick_np(vel[i].astype(float), float(th[i]), float(k[i]),
                                      float(e[i])) for i in range(n)])
    np.testing.assert_allclose(got, want, atol=2e-6)
    assert got.dtype == np.float32


def test_kick_velocity_analytic_cases():
    e = P.ball.kick_restitution
    h = np.array([1.0, 0.0], np.float32)

    def kick(v, k=2.0):
        return np.asarray(kick_velocity(np.asarray(v, np.float32), h, k, e))

    np.testing.assert_allclose(kick([0.0, 0.0]), [2.0, 0.0], atol=1e-6)  # resting ball
    np.testing.assert_allclose(kick([-1.2, 0.0]), [2.0 + e * 1.2, 0.0], atol=1e-6)  # head-on
    np.testing.assert_allclose(kick([0.0, 1.0]), [2.0, 1.0], atol=1e-6)  # across: kept
    np.testing.assert_allclose(kick([3.0, 0.5]), [3.0, 0.5], atol=1e-6)  # faster than face
    # the impulse is along the heading only, and never pulls the ball back
    v = np.array([-0.7, 0.4], np.float32)
    np.testing.assert_allclose((kick(v) - v)[1], 0.0, atol=1e-7)
    assert (kick(v) - v)[0] > 0


def test_never_through_a_wall_at_high_speed():
    n = 256
    key = jax.random.key(3)
    k1, k2, k3 = jax.random.split(key, 3)
    ang = jax.random.uniform(k1, (n,), jnp.float32, -np.pi, np.pi)
    vmax = P.ball.max_speed
    vel = vmax * jnp.stack([jnp.cos(ang), jnp.sin(ang)], -1)
    ball = jax.random.uniform(k2, (n, 2), jnp.float32, -1.0, 1.0) * jnp.array([3.0, 1.5])
    robots = jnp.tile(jnp.array([[[-3.5, 1.5, 0.0], [3.0, -1.0, 1.0]]], jnp.float32), (n, 1, 1))
    states = jax.vmap(make_state)(robots, ball, vel)
    acts = jax.random.randint(k3, (n, 60, 2), 0, 9, jnp.int32)
    p = _with(P, robot_kinds=("two_motor", "two_motor"), ball__wall_restitution=1.0,
              ball__rolling_decel=0.0, ball__drag=0.0)
    traj, _ = jax.jit(jax.vmap(lambda s, a: rollout(p, s, a, jax.random.key(0))))(states, acts)
    b = np.asarray(traj.ball)
    eps = 1e-5
    assert np.all(np.abs(b[..., 1]) <= W2 - RB + eps)
    assert np.all(b[..., 0] >= -L2 + RB - eps)
    beyond = b[..., 0] > L2 - RB + eps
    assert np.all(np.abs(b[..., 1][beyond]) <= G2)  # only through the goal mouth
    r = np.asarray(traj.robots)
    assert np.all(np.abs(r[..., 0]) <= L2 - RR + eps) and np.all(np.abs(r[..., 1]) <= W2 - RR + eps)
    sep = np.linalg.norm(r[..., 0, :2] - r[..., 1, :2], axis=-1)
    assert np.all(sep >= 2 * RR - 0.05)  # robots do not pass through each other


def test_goal_counted_exactly_once_and_ball_stays_in():
    st = make_state([[-3.0, 0.0, 0.0]], [2.5, 0.1], [2.5, 0.3])
    traj, ev = _rollout(P, st, np.full((40, 1), 4, np.int32))
    goals = np.asarray(ev.goal)
    assert goals.sum() == 1 and bool(traj.scored[-1])
    t = int(np.argmax(goals))
    assert np.all(np.asarray(traj.ball[t:]) == np.asarray(traj.ball[t]))
    assert traj.ball[t, 0] > L2 and abs(traj.ball[t, 1]) <= G2
    assert not np.any(np.asarray(ev.ball_out))
    # beside the goal: bounces back, no goal
    st = make_state([[-3.0, 0.0, 0.0]], [2.5, 1.5], [2.5, 0.0])
    traj, ev = _rollout(P, st, np.full((40, 1), 4, np.int32))
    assert not np.any(np.asarray(ev.goal)) and np.all(np.asarray(traj.ball[:, 0]) <= L2 - RB)
    assert np.min(np.asarray(traj.ball_vel[:, 0])) < 0
    # walls off: beside the goal the ball leaves the field (once), no goal
    p = _with(P, field__walls=False)
    traj, ev = _rollout(p, st, np.full((40, 1), 4, np.int32))
    assert not np.any(np.asarray(ev.goal)) and np.asarray(ev.ball_out).sum() == 1
    assert bool(traj.ball_out[-1])


def test_goal_corners_order():
    c = np.asarray(goal_corners(P))
    assert c.shape == (4, 3) and c.dtype == np.float32
    np.testing.assert_allclose(c, [[L2, G2, 0], [L2, G2, 0.5], [L2, -G2, 0.5], [L2, -G2, 0]],
                               atol=1e-6)


def test_tire_slip_noise():
    acts = np.full((10, 1), 8, np.int32)
    st = make_state([[0.0, 0.0, 0.0]], [-3.0, 1.0])
    a, _ = _rollout(P, st, acts, jax.random.key(1))
    b, _ = _rollout(P, st, acts, jax.random.key(2))
    np.testing.assert_array_equal(a.robots, b.robots)  # slip off: draws are irrelevant
    p = _with(P, robot__slip_std=0.2)
    a, _ = _rollout(p, st, acts, jax.random.key(1))
    b, _ = _rollout(p, st, acts, jax.random.key(2))
    assert np.max(np.abs(np.asarray(a.robots - b.robots))) > 1e-3


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(ParamError, match="ball.radius"):
        validate(_with(P).replace(ball=P.ball.replace(radius=-0.1)))
    with pytest.raises(ParamError, match="unknown robot kind"):
        validate(P.replace(robot_kinds=("tank",)))
    with pytest.raises(ParamError, match="goal.width"):
        validate(P.replace(goal=P.goal.replace(width=5.0)))
    with pytest.raises(ParamError, match="tunnelling"):
        validate(P.replace(substeps=1))
    with pytest.raises(ValueError, match="out of range"):
        check_actions(np.array([9], np.int32), P)
    with pytest.raises(ValueError, match="shape"):
        check_actions(np.array([1, 2], np.int32), P)
    with pytest.raises(ValueError, match=r"\(R, 3\)"):
        make_state([0.0, 0.0, 0.0], [1.0, 0.0])
