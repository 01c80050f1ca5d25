"""Pixel images of the robot's camera and a top view of the field (pure JAX, float32).

The camera image is ray cast: one ray per pixel centre, from the camera model of
:mod:`vbl.vision.camera` (the same pose, tilt, field of view and near plane the analytic
features of :mod:`vbl.vision.projection` use), intersected with the floor, the four walls,
the goal mouth, the ball (a sphere) and the other robot (the box ``[length, width,
height]`` the analytic Section 3 camera sees); the nearest hit beyond the near plane
gives the pixel its colour. Every array operation works on whole images (``(H, W)``
arrays), and a batch is a ``jax.vmap`` over scenes: there is no Python loop over pixels
or scenes. Reference: ``docs/render.md``.

Pixel ``(i, j)`` of an ``H x W`` image (row ``i`` from the top, column ``j`` from the
left) looks through the camera point ``u = ((j + 1/2) / W - 1/2) * cam.image_width``,
``v = (1/2 - (i + 1/2) / H) * cam.image_height`` (px of the analytic camera: origin at
the image centre, u right, v up), so an image of any size covers the same field of view.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import param
from vbl.vision.camera import F32, CameraParams, camera_frame, focal_lengths
from vbl.world.params import FieldParams, WorldParams
from vbl.world.physics import goal_corners as world_goal_corners

__all__ = ["RenderParams", "pixel_grid", "render_camera", "render_top", "render_world",
           "to_uint8", "FLOOR_RGB", "LINE_RGB", "WALL_RGB", "SKY_RGB", "GOAL_RGB",
           "BALL_RGB", "OTHER_RGB", "ROBOT_RGB", "VIEW_TINT", "OUTSIDE_RGB", "LIGHT_DIR",
           "GOAL_DEPTH_BIAS"]

#: Colours (linear RGB in [0, 1]). The blob detector (:mod:`vbl.vision.blobs`) finds the
#: ball, goal and other robot by hue; the floor (hue 130 deg) and the grey/white
#: surfaces (saturation < 0.1) fall outside all three of its colour classes.
FLOOR_RGB = (0.13, 0.45, 0.18)     #: carpet, green
LINE_RGB = (0.92, 0.92, 0.92)      #: field lines, white
WALL_RGB = (0.85, 0.85, 0.82)      #: walls, off-white
SKY_RGB = (0.25, 0.25, 0.28)       #: above the walls, dark grey
GOAL_RGB = (0.10, 0.25, 0.85)      #: goal mouth, blue (hue 228 deg)
BALL_RGB = (0.90, 0.15, 0.10)      #: ball, red (hue 4 deg)
OTHER_RGB = (0.95, 0.85, 0.10)     #: the other robot, yellow (hue 53 deg)
ROBOT_RGB = (0.95, 0.95, 0.95)     #: the camera's own robot in the top view, white
VIEW_TINT = 0.35                   #: top view: the camera's floor footprint is lightened by this
OUTSIDE_RGB = (0.10, 0.10, 0.10)   #: top view: beyond the walls
#: Direction towards the light (world frame, unit vector) for the ball's and the robot's
#: shading; shading scales brightness only (hue and saturation stay, so blob masks do not
#: depend on it).
LIGHT_DIR = tuple(float(x) for x in np.array([0.3, 0.2, 0.93]) / np.linalg.norm([0.3, 0.2, 0.93]))
#: The goal mouth lies in the end wall's plane; its hits are taken this much nearer (m) so
#: the goal, not the wall, wins the tie.
GOAL_DEPTH_BIAS = 1e-3
#: Smallest |denominator| of a ray-plane division; smaller ones are replaced by this
#: number with their sign (finite, no NaN).
_TINY = 1e-12
#: "No hit" depth, m.
_FAR = 1e9


@struct.dataclass
class RenderParams:
    """Image sizes and drawing options of the renderer (sizes and switches are static)."""

    width: int = param(512, doc="camera image width W' (the field of view is the camera's "
                       "at any size)", unit="px", source="P", static=True, gt=0)
    height: int = param(480, doc="camera image height H'", unit="px", source="P",
                        static=True, gt=0)
    field_lines: bool = param(True, doc="draw the halfway line and the centre circle",
                              static=True)
    line_width: float = param(0.05, doc="field line width", unit="m", gt=0.0)
    centre_circle_radius: float = param(0.5, doc="centre circle radius", unit="m", gt=0.0)
    shading: float = param(0.3, doc="fraction of the ball's and robot's brightness that "
                           "depends on the light direction (0 = flat colours)", ge=0.0, le=0.6)
    top_width: int = param(320, doc="top view width", unit="px", static=True, gt=0)
    top_height: int = param(192, doc="top view height", unit="px", static=True, gt=0)
    top_margin: float = param(0.3, doc="top view: margin shown around the field", unit="m",
                              ge=0.0)
    top_goal_depth: float = param(0.15, doc="top view: depth of the goal drawn behind the "
                                  "goal line", unit="m", gt=0.0)
    top_heading_width: float = param(0.04, doc="top view: width of a robot's heading mark",
                                     unit="m", gt=0.0)


def _safe_recip(x):
    """1 / x with |x| < _TINY replaced by +-_TINY (finite)."""
    tiny = jnp.asarray(_TINY, F32)
    return 1.0 / jnp.where(jnp.abs(x) < tiny, jnp.where(x < 0, -tiny, tiny), x)


def pixel_grid(cam: CameraParams, width: int, height: int):
    """Camera coordinates of the pixel centres of a ``height x width`` image.

    Returns ``u`` (width,) and ``v`` (height,) float32 px of the analytic camera (origin
    at the image centre, u right, v up; row 0 is the top row), and the pixel size
    ``(su, sv)`` in those px (``cam.image_width / width``, ``cam.image_height / height``).
    """
    cw = jnp.asarray(cam.image_width, F32)
    ch = jnp.asarray(cam.image_height, F32)
    u = ((jnp.arange(width, dtype=F32) + 0.5) / width - 0.5) * cw
    v = (0.5 - (jnp.arange(height, dtype=F32) + 0.5) / height) * ch
    return u, v, (cw / width, ch / height)


def _rays(cam: CameraParams, width: int, height: int, frame):
    """World directions (3 arrays (H, W)) of the pixel rays, scaled so that the camera
    depth of ``C + lam * d`` is ``lam`` (m)."""
    u, v, _ = pixel_grid(cam, width, height)
    fu, fv = focal_lengths(cam)
    t = (u / fu)[None, :]
    s = (v / fv)[:, None]
    rot = frame.rot
    return [t * rot[0, k] + s * rot[1, k] + rot[2, k] for k in range(3)]


def _rgb(c):
    return jnp.asarray(c, F32)


def _pick(layers, default):
    """Colour (H, W, 3) of the nearest layer: ``layers`` = [(depth (H, W), rgb (H, W, 3) or
    (3,))] with depth ``_FAR`` where the layer is not hit."""
    depth = jnp.full(layers[0][0].shape, _FAR, F32)
    out = jnp.broadcast_to(_rgb(default), depth.shape + (3,))
    for d, col in layers:
        near = d < depth
        out = jnp.where(near[..., None], col, out)
        depth = jnp.where(near, d, depth)
    return out


def _shade(rgb, n, rp: RenderParams):
    """``rgb`` (3,) scaled by ``1 - shading * (1 - max(n . light, 0))``; n: 3 arrays."""
    lam = n[0] * LIGHT_DIR[0] + n[1] * LIGHT_DIR[1] + n[2] * LIGHT_DIR[2]
    k = 1.0 - jnp.asarray(rp.shading, F32) * (1.0 - jnp.maximum(lam, 0.0))
    return k[..., None] * _rgb(rgb)


def _floor_colour(x, y, rp: RenderParams):
    """Carpet or line colour (H, W, 3) at floor points ``x, y`` (H, W) m."""
    if not rp.field_lines:
        return jnp.broadcast_to(_rgb(FLOOR_RGB), x.shape + (3,))
    hw = 0.5 * jnp.asarray(rp.line_width, F32)
    circ = jnp.abs(jnp.sqrt(x * x + y * y) - jnp.asarray(rp.centre_circle_radius, F32)) <= hw
    line = (jnp.abs(x) <= hw) | circ
    return jnp.where(line[..., None], _rgb(LINE_RGB), _rgb(FLOOR_RGB))


def _room(c, d, field: FieldParams, near, rp: RenderParams):
    """Where each ray leaves the walled field: (depth (H, W) m, colour (H, W, 3)).

    The camera is inside the box of the field and the walls, so each ray leaves it
    through one side wall, the floor, or the open top (sky). Floor beyond the walls is
    never seen (walls are higher than the camera)."""
    half = (0.5 * jnp.asarray(field.length, F32), 0.5 * jnp.asarray(field.width, F32))
    lam_w = []
    for k in range(2):
        wall = jnp.where(d[k] >= 0, half[k], -half[k])
        lam_w.append((wall - c[k]) * _safe_recip(d[k]))
    lam_wall = jnp.minimum(lam_w[0], lam_w[1])
    lam_floor = jnp.where(d[2] < 0, -c[2] * _safe_recip(d[2]), _FAR)
    on_floor = lam_floor <= lam_wall
    lam = jnp.where(on_floor, lam_floor, lam_wall)
    z = c[2] + lam * d[2]
    sky = ~on_floor & (z > jnp.asarray(field.wall_height, F32))
    fx, fy = c[0] + lam_floor * d[0], c[1] + lam_floor * d[1]
    col = jnp.where(on_floor[..., None], _floor_colour(fx, fy, rp),
                    jnp.where(sky[..., None], _rgb(SKY_RGB), _rgb(WALL_RGB)))
    return jnp.where(lam >= near, lam, _FAR), col


def _goal_hit(c, d, corners, near):
    """Depth (H, W) m of the rays' hits on the goal mouth (the parallelogram of the
    corners left-bottom, left-top, _, right-bottom), ``_FAR`` where missed."""
    c0 = corners[0]
    e1, e2 = corners[3] - c0, corners[1] - c0
    n = jnp.cross(e1, e2)
    nd = n[0] * d[0] + n[1] * d[1] + n[2] * d[2]
    lam = sum(n[k] * (c0[k] - c[k]) for k in range(3)) * _safe_recip(nd)
    p = [c[k] + lam * d[k] - c0[k] for k in range(3)]
    a = (p[0] * e1[0] + p[1] * e1[1] + p[2] * e1[2]) / jnp.dot(e1, e1)
    b = (p[0] * e2[0] + p[1] * e2[1] + p[2] * e2[2]) / jnp.dot(e2, e2)
    hit = (lam >= near) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    return jnp.where(hit, lam - GOAL_DEPTH_BIAS, _FAR)


def _ball_hit(c, d, centre, radius, near, rp: RenderParams):
    """Depth (H, W) m of the rays' first hits on the ball and its shaded colour."""
    oc = [c[k] - centre[k] for k in range(3)]
    a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    b = d[0] * oc[0] + d[1] * oc[1] + d[2] * oc[2]
    cc = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - radius * radius
    disc = b * b - a * cc
    lam = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / a
    hit = (disc >= 0) & (lam >= near)
    n = [(oc[k] + lam * d[k]) / radius for k in range(3)]
    return jnp.where(hit, lam, _FAR), _shade(BALL_RGB, n, rp)


