"""The renderer's pixel rays, pixel by pixel: the set of ball pixels of a camera image
equals the set of pixel centres whose ray meets the ball's sphere, computed in float64
from the documented pixel centres (docs/render.md: pixel ``(i, j)`` of an ``H' x W'``
image looks through ``u = ((j + 1/2)/W' - 1/2) 512``, ``v = (1/2 - (i + 1/2)/H') 480``)
and the independent camera of ``tests/reference/camera_np``. A shift of the pixel
centres by half a pixel changes the set (hundreds of pixels on the outline)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.reference.camera_np import to_cam_np
from vbl.vision.camera import CameraParams
from vbl.vision.render import BALL_RGB, RenderParams, render_camera
from vbl.world import WorldParams, goal_corners

WORLD = WorldParams()
CAM = CameraParams()
#: Focal lengths from the field of view (67 x 60 deg over 512 x 480 px), written out.
FU = 256.0 / math.tan(math.radians(67.0 / 2))
FV = 240.0 / math.tan(math.radians(60.0 / 2))
#: Pixel centres whose ray passes within this distance (m) of the sphere's surface are
#: not compared (float32 ray arithmetic in the renderer; a half-pixel shift moves the
#: outline rays by millimetres).
MARGIN = 2e-5


def expected_ball_pixels(pose, ball_xy, radius, width, height):
    """(H', W') bool where the ray through the pixel centre meets the sphere, and (H', W')
    bool where that ray passes within MARGIN of the sphere's surface (undecided)."""
    b = to_cam_np([ball_xy[0], ball_xy[1], radius], pose, {})
    u = ((np.arange(width) + 0.5) / width - 0.5) * 512.0
    v = (0.5 - (np.arange(height) + 0.5) / height) * 480.0
    d = np.stack(np.broadcast_arrays((u / FU)[None, :], (v / FV)[:, None], 1.0), -1)
    along = (d @ b) / np.sum(d * d, -1)
    miss = np.linalg.norm(b - along[..., None] * d, axis=-1)
    return (along > 0) & (miss <= radius), np.abs(miss - radius) < MARGIN


def _ball_pixels(img):
    """Pixels whose colour is the ball's (shaded: a multiple of BALL_RGB)."""
    ratio = img / np.asarray(BALL_RGB)
    return (img[..., 0] > 0.1) & (np.ptp(ratio, axis=-1) < 1e-3 * ratio[..., 0] + 1e-6)


@pytest.mark.parametrize("width,height", [(128, 120), (96, 60)])
def test_ball_pixels_are_the_pixel_centre_rays_that_meet_the_sphere(width, height):
    rp = RenderParams(width=width, height=height, field_lines=False)
    gc = goal_corners(WORLD)
    render = jax.jit(jax.vmap(lambda p, b: render_camera(p, b, WORLD.ball.radius, gc,
                                                         WORLD.field, CAM, rp)))
    poses = np.array([[0.0, 0.0, 0.0], [-1.0, 0.5, -0.4], [1.5, -1.0, 2.8]], np.float32)
    # ball ahead, left of centre, and right and low (partly below the bottom border)
    offsets = [(0.9, 0.1), (0.6, 0.25), (0.45, -0.15)]
    balls = np.array([[p[0] + a * math.cos(p[2]) - s * math.sin(p[2]),
                       p[1] + a * math.sin(p[2]) + s * math.cos(p[2])]
                      for p, (a, s) in zip(poses, offsets, strict=True)], np.float32)
    imgs = np.asarray(render(jnp.asarray(poses), jnp.asarray(balls)))
    for img, pose, ball in zip(imgs, poses, balls, strict=True):
        want, undecided = expected_ball_pixels(pose.astype(float), ball.astype(float),
                                               float(WORLD.ball.radius), width, height)
        got = _ball_pixels(img)
        assert want.sum() > 100, "the ball covers too few pixels to test the outline"
        diff = (got != want) & ~undecided
        assert not diff.any(), (f"{int(diff.sum())} pixels differ of {int(want.sum())} "
                                f"(pose {pose}, ball {ball}, {width} x {height})")


