"""Closed-form images (vbl/vision/projection.py) against brute force: the ball's visible
box against rays cast through a fine grid of image points (NumPy), and the interval and
segment clipping against hand-worked cases."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from vbl.vision.camera import CameraParams, focal_lengths
from vbl.vision.projection import _clip_rect as clip_rect
from vbl.vision.projection import ball_image, lost_side, project, subtract_interval

CAM = CameraParams()
R = 0.11


def _brute_box(centre, r, step=0.5):
    """(u_lo, u_hi, v_lo, v_hi) of the image points (px, every ``step``) whose ray hits
    the sphere, or None when none does."""
    fu, fv = (float(f) for f in focal_lengths(CAM))
    w, h = CAM.image_width / 2, CAM.image_height / 2
    u = np.arange(-w, w + step / 2, step)
    v = np.arange(-h, h + step / 2, step)
    c = np.asarray(centre, np.float64)
    d = np.stack(np.broadcast_arrays(u[None, :] / fu, v[:, None] / fv, 1.0), -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    along = d @ c
    hit = (along > 0) & (c @ c - along**2 <= r * r)
    if not hit.any():
        return None
    cols, rows = np.flatnonzero(hit.any(0)), np.flatnonzero(hit.any(1))
    return u[cols[0]], u[cols[-1]], v[rows[0]], v[rows[-1]]


@pytest.mark.parametrize("centre", [
    (0.0, 0.0, 1.0),        # straight ahead
    (0.3, -0.1, 0.8),       # off-centre, inside the image
    (0.62, 0.05, 0.9),      # cut by the right border
    (-0.6, 0.55, 0.9),      # cut by a corner (left, v > 0)
    (0.05, -0.6, 1.0),      # cut by the v < 0 edge
])
def test_the_visible_ball_box_is_that_of_the_rays_hitting_the_sphere(centre):
    bi = ball_image(jnp.asarray(centre, jnp.float32), R, CAM)
    want = _brute_box(centre, R)
    assert bool(bi.visible) and want is not None
    got = [float(x) for x in (bi.u_lo, bi.u_hi, bi.v_lo, bi.v_hi)]
    np.testing.assert_allclose(got, want, atol=0.75)


def test_a_ball_outside_the_view_or_at_the_near_plane_is_not_visible():
    assert _brute_box((3.0, 0.0, 1.0), R) is None
    assert not bool(ball_image(jnp.asarray([3.0, 0.0, 1.0]), R, CAM).visible)
    behind = ball_image(jnp.asarray([0.0, 0.0, R]), R, CAM)  # its near side at depth 0
    assert not bool(behind.valid) and not bool(behind.visible)


@pytest.mark.parametrize("occ, want", [
    ((-2.0, 3.0), (3.0, 10.0)),    # cuts the low end
    ((0.0, 3.0), (3.0, 10.0)),     # from the low end exactly
    ((8.0, 12.0), (0.0, 8.0)),     # cuts the high end
    ((4.0, 6.0), (0.0, 10.0)),     # inside: the extent stays
    ((-1.0, 11.0), None),          # covers it all: empty
    ((12.0, 15.0), (0.0, 10.0)),   # beside it
])
def test_subtracting_an_occluder_from_an_interval(occ, want):
    lo, hi = (float(x) for x in subtract_interval(0.0, 10.0, *occ, True))
    if want is None:
        assert lo == hi
    else:
        assert (lo, hi) == want
    assert [float(x) for x in subtract_interval(0.0, 10.0, *occ, False)] == [0.0, 10.0]


def test_segments_are_clipped_to_the_image_box():
    box = ((-10.0, -5.0), (10.0, 5.0))
    (a, b), (c, d), ok = clip_rect((-20.0, 0.0), (20.0, 10.0), *box)
    assert bool(ok)
    np.testing.assert_allclose([a, b, c, d], [-10.0, 2.5, 0.0, 5.0], atol=1e-5)
    (a, b), (c, d), ok = clip_rect((-3.0, 1.0), (2.0, -4.0), *box)  # inside: unchanged
    assert bool(ok)
    np.testing.assert_allclose([a, b, c, d], [-3.0, 1.0, 2.0, -4.0])
    for p0, p1 in (((-20.0, 7.0), (20.0, 7.0)), ((11.0, -9.0), (30.0, 9.0)),
                   ((12.0, 0.0), (12.0, 3.0))):
        assert not bool(clip_rect(p0, p1, *box)[2])


def test_lost_side_and_projection_at_the_mid_plane_and_near_plane():
    np.testing.assert_array_equal(lost_side(jnp.asarray([-0.1, 0.0, 0.2])), [-1, 1, 1])
    p = project(jnp.asarray([[0.2, -0.1, 0.5], [0.2, -0.1, 0.001]]), 100.0, 50.0, 0.01)
    np.testing.assert_allclose(p, [[40.0, -10.0], [2000.0, -500.0]], rtol=1e-6)
