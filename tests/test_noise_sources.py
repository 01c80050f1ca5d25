"""Every random source of the two-robot env has the spread its parameter promises.

Each test drives the public ``ShootPassEnv("shoot").step_env`` (one compiled call vmapped
over thousands of independent keys and hand-built states) and measures a noise source
against independent truth: the geometry of the scene, the documented noise model of
Section 3.4.2 (``docs/two_robot_task.md``), the robot kinematics of ``docs/world.md`` and
sampling statistics. A zero std must give exactly no noise.

* the scripted passer's kick direction: std ``other.aim_noise_deg`` around the direction
  from the ball to the shooter's centre;
* image noise ``noise.image_std`` and the camera's ``pixel_noise_std``: independent
  Gaussian noise of std ``sqrt(image^2 + camera^2)`` on every pixel coordinate and size of
  a visible object (areas, flags and lost sides untouched);
* ball centroid eccentricity ``noise.ecc_centroid``: the observed centroid is displaced by
  ``ecc * (w/2 cos psi, h/2 sin psi)``, ``psi`` the rolling phase (distance rolled / ball
  radius);
* rolling wobble ``noise.ecc_turn_std``: the heading of a rolling ball performs a random
  walk of variance ``ecc_turn_std^2 * d / (2 pi r)`` for ``d`` metres rolled;
* tire slip ``noise.slip_std``: each motor command (speed and steering angle) is scaled by
  ``1 + s N(0, 1)`` per primitive with ``s = sqrt(noise.slip_std^2 +
  world.robot.slip_std^2)``.

Each source is switched on in ``params.noise_on`` where its std is set (a static switch:
a source that is off is not drawn). All draws use fixed seeds; a std from N = 4,000
samples has a relative standard error of ``1 / sqrt(2 N)`` = 1.1 %, so the 7.5 %
tolerances are more than 6 standard errors.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from vbl.envs.other_agents import AgentMemory
from vbl.envs.shoot_pass import OBS_SLICES, ShootPassEnv, ShootPassState
from vbl.world.physics import WorldState

N = 4000  #: independent draws per measurement (one vmapped call)
STOP, FORWARD, FORWARD_LEFT = 0, 1, 2  #: FOUR_WHEEL_U rows (0, 0), (1, 0), (1, 1)

# pixel features of the flat observation (docs/vision.md): the ball's centre and size,
# the goal's four end points and area centroid, the other robot's centroid and size;
# the areas, visible flags and lost sides carry no pixel noise
PIXEL = np.r_[0:4, 4:14, 15:19]
NOT_PIXEL = np.r_[14, 19, 20:26]


@pytest.fixture(scope="module")
def env():
    return ShootPassEnv("shoot")


@pytest.fixture(scope="module")
def step(env):
    """``step_env`` vmapped over keys, states and actions; params shared (traced)."""
    return jax.jit(jax.vmap(env.step_env, in_axes=(0, 0, 0, None)))


def keys(seed: int, n: int = N) -> jax.Array:
    return jax.random.split(jax.random.PRNGKey(seed), n)


def states(robots, ball, vel=None, phase=None, passer_delay: int = 1000) -> ShootPassState:
    """N env states; robots (N, 2, 3) (0 shooter, 1 passer), ball and vel (N, 2), phase
    (N,). The scripted passer waits ``passer_delay`` steps before it drives to the ball."""
    robots = np.broadcast_to(np.asarray(robots, np.float32), (N, 2, 3))
    ball = np.broadcast_to(np.asarray(ball, np.float32), (N, 2))
    vel = np.zeros((N, 2), np.float32) if vel is None else np.broadcast_to(
        np.asarray(vel, np.float32), (N, 2))
    phase = np.zeros(N, np.float32) if phase is None else np.asarray(phase, np.float32)
    zi, zb = np.zeros(N, np.int32), np.zeros(N, bool)
    world = WorldState(robots=jnp.asarray(robots), ball=jnp.asarray(ball),
                       ball_vel=jnp.asarray(vel), scored=jnp.asarray(zb),
                       ball_out=jnp.asarray(zb))
    memory = AgentMemory(action=jnp.asarray(zi), t=jnp.asarray(zi),
                         delay=jnp.full(N, passer_delay, np.int32), kicked=jnp.asarray(zb))
    return ShootPassState(world=world, step=jnp.asarray(zi), memory=memory,
                          touched=jnp.asarray(zb), kicked=jnp.asarray(zb),
                          phase=jnp.asarray(phase))


def switched_on(p, **on):
    """``p`` with the static switches ``on`` (e.g. ``pixel=True``) of ``p.noise_on``."""
    return p.replace(noise_on=p.noise_on.replace(**on))


def actions(a) -> jax.Array:
    return jnp.asarray(np.broadcast_to(np.asarray(a, np.int32), (N,)))


def wrap(a):
    return (np.asarray(a, float) + np.pi) % (2 * np.pi) - np.pi


def assert_std(x, want, rtol=0.075, what=""):
    """Sample std of x (along axis 0) equals ``want`` within ``rtol``; mean within 5
    standard errors of 0."""
    x = np.asarray(x, float)
    sd = x.std(axis=0)
    np.testing.assert_allclose(sd, want, rtol=rtol, err_msg=f"std of {what}")
    assert np.all(np.abs(x.mean(axis=0)) < 5 * want / np.sqrt(len(x))), f"mean of {what}"


# ----------------------------------------------------------------------- the passer's aim


@pytest.mark.parametrize("aim_deg", [0.0, 5.0, 20.0])
def test_passer_kick_direction_spread(env, step, aim_deg):
    """The scripted passer, touching the ball while driving at it, kicks it towards the
    shooter's centre: exactly so without aim noise, else with a Gaussian direction error
    whose std is ``other.aim_noise_deg``."""
    p = env.default_params
    p = p.replace(other=p.other.replace(aim_noise_deg=aim_deg))
    rng = np.random.default_rng(11)
    # the passer at a random place and heading in the left half, the ball just ahead of it
    # (touched within the first sub-step); the shooter stands still at (2.5, 0)
    px = np.stack([rng.uniform(-2.5, 0.0, N), rng.uniform(-1.2, 1.2, N),
                   rng.uniform(-np.pi, np.pi, N)], axis=1)
    gap = p.world.robot.radius + p.world.ball.radius + 0.01
    ball = px[:, :2] + gap * np.stack([np.cos(px[:, 2]), np.sin(px[:, 2])], axis=1)
    shooter = np.broadcast_to(np.array([2.5, 0.0, np.pi]), (N, 3))
    st = states(np.stack([shooter, px], axis=1), ball, passer_delay=0)
    _, new, _, _, _, info = step(keys(1), st, actions(STOP), p)
    assert np.all(np.asarray(info["kicked"])), "the passer must kick in every sample"
    b = np.asarray(new.world.ball, float)
    s = np.asarray(new.world.robots[:, 0, :2], float)
    v = np.asarray(new.world.ball_vel, float)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), p.other.kick_speed, rtol=1e-5)
    aimed = np.arctan2(s[:, 1] - b[:, 1], s[:, 0] - b[:, 0])  # ball -> shooter centre
    err = wrap(np.arctan2(v[:, 1], v[:, 0]) - aimed)
    if aim_deg == 0.0:
        assert np.max(np.abs(err)) < 1e-5
    else:
        assert_std(err, np.deg2rad(aim_deg), rtol=0.1, what="kick direction error")


# ----------------------------------------------------------------------- image noise

# the shooter faces the goal from (1, 0); the ball and the passer are in view, apart
SCENE = dict(robots=[[1.0, 0.0, 0.0], [2.6, -0.7, np.pi]], ball=[2.0, 0.25])


@pytest.mark.parametrize("image_std,camera_std", [(2.0, 0.0), (0.0, 1.5), (2.0, 1.5)])
def test_image_and_camera_pixel_noise(env, step, image_std, camera_std):
    """Noise of std ``sqrt(image_std^2 + pixel_noise_std^2)`` on each pixel feature of
    every visible object, independent across features and zero-mean; the areas, visible
    flags and lost sides are exact; with both stds 0 the observation is noise-free."""
    p = env.default_params
    st = states(**SCENE)
    clean, _, _, _, _, _ = step(keys(2), st, actions(STOP), p)
    clean = np.asarray(clean, float)
    assert np.all(clean[:, OBS_SLICES["visible"]] == 1.0), "ball, goal and passer in view"
    # no noise: the observation does not depend on the key
    np.testing.assert_array_equal(clean, np.broadcast_to(clean[0], clean.shape))
    noisy_p = switched_on(p.replace(
        noise=p.noise.replace(image_std=image_std),
        shooter_camera=p.shooter_camera.replace(pixel_noise_std=camera_std)), pixel=True)
    obs, _, _, _, _, _ = step(keys(3), st, actions(STOP), noisy_p)
    d = np.asarray(obs, float) - clean
    np.testing.assert_array_equal(d[:, NOT_PIXEL], 0.0)
    want = np.hypot(image_std, camera_std)
    assert_std(d[:, PIXEL], want, what="pixel noise")
    corr = np.corrcoef(d[:, PIXEL].T)
    assert np.max(np.abs(corr - np.eye(len(PIXEL)))) < 0.1, "pixel noises are independent"


# ----------------------------------------------------------------------- eccentricity


def test_ball_centroid_eccentricity(env, step):
    """The ball's rolling phase advances by the distance rolled / ball radius, and the
    observed centroid is displaced by ``ecc * (w/2 cos psi, h/2 sin psi)`` at that phase
    (amplitude exactly ``ecc`` times the half size); everything else is unchanged. Without
    eccentricity the observation does not depend on the phase."""
    p = env.default_params
    ecc = 0.3
    rng = np.random.default_rng(5)
    psi0 = rng.uniform(0, 2 * np.pi, N)
    speed = rng.uniform(0.0, 1.2, N)  # rolling along +x, every fourth ball at rest
    speed[::4] = 0.0
    st = states(SCENE["robots"], SCENE["ball"], np.stack([speed, 0 * speed], 1), psi0)
    k = keys(4)
    clean, new, _, _, _, _ = step(k, st, actions(STOP), p)
    obs, new_e, _, _, _, _ = step(k, st, actions(STOP),
                                  p.replace(noise=p.noise.replace(ecc_centroid=ecc)))
    clean, obs = np.asarray(clean, float), np.asarray(obs, float)
    assert np.all(clean[:, OBS_SLICES["visible"]][:, 0] == 1.0), "ball in view"
    # rolling phase: arc length / radius
    rolled = np.linalg.norm(np.asarray(new.world.ball, float)
                            - np.asarray(st.world.ball, float), axis=1)
    assert rolled.max() > 0.05 and rolled.min() == 0.0
    psi = np.asarray(new_e.phase, float)
    assert np.max(np.abs(wrap(psi - psi0 - rolled / p.world.ball.radius))) < 1e-4
    assert np.all((psi >= 0) & (psi < 2 * np.pi))
    # the displacement at that phase
    half_w, half_h = clean[:, 2] / 2, clean[:, 3] / 2
    np.testing.assert_allclose(obs[:, 0] - clean[:, 0], ecc * half_w * np.cos(psi), atol=2e-3)
    np.testing.assert_allclose(obs[:, 1] - clean[:, 1], ecc * half_h * np.sin(psi), atol=2e-3)
    amp = np.hypot((obs[:, 0] - clean[:, 0]) / half_w, (obs[:, 1] - clean[:, 1]) / half_h)
    np.testing.assert_allclose(amp, ecc, atol=1e-4)
    np.testing.assert_array_equal(obs[:, 2:], clean[:, 2:])
    # zero eccentricity: another phase, the same observation
    shifted = st.replace(phase=jnp.asarray((psi0 + 1.0) % (2 * np.pi), np.float32))
    other, _, _, _, _, _ = step(k, shifted, actions(STOP), p)
    np.testing.assert_array_equal(np.asarray(other, float), clean)


def test_rolling_ball_heading_random_walk(env, step):
    """A rolling ball's heading performs a random walk: per step a turn of variance
    ``ecc_turn_std^2 * d / (2 pi r)`` for the ``d`` metres rolled, independent across
    steps (the variance of the summed turn grows with the total distance), the speed
    untouched. Without it the heading never changes."""
    p = env.default_params
    r = p.world.ball.radius
    sigma = 0.3  # rad per sqrt(revolution)
    rng = np.random.default_rng(6)
    alpha = rng.uniform(-np.pi, np.pi, N)
    # the ball rolls freely from (-1.5, 0.8) at 1.2 m/s; both robots stand well away
    st0 = states([[1.5, -1.5, 0.0], [2.5, -1.5, np.pi]], [-1.5, 0.8],
                 1.2 * np.stack([np.cos(alpha), np.sin(alpha)], axis=1))
    steps = 8

    def roll(params, seed):
        st, balls, vels = st0, [np.asarray(st0.world.ball, float)], [
            np.asarray(st0.world.ball_vel, float)]
        for i in range(steps):
            _, st, _, _, _, _ = step(keys(seed * 100 + i), st, actions(STOP), params)
            balls.append(np.asarray(st.world.ball, float))
            vels.append(np.asarray(st.world.ball_vel, float))
        return np.stack(balls), np.stack(vels)

    b0, v0 = roll(p, 7)
    b1, v1 = roll(switched_on(p.replace(noise=p.noise.replace(ecc_turn_std=sigma)),
                              wobble=True), 8)
    heading0 = np.arctan2(v0[..., 1], v0[..., 0])
    heading1 = np.arctan2(v1[..., 1], v1[..., 0])
    # off: the heading never changes
    assert np.max(np.abs(wrap(heading0 - alpha))) < 1e-5
    # on: the speed is the noise-free one at every step (a turn, no speed change)
    np.testing.assert_allclose(np.linalg.norm(v1, axis=-1), np.linalg.norm(v0, axis=-1),
                               rtol=1e-5)
    d = np.linalg.norm(np.diff(b1, axis=0), axis=-1)  # (steps, N) metres rolled per step
    assert d.min() > 0.05
    turns = wrap(np.diff(heading1, axis=0))
    revs = d / (2 * np.pi * r)
    assert_std((turns / np.sqrt(revs)).reshape(-1), sigma, rtol=0.05, what="turn per step")
    total = wrap(heading1[-1] - heading1[0]) / np.sqrt(revs.sum(axis=0))
    assert_std(total, sigma, what=f"summed turn over {steps} steps")


# ----------------------------------------------------------------------- tire slip


@pytest.mark.parametrize("noise_slip,world_slip", [(0.0, 0.0), (0.1, 0.0), (0.08, 0.06)])
def test_tire_slip(env, step, noise_slip, world_slip):
    """Tire slip scales the robot's speed and steering angle by independent factors
    ``1 + s N(0, 1)`` per primitive, ``s = sqrt(noise.slip_std^2 + world.robot.slip_std^2)``.

    Measured from the shooter's motion in one primitive (``docs/world.md``): driving
    straight, the distance covered is ``v dt``; steering left, the heading turns by
    ``omega dt``, ``omega = 2 v tan(delta) / wheelbase``, and with the midpoint heading
    over ``n`` sub-steps of ``h = dt / n`` the chord is ``v h sin(omega dt / 2) /
    sin(omega h / 2)``. Without slip the motion is exact."""
    p = env.default_params
    p = switched_on(p.replace(
        noise=p.noise.replace(slip_std=noise_slip),
        world=p.world.replace(robot=p.world.robot.replace(slip_std=world_slip))), slip=True)
    fw = p.world.four_wheel
    dt, n = p.world.action_dt, p.world.substeps
    h = dt / n
    s = np.hypot(noise_slip, world_slip)
    rng = np.random.default_rng(9)
    theta = rng.uniform(-np.pi, np.pi, N)
    shooter = np.stack([np.full(N, -1.0), np.full(N, 0.5), theta], axis=1)
    passer = np.broadcast_to(np.array([2.5, -1.5, np.pi]), (N, 3))
    st = states(np.stack([shooter, passer], axis=1), [2.0, 1.5])
    before = np.asarray(st.world.robots[:, 0], float)

    def motion(action, seed):
        _, new, _, _, _, _ = step(keys(seed), st, actions(action), p)
        after = np.asarray(new.world.robots[:, 0], float)
        return np.linalg.norm(after[:, :2] - before[:, :2], axis=1), wrap(after[:, 2]
                                                                          - before[:, 2])

    # straight ahead: only the speed command matters
    chord, turn = motion(FORWARD, 12)
    assert np.max(np.abs(turn)) < 1e-6
    rel_v = chord / (fw.speed * dt) - 1
    # steering left: speed and steering angle
    chord_l, turn_l = motion(FORWARD_LEFT, 13)
    v = chord_l * np.sin(turn_l / (2 * n)) / (h * np.sin(turn_l / 2))
    delta = np.arctan(turn_l * fw.wheelbase / (2 * v * dt))
    rel_v_l = v / fw.speed - 1
    rel_delta = delta / np.deg2rad(fw.max_steer_deg) - 1
    if s == 0:
        for x in (rel_v, rel_v_l, rel_delta):
            assert np.max(np.abs(x)) < 1e-4
        return
    assert_std(rel_v, s, what="relative speed noise (straight)")
    assert_std(rel_v_l, s, what="relative speed noise (steering)")
    assert_std(rel_delta, s, what="relative steering-angle noise")
    assert abs(np.corrcoef(rel_v_l, rel_delta)[0, 1]) < 0.1, "speed and steering independent"