def test_pixel_centres_and_sizes_of_an_image_with_oblong_pixels():
    """64 x 30 pixels over the 512 x 480 px camera: pixels 8 px wide and 16 px high; the
    first centre at u = -256 + 4, v = 240 - 8 (row 0 at the top), the last mirrored."""
    from vbl.vision.render import pixel_grid

    u, v, (su, sv) = pixel_grid(CameraParams(), 64, 30)
    assert (float(su), float(sv)) == (8.0, 16.0)
    assert u.shape == (64,) and v.shape == (30,)
    np.testing.assert_allclose([u[0], u[-1], v[0], v[-1]], [-252, 252, 232, -232], atol=1e-4)
    np.testing.assert_allclose(np.diff(u), 8.0, atol=1e-4)
    np.testing.assert_allclose(np.diff(v), -16.0, atol=1e-4)


def test_intensities_become_bytes_by_rounding_after_clipping():
    """[0, 1] -> 0..255 to the nearest byte (0.999 x 255 = 254.7 -> 255, 0.002 x 255 = 0.51
    -> 1), values outside [0, 1] clipped first."""
    from vbl.vision.render import to_uint8

    got = to_uint8(jnp.asarray([0.0, 0.999, 0.6, 1.0, 1.7, -0.2, 0.002], jnp.float32))
    assert got.dtype == jnp.uint8
    assert np.asarray(got).tolist() == [0, 255, 153, 255, 255, 0, 1]


def test_a_side_wall_is_drawn_up_to_its_height_and_the_sky_above_it():
    """Facing the +y wall from 3.95 m: each pixel centre's ray (camera axes as docs/vision.md
    writes them, in NumPy) meets the floor, the wall below wall_height (also above the
    camera's own height), or passes over the wall (sky)."""
    from vbl.vision.render import FLOOR_RGB, SKY_RGB, WALL_RGB

    field = WORLD.field
    th, tau = math.pi / 2, math.radians(CAM.tilt_deg)
    pose = np.array([0.0, field.width / 2 - 4.0, th])
    c = np.array([pose[0] + CAM.forward_offset * math.cos(th),
                  pose[1] + CAM.forward_offset * math.sin(th), CAM.height])
    r = np.array([math.sin(th), -math.cos(th), 0.0])
    a = np.array([-math.cos(th) * math.sin(tau), -math.sin(th) * math.sin(tau), math.cos(tau)])
    f = np.array([math.cos(th) * math.cos(tau), math.sin(th) * math.cos(tau), math.sin(tau)])
    w, h = 32, 60
    u = ((np.arange(w) + 0.5) / w - 0.5) * 512.0
    v = (0.5 - (np.arange(h) + 0.5) / h) * 480.0
    d = (u / FU)[None, :, None] * r + (v / FV)[:, None, None] * a + f  # (h, w, 3)
    lam_wall = (field.width / 2 - c[1]) / d[..., 1]
    lam_floor = np.where(d[..., 2] < 0, -c[2] / np.minimum(d[..., 2], -1e-12), np.inf)
    z_wall = c[2] + lam_wall * d[..., 2]
    floor = lam_floor < lam_wall
    sky = ~floor & (z_wall > field.wall_height)
    want = np.where(floor[..., None], FLOOR_RGB, np.where(sky[..., None], SKY_RGB, WALL_RGB))
    sure = np.abs(z_wall - field.wall_height) > 1e-3  # rays not grazing the wall's top
    assert (sky & sure).sum() > w and (~sky & ~floor & (z_wall > CAM.height)).sum() > w
    img = np.asarray(render_camera(jnp.asarray(pose, jnp.float32), jnp.asarray([-3.0, -1.0]),
                                   0.11, goal_corners(WORLD), field, CAM,
                                   RenderParams(width=w, height=h, field_lines=False)))
    np.testing.assert_allclose(img[sure], want[sure], atol=1e-6)
