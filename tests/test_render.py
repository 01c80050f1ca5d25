"""The pixel renderer (vbl.vision.render): the same camera as the analytic features, each
object where the analytic camera puts it, occlusion by depth, sizes, dtypes, the top view.
"""

from __future__ import annotations

import functools
import importlib.util
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.vision.blobs import MASK_BALL, MASK_GOAL, MASK_OTHER, BlobParams, colour_masks
from vbl.vision.camera import CameraParams, camera_frame, project_points, to_camera
from vbl.vision.projection import ball_image
from vbl.vision.render import (
    BALL_RGB,
    FLOOR_RGB,
    OTHER_RGB,
    ROBOT_RGB,
    RenderParams,
    pixel_grid,
    render_camera,
    render_top,
    render_world,
    to_uint8,
)
from vbl.vision.scenes import OTHER_HEIGHT, SCENE_KINDS, random_scenes
from vbl.vision.section3 import flatten_section3, section3_features
from vbl.world import WorldParams, goal_corners

WORLD = WorldParams()
CAM = CameraParams()
BP = BlobParams()
GC = goal_corners(WORLD)
R = WORLD.ball.radius
SIZE = jnp.asarray([2 * WORLD.robot.radius, 2 * WORLD.robot.radius, OTHER_HEIGHT])
CHUNK = 16
#: Float32 rounding allowance of a pixel centre's position against an analytic edge, px.
EPS = 0.02


@functools.cache
def _masks_program(with_other, section3):
    """Compiled (pose, ball, other) (B, ...) -> colour masks (B, 3, 480, 512), the analytic
    ball box (B, 4), the projected ball centre (B, 2) and (``section3``) the analytic
    Section 3 vector (B, 26), else zeros (the analytic Section 3 camera is left out of
    programs that do not need it: it is most of their compile time)."""
    rp = RenderParams()

    def one(pose, ball, other):
        img = render_camera(pose, ball, R, GC, WORLD.field, CAM, rp,
                            other if with_other else None, SIZE if with_other else None)
        bw = jnp.stack([ball[0], ball[1], jnp.asarray(R, jnp.float32)])
        bi = ball_image(to_camera(bw, camera_frame(pose, CAM)), R, CAM)
        centre, _ = project_points(bw, pose, CAM)
        a3 = (flatten_section3(section3_features(pose, ball, R, GC, other, SIZE, CAM))
              if section3 else jnp.zeros(26, jnp.float32))
        return (colour_masks(to_uint8(img), BP), jnp.stack([bi.u_lo, bi.u_hi, bi.v_lo, bi.v_hi]),
                centre, a3)

    return jax.jit(jax.vmap(one))


def _run(kind, n, seed, with_other, section3=False):
    s = random_scenes(n, kind, seed=seed, world=WORLD)
    prog = _masks_program(with_other, section3)
    outs = [[np.asarray(x) for x in prog(s["pose"][i:i + CHUNK], s["ball"][i:i + CHUNK],
                                         s["other"][i:i + CHUNK])] for i in range(0, n, CHUNK)]
    return [np.concatenate([o[j] for o in outs]) for j in range(4)]


def _check_ball_pixels(kind, n, seed):
    """Red pixels of the ball (no other robot) lie inside the analytic ball's image box; a
    visible ball has red pixels spanning that box to within a pixel at each edge; the pixel
    at the projected ball centre is red when the centre is in the image."""
    masks, box, centre, _ = _run(kind, n, seed, with_other=False)
    u, v = (np.asarray(x) for x in pixel_grid(CAM, 512, 480)[:2])
    bad = []
    for i in range(n):
        red = masks[i, MASK_BALL]
        lo_u, hi_u, lo_v, hi_v = box[i]
        if not red.any():
            if hi_u - lo_u >= 2 and hi_v - lo_v >= 2:
                bad.append(f"{kind} {i}: analytic ball {box[i]} has no red pixel")
            continue
        rows, cols = np.nonzero(red)
        pu, pv = u[cols], v[rows]
        if (pu.min() < lo_u - EPS or pu.max() > hi_u + EPS or pv.min() < lo_v - EPS
                or pv.max() > hi_v + EPS):
            bad.append(f"{kind} {i}: red pixels outside the analytic box {box[i]}")
        # the extreme red pixel centres lie within a pixel of the box's edges (the extent
        # across a border the ball touches is read half a pixel inside it, where the
        # outline spans less: not checked)
        side = lo_u <= -255.99 or hi_u >= 255.99
        end = lo_v <= -239.99 or hi_v >= 239.99
        short_u = (pu.min() - lo_u > 1.0 + EPS or hi_u - pu.max() > 1.0 + EPS) and not end
        short_v = (pv.min() - lo_v > 1.0 + EPS or hi_v - pv.max() > 1.0 + EPS) and not side
        if (short_u or short_v) and min(hi_u - lo_u, hi_v - lo_v) >= 4:
            bad.append(f"{kind} {i}: red pixels span less than the analytic box {box[i]}")
        cu, cv = centre[i]
        if abs(cu) < 255 and abs(cv) < 239:
            j, k = int(np.floor(cu + 256)), int(np.floor(240 - cv))
            if not red[k, j]:
                bad.append(f"{kind} {i}: pixel of the projected ball centre is not red")
    assert not bad, "\n".join(bad[:20])


