"""Pixel-derived observations (vbl.envs.pixels) and pixel identification data
(vbl.envs.collect, obs_source="pixels") against independent truth: a NumPy reference of
the image noise, the analytic camera's features and lost sides on random scenes, and the
analytic collection's motor commands (the observer does not look at its features, so the
two collections drive the same trajectories)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.envs.collect import CollectParams, collect, collect_many
from vbl.envs.noise import NOISE_ON, NOISE_ON_PIXELS, NoiseParams
from vbl.envs.pixels import PixelObsParams, noisy_image, section3_pixels
from vbl.envs.shoot_pass import OBS_SLICES, ShootPassParams, default_world, observe
from vbl.params import ParamError, validate
from vbl.programs.identification import RowSetup, table3_scenarios
from vbl.vision.camera import CameraParams
from vbl.vision.render import RenderParams
from vbl.vision.scenes import OTHER_HEIGHT, random_scenes
from vbl.world.physics import WorldState

WORLD = default_world()
CAM = CameraParams()
#: 128 x 120: a pixel is 4 analytic px wide and high.
PIX = PixelObsParams(render=RenderParams(width=128, height=120))
PX = 4.0


def test_noisy_image_matches_numpy():
    rng = np.random.default_rng(0)
    img = rng.uniform(-0.1, 1.1, (6, 5, 3)).astype(np.float32)
    eps = rng.standard_normal((6, 5, 3)).astype(np.float32)
    ref = np.round(np.clip(img + np.float32(0.07) * eps, 0, 1) * 255).astype(np.uint8)
    out = np.asarray(noisy_image(jnp.asarray(img), jnp.asarray(eps), 0.07))
    assert out.dtype == np.uint8
    assert np.abs(out.astype(int) - ref.astype(int)).max() <= 1   # float rounding at .5
    assert (out == ref).mean() > 0.95
    clean = np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)
    np.testing.assert_array_equal(np.asarray(noisy_image(jnp.asarray(img), None, 0.07)), clean)


def _worlds(kind, n, seed):
    s = random_scenes(n, kind, seed=seed, world=WORLD)
    robots = np.stack([s["pose"], s["other"]], axis=1).astype(np.float32)
    zero = jnp.zeros((n,), bool)
    return WorldState(robots=jnp.asarray(robots), ball=jnp.asarray(s["ball"], jnp.float32),
                      ball_vel=jnp.zeros((n, 2), jnp.float32), scored=zero, ball_out=zero)


@jax.jit
def _both(worlds):
    phase = jnp.zeros((), jnp.float32)
    nz = NoiseParams()

    def one(w):
        return (section3_pixels(w, 0, CAM, WORLD, nz, OTHER_HEIGHT, phase, PIX, None),
                observe(w, 0, CAM, WORLD, nz, OTHER_HEIGHT, phase, None))

    return jax.vmap(one)(worlds)


@pytest.mark.parametrize("kind", ["close", "far", "lost"])
def test_pixel_obs_agrees_with_analytic(kind):
    """Noise-free pixel features of a two-robot world: the ball's centre within a pixel
    (4 px) of the analytic centre where it is fully in view and at least 3 pixels wide
    (docs/render.md: 1 px at 512 x 480, scaling with the pixel size); a coloured pixel only
    where the analytic object is visible; lost sides equal the analytic ones."""
    pix, ana = (np.asarray(a) for a in _both(_worlds(kind, 24, seed=3)))
    vis = OBS_SLICES["visible"]
    assert np.all(pix[:, vis] <= ana[:, vis])            # no pixel without an object
    lost = (pix[:, vis] == 0) & (ana[:, vis] == 0)
    side = OBS_SLICES["lost_side"]
    np.testing.assert_array_equal(pix[:, side][lost], ana[:, side][lost])
    b = OBS_SLICES["ball"]
    ball_a, ball_p = ana[:, b], pix[:, b]
    inside = (np.abs(ball_a[:, 0]) + ball_a[:, 2] / 2 < 256 - PX) & (
        np.abs(ball_a[:, 1]) + ball_a[:, 3] / 2 < 240 - PX)
    ok = (ana[:, vis][:, 0] > 0) & (pix[:, vis][:, 0] > 0) & inside & (ball_a[:, 2] >= 3 * PX)
    if kind != "lost":
        assert ok.sum() >= 6
    assert np.all(np.abs(ball_p[ok, :2] - ball_a[ok, :2]) <= PX)


@pytest.mark.slow
def test_pixel_collection_drives_the_analytic_trajectories():
    c = CollectParams(num_steps=24, focus="ball", other_behaviour="move_to_ball",
                      pixels=PixelObsParams(render=RenderParams(width=64, height=60)))
    key = jax.random.PRNGKey(1)
    a = collect(key, c, 2)
    p = collect(key, c.replace(obs_source="pixels"), 2)
    np.testing.assert_array_equal(np.asarray(a.u), np.asarray(p.u))
    both = (np.asarray(a.visible[..., 0]) > 0) & (np.asarray(p.visible[..., 0]) > 0)
    assert both.sum() >= 10
    # the ball's centre u: within a pixel (8 analytic px at 64 x 60) in the median
    err = np.abs(np.asarray(a.ball)[..., 0] - np.asarray(p.ball)[..., 0])[both]
    assert np.median(err) <= 8.0
    assert p.ball.dtype == jnp.float32 and p.goal.shape == a.goal.shape


def test_noise_sources_must_match_the_obs_source():
    with pytest.raises(ParamError, match="noise.image_std"):
        validate(CollectParams(obs_source="pixels", noise=NOISE_ON))
    with pytest.raises(ParamError, match="camera.pixel_noise_std"):
        validate(CollectParams(obs_source="pixels", camera=CameraParams(pixel_noise_std=1.0)))
    with pytest.raises(ParamError, match="pixel_std"):
        validate(CollectParams(noise=NOISE_ON_PIXELS))
    validate(CollectParams(obs_source="pixels", noise=NOISE_ON_PIXELS))


def test_table3_pixels_preset_validates():
    from vbl.engine.config import apply_overrides
    from vbl.engine.registry import discover

    exp = discover()["table3_noisy"]
    cfg = apply_overrides(exp.default_config, exp.preset("pixels"))   # validates, check()
    assert cfg.collect.obs_source == "pixels" and cfg.noise.pixel_std > 0
    assert "pixels" in exp.published_presets


# ----------------------------------------------------------------------------- envs
SMALL = PixelObsParams(render=RenderParams(width=64, height=60))


def _shoot_pass(**kw):
    from vbl.envs.shoot_pass import ShootPassEnv, ShootPassParams

    return ShootPassEnv("shoot", ShootPassParams(obs_source="pixels", pixels=SMALL, **kw))


@pytest.mark.slow
def test_shoot_pass_pixel_obs_sees_what_the_analytic_camera_sees():
    """Pixel obs of the env's own states: a coloured pixel only where the analytic object
    is visible, the goal seen by both at the start (the shooter faces it), the ball's centre
    u within a pixel (8 px at 64 x 60) where both see it whole; the image is uint8."""
    env = _shoot_pass()
    ana = env.default_params.replace(obs_source="analytic")

    @jax.jit
    def run(keys):
        def one(k):
            obs, st = env.reset(k)
            return obs, env.get_obs(st, ana), env.get_pixels(st, env.default_params)
        return jax.vmap(one)(keys)

    pix, a, img = (np.asarray(x) for x in run(jax.random.split(jax.random.PRNGKey(0), 16)))
    assert img.shape == (16, 60, 64, 3) and img.dtype == np.uint8
    assert env.image_shape() == (60, 64, 3)
    vis = OBS_SLICES["visible"]
    assert np.all(pix[:, vis] <= a[:, vis]) and pix[:, vis][:, 1].mean() > 0.8
    b = OBS_SLICES["ball"]
    ok = (pix[:, vis][:, 0] > 0) & (a[:, b][:, 2] >= 24) & (
        np.abs(a[:, b][:, 0]) + a[:, b][:, 2] / 2 < 248)
    assert np.all(np.abs(pix[ok, b][:, 0] - a[ok, b][:, 0]) <= 8.0)


def test_image_noise_is_the_pixel_noise_draw():
    """With noise_on.pixel, get_pixels adds pixel_std times the step's normals to each
    channel: the NumPy reference of the noisy uint8 image from the noise-free float image."""
    from vbl.envs.noise import NoiseParams as NP
    from vbl.envs.shoot_pass import ShootPassNoiseOn

    env = _shoot_pass(noise=NP(pixel_std=0.05), noise_on=ShootPassNoiseOn(pixel=True))
    p = env.default_params
    state, eps = env.reset_state(jax.random.PRNGKey(2))
    assert eps.shape == (60 * 64 * 3,)
    clean = np.asarray(env.observer(p).image(state), np.float32)
    ref = np.round(np.clip(clean + np.float32(0.05) * np.asarray(eps).reshape(60, 64, 3), 0, 1)
                   * 255)
    got = np.asarray(env.get_pixels(state, p, eps)).astype(float)
    assert np.abs(got - ref).max() <= 1 and (got == ref).mean() > 0.95
    assert np.abs(got - np.round(clean * 255)).std() > 5       # the noise is there


def test_env_noise_sources_must_match_the_obs_source():
    from vbl.envs.noise import NoiseParams as NP
    from vbl.envs.shoot_pass import ShootPassEnv, ShootPassNoiseOn, ShootPassParams
    from vbl.envs.shooting import ShootingEnv, ShootingParams

    on = ShootPassNoiseOn(pixel=True)
    with pytest.raises(ParamError, match="noise.image_std"):
        ShootPassEnv("shoot", ShootPassParams(obs_source="pixels", noise=NP(image_std=1.0),
                                              noise_on=on))
    with pytest.raises(ParamError, match="noise.pixel_std"):
        ShootPassEnv("shoot", ShootPassParams(noise=NP(pixel_std=0.1), noise_on=on))
    with pytest.raises(ParamError, match="noise_on.pixel"):
        ShootPassEnv("shoot", ShootPassParams(obs_source="pixels", noise=NP(pixel_std=0.1)))
    with pytest.raises(ParamError, match="camera.pixel_noise_std"):
        ShootingEnv(params=ShootingParams(obs_source="pixels",
                                          camera=CameraParams(pixel_noise_std=1.0)))


def test_shooting_pixel_obs_on_easy_starts():
    """Section 2 from pixels at the easy start (ball just ahead, goal ahead): both visible,
    the ball's centre x2 within a pixel (8 px) of the analytic one."""
    from vbl.envs.shooting import ShootingEnv, ShootingParams
    from vbl.vision.section2 import SEC2_BALL_POS, SEC2_BALL_VISIBLE, SEC2_GOAL_VISIBLE

    p = ShootingParams(obs_source="pixels", pixels=SMALL, start_difficulty=0.0)
    p = p.replace(world=p.world.replace(robot_kinds=("two_motor",)))
    env = ShootingEnv("two_motor", p)
    obs, st = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(3), 8))
    ana = jax.vmap(lambda s: env.get_obs(s, p.replace(obs_source="analytic")))(st)
    obs, ana = np.asarray(obs), np.asarray(ana)
    assert obs.shape == (8, 9)
    assert np.all(obs[:, SEC2_BALL_VISIBLE] == 1) and np.all(obs[:, SEC2_GOAL_VISIBLE] == 1)
    assert np.all(np.abs(obs[:, SEC2_BALL_POS] - ana[:, SEC2_BALL_POS]) <= 8.0)