def _box_hit(c, d, pose, size, near, rp: RenderParams):
    """Depth (H, W) m of the rays' entry into the box ``size = [length, width, height]``
    standing on the floor at ``pose = (x, y, theta)`` (length along theta), and its shaded
    colour. A ray entering before the near plane does not count (as in the analytic
    camera, whose box faces are clipped to the near plane)."""
    cs, sn = jnp.cos(pose[2]), jnp.sin(pose[2])
    half = 0.5 * size
    rel = [c[0] - pose[0], c[1] - pose[1], c[2] - half[2]]
    cl = [cs * rel[0] + sn * rel[1], -sn * rel[0] + cs * rel[1], rel[2]]
    dl = [cs * d[0] + sn * d[1], -sn * d[0] + cs * d[1], d[2]]
    t_in, t_out = [], []
    for k in range(3):
        inv = _safe_recip(dl[k])
        t1, t2 = (-half[k] - cl[k]) * inv, (half[k] - cl[k]) * inv
        t_in.append(jnp.minimum(t1, t2))
        t_out.append(jnp.maximum(t1, t2))
    lam_in = jnp.maximum(jnp.maximum(t_in[0], t_in[1]), t_in[2])
    lam_out = jnp.minimum(jnp.minimum(t_out[0], t_out[1]), t_out[2])
    hit = (lam_in <= lam_out) & (lam_in >= near)
    # outward normal of the entry face: the axis whose slab is entered last
    axis = jnp.where(t_in[0] >= jnp.maximum(t_in[1], t_in[2]), 0,
                     jnp.where(t_in[1] >= t_in[2], 1, 2))
    sign = -jnp.sign(jnp.where(axis == 0, dl[0], jnp.where(axis == 1, dl[1], dl[2])))
    nl = [jnp.where(axis == k, sign, 0.0) for k in range(3)]
    n = [cs * nl[0] - sn * nl[1], sn * nl[0] + cs * nl[1], nl[2]]
    return jnp.where(hit, lam_in, _FAR), _shade(OTHER_RGB, n, rp)