@pytest.mark.parametrize("kind", ["close", "far", "left", "right", "bottom", "lost"])
def test_ball_pixels_sit_where_the_analytic_camera_puts_the_ball(kind):
    _check_ball_pixels(kind, 16, seed=3)


@pytest.mark.slow
def test_ball_pixels_on_1024_scenes():
    for kind in SCENE_KINDS:
        _check_ball_pixels(kind, 128, seed=31)


def test_occlusion_by_depth():
    """Adding the other robot only turns pixels yellow, and the ball's lost red pixels
    become yellow (the robot is in front); a ball in front of the robot keeps its pixels."""
    bad = []
    for kind in ("occluded", "close"):
        with_o = _run(kind, 16, 7, with_other=True)[0]
        without = _run(kind, 16, 7, with_other=False)[0]
        red_lost = without[:, MASK_BALL] & ~with_o[:, MASK_BALL]
        if np.any(red_lost & ~with_o[:, MASK_OTHER]):
            bad.append(f"{kind}: red pixels hidden by something not yellow")
        if np.any(with_o[:, MASK_BALL] & ~without[:, MASK_BALL]):
            bad.append(f"{kind}: the robot made red pixels")
        if kind == "occluded" and red_lost.any(axis=(1, 2)).mean() < 0.5:
            bad.append("occluded scenes rarely hide the ball")
    # the ball in front of the robot: ball 0.5 m ahead, robot 2 m ahead on the same line
    pose = jnp.asarray([0.0, 0.0, 0.0])
    rp = RenderParams()
    front = render_camera(pose, jnp.asarray([0.6, 0.0]), R, GC, WORLD.field, CAM, rp,
                          jnp.asarray([2.0, 0.0, 0.3]), SIZE)
    alone = render_camera(pose, jnp.asarray([0.6, 0.0]), R, GC, WORLD.field, CAM, rp)
    m_front = np.asarray(colour_masks(to_uint8(front), BP))
    m_alone = np.asarray(colour_masks(to_uint8(alone), BP))
    np.testing.assert_array_equal(m_front[MASK_BALL], m_alone[MASK_BALL])
    assert m_front[MASK_OTHER].sum() > 100
    assert not bad, bad


def test_goal_and_robot_pixels_lie_in_the_analytic_regions():
    """Blue pixels lie inside the box of the analytic goal's end points, yellow pixels
    inside the analytic robot's bounding box (scenes with the ball clear of both)."""
    masks, box, _, a3 = _run("close", 16, 9, with_other=True, section3=True)
    u, v = (np.asarray(x) for x in pixel_grid(CAM, 512, 480)[:2])
    checked = 0
    for i in range(len(a3)):
        if a3[i, 21] > 0 and masks[i, MASK_GOAL].any():
            pts = a3[i, 4:12].reshape(4, 2)
            ok = np.all(pts != 0, axis=1)
            if ok.all():
                rows, cols = np.nonzero(masks[i, MASK_GOAL])
                assert u[cols].min() >= pts[:, 0].min() - 1 and u[cols].max() <= pts[:, 0].max() + 1
                assert v[rows].min() >= pts[:, 1].min() - 1 and v[rows].max() <= pts[:, 1].max() + 1
                checked += 1
        if a3[i, 22] > 0 and masks[i, MASK_OTHER].any():
            cu, cv, w, h = a3[i, 15:19]
            rows, cols = np.nonzero(masks[i, MASK_OTHER])
            if not masks[i, MASK_BALL].any():   # no ball box cuts the analytic one
                assert np.abs(u[cols] - cu).max() <= w / 2 + EPS
                assert np.abs(v[rows] - cv).max() <= h / 2 + EPS
                checked += 1
    assert checked >= 5


