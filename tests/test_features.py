"""Image features: analytic pinhole geometry, the NumPy reference, vmap, noise."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from tests.reference.camera_np import section2_features_np, section3_features_np
from vbl.vision import CameraParams, flatten_section3, section2_features, section3_features
from vbl.vision import section2 as S2
from vbl.vision import section3 as S3

CAM = CameraParams()
R = 0.11
HL = 8.22 / 2
GOAL = np.array([[HL, 0.75, 0.0], [HL, 0.75, 0.5], [HL, -0.75, 0.5], [HL, -0.75, 0.0]])
FU = 256 / math.tan(math.radians(67 / 2))
FV = 240 / math.tan(math.radians(60 / 2))
SIZE = np.array([0.4, 0.4, 0.3])
# tolerance: 1e-4 of each feature's range (image width for px, W*H for areas, 2 for x5)
TOL2 = np.array([512, 512, 480, 512, 2, 1, 1, 1, 1]) * 1e-4
TOL3 = np.r_[[512] * 4, [512] * 10, 512 * 480, [512] * 4, 512 * 480, [1] * 6] * 1e-4

sec2 = jax.jit(section2_features)
sec3 = jax.jit(lambda *a: flatten_section3(section3_features(*a)))
# batched versions (one compilation each, shared by the reference, vmap and noise tests)
sec2_batch = jax.jit(jax.vmap(section2_features, in_axes=(0, 0, None, None, None, 0)))
sec3_batch = jax.jit(jax.vmap(lambda p, b, o: flatten_section3(section3_features(
    p, b, R, jnp.asarray(GOAL, jnp.float32), o, jnp.asarray(SIZE, jnp.float32), CAM))))


def f32(x):
    return jnp.asarray(x, jnp.float32)


def s2(pose, ball, cam=CAM, radius=R, goal=GOAL, eps=None):
    return np.asarray(sec2(f32(pose), f32(ball), radius, f32(goal), cam, eps))


def normals(seed, n):
    """(n, SEC2_NOISE_DIM) standard normal pixel-noise draws."""
    return jax.random.normal(jax.random.key(seed), (n, S2.SEC2_NOISE_DIM), jnp.float32)


def s3(pose, ball, other, cam=CAM, size=SIZE):
    return np.asarray(sec3(f32(pose), f32(ball), R, f32(GOAL), f32(other), f32(size), cam))


# ----------------------------------------------------------------------------- analytic

def test_ball_on_optical_axis():
    # ball centre on the optical axis: ground distance g from the camera with
    # (h - r) / g = tan 26 deg; the image of a sphere seen on-axis is a circle of angular
    # radius alpha, sin alpha = r / d, so its width is 2 fu tan(alpha) = 2 fu r/sqrt(d^2-r^2)
    g = (CAM.height - R) / math.tan(math.radians(26))
    d = math.hypot(g, CAM.height - R)
    ball = [CAM.forward_offset + g, 0.0]
    x = s2([0, 0, 0], ball)
    np.testing.assert_allclose(x[S2.SEC2_BALL_SIZE], 2 * FU * R / math.sqrt(d * d - R * R),
                               rtol=1e-5)
    assert abs(x[S2.SEC2_BALL_POS]) < 1e-3 and x[S2.SEC2_BALL_VISIBLE] == 1
    y = s3([0, 0, 0], ball, [-3, 0, 0])
    np.testing.assert_allclose(y[:4], [0, 0, 2 * FU * R / math.sqrt(d * d - R * R),
                                       2 * FV * R / math.sqrt(d * d - R * R)],
                               rtol=1e-5, atol=1e-3)


@pytest.mark.parametrize("dist", [0.4, 1.0, 2.5])
def test_ball_straight_ahead_any_distance(dist):
    # straight ahead (X = 0) but off-axis: the vertical image lines u = c tangent to the
    # sphere are planes through the camera with normal (1, 0, -c/fu) at distance r from
    # the centre (0, Y, Z): (c Z / fu)^2 = r^2 (1 + c^2/fu^2) -> c = ±fu r/sqrt(Z^2-r^2),
    # Z = depth of the centre along the tilted axis.
    tau = math.radians(-26)
    z = dist * math.cos(tau) + (R - CAM.height) * math.sin(tau)
    x = s2([1.0, 0.5, 0.0], [1.0 + CAM.forward_offset + dist, 0.5])
    np.testing.assert_allclose(x[0], 2 * FU * R / math.sqrt(z * z - R * R), rtol=1e-5)
    assert abs(x[1]) < 1e-3


def test_ball_partial_at_right_border_level_camera():
    # level camera at the ball's height: the horizontal tangents from the camera to the
    # ball's equator are at angles phi_c ± asin(r/d); put the centre just beyond the border
    cam = CameraParams(height=R, tilt_deg=0.0, forward_offset=0.0)
    d = 1.5
    half = math.radians(67 / 2)
    phi_c = half + 0.5 * math.asin(R / d)         # right tangent outside, left one inside
    ball = [d * math.cos(phi_c), -d * math.sin(phi_c)]
    x = s2([0, 0, 0], ball, cam=cam)
    u_left = FU * math.tan(phi_c - math.asin(R / d))
    assert x[S2.SEC2_BALL_VISIBLE] == 1
    np.testing.assert_allclose(x[0], 256 - u_left, rtol=1e-4)
    np.testing.assert_allclose(x[1], 0.5 * (256 + u_left), rtol=1e-5)
    # moving it further right: lost to the right
    phi = half + 1.2 * math.asin(R / d)
    x = s2([0, 0, 0], [d * math.cos(phi), -d * math.sin(phi)], cam=cam)
    assert x[S2.SEC2_BALL_VISIBLE] == 0 and x[S2.SEC2_BALL_LOST_SIDE] == 1 and x[0] == 0


def test_goal_frontal_and_mirrored():
    x = s2([0, 0, 0], [1, 0])
    assert x[S2.SEC2_GOAL_VISIBLE] == 1
    assert abs(x[S2.SEC2_GOAL_POS]) < 1e-3 and abs(x[S2.SEC2_GOAL_ORIENT]) < 1e-5
    a = s2([1.0, 0.8, -0.3], [2.0, 0.3])
    b = s2([1.0, -0.8, 0.3], [2.0, -0.3])
    assert a[S2.SEC2_GOAL_ORIENT] > 0.02                 # left post nearer: taller
    np.testing.assert_allclose(a[[1, 3, 4]], -b[[1, 3, 4]], atol=1e-3)
    np.testing.assert_allclose(a[[0, 2]], b[[0, 2]], rtol=1e-5)


def test_goal_image_height_level_camera():
    # level camera at the goal's mid-height facing it at depth D: post height fv * 0.5 / D
    cam = CameraParams(height=0.25, tilt_deg=0.0, forward_offset=0.0)
    dd = 3.0
    x = s2([HL - dd, 0, 0], [-3, 0], cam=cam)
    np.testing.assert_allclose(x[S2.SEC2_GOAL_SIZE], FV * 0.5 / dd, rtol=1e-5)
    y = s3([HL - dd, 0, 0], [-3, 0], [-3, 1, 0], cam=cam)
    w, h = FU * 1.5 / dd, FV * 0.5 / dd
    np.testing.assert_allclose(y[4:12], [-w / 2, -h / 2, -w / 2, h / 2, w / 2, h / 2,
                                         w / 2, -h / 2], rtol=1e-5)
    np.testing.assert_allclose(y[12:15], [0, 0, w * h], rtol=1e-5, atol=1e-3)


def test_other_robot_front_face_level_camera():
    # level camera at the box's mid-height, box front face square on: only that face
    cam = CameraParams(height=0.15, tilt_deg=0.0, forward_offset=0.0)
    dd = 2.0
    y = s3([0, 0, 0], [-3, 0], [dd + SIZE[0] / 2, 0, 0.0], cam=cam)
    w, h = FU * SIZE[1] / dd, FV * SIZE[2] / dd
    np.testing.assert_allclose(y[15:20], [0, 0, w, h, w * h], rtol=1e-5, atol=1e-3)


def test_lost_behind_and_outside():
    x = s2([0, 0.5, math.pi], [1, 0.8])   # facing -x: +y is on the camera's right
    assert x[S2.SEC2_BALL_VISIBLE] == 0 and x[S2.SEC2_BALL_LOST_SIDE] == 1
    assert x[S2.SEC2_GOAL_VISIBLE] == 0 and x[S2.SEC2_GOAL_LOST_SIDE] == -1
    np.testing.assert_array_equal(x[:5], 0)
    x = s2([0, 0, 0], [0.5, -1.5])         # 72 deg to the right
    assert x[S2.SEC2_BALL_VISIBLE] == 0 and x[S2.SEC2_BALL_LOST_SIDE] == 1
    x = s2([0, 0, 1.4], [0.5, -1.5])       # goal far to the right of the view
    assert x[S2.SEC2_GOAL_VISIBLE] == 0 and x[S2.SEC2_GOAL_LOST_SIDE] == 1


def test_goal_partial_view_and_ranges():
    x = s2([3.6, 0, 0], [0, 0])            # close: both posts outside the image
    assert x[S2.SEC2_GOAL_VISIBLE] == 1 and abs(x[S2.SEC2_GOAL_POS]) < 1e-3
    assert 0 < x[S2.SEC2_GOAL_SIZE] <= 480
    x = s2([2.0, 1.2, -0.2], [0, 0])       # left post cut by the left border
    assert x[S2.SEC2_GOAL_VISIBLE] == 1 and -256 <= x[S2.SEC2_GOAL_POS] <= 256
    assert -1 <= x[S2.SEC2_GOAL_ORIENT] <= 1


def test_ball_occludes_post():
    pose = [2.0, 0.75, 0.0]
    free = s2(pose, [0, -2])
    hidden = s2(pose, [3.6, 0.75])         # ball in front of the left post's foot
    # left end loses its lower part: x5 = (hl - hr) / x3 falls
    assert hidden[S2.SEC2_GOAL_ORIENT] < free[S2.SEC2_GOAL_ORIENT] - 0.05
    behind = s2([2.0, 0.75, 0.0], [4.3, 0.75])   # ball inside the goal: no occlusion
    np.testing.assert_allclose(behind[2:5], free[2:5], atol=1e-4)


def test_robot_occludes_ball():
    y = s3([0, 0, 0], [2.0, 0], [1.5, 0, 0])    # ball hidden behind a 0.3 m-high box
    assert y[20] == 0 and y[22] == 1
    y = s3([0, 0, 0], [1.0, 0], [1.5, 0, 0])    # ball in front: robot area reduced
    z = s3([0, 0, 0], [1.0, 2.0], [1.5, 0, 0])
    assert y[20] == 1 and y[19] < z[19]


# ----------------------------------------------------------------------------- reference

def _random_scenes(n, seed):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        if i % 3 == 0:                      # near the goal, looking at it
            pose = [rng.uniform(2.6, 3.8), rng.uniform(-1.2, 1.2), rng.uniform(-0.8, 0.8)]
        else:
            pose = [rng.uniform(-2, 3.5), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)]
        ang = pose[2] + rng.uniform(-0.8, 0.8)
        ball = np.array(pose[:2]) + rng.uniform(0.32, 2.5) * np.array([np.cos(ang),
                                                                        np.sin(ang)])
        ang = pose[2] + rng.uniform(-0.6, 0.6)
        other = np.r_[np.array(pose[:2]) + rng.uniform(0.5, 2.5) * np.array(
            [np.cos(ang), np.sin(ang)]), rng.uniform(-np.pi, np.pi)]
        out.append((np.array(pose), ball, other))
    return out


def _batch(scenes):
    return [f32(np.stack([sc[i] for sc in scenes])) for i in range(3)]


def test_section2_matches_numpy_reference():
    scenes = _random_scenes(45, 1)
    poses, balls, _ = _batch(scenes)
    eps = normals(0, len(scenes))   # std 0: exact
    got = np.asarray(sec2_batch(poses, balls, R, f32(GOAL), CAM, eps))
    for g, (pose, ball, _) in zip(got, scenes, strict=True):
        want = section2_features_np(pose, ball, R, GOAL, CAM)
        assert np.all(np.abs(g - want) <= TOL2), (pose, ball, g, want)


def test_section3_matches_numpy_reference():
    scenes = _random_scenes(24, 2)
    got = np.asarray(sec3_batch(*_batch(scenes)))
    for g, (pose, ball, other) in zip(got, scenes, strict=True):
        want = section3_features_np(pose, ball, R, GOAL, other, SIZE, CAM)
        assert np.all(np.abs(g - want) <= TOL3), (pose, ball, other, g, want)


# ----------------------------------------------------------------------------- jax

def test_vmap_equals_loop_and_dtypes():
    poses, balls, others = _batch(_random_scenes(8, 3))
    b2 = sec2_batch(poses, balls, R, f32(GOAL), CAM, normals(0, 8))
    b3 = sec3_batch(poses, balls, others)
    assert b2.dtype == jnp.float32 and b3.dtype == jnp.float32
    assert b2.shape == (8, S2.SEC2_DIM) and b3.shape == (8, S3.SEC3_DIM)
    for i in range(8):
        np.testing.assert_allclose(np.asarray(b2[i]), s2(poses[i], balls[i]), atol=1e-3)
        np.testing.assert_allclose(np.asarray(b3[i]), s3(poses[i], balls[i], others[i]),
                                   rtol=1e-5, atol=1e-2)
    obs = jax.eval_shape(section3_features, poses[0], balls[0], R, f32(GOAL), others[0],
                         f32(SIZE), CAM)
    for leaf in jax.tree_util.tree_leaves(obs):
        assert leaf.dtype == jnp.float32


def test_pixel_noise():
    pose, ball = [1.0, 0.3, 0.1], [2.2, 0.4]
    exact = s2(pose, ball)
    np.testing.assert_array_equal(s2(pose, ball, eps=normals(0, 1)[0]), exact)  # std 0
    std = 2.0
    cam = CameraParams(pixel_noise_std=std)
    n = 4000
    xs = np.asarray(sec2_batch(jnp.tile(f32(pose), (n, 1)), jnp.tile(f32(ball), (n, 1)), R,
                               f32(GOAL), cam, normals(1, n)))
    for idx, want in ((S2.SEC2_BALL_SIZE, std), (S2.SEC2_BALL_POS, std),
                      (S2.SEC2_GOAL_POS, std / math.sqrt(2)),
                      (S2.SEC2_GOAL_SIZE, std / math.sqrt(2))):
        np.testing.assert_allclose(xs[:, idx].std(), want, rtol=0.06)
        np.testing.assert_allclose(xs[:, idx].mean(), exact[idx], atol=4 * want / 60)
    np.testing.assert_array_equal(xs[:, 5:], np.broadcast_to(exact[5:], xs[:, 5:].shape))


def test_each_pixel_noise_normal_moves_only_its_own_feature():
    """One normal at a time (std 2 px): eps[0] the ball width, eps[1] the ball u, eps[2:4]
    the goal's left/right end heights (x3 by std/2 and x5 as (h_l - h_r) / mean), eps[4:6]
    the left/right end u (x4 by std/2). Reference: the ends' heights recovered from the
    exact x3, x5 (h_l = x3 (1 + x5 / 2), h_r = x3 (1 - x5 / 2))."""
    pose, ball, std = [1.0, 0.3, 0.1], [2.2, 0.4], 2.0
    cam = CameraParams(pixel_noise_std=std)
    exact = s2(pose, ball, cam=cam).astype(np.float64)
    assert exact[S2.SEC2_BALL_VISIBLE] == exact[S2.SEC2_GOAL_VISIBLE] == 1
    x3, x5 = exact[S2.SEC2_GOAL_SIZE], exact[S2.SEC2_GOAL_ORIENT]
    assert abs(x5) < 0.5
    h = np.array([x3 * (1 + x5 / 2), x3 * (1 - x5 / 2)])
    for k in range(S2.SEC2_NOISE_DIM):
        want = exact.copy()
        if k < 2:
            want[[S2.SEC2_BALL_SIZE, S2.SEC2_BALL_POS][k]] += std
        elif k < 4:
            hk = h.copy()
            hk[k - 2] += std
            want[S2.SEC2_GOAL_SIZE] = hk.mean()
            want[S2.SEC2_GOAL_ORIENT] = (hk[0] - hk[1]) / hk.mean()
        else:
            want[S2.SEC2_GOAL_POS] += std / 2
        got = s2(pose, ball, cam=cam, eps=np.eye(S2.SEC2_NOISE_DIM, dtype=np.float32)[k])
        assert np.all(np.abs(got - want) <= TOL2), (k, got - want)


def test_noise_never_makes_a_size_negative_section2():
    """A normal of -40 (80 px at std 2) on the 75 px ball width gives width 0; -50 on the
    left end's height makes it 0: x3 = h_right / 2 and x5 = (0 - h_r) / x3 clipped to -1.
    Positions are not clipped: -40 on the ball's u moves it by -80 px."""
    pose, ball = [1.0, 0.3, 0.1], [2.2, 0.4]
    cam = CameraParams(pixel_noise_std=2.0)
    exact = s2(pose, ball, cam=cam).astype(np.float64)
    h_r = exact[S2.SEC2_GOAL_SIZE] * (1 - exact[S2.SEC2_GOAL_ORIENT] / 2)
    got = s2(pose, ball, cam=cam, eps=np.array([-40, -40, -50, 0, 0, 0], np.float32))
    assert got[S2.SEC2_BALL_SIZE] == 0.0
    np.testing.assert_allclose(got[S2.SEC2_BALL_POS], exact[S2.SEC2_BALL_POS] - 80, atol=1e-3)
    np.testing.assert_allclose(got[S2.SEC2_GOAL_SIZE], h_r / 2, rtol=1e-5)
    assert got[S2.SEC2_GOAL_ORIENT] == -1.0