def render_camera(robot_pose, ball_xy, ball_radius, goal_corners, field: FieldParams,
                  cam: CameraParams, rp: RenderParams, other_pose=None,
                  other_size=None) -> jnp.ndarray:
    """The robot camera's image: (rp.height, rp.width, 3) float32 RGB in [0, 1].

    Args:
      robot_pose: (3,) ``(x, y, theta)`` m, m, rad of the robot carrying the camera.
      ball_xy: (2,) ball centre on the floor, m (the centre is at height ``ball_radius``).
      ball_radius: scalar, m.
      goal_corners: (4, 3) world m, left-bottom, left-top, right-top, right-bottom (a
        parallelogram; :func:`vbl.world.goal_corners`).
      field: field size and wall height.
      cam: the camera (pose on the robot, tilt, field of view, near plane).
      rp: image size and drawing options.
      other_pose: optional (3,) pose of the other robot, drawn as the box ``other_size``
        (3,) ``[length, width, height]`` m standing on the floor (the analytic Section 3
        camera's body); None: no other robot.

    The camera's own robot is not drawn (the analytic camera does not see it either).
    """
    frame = camera_frame(jnp.asarray(robot_pose, F32), cam)
    c = [frame.c[k] for k in range(3)]
    d = _rays(cam, rp.width, rp.height, frame)
    near = jnp.asarray(cam.near_plane, F32)
    layers = [_room(c, d, field, near, rp)]
    layers.append((_goal_hit(c, d, jnp.asarray(goal_corners, F32), near), _rgb(GOAL_RGB)))
    r = jnp.asarray(ball_radius, F32)
    bxy = jnp.asarray(ball_xy, F32)
    layers.append(_ball_hit(c, d, jnp.stack([bxy[0], bxy[1], r]), r, near, rp))
    if other_pose is not None:
        layers.append(_box_hit(c, d, jnp.asarray(other_pose, F32),
                               jnp.asarray(other_size, F32), near, rp))
    return _pick(layers, SKY_RGB).astype(F32)


