"""Green's theorem on clamped boundaries (vbl.vision.section3) and the Section 3 camera's
edge cases, against independent truth: the NumPy reference's Sutherland-Hodgman
clipping and shoelace formula (``tests/reference/camera_np``)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from tests.reference.camera_np import (
    _area_centroid,
    _clip_poly_box,
    project_points_np,
    robot_box_corners_np,
    section3_features_np,
    to_cam_np,
)
from vbl.vision import CameraParams, flatten_section3, section3_features
from vbl.vision import section3 as S3

CAM = CameraParams()
R = 0.11
HL = 8.22 / 2
GOAL = np.array([[HL, 0.75, 0.0], [HL, 0.75, 0.5], [HL, -0.75, 0.5], [HL, -0.75, 0.0]])
SIZE = np.array([0.4, 0.4, 0.3])
# tolerance: 1e-4 of each feature's range (image width for px, W*H for areas)
TOL3 = np.r_[[512] * 4, [512] * 10, 512 * 480, [512] * 4, 512 * 480, [1] * 6] * 1e-4


#: Below this visible area (px^2) a region is a sub-pixel sliver: float32 inputs (camera
#: frame, projected corners) leave its centroid good to about a pixel, not 1e-4 of 512.
SLIVER = 1.0


def _tol(want):
    """TOL3, with centroids of sub-pixel slivers (goal, other robot) compared to 1 px."""
    tol = TOL3.copy()
    for area, cols in ((14, [12, 13]), (19, [15, 16])):
        if 0 < want[area] < SLIVER:
            tol[cols] = 1.0
    return tol


def f32(x):
    return jnp.asarray(x, jnp.float32)


chain_in_rects = jax.jit(S3._chain_in_rects)
sec3_batch = jax.jit(jax.vmap(lambda p, b, o: flatten_section3(section3_features(
    p, b, R, f32(GOAL), o, f32(SIZE), CAM))))


def _random_convex(rng, n, centre, radius):
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    rad = radius * rng.uniform(0.5, 1.0)
    return centre + rad * np.stack([np.cos(ang), np.sin(ang) * rng.uniform(0.3, 1.5)], -1)


def _truth(poly, lo, hi):
    clipped = _clip_poly_box([np.asarray(p, float) for p in poly], lo, hi)
    a, mu, mv = _area_centroid(clipped)
    if a <= 0:
        return 0.0, 0.0, 0.0, None
    arr = np.array(clipped)
    return a, mu, mv, (arr.min(axis=0), arr.max(axis=0))


def test_green_on_clamped_boundary_matches_polygon_clipping():
    # random convex polygons (either orientation, edges shuffled, some far outside the
    # image like near-plane projections) inside random boxes: area, moments, bounding box
    rng = np.random.default_rng(0)
    for i in range(60):
        poly = _random_convex(rng, int(rng.integers(3, 9)), rng.uniform(-400, 400, 2),
                              rng.uniform(20, 3000))
        if i % 2:
            poly = poly[::-1]
        lo = rng.uniform([-256, -240], [100, 100])
        hi = lo + rng.uniform(5, 400, 2)
        p0, p1 = poly, np.roll(poly, -1, axis=0)
        order = rng.permutation(len(poly))
        reg = chain_in_rects(f32(p0[order]), f32(p1[order]), f32(np.ones(len(poly))),
                             f32(lo[None]), f32(hi[None]), f32(rng.uniform(-50, 50, 2)))
        a, mu, mv, box = _truth(poly, lo, hi)
        sign = 1.0 if float(reg.area[0]) >= 0 else -1.0
        scale = (hi - lo).prod()
        np.testing.assert_allclose(sign * float(reg.area[0]), a, atol=1e-4 * scale + 1e-3)
        if a > 1e-3 * scale:
            np.testing.assert_allclose(sign * float(reg.mu[0]) / a, mu / a, atol=0.05)
            np.testing.assert_allclose(sign * float(reg.mv[0]) / a, mv / a, atol=0.05)
            np.testing.assert_allclose(np.asarray(reg.lo), box[0], atol=0.02)
            np.testing.assert_allclose(np.asarray(reg.hi), box[1], atol=0.02)
        elif box is None:
            assert np.any(np.asarray(reg.hi) <= np.asarray(reg.lo) + 1e-3)


def test_green_boundary_with_hole_and_zero_weights():
    # an annulus-like region: outer square +1, inner square reversed (a hole), plus
    # segments of weight 0 that must change nothing (neither sums nor bounding box)
    outer = np.array([[-100, -80], [120, -80], [120, 90], [-100, 90]], float)
    inner = np.array([[-20, -10], [-20, 30], [40, 30], [40, -10]], float)   # clockwise
    junk = np.array([[900, 900], [-900, 700]], float)
    p0 = np.concatenate([outer, inner, junk[:1]])
    p1 = np.concatenate([np.roll(outer, -1, 0), np.roll(inner, -1, 0), junk[1:]])
    w = np.r_[np.ones(8), 0.0]
    lo, hi = np.array([-256.0, -240.0]), np.array([256.0, 240.0])
    reg = chain_in_rects(f32(p0), f32(p1), f32(w), f32(lo[None]), f32(hi[None]), f32([0, 0]))
    a_out, mu_out, mv_out, _ = _truth(outer, lo, hi)
    a_in, mu_in, mv_in, _ = _truth(inner, lo, hi)
    np.testing.assert_allclose(float(reg.area[0]), a_out - a_in, rtol=1e-5)
    np.testing.assert_allclose(float(reg.mu[0]), mu_out - mu_in, rtol=1e-4, atol=1.0)
    np.testing.assert_allclose(float(reg.mv[0]), mv_out - mv_in, rtol=1e-4, atol=1.0)
    np.testing.assert_allclose(np.asarray(reg.lo), outer.min(axis=0), atol=1e-3)
    np.testing.assert_allclose(np.asarray(reg.hi), outer.max(axis=0), atol=1e-3)


# ----------------------------------------------------------------------------- edge cases

def _near_plane_crossing(pose, other):
    zs = [to_cam_np(p, pose, CAM)[2] for p in robot_box_corners_np(other, SIZE)]
    return min(zs) < CAM.near_plane < max(zs)


EDGE_SCENES = {
    # the other robot beside the camera: corners behind the near plane, cut by the border
    "robot partly behind the near plane": ([0, 0, 0], [1.5, -0.5], [0.1, 0.4, 0.3]),
    "robot partly behind the near plane, right": ([0, 0, 0], [1.5, 0.5], [0.1, -0.4, -0.3]),
    # ... and straddling the camera, filling the image's width (its chords matter)
    "robot filling the view": ([0, 0, 0], [2.5, 0.3], [0.2, 0.0, 0.8]),
    # straddling the left / right image border
    "robot at the left border": ([0, 0, 0], [1.2, 0], [1.5, 1.05, 0.4]),
    "robot at the right border": ([0, 0, 0], [1.2, 0], [1.6, -1.1, -0.2]),
    "robot at the bottom border": ([0, 0, 0], [2.5, 0.5], [0.55, 0.05, 0.1]),
    # ball between the camera and the robot, overlapping it
    "ball in front of the robot": ([0, 0, 0], [0.8, 0.05], [1.5, 0.1, 0.3]),
    "ball in front, robot at the border": ([0, 0, 0], [0.9, 0.45], [1.5, 0.9, 0.0]),
    # robot (and ball) in front of the goal
    "robot in front of the goal": ([1.5, 0, 0], [0, -2], [3.0, 0.2, 0.5]),
    "robot and ball in front of the goal": ([1.5, 0, 0], [2.4, -0.3], [3.0, 0.3, 0.0]),
    # lost objects: robot behind the camera, ball far left, goal behind
    "robot behind the camera": ([0, 0, 0], [1.0, 0.2], [-1.0, 0.3, 0.0]),
    "everything lost": ([0, 0.3, math.pi], [1.0, 2.5], [2.0, 0.8, 0.0]),
}


def test_edge_scenes_match_numpy_reference():
    names = list(EDGE_SCENES)
    poses, balls, others = (np.array([EDGE_SCENES[n][i] for n in names], float)
                            for i in range(3))
    got = np.asarray(sec3_batch(f32(poses), f32(balls), f32(others)))
    for name, g, pose, ball, other in zip(names, got, poses, balls, others, strict=True):
        want = section3_features_np(pose, ball, R, GOAL, other, SIZE, CAM)
        assert np.all(np.abs(g - want) <= _tol(want)), (name, g, want)
    # the scenes are what their names say
    rows = dict(zip(names, got, strict=True))
    for name in ("robot partly behind the near plane",
                 "robot partly behind the near plane, right", "robot filling the view"):
        assert _near_plane_crossing(EDGE_SCENES[name][0], EDGE_SCENES[name][2]), name
        assert rows[name][22] == 1, name
    for name in ("robot at the left border", "robot at the right border",
                 "robot at the bottom border"):
        pose, _, other = EDGE_SCENES[name]
        uv, _ = project_points_np(robot_box_corners_np(other, SIZE), pose, CAM)
        cut = [(uv[:, i].min() < -h < uv[:, i].max()) or (uv[:, i].min() < h < uv[:, i].max())
               for i, h in ((0, 256), (1, 240))]
        assert rows[name][22] == 1 and any(cut), name
    assert rows["robot filling the view"][17] == 512
    front = rows["ball in front of the robot"]
    assert front[20] == 1 and front[22] == 1
    assert front[19] < section3_features_np([0, 0, 0], [0.8, 3.0], R, GOAL, [1.5, 0.1, 0.3],
                                            SIZE, CAM)[19] - 100
    assert rows["robot behind the camera"][22] == 0
    assert np.all(rows["everything lost"][20:23] == 0)
    np.testing.assert_array_equal(rows["everything lost"][:20], 0)
    np.testing.assert_array_equal(rows["everything lost"][23:], [1, -1, 1])


@pytest.mark.parametrize("seed", [11, 12])
def test_random_close_scenes_match_numpy_reference(seed):
    # the other robot close to the camera (0.25 - 1 m, any heading, anywhere in a wide
    # cone): near-plane cuts, border straddles and ball occlusion happen often
    rng = np.random.default_rng(seed)
    n = 24
    poses = np.c_[rng.uniform(-1, 2, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    ang = poses[:, 2] + rng.uniform(-1.2, 1.2, n)
    dist = rng.uniform(0.25, 1.0, n)
    others = np.c_[poses[:, :2] + dist[:, None] * np.c_[np.cos(ang), np.sin(ang)],
                   rng.uniform(-np.pi, np.pi, n)]
    ang_b = ang + rng.uniform(-0.2, 0.2, n)
    balls = poses[:, :2] + (dist * rng.uniform(0.5, 1.5, n))[:, None] * np.c_[
        np.cos(ang_b), np.sin(ang_b)]
    got = np.asarray(sec3_batch(f32(poses), f32(balls), f32(others)))
    for g, pose, ball, other in zip(got, poses, balls, others, strict=True):
        want = section3_features_np(pose, ball, R, GOAL, other, SIZE, CAM)
        assert np.all(np.abs(g - want) <= _tol(want)), (pose, ball, other, g, want)


@pytest.mark.parametrize("height", [0.3, 0.6])
def test_every_face_pattern_matches_numpy_reference(height):
    # the camera (0.35 m high) all around the other robot, looking at it from 0.5 and
    # 1.5 m: every pattern of front faces it can see (top front for the 0.3 m box, top
    # not front for the 0.6 m one; per local axis the + face, the - face or neither)
    # gives the reference's silhouette
    size = np.array([0.5, 0.3, height])
    other = np.array([0.4, -0.2, 0.7])
    bearing = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    dist = np.repeat([0.5, 1.5], len(bearing))
    bearing = np.tile(bearing, 2) + 0.07
    cam_xy = other[:2] + dist[:, None] * np.c_[np.cos(bearing), np.sin(bearing)]
    poses = np.c_[cam_xy - CAM.forward_offset * np.c_[np.cos(bearing + np.pi),
                                                        np.sin(bearing + np.pi)],
                  bearing + np.pi]
    balls = np.tile([[-3.0, 2.9]], (len(poses), 1))
    sec3 = jax.jit(jax.vmap(lambda p, b, o: flatten_section3(section3_features(
        p, b, R, f32(GOAL), o, f32(size), CAM)), (0, 0, None)))
    got = np.asarray(sec3(f32(poses), f32(balls), f32(other)))
    patterns = set()
    c, s = math.cos(other[2]), math.sin(other[2])
    for g, pose, ball in zip(got, poses, balls, strict=True):
        want = section3_features_np(pose, ball, R, GOAL, other, size, CAM)
        assert want[22] == 1
        assert np.all(np.abs(g - want) <= _tol(want)), (pose, g, want)
        rel = cam_xy_of(pose) - other[:2]
        loc = (c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1])
        patterns.add(tuple(int(np.sign(v) * (abs(v) > h / 2))
                           for v, h in zip(loc, size[:2], strict=True)))
    assert len(patterns) == 8


def cam_xy_of(pose):
    return pose[:2] + CAM.forward_offset * np.array([math.cos(pose[2]), math.sin(pose[2])])