@pytest.mark.slow  # 42 s: a compilation per size and batch
def test_shapes_dtypes_sizes_and_batching():
    rp = RenderParams(width=64, height=60)
    pose, ball = jnp.asarray([0.0, 0.0, 0.0]), jnp.asarray([1.0, 0.0])
    img = jax.jit(lambda p, b: render_camera(p, b, R, GC, WORLD.field, CAM, rp))(pose, ball)
    assert img.shape == (60, 64, 3) and img.dtype == jnp.float32
    assert float(img.min()) >= 0 and float(img.max()) <= 1
    u8 = to_uint8(img)
    assert u8.dtype == jnp.uint8
    poses = jnp.tile(pose, (5, 1)).at[:, 2].set(jnp.linspace(-1, 1, 5))
    batch = jax.vmap(lambda p: render_camera(p, ball, R, GC, WORLD.field, CAM, rp))(poses)
    assert batch.shape == (5, 60, 64, 3)
    np.testing.assert_allclose(np.asarray(batch[2]), np.asarray(img), atol=1e-5)
    # the same field of view at every size: the ball straight ahead is at the centre
    for w, h in ((64, 60), (128, 120), (512, 480)):
        rpw = RenderParams(width=w, height=h)
        m = jax.jit(lambda p, b, rpw=rpw: colour_masks(to_uint8(render_camera(
            p, b, R, GC, WORLD.field, CAM, rpw)), BP))(pose, ball)
        rows, cols = np.nonzero(np.asarray(m[MASK_BALL]))
        uu, vv, _ = pixel_grid(CAM, w, h)
        cu, cv = np.asarray(project_points(jnp.asarray([1.0, 0.0, R]), pose, CAM)[0])
        assert abs(np.asarray(uu)[cols].mean() - cu) < 512 / w
        assert abs(np.asarray(vv)[rows].mean() - cv) < 480 / h + 2


def test_floor_walls_and_lines():
    pose = jnp.asarray([-1.0, 0.0, np.pi])          # looking at the -x wall, 3 m away
    rp = RenderParams(width=64, height=60, field_lines=False)
    img = np.asarray(render_camera(pose, jnp.asarray([3.0, 1.0]), R, GC, WORLD.field, CAM, rp))
    np.testing.assert_allclose(img[-1], np.broadcast_to(FLOOR_RGB, (64, 3)), atol=1e-6)
    # looking at x = 0 from 1 m: the halfway line crosses the image when lines are on
    look = jnp.asarray([-1.0, 0.0, 0.0])
    on = np.asarray(render_camera(look, jnp.asarray([3.0, 1.9]), R, GC, WORLD.field, CAM,
                                  RenderParams(width=128, height=120)))
    white = np.all(on > 0.9, axis=-1)
    assert white.sum() > 50
    off = np.asarray(render_camera(look, jnp.asarray([3.0, 1.9]), R, GC, WORLD.field, CAM,
                                   RenderParams(width=128, height=120, field_lines=False)))
    assert np.all(off > 0.9, axis=-1).sum() < white.sum()