def test_each_section3_noise_normal_moves_only_its_own_coordinate():
    """Flat layout: ball 0-3 (u, v, width, height) take eps 0-3, the goal's 4 end points
    (4-11) and area centroid (12, 13) eps 4-13, the other robot's centroid and box (15-18)
    eps 14-17; the areas (14, 19), flags and lost sides take none. A -60 normal (120 px)
    makes the ball's 75 px width and the robot's 106 px height 0, not negative."""
    pose, ball, other, std = [1.0, 0.3, 0.1], [2.2, 0.4], [2.6, -0.6, 0.3], 2.0
    cam = CameraParams(pixel_noise_std=std)
    target = [*range(0, 14), *range(15, 19)]  # eps k -> flat index target[k]
    args = (f32(pose), f32(ball), R, f32(GOAL), f32(other), f32(SIZE), cam)
    exact = np.asarray(sec3(*args, jnp.zeros(S3.SEC3_NOISE_DIM)), np.float64)  # one compile
    assert np.all(exact[20:23] == 1)
    for k in range(S3.SEC3_NOISE_DIM):
        got = np.asarray(sec3(*args, jnp.eye(S3.SEC3_NOISE_DIM)[k]), np.float64)
        want = exact.copy()
        want[target[k]] += std
        np.testing.assert_allclose(got, want, atol=2e-3, err_msg=f"eps[{k}]")
    eps = jnp.zeros(S3.SEC3_NOISE_DIM).at[2].set(-60.0).at[17].set(-60.0)
    got = np.asarray(sec3(*args, eps))
    assert got[2] == 0.0 and got[18] == 0.0


