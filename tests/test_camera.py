"""Pinhole camera: analytic projections, the NumPy reference, dtypes and validation."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from tests.reference.camera_np import project_points_np
from vbl.params import ParamError, validate
from vbl.vision import CameraParams, check_inputs, project_points

CAM = CameraParams()
FU = 256 / math.tan(math.radians(67 / 2))
FV = 240 / math.tan(math.radians(60 / 2))
project = jax.jit(project_points)


def _axes(theta, tilt_deg=-26.0):
    """Camera forward / right / up unit vectors written out by hand."""
    tau = math.radians(tilt_deg)
    f = np.array([math.cos(theta) * math.cos(tau), math.sin(theta) * math.cos(tau),
                  math.sin(tau)])
    r = np.array([math.sin(theta), -math.cos(theta), 0.0])
    return f, r, np.cross(r, f)


def _centre(pose, cam=CAM):
    return np.array([pose[0] + cam.forward_offset * math.cos(pose[2]),
                     pose[1] + cam.forward_offset * math.sin(pose[2]), cam.height])


@pytest.mark.parametrize("theta", [0.0, 0.7, -2.5])
def test_optical_axis_projects_to_origin(theta):
    pose = np.array([0.3, -0.4, theta])
    f, _, _ = _axes(theta)
    pts = _centre(pose) + np.outer([0.5, 1.0, 3.0], f)
    uv, depth = project(jnp.asarray(pts, jnp.float32), jnp.asarray(pose, jnp.float32), CAM)
    np.testing.assert_allclose(np.asarray(uv), 0.0, atol=1e-3)
    np.testing.assert_allclose(np.asarray(depth), [0.5, 1.0, 3.0], rtol=1e-5)
    assert uv.dtype == jnp.float32 and depth.dtype == jnp.float32


def test_fov_edges_project_to_border():
    pose = np.array([1.0, 0.5, 0.4])
    f, r, a = _axes(pose[2])
    th, tv = math.tan(math.radians(67 / 2)), math.tan(math.radians(60 / 2))
    c = _centre(pose)
    pts = np.stack([c + 2.0 * (f + th * r), c + 2.0 * (f - th * r),
                    c + 2.0 * (f + tv * a), c + 2.0 * (f - tv * a)])
    uv, _ = project(jnp.asarray(pts, jnp.float32), jnp.asarray(pose, jnp.float32), CAM)
    np.testing.assert_allclose(np.asarray(uv), [[256, 0], [-256, 0], [0, 240], [0, -240]],
                               atol=2e-3)


def test_focal_lengths_and_floor_point():
    # the optical axis meets the floor at h / tan(26 deg) ahead of the camera
    pose = np.zeros(3)
    g = CAM.height / math.tan(math.radians(26))
    uv, depth = project(jnp.array([[CAM.forward_offset + g, 0.0, 0.0]], jnp.float32),
                        jnp.zeros(3, jnp.float32), CAM)
    np.testing.assert_allclose(np.asarray(uv), 0.0, atol=1e-3)
    np.testing.assert_allclose(float(depth[0]), math.hypot(g, CAM.height), rtol=1e-6)
    # a point 1 m to the left of the axis at depth 2: u = -fu / 2
    f, r, _ = _axes(0.0)
    p = _centre(pose) + 2.0 * f - 1.0 * r
    uv, _ = project(jnp.asarray(p[None], jnp.float32), jnp.zeros(3, jnp.float32), CAM)
    np.testing.assert_allclose(float(uv[0, 0]), -FU / 2, rtol=1e-5)


def test_behind_camera_has_negative_depth_and_finite_uv():
    uv, depth = project(jnp.array([[-2.0, 0.3, 0.2]], jnp.float32),
                        jnp.zeros(3, jnp.float32), CAM)
    assert float(depth[0]) < 0 and np.all(np.isfinite(np.asarray(uv)))


def test_points_behind_or_nearer_than_the_near_plane_divide_by_it():
    """Documented: for a depth below near_plane the division uses near_plane (finite, never
    NaN): u = fu X / near, v = fv Y / near, as the NumPy reference computes; a point at the
    camera centre projects to the image centre."""
    pose = np.array([0.4, -0.2, 0.7])
    f, r, a = _axes(pose[2])
    c = _centre(pose)
    pts = np.stack([c - 0.5 * f + 0.2 * r + 0.1 * a, c + 0.004 * f - 0.3 * r - 0.2 * a, c])
    uv, depth = project(jnp.asarray(pts, jnp.float32), jnp.asarray(pose, jnp.float32), CAM)
    ruv, rd = project_points_np(pts, pose, CAM)
    np.testing.assert_allclose(np.asarray(depth), [-0.5, 0.004, 0.0], atol=1e-5)
    np.testing.assert_allclose(np.asarray(uv), ruv, rtol=1e-4, atol=1e-2)
    np.testing.assert_allclose(np.asarray(uv[1]), [-0.3 * FU / CAM.near_plane,
                                                   -0.2 * FV / CAM.near_plane], rtol=1e-3)
    np.testing.assert_array_equal(np.asarray(uv[2]), [0.0, 0.0])


def test_matches_numpy_reference():
    rng = np.random.default_rng(0)
    poses = np.c_[rng.uniform(-3, 3, (20, 2)), rng.uniform(-np.pi, np.pi, 20)]
    pts = rng.uniform([-4, -2, 0], [4, 2, 1], (20, 5, 3))
    uv, depth = jax.vmap(project, in_axes=(0, 0, None))(
        jnp.asarray(pts, jnp.float32), jnp.asarray(poses, jnp.float32), CAM)
    for i in range(20):
        ruv, rd = project_points_np(pts[i], poses[i], CAM)
        front = rd > 0.2
        np.testing.assert_allclose(np.asarray(depth[i]), rd, atol=1e-5)
        np.testing.assert_allclose(np.asarray(uv[i])[front], ruv[front], rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("field,value", [("hfov_deg", 180.0), ("hfov_deg", 0.0),
                                         ("vfov_deg", -5.0), ("height", -0.1),
                                         ("tilt_deg", 95.0), ("pixel_noise_std", -1.0),
                                         ("image_width", 0)])
def test_bad_params_raise(field, value):
    with pytest.raises(ParamError, match=field):
        validate(CameraParams(**{field: value}))


def test_a_near_plane_at_or_above_the_camera_height_is_refused():
    """The near plane must lie below the camera's height (a floor point straight below is
    nearer than the camera is high)."""
    validate(CameraParams(height=0.2, near_plane=0.19))
    for near in (0.2, 0.3):
        with pytest.raises(ParamError, match="near_plane"):
            validate(CameraParams(height=0.2, near_plane=near))


def test_check_inputs_shapes_and_sizes():
    gc = np.zeros((4, 3))
    check_inputs(np.zeros(3), np.zeros(2), 0.11, gc, CAM)
    with pytest.raises(ValueError, match="robot_pose"):
        check_inputs(np.zeros(2), np.zeros(2), 0.11, gc, CAM)
    with pytest.raises(ValueError, match="goal_corners"):
        check_inputs(np.zeros(3), np.zeros(2), 0.11, np.zeros((3, 3)), CAM)
    with pytest.raises(ValueError, match="ball_radius"):
        check_inputs(np.zeros(3), np.zeros(2), -0.1, gc, CAM)
    with pytest.raises(ValueError, match="ball_radius must be > 0"):  # a ball of no size
        check_inputs(np.zeros(3), np.zeros(2), 0.0, gc, CAM)
    with pytest.raises(ValueError, match="other_size"):
        check_inputs(np.zeros(3), np.zeros(2), 0.11, gc, CAM, np.zeros(3), [0.4, -1, 0.3])
    with pytest.raises(ValueError, match="batch shape"):
        check_inputs(np.zeros((5, 3)), np.zeros((4, 2)), 0.11, np.zeros((5, 4, 3)), CAM)
    with pytest.raises(ParamError, match="hfov_deg"):
        check_inputs(np.zeros(3), np.zeros(2), 0.11, gc, CameraParams(hfov_deg=200.0))


def test_pixel_noise_is_std_times_the_draws_on_visible_objects_only():
    from vbl.vision import CameraParams
    from vbl.vision.noise import add_pixel_noise

    eps = jnp.asarray([1.0, -2.0, 0.5])
    values = jnp.asarray([10.0, 20.0, 0.0])
    vis = jnp.asarray([True, True, False])
    got = add_pixel_noise(eps, values, CameraParams(pixel_noise_std=3.0), vis)
    np.testing.assert_array_equal(got, [13.0, 14.0, 0.0])
    off = add_pixel_noise(eps, values, CameraParams(), vis)
    np.testing.assert_array_equal(off, values)
    assert off.dtype == jnp.float32


def test_a_stored_value_is_exactly_the_value():
    from vbl.vision.fusion import stored, stored_once

    x = jnp.asarray([0.1, -3.7, 1e-30, 2.5e7], jnp.float32)
    np.testing.assert_array_equal(jax.jit(stored_once)(x), x)
    np.testing.assert_array_equal(stored(x, jnp.float32(1.0)), x)