def _other_robot_is_a_box_of_its_diameter(img, robots, rp):
    """render_world's other robot is the box [2 radius, 2 radius, 0.3 m]: its yellow pixels
    span the u extent of that box's corners (NumPy pinhole reference) inside the image, to
    a pixel."""
    from tests.reference.camera_np import project_points_np

    yellow = np.asarray(colour_masks(img, BlobParams())[MASK_OTHER])
    (x, y, th), r = robots[1], WORLD.robot.radius
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    corners = np.array([[*(np.array([x, y]) + rot @ [sx * r, sy * r]), z]
                        for sx in (-1, 1) for sy in (-1, 1) for z in (0.0, 0.3)])
    uv, depth = project_points_np(corners, robots[0], CAM)
    assert np.all(depth > CAM.near_plane)
    hw = CAM.image_width / 2
    lo, hi = np.clip(uv[:, 0].min(), -hw, hw), np.clip(uv[:, 0].max(), -hw, hw)
    assert hi - lo > 50  # well inside the image: a box of half the size would differ
    u = np.asarray(pixel_grid(CAM, rp.width, rp.height)[0])
    cols = np.flatnonzero(yellow.any(axis=0))
    su = CAM.image_width / rp.width
    assert abs(u[cols].min() - lo) <= su and abs(u[cols].max() - hi) <= su


def test_top_view_and_render_world():
    rp = RenderParams(width=64, height=60)
    robots = jnp.asarray([[0.0, 0.0, 0.0], [2.0, 1.0, 1.0]])
    ball = jnp.asarray([1.0, -0.5])
    cam_img, top = jax.jit(lambda r, b: render_world(r, b, WORLD, CAM, rp))(robots, ball)
    assert cam_img.shape == (60, 64, 3) and top.shape == (rp.top_height, rp.top_width, 3)
    top = np.asarray(top)
    scale = max((WORLD.field.length + 2 * rp.top_margin) / rp.top_width,
                (WORLD.field.width + 2 * rp.top_margin) / rp.top_height)

    def px(x, y):
        return int(rp.top_height / 2 - y / scale), int(rp.top_width / 2 + x / scale)

    np.testing.assert_allclose(top[px(1.0, -0.5)], BALL_RGB, atol=1e-6)
    np.testing.assert_allclose(top[px(2.0 - 0.1 * np.cos(1.0), 1.0 - 0.1 * np.sin(1.0))],
                               OTHER_RGB, atol=1e-6)
    np.testing.assert_allclose(top[px(0.0, 0.15)], ROBOT_RGB, atol=1e-6)
    # the view cone: lightened floor ahead of the robot, plain floor behind it
    ahead, behind = top[px(1.5, 0.2)], top[px(-1.5, 0.2)]
    assert ahead.mean() > behind.mean() + 0.1
    _other_robot_is_a_box_of_its_diameter(np.asarray(cam_img), np.asarray(robots), rp)
    one_robot = render_world(robots[:1], ball, WORLD, CAM, rp)[0]
    assert one_robot.shape == (60, 64, 3)
    top2 = render_top(robots[0], ball, R, GC, WORLD.field, CAM, rp, WORLD.robot.radius)
    assert top2.shape == top.shape


def test_render_is_pure_and_float32():
    """No global JAX setting changes on import; outputs stay float32 with x64 on."""
    with jax.enable_x64(True):
        img = render_camera(jnp.zeros(3), jnp.asarray([1.0, 0.0]), R, GC, WORLD.field, CAM,
                            RenderParams(width=16, height=15))
    assert img.dtype == jnp.float32


def _load_benchmark():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "render_throughput.py"
    spec = importlib.util.spec_from_file_location("bench_render_throughput", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_render_throughput_benchmark_runs_tiny(tmp_path, capsys):
    """benchmarks/render_throughput.py at its --tiny size (the analytic row is left out
    here: its compilation is most of the time, and test_blobs compiles that camera), and
    a working-set limit that skips every combination."""
    bench = _load_benchmark()
    out = tmp_path / "rt"
    assert bench.main(["--tiny", "--rows", "render", "pixel features", "--out", str(out)]) == 0
    result = json.loads(out.with_suffix(".json").read_text())
    assert [r["row"] for r in result["rows"]] == ["render", "pixel features"]
    assert all(r["frames_per_s"] > 0 and r["calls"] >= 1 for r in result["rows"])
    md = out.with_suffix(".md").read_text()
    assert "| 16x15 | 1 |" in md and "| - |" in md      # analytic column left empty
    assert bench.main(["--tiny", "--max-gb", "0", "--out", str(out)]) == 0
    result = json.loads(out.with_suffix(".json").read_text())
    assert result["rows"] == [] and len(result["skipped"]) == 1
    assert "Skipped" in out.with_suffix(".md").read_text()
    assert bench.working_set_gb(1024, 512, 480) > bench.MAX_GB
    capsys.readouterr()