def to_uint8(img) -> jnp.ndarray:
    """RGB in [0, 1] (..., 3) float -> uint8 (rounded, clipped)."""
    return jnp.round(jnp.clip(img, 0.0, 1.0) * 255.0).astype(jnp.uint8)


def _in_view(x, y, robot_pose, cam: CameraParams):
    """True (H, W) where the floor point (x, y, 0) projects inside the camera image."""
    frame = camera_frame(jnp.asarray(robot_pose, F32), cam)
    p = [x - frame.c[0], y - frame.c[1], -frame.c[2]]
    xc, yc, zc = (p[0] * frame.rot[i, 0] + p[1] * frame.rot[i, 1] + p[2] * frame.rot[i, 2]
                  for i in range(3))
    fu, fv = focal_lengths(cam)
    zs = jnp.maximum(zc, jnp.asarray(cam.near_plane, F32))
    u, v = fu * xc / zs, fv * yc / zs
    hw = 0.5 * jnp.asarray(cam.image_width, F32)
    hh = 0.5 * jnp.asarray(cam.image_height, F32)
    return (zc >= cam.near_plane) & (jnp.abs(u) <= hw) & (jnp.abs(v) <= hh)


def _disc(x, y, cx, cy, r):
    return (x - cx) ** 2 + (y - cy) ** 2 <= r * r


def _heading_mark(x, y, pose, length, width):
    """True (H, W) on the segment from the robot centre along its heading."""
    ex, ey = jnp.cos(pose[2]), jnp.sin(pose[2])
    px, py = x - pose[0], y - pose[1]
    along = px * ex + py * ey
    across = jnp.abs(-px * ey + py * ex)
    return (along >= 0) & (along <= length) & (across <= 0.5 * width)