def test_brax_adapter_pixels_observation():
    from vbl.envs.brax_adapter import BraxAdapter
    from vbl.envs.shooting import ShootingEnv

    env = _shoot_pass()
    ad = BraxAdapter(env, obs="pixels")
    assert ad.observation_size == (60, 64, 3)
    st = jax.jit(ad.reset)(jax.random.PRNGKey(0))
    assert st.obs.shape == (60, 64, 3) and st.obs.dtype == jnp.uint8
    np.testing.assert_array_equal(np.asarray(st.obs),
                                  np.asarray(env.get_pixels(st.pipeline_state, ad.params)))
    st2 = jax.jit(ad.step)(st, jnp.int32(1))
    assert st2.obs.dtype == jnp.uint8 and st2.obs.shape == (60, 64, 3)
    assert BraxAdapter(env).observation_size == 26
    with pytest.raises(ValueError, match="obs="):
        BraxAdapter(ShootingEnv(), obs="image")

    class NoCamera:
        reset_state = step_state = None
        num_actions, observation_shape, default_params = 3, (2,), None

    with pytest.raises(TypeError, match="camera image"):
        BraxAdapter(NoCamera(), obs="pixels")


# Table 3's pixel rows (collect.num_steps 16, 64 x 60 images, one data set each from
# collect_many(PRNGKey(5), ..., 1)), recorded with a pixel pipeline that stored nothing
# once per frame (vbl.vision.fusion.stored changes the speed only), the goal sums with the
# goal-end widths in image pixels (post_band, min_post): sums of |u|, |ball|, |goal|,
# |other| and the visible flags per row.
PIXEL_ROWS_REFERENCE = {
    "shooter_ball": [27.0, 5796.897, 328867.2, 175303.3, 48.0],
    "shooter_goal": [20.0, 5828.4, 172397.9, 177824.7, 48.0],
    "shooter_other": [27.0, 5734.8, 252602.6, 194329.6, 48.0],
    "passer_ball": [19.0, 4436.8, 176412.0, 222148.2, 48.0],
    "passer_other": [22.0, 5222.8, 140894.2, 189205.1, 48.0],
    "noise_free_goal": [25.0, 4692.0, 163259.5, 428765.4, 47.0],
    "noise_free_ball": [22.0, 4896.0, 117876.8, 141695.3, 48.0],
    "noise_free_other": [30.0, 5968.0, 269898.6, 227794.5, 47.0],
}


def test_table3_pixel_rows_match_the_recorded_reference():
    c = CollectParams(num_steps=16, obs_source="pixels",
                      pixels=PixelObsParams(render=RenderParams(width=64, height=60)))
    sc = table3_scenarios(c, RowSetup(), ShootPassParams(), NOISE_ON_PIXELS)
    out = collect_many(jax.random.PRNGKey(5), list(sc.values()), 1)
    for name, d in zip(sc, out, strict=True):
        got = [np.abs(np.asarray(getattr(d, f), np.float64)).sum()
               for f in ("u", "ball", "goal", "other", "visible")]
        np.testing.assert_allclose(got, PIXEL_ROWS_REFERENCE[name], rtol=1e-5, err_msg=name)