def test_feature_inputs_are_checked_before_any_tracing():
    """S2.check_inputs: sizes must be > 0 (a ball of radius 0, a robot of width 0 are
    refused), values finite, batches of one size; equal batches pass."""
    ok = (np.zeros(3), np.zeros(2), R, GOAL, CAM)
    S2.check_inputs(*ok)
    S2.check_inputs(np.zeros((5, 3)), np.zeros((5, 2)), R, np.zeros((5, 4, 3)), CAM,
                    np.zeros((5, 3)), np.tile(SIZE, (5, 1)))
    for radius in (0.0, -R, np.nan):
        with pytest.raises(ValueError, match="ball_radius must be > 0"):
            S2.check_inputs(np.zeros(3), np.zeros(2), radius, GOAL, CAM)
    with pytest.raises(ValueError, match="other_size"):
        S2.check_inputs(*ok, np.zeros(3), [0.4, 0.0, 0.3])
    with pytest.raises(ValueError, match="ball_xy must be finite"):
        S2.check_inputs(np.zeros(3), [np.inf, 0.0], R, GOAL, CAM)
    with pytest.raises(ValueError, match=r"ball_xy has batch shape \(4,\); the others have "
                                         r"\(5,\)"):
        S2.check_inputs(np.zeros((5, 3)), np.zeros((4, 2)), R, np.zeros((5, 4, 3)), CAM)
    with pytest.raises(ValueError, match=r"other_pose has shape \(2,\)"):
        S2.check_inputs(*ok, np.zeros(2), SIZE)
