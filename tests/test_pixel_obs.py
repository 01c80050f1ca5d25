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

from vbl.envs.collect import CollectParams, collect
from vbl.envs.noise import NOISE_ON, NOISE_ON_PIXELS, NoiseParams
from vbl.envs.pixels import PixelObsParams, noisy_image, section3_pixels
from vbl.envs.shoot_pass import OBS_SLICES, default_world, observe
from vbl.params import ParamError, validate
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