def render_top(robot_pose, ball_xy, ball_radius, goal_corners, field: FieldParams,
               cam: CameraParams, rp: RenderParams, robot_radius,
               other_pose=None) -> jnp.ndarray:
    """Top view of the field: (rp.top_height, rp.top_width, 3) float32 RGB in [0, 1].

    +x (towards the goal) points right, +y up; the whole field plus ``rp.top_margin`` is
    shown at one scale (m per px = the larger of the two axes' needs), centred. Drawn:
    carpet (and lines), the goal behind the +x goal line (blue, ``rp.top_goal_depth``
    deep), the floor the camera sees (lightened by ``VIEW_TINT``: floor points that
    project inside the image, ignoring occlusion), the camera's robot (white disc of
    ``robot_radius`` with a dark heading mark), the other robot (yellow) and the ball (red).
    Inputs as :func:`render_camera`.
    """
    tw, th = rp.top_width, rp.top_height
    L, W = jnp.asarray(field.length, F32), jnp.asarray(field.width, F32)
    m = jnp.asarray(rp.top_margin, F32)
    scale = jnp.maximum((L + 2 * m) / tw, (W + 2 * m) / th)   # m per px
    x = ((jnp.arange(tw, dtype=F32) + 0.5 - 0.5 * tw) * scale)[None, :]
    y = ((0.5 * th - jnp.arange(th, dtype=F32) - 0.5) * scale)[:, None]
    x, y = jnp.broadcast_arrays(x, y)
    inside = (jnp.abs(x) <= L / 2) & (jnp.abs(y) <= W / 2)
    img = jnp.where(inside[..., None], _floor_colour(x, y, rp), _rgb(OUTSIDE_RGB))
    pose = jnp.asarray(robot_pose, F32)
    view = inside & _in_view(x, y, pose, cam)
    img = jnp.where(view[..., None], img + VIEW_TINT * (1.0 - img), img)
    gc = jnp.asarray(goal_corners, F32)
    gx = gc[0, 0]
    gy_lo, gy_hi = jnp.minimum(gc[0, 1], gc[3, 1]), jnp.maximum(gc[0, 1], gc[3, 1])
    goal = (x >= gx) & (x <= gx + rp.top_goal_depth) & (y >= gy_lo) & (y <= gy_hi)
    img = jnp.where(goal[..., None], _rgb(GOAL_RGB), img)
    rr = jnp.asarray(robot_radius, F32)
    hw = jnp.asarray(rp.top_heading_width, F32)
    robots = [(pose, ROBOT_RGB)]
    if other_pose is not None:
        robots.append((jnp.asarray(other_pose, F32), OTHER_RGB))
    for p, col in robots:
        img = jnp.where(_disc(x, y, p[0], p[1], rr)[..., None], _rgb(col), img)
        mark = _heading_mark(x, y, p, rr, jnp.maximum(hw, scale))
        img = jnp.where(mark[..., None], _rgb(OUTSIDE_RGB), img)
    bxy = jnp.asarray(ball_xy, F32)
    r = jnp.maximum(jnp.asarray(ball_radius, F32), scale)
    img = jnp.where(_disc(x, y, bxy[0], bxy[1], r)[..., None], _rgb(BALL_RGB), img)
    return img.astype(F32)


def render_world(robots, ball_xy, world: WorldParams, cam: CameraParams, rp: RenderParams,
                 me: int = 0, robot_height=0.3):
    """Camera image and top view of robot ``me`` (static int) in a world state.

    Args:
      robots: (R, 3) robot poses (``WorldState.robots``); ball_xy: (2,) m.
      world: world parameters (field, goal, ball radius, robot radius).
      cam, rp: camera and drawing parameters.
      me: the robot whose camera is drawn; with R = 2 the other robot is drawn as the box
        ``[2 robot.radius, 2 robot.radius, robot_height]`` (the body the Section 3
        observation sees; ``robot_height`` m).

    Returns ``(camera (rp.height, rp.width, 3), top (rp.top_height, rp.top_width, 3))``
    float32 RGB in [0, 1].
    """
    robots = jnp.asarray(robots, F32)
    corners = world_goal_corners(world)
    r = jnp.asarray(world.ball.radius, F32)
    other, size = None, None
    if robots.shape[0] > 1:
        other = robots[1 - me]
        dia = 2 * jnp.asarray(world.robot.radius, F32)
        size = jnp.stack([dia, dia, jnp.asarray(robot_height, F32)])
    img = render_camera(robots[me], ball_xy, r, corners, world.field, cam, rp, other, size)
    top = render_top(robots[me], ball_xy, r, corners, world.field, cam, rp,
                     world.robot.radius, other)
    return img, top

