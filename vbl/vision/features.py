"""Image features of the ball, the goal and another robot, by projecting geometry.

Nothing is rasterised: every feature is a closed-form function of the camera pose and
the object geometry (pure JAX, float32, jit/vmap-able, no data-dependent branches).
Exact definitions, clipping and occlusion rules are in ``docs/vision.md``; in short

* the ball (a sphere) images to an ellipse (the cone of rays tangent to the sphere cut
  by the image plane); its visible part is that ellipse intersected with the image
  rectangle, and extents are computed exactly from the conic;
* straight edges (goal posts, crossbar, robot box edges) are clipped to the near plane
  in 3-D, projected, and clipped to the image rectangle (Liang-Barsky);
* areas and centroids of planar regions (the goal mouth, the other robot's silhouette)
  use Green's theorem on their boundary, a set of directed segments in any order (the
  robot's silhouette edges, the near plane's chords), mapped into a rectangle by the
  clamp onto it (:func:`_chain_in_rects`);
* an object the camera cannot see at all is *lost*; its lost side is -1 when its
  reference point lies left of the camera's vertical mid-plane (camera X < 0), else +1.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.vision.camera import F32, CameraParams, camera_frame, focal_lengths, to_camera
from vbl.vision.noise import add_pixel_noise

__all__ = [
    "SEC2_DIM", "SEC2_BALL_SIZE", "SEC2_BALL_POS", "SEC2_GOAL_SIZE", "SEC2_GOAL_POS",
    "SEC2_GOAL_ORIENT", "SEC2_BALL_VISIBLE", "SEC2_GOAL_VISIBLE", "SEC2_BALL_LOST_SIDE",
    "SEC2_GOAL_LOST_SIDE", "SEC2_NOISE_DIM", "SEC3_NOISE_DIM", "SEC3_BALL_DIM",
    "SEC3_GOAL_DIM", "SEC3_OTHER_DIM", "SEC3_DIM",
    "Section3Obs", "section2_features", "section3_features", "flatten_section3",
    "ball_image", "check_inputs",
]

SEC2_DIM = 9
SEC2_BALL_SIZE = 0
SEC2_BALL_POS = 1
SEC2_GOAL_SIZE = 2
SEC2_GOAL_POS = 3
SEC2_GOAL_ORIENT = 4
SEC2_BALL_VISIBLE = 5
SEC2_GOAL_VISIBLE = 6
SEC2_BALL_LOST_SIDE = 7
SEC2_GOAL_LOST_SIDE = 8

#: Standard normals one Section 2 observation's pixel noise takes: ball width, u; goal
#: h_left, h_right, u_left, u_right.
SEC2_NOISE_DIM = 6

SEC3_BALL_DIM = 4
SEC3_GOAL_DIM = 11
SEC3_OTHER_DIM = 5
SEC3_DIM = SEC3_BALL_DIM + SEC3_GOAL_DIM + SEC3_OTHER_DIM + 3 + 3
#: Standard normals one Section 3 observation's pixel noise takes: the ball's 4 features,
#: the goal's 4 end points (8) and area centroid (2), the other robot's centroid and extent.
SEC3_NOISE_DIM = 4 + 10 + 4

#: Smallest |denominator| of a division; smaller ones are replaced by +-_TINY (no NaN).
_TINY = 1e-12
#: Stand-in for "no candidate" in min/max reductions over image coordinates, px.
_BIG = 1e9
#: Smallest visible area of a region (goal, other robot), px^2: below it the object is lost.
_MIN_AREA = 1e-6


def _safe_div(a, b):
    """a / b with b == 0 replaced by a tiny number of the same sign (finite, no NaN)."""
    tiny = jnp.asarray(_TINY, jnp.result_type(b))
    b = jnp.where(jnp.abs(b) < tiny, jnp.where(b < 0, -tiny, tiny), b)
    return a / b


def _lost_side(x_cam):
    """-1 when the reference point is left of the camera mid-plane (X < 0), else +1."""
    return jnp.where(x_cam < 0, jnp.float32(-1.0), jnp.float32(1.0))


# ----------------------------------------------------------------------------- ball (sphere)

def _chord(p, xf, xb, z, k):
    """Chord of the sphere's image conic along the line ``fixed coordinate = p``.

    Normalised image coordinates (t, s) = (X/Z, Y/Z); ``xf``/``xb`` are the sphere centre's
    camera coordinates along the fixed / free axis, ``z`` its depth, ``k = |B|^2 - r^2``.
    A ray (t, s, 1) hits the sphere iff ``(X t + Y s + Z)^2 >= k (t^2 + s^2 + 1)``.
    Returns (lo, hi, exists) of the free coordinate.
    """
    a = k - xb * xb                       # > 0 whenever the sphere is in front (z > r)
    w = xf * p + z
    bh = xb * w
    c = w * w - k * (p * p + 1.0)
    disc = bh * bh + a * c
    exists = disc > 0
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    return _safe_div(bh - sq, a), _safe_div(bh + sq, a), exists


def _extremes(xa, xb, z, r, ha, hb):
    """The ellipse's two extreme points along axis ``a`` (normalised coordinates).

    Returns their ``a`` coordinates (2,) and whether each lies inside the rectangle
    ``[-ha, ha] x [-hb, hb]`` (2,) bool.
    """
    den = z * z - r * r
    root = r * jnp.sqrt(jnp.maximum(xa * xa + z * z - r * r, 0.0))
    a_ext = jnp.stack([_safe_div(xa * z - root, den), _safe_div(xa * z + root, den)])
    b_ext = _safe_div(xb * (xa * a_ext + z), xa * xa + z * z - r * r)
    return a_ext, (jnp.abs(a_ext) <= ha) & (jnp.abs(b_ext) <= hb)


def _axis_extent(a_ext, ok_ext, lo_c, hi_c, ok_c, ok_side, ha):
    """Extent along axis ``a`` of (ellipse ∩ rectangle) from its candidates.

    Exact: the extreme points of the convex intersection are the ellipse's own extreme
    points inside the rectangle (``a_ext``, ``ok_ext``), the ends of its chords along the
    rectangle's edges ``b = ±hb`` clipped to ``|a| <= ha`` (``lo_c``, ``hi_c``, ``ok_c``,
    each (2,)), or the rectangle's sides ``a = -ha, +ha`` where the ellipse crosses them
    (``ok_side`` (2,)). Returns (lo, hi, any).
    """
    big = jnp.asarray(_BIG, F32)
    lo = jnp.minimum(jnp.where(ok_ext[0], a_ext[0], big),
                     jnp.minimum(jnp.min(jnp.where(ok_c, lo_c, big)),
                                 jnp.where(ok_side[0], -ha, big)))
    hi = jnp.maximum(jnp.where(ok_ext[1], a_ext[1], -big),
                     jnp.maximum(jnp.max(jnp.where(ok_c, hi_c, -big)),
                                 jnp.where(ok_side[1], ha, -big)))
    anyv = jnp.any(ok_ext) | jnp.any(ok_c) | jnp.any(ok_side)
    return jnp.where(anyv, lo, 0.0), jnp.where(anyv, hi, 0.0), anyv


@struct.dataclass
class BallImage:
    """Visible part of the ball's image: px box [u_lo, u_hi] x [v_lo, v_hi] and flags."""

    u_lo: jnp.ndarray
    u_hi: jnp.ndarray
    v_lo: jnp.ndarray
    v_hi: jnp.ndarray
    visible: jnp.ndarray   # bool: some of the ellipse is inside the image
    valid: jnp.ndarray     # bool: the sphere lies wholly beyond the near plane
    cam_xyz: jnp.ndarray   # (3,) ball centre in camera coordinates, m
    radius: jnp.ndarray


def ball_image(ball_cam: jnp.ndarray, radius, cam: CameraParams) -> BallImage:
    """Visible bounding box (px) of a sphere with centre ``ball_cam`` (camera coords, m).

    The sphere must lie wholly beyond the near plane (``Z - r >= near_plane``); otherwise
    it is treated as not visible (``valid`` False; unreachable with the default robot,
    whose body keeps the ball away from the camera). The four chords of the ellipse along
    the image's edges serve both extents (u and v).
    """
    fu, fv = focal_lengths(cam)
    ht = jnp.asarray(cam.image_width, F32) / 2 / fu
    hs = jnp.asarray(cam.image_height, F32) / 2 / fv
    r = jnp.asarray(radius, F32)
    x, y, z = ball_cam[0], ball_cam[1], ball_cam[2]
    valid = z - r >= jnp.asarray(cam.near_plane, F32)
    z = jnp.where(valid, z, r + 1.0)  # keep the algebra finite where invalid
    k = x * x + y * y + z * z - r * r
    # chords along the rows s = ±hs (t-intervals) and the columns t = ±ht (s-intervals)
    rl, rh, rex = _chord(jnp.stack([-hs, hs]), y, x, z, k)
    cl, ch, cex = _chord(jnp.stack([-ht, ht]), x, y, z, k)
    rl, rh = jnp.maximum(rl, -ht), jnp.minimum(rh, ht)
    cl, ch = jnp.maximum(cl, -hs), jnp.minimum(ch, hs)
    row_ok, col_ok = rex & (rl <= rh), cex & (cl <= ch)
    t_ext, t_ok = _extremes(x, y, z, r, ht, hs)
    s_ext, s_ok = _extremes(y, x, z, r, hs, ht)
    tlo, thi, tany = _axis_extent(t_ext, t_ok, rl, rh, row_ok, col_ok, ht)
    slo, shi, sany = _axis_extent(s_ext, s_ok, cl, ch, col_ok, row_ok, hs)
    vis = valid & tany & sany & (thi > tlo) & (shi > slo)
    m = vis.astype(F32)
    return BallImage(u_lo=m * fu * tlo, u_hi=m * fu * thi, v_lo=m * fv * slo,
                     v_hi=m * fv * shi, visible=vis, valid=valid, cam_xyz=ball_cam,
                     radius=r)


def _ball_column_chord(bi: BallImage, u, cam: CameraParams):
    """v-interval (px) covered by the ball's image on image column ``u`` (px)."""
    fu, fv = focal_lengths(cam)
    x, y, z = bi.cam_xyz[0], bi.cam_xyz[1], bi.cam_xyz[2]
    r = bi.radius
    z = jnp.where(bi.valid, z, r + 1.0)
    k = x * x + y * y + z * z - r * r
    lo, hi, ex = _chord(u / fu, x, y, z, k)
    return fv * lo, fv * hi, ex & bi.valid


# ----------------------------------------------------------------------------- segments

def _proj(p, fu, fv, zn):
    """Camera coords (..., 3) with Z >= zn -> px (..., 2)."""
    z = jnp.maximum(p[..., 2], zn)
    return jnp.stack([fu * p[..., 0] / z, fv * p[..., 1] / z], axis=-1)


def _clip_rect(p0, p1, lo, hi):
    """Liang-Barsky: clip the image segment p0 -> p1 ((u, v) scalars) to the box [lo, hi]
    ((u, v) scalars). Returns clipped (q0, q1, ok)."""
    d = (p1[0] - p0[0], p1[1] - p0[1])
    # inequalities  -d t <= p0 - lo   and   d t <= hi - p0  per axis
    pp = (-d[0], -d[1], d[0], d[1])
    qq = (p0[0] - lo[0], p0[1] - lo[1], hi[0] - p0[0], hi[1] - p0[1])
    t0, t1 = jnp.zeros((), F32), jnp.ones((), F32)
    ok = jnp.ones((), bool)
    for p, q in zip(pp, qq, strict=True):
        par = jnp.abs(p) < _TINY
        ratio = _safe_div(q, p)
        t0 = jnp.where(~par & (p < 0), jnp.maximum(t0, ratio), t0)
        t1 = jnp.where(~par & (p > 0), jnp.minimum(t1, ratio), t1)
        ok = ok & ~(par & (q < 0))
    ok = ok & (t0 <= t1)
    return (p0[0] + t0 * d[0], p0[1] + t0 * d[1]), (p0[0] + t1 * d[0], p0[1] + t1 * d[1]), ok


def _interp_v(a, b, ok, u):
    """v of the image segment a -> b ((u, v) scalars) at column u; (v, valid)."""
    du = b[0] - a[0]
    inside = ok & (jnp.minimum(a[0], b[0]) <= u) & (u <= jnp.maximum(a[0], b[0])) & (
        jnp.abs(du) > 1e-6)
    return a[1] + _safe_div(u - a[0], du) * (b[1] - a[1]), inside


def _subtract_interval(lo, hi, olo, ohi, occ):
    """Extent of [lo, hi] minus the occluder [olo, ohi] when it cuts off an end (occ: bool).

    An occluder inside the interval leaves its extent unchanged; one covering it all
    leaves an empty interval (lo == hi).
    """
    cut_lo = occ & (olo <= lo) & (ohi > lo)
    cut_hi = occ & (ohi >= hi) & (olo < hi)
    nlo = jnp.where(cut_lo, jnp.minimum(ohi, hi), lo)
    nhi = jnp.where(cut_hi, jnp.maximum(olo, lo), hi)
    nhi = jnp.maximum(nhi, nlo)
    return nlo, nhi


# ----------------------------------------------------------------------------- the goal

@struct.dataclass
class GoalEnds:
    """The two visible ends of the goal (left = +y post), each a segment in px."""

    bot: jnp.ndarray      # (2, 2): [left, right] lower end point (u, v)
    top: jnp.ndarray      # (2, 2): [left, right] upper end point (u, v)
    visible: jnp.ndarray  # bool


class GoalSegs(NamedTuple):
    """The goal's 4 segments (``_GOAL_SEGS``) near-clipped and projected; fields (4,)."""

    u0: jnp.ndarray    # image of the clipped start, px
    v0: jnp.ndarray
    u1: jnp.ndarray    # image of the clipped end, px
    v1: jnp.ndarray
    ok: jnp.ndarray    # bool: some of the segment lies in front of the near plane
    cu: jnp.ndarray    # image of its crossing with the near plane (where it crosses), px
    cv: jnp.ndarray
    xf: jnp.ndarray    # 1.0 where start in front, end behind (else 0.0)
    xb: jnp.ndarray    # 1.0 where end in front, start behind
    q: tuple           # (q0u, q0v, q1u, q1v, ok): the image segment clipped to the image
    col: tuple         # (v, ok) at the left border column, (v, ok) at the right one


#: Goal segments (corner indices a -> b; corners left-bottom, left-top, right-top,
#: right-bottom): left post, right post, bottom edge, crossbar.
_GOAL_SEGS = ((0, 1), (3, 2), (0, 3), (1, 2))
#: The goal mouth's boundary cycle LB->LT->RT->RB->LB: (segment, runs it forwards).
_GOAL_CYCLE = ((0, True), (3, True), (1, False), (2, False))


def _goal_segments(pc, cam: CameraParams, fu, fv) -> GoalSegs:
    """The goal's segments from its camera-frame corners ``pc`` (4, 3) m: one
    ``lax.scan`` step per segment clips it to the near plane, projects it, clips the
    image segment to the image and reads its v at the two border columns."""
    zn = jnp.asarray(cam.near_plane, F32)
    hw = jnp.asarray(cam.image_width, F32) / 2
    hh = jnp.asarray(cam.image_height, F32) / 2
    pcs = [[pc[k, i] for i in range(3)] for k in range(4)]

    def step(carry, tab):
        sa, sb = tab
        pa = [sum(sa[k] * pcs[k][i] for k in range(4)) for i in range(3)]
        pb = [sum(sb[k] * pcs[k][i] for k in range(4)) for i in range(3)]
        ina, inb = pa[2] >= zn, pb[2] >= zn
        t = _safe_div(zn - pa[2], pb[2] - pa[2])
        cu = fu * (pa[0] + t * (pb[0] - pa[0])) / zn
        cv = fv * (pa[1] + t * (pb[1] - pa[1])) / zn
        iza, izb = 1.0 / jnp.maximum(pa[2], zn), 1.0 / jnp.maximum(pb[2], zn)
        p0 = (jnp.where(ina, fu * pa[0] * iza, cu), jnp.where(ina, fv * pa[1] * iza, cv))
        p1 = (jnp.where(inb, fu * pb[0] * izb, cu), jnp.where(inb, fv * pb[1] * izb, cv))
        ok = ina | inb
        q0, q1, qok = _clip_rect(p0, p1, (-hw, -hh), (hw, hh))
        col = [_interp_v(p0, p1, ok, c) for c in (-hw, hw)]
        return carry, (*p0, *p1, ok, cu, cv, (ina & ~inb).astype(F32),
                       (inb & ~ina).astype(F32), (*q0, *q1, qok), tuple(col))

    eye = np.eye(4, dtype=np.float32)
    tabs = (jnp.asarray(eye[[a for a, _ in _GOAL_SEGS]]),
            jnp.asarray(eye[[b for _, b in _GOAL_SEGS]]))
    _, ys = jax.lax.scan(step, jnp.zeros((), F32), tabs)
    return GoalSegs(*ys)


def _goal_ends(seg: GoalSegs, cam: CameraParams) -> GoalEnds:
    """Visible ends of the goal from its projected segments (:func:`_goal_segments`).

    End rule: a post whose projected segment meets the image is its own end (clipped to
    the image); otherwise the end is the goal's extent on the image border column on that
    side (u = -W/2 for the left post, +W/2 for the right), between the projected
    bottom edge and crossbar, clipped to the image.
    """
    hw = jnp.asarray(cam.image_width, F32) / 2
    hh = jnp.asarray(cam.image_height, F32) / 2
    q0u, q0v, q1u, q1v, qok = seg.q
    bot, top, vis = [], [], jnp.zeros((), bool)
    for k, col in ((0, -hw), (1, hw)):           # left post, right post
        post_ok = seg.ok[k] & qok[k]
        # the border column, for an end whose post is out of the image
        (vb, okb), (vt, okt) = ((seg.col[k][0][i], seg.col[k][1][i]) for i in (2, 3))
        col_lo = jnp.clip(jnp.minimum(vb, vt), -hh, hh)
        col_hi = jnp.clip(jnp.maximum(vb, vt), -hh, hh)
        col_ok = okb & okt & (col_hi > col_lo)
        a_low = q0v[k] <= q1v[k]
        low = (jnp.where(a_low, q0u[k], q1u[k]), jnp.where(a_low, q0v[k], q1v[k]))
        up = (jnp.where(a_low, q1u[k], q0u[k]), jnp.where(a_low, q1v[k], q0v[k]))
        end_ok = post_ok | col_ok
        b = [jnp.where(end_ok, jnp.where(post_ok, low[i], (col, col_lo)[i]), 0.0)
             for i in range(2)]
        t = [jnp.where(end_ok, jnp.where(post_ok, up[i], (col, col_hi)[i]), 0.0)
             for i in range(2)]
        vis = vis | (end_ok & (t[1] > b[1]))
        bot.append(jnp.stack(b))
        top.append(jnp.stack(t))
    return GoalEnds(bot=jnp.stack(bot), top=jnp.stack(top), visible=vis)


def _goal_chain(seg: GoalSegs):
    """Boundary of the near-clipped goal mouth: (p0, p1 (5, 2), w (5,)): 4 edges + the
    near-plane chord from where the cycle leaves the near plane to where it returns."""
    w = jnp.stack([jnp.where(seg.ok[k], jnp.float32(1.0 if fw else -1.0), 0.0)
                   for k, fw in sorted(_GOAL_CYCLE)])
    leave = [seg.xf[k] if fw else seg.xb[k] for k, fw in _GOAL_CYCLE]
    back = [seg.xb[k] if fw else seg.xf[k] for k, fw in _GOAL_CYCLE]
    idx = [k for k, _ in _GOAL_CYCLE]
    c0 = [sum(m * f[k] for m, k in zip(leave, idx, strict=True)) for f in (seg.cu, seg.cv)]
    c1 = [sum(m * f[k] for m, k in zip(back, idx, strict=True)) for f in (seg.cu, seg.cv)]
    p0 = jnp.concatenate([jnp.stack([seg.u0, seg.v0], axis=-1), jnp.stack(c0)[None]])
    p1 = jnp.concatenate([jnp.stack([seg.u1, seg.v1], axis=-1), jnp.stack(c1)[None]])
    return p0, p1, jnp.concatenate([w, jnp.minimum(sum(leave), 1.0)[None]])


def _plane_side(corners, p):
    """Signed distance-like side of point(s) p w.r.t. the plane of the goal corners."""
    n = jnp.cross(corners[1] - corners[0], corners[3] - corners[0])
    return jnp.dot(p - corners[0], n)


# ----------------------------------------------------------------------------- section 2

def section2_features(robot_pose, ball_xy, ball_radius, goal_corners, cam: CameraParams,
                      eps=None) -> jnp.ndarray:
    """Section 2 observation (9,) float32 of one robot's camera (layout ``SEC2_*``).

    Args:
      robot_pose: (3,) ``(x, y, theta)`` m, m, rad.
      ball_xy: (2,) ball centre on the floor, m (the centre is at height ``ball_radius``).
      ball_radius: scalar, m.
      goal_corners: (4, 3) world m, order left-bottom, left-top, right-top, right-bottom
        ("left" = +y post).
      cam: camera parameters.
      eps: optional (SEC2_NOISE_DIM,) float32 standard normals, the pixel noise in units
        of ``cam.pixel_noise_std`` (see :mod:`vbl.draws`); None = exact features.

    Features (px unless stated; 0 when the object is lost):
      x1 ball diameter = horizontal extent of the visible part of the ball's image (for a
      wholly visible ball: the distance between the two vertical image lines tangent to
      its outline); x2 = centre of that extent. x3 = mean of the image heights (v extent)
      of the goal's left and right ends, x4 = mean of their u positions, x5 = (h_left -
      h_right) / x3 clipped to [-1, 1]. Flags and lost sides as in ``docs/vision.md``.
    """
    fu, fv = focal_lengths(cam)
    frame = camera_frame(robot_pose, cam)
    r = jnp.asarray(ball_radius, F32)
    bxy = jnp.asarray(ball_xy, F32)
    ball_w = jnp.stack([bxy[0], bxy[1], r])
    ball_c = to_camera(ball_w, frame)
    bi = ball_image(ball_c, r, cam)
    corners = jnp.asarray(goal_corners, F32)
    pc = to_camera(corners, frame)
    ends = _goal_ends(_goal_segments(pc, cam, fu, fv), cam)
    # the ball hides the goal behind it when it is on the camera's side of the goal plane
    occ = (_plane_side(corners, ball_w) * _plane_side(corners, frame.c) > 0) & bi.valid
    u_end = 0.5 * (ends.bot[:, 0] + ends.top[:, 0])
    clo, chi, cex = _ball_column_chord(bi, u_end, cam)
    vlo, vhi = _subtract_interval(ends.bot[:, 1], ends.top[:, 1], clo, chi, occ & cex)
    h = vhi - vlo
    bu = 0.5 * (bi.u_lo + bi.u_hi)
    bw = bi.u_hi - bi.u_lo
    if eps is not None:
        eps = jnp.asarray(eps, F32)
        std = jnp.asarray(cam.pixel_noise_std, F32)
        zero = jnp.zeros((), F32)
        bw = bw + jnp.where(bi.visible, std * eps[0], zero)
        bu = bu + jnp.where(bi.visible, std * eps[1], zero)
        h = h + jnp.where(ends.visible, std * eps[2:4], zero)
        u_end = u_end + jnp.where(ends.visible, std * eps[4:6], zero)
        bw = jnp.maximum(bw, 0.0)
        h = jnp.maximum(h, 0.0)
    x3 = 0.5 * (h[0] + h[1])
    x4 = 0.5 * (u_end[0] + u_end[1])
    x5 = jnp.clip(_safe_div(h[0] - h[1], x3), jnp.float32(-1.0), jnp.float32(1.0))
    bvis, gvis = bi.visible, ends.visible
    gcen = jnp.mean(pc, axis=0)
    out = jnp.stack([
        jnp.where(bvis, bw, 0.0), jnp.where(bvis, bu, 0.0),
        jnp.where(gvis, x3, 0.0), jnp.where(gvis, x4, 0.0),
        jnp.where(gvis & (x3 > 0), x5, 0.0),
        bvis.astype(F32), gvis.astype(F32),
        jnp.where(bvis, 0.0, _lost_side(ball_c[0])),
        jnp.where(gvis, 0.0, _lost_side(gcen[0])),
    ])
    return out.astype(F32)


def check_inputs(robot_pose, ball_xy, ball_radius, goal_corners, cam: CameraParams,
                 other_pose=None, other_size=None) -> None:
    """Non-jitted validation of the feature functions' inputs (raises ValueError/ParamError).

    Checks ``vbl.params.validate(cam)``, shapes (robot_pose (3,), ball_xy (2,),
    goal_corners (4, 3), other_pose (3,), other_size (3,), optionally with equal leading
    batch dimensions), finiteness, and positive sizes (ball_radius > 0, other_size > 0).
    """
    import numpy as np

    from vbl.params import validate

    validate(cam)
    shapes = dict(robot_pose=(3,), ball_xy=(2,), goal_corners=(4, 3))
    values = dict(robot_pose=robot_pose, ball_xy=ball_xy, goal_corners=goal_corners)
    if other_pose is not None or other_size is not None:
        shapes.update(other_pose=(3,), other_size=(3,))
        values.update(other_pose=other_pose, other_size=other_size)
    batch = None
    for name, want in shapes.items():
        arr = np.asarray(values[name])
        if arr.ndim < len(want) or arr.shape[arr.ndim - len(want):] != want:
            raise ValueError(f"{name} has shape {arr.shape}; expected (..., "
                             f"{', '.join(map(str, want))})")
        lead = arr.shape[:arr.ndim - len(want)]
        if batch is not None and lead != batch:
            raise ValueError(f"{name} has batch shape {lead}; the others have {batch}")
        batch = lead
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got {arr}")
    rad = np.asarray(ball_radius)
    if not np.all(np.isfinite(rad)) or not np.all(rad > 0):
        raise ValueError(f"ball_radius must be > 0 (m), got {ball_radius}")
    if other_size is not None and not np.all(np.asarray(other_size) > 0):
        raise ValueError(f"other_size [length, width, height] must be > 0 (m), "
                         f"got {other_size}")


# ----------------------------------------------------------------------------- section 3

@struct.dataclass
class Section3Obs:
    """Section 3 observation: ball (4,), goal (11,), other (5,), visible (3,), lost_side (3,)."""

    ball: jnp.ndarray
    goal: jnp.ndarray
    other: jnp.ndarray
    visible: jnp.ndarray
    lost_side: jnp.ndarray


@struct.dataclass
class Region:
    """Area (px^2) and first moments (px^3) of a region inside R boxes, and its bounding
    box (px) inside box 0."""

    area: jnp.ndarray  # (R,)
    mu: jnp.ndarray    # (R,)
    mv: jnp.ndarray    # (R,)
    lo: jnp.ndarray    # (2,) u_lo, v_lo in box 0 (lo > hi: empty)
    hi: jnp.ndarray    # (2,) u_hi, v_hi in box 0


def _boxes_and_origins(lo, hi, origin):
    """Boxes (R, 2) as scalar tuples (lu, lv, hu, hv) and ``origin`` clamped into each."""
    boxes = [(lo[j, 0], lo[j, 1], hi[j, 0], hi[j, 1]) for j in range(lo.shape[0])]
    orig = [(jnp.clip(origin[0], b[0], b[2]), jnp.clip(origin[1], b[1], b[3])) for b in boxes]
    return boxes, orig


def _green_init(n_box):
    """Empty sums: (area, mu, mv) per box and the box-0 bounding box (lo > hi)."""
    zero, big = jnp.zeros((), F32), jnp.asarray(_BIG, F32)
    return tuple((zero, zero, zero) for _ in range(n_box)), (big, big, -big, -big)


def _opaque_one(x):
    """Exactly 1 for finite ``x``, but not known to the compiler (the ``one`` of
    :func:`_stored`)."""
    return x * 0.0 + 1.0


def _stored(x, one):
    """``x / one`` with ``one`` == 1 not known to the compiler: exactly ``x``, but XLA does
    not copy a division into each of its consumers, so ``x`` is computed once and stored
    (otherwise every consumer recomputes ``x`` and all it is made of)."""
    return x / one


def _green_step(carry, seg, boxes, orig):
    """Add one directed segment ``(x0, y0, x1, y1, w)`` (scalars, px) to the sums.

    See :func:`_chain_in_rects`: the part of the segment inside each box's row band is
    split at the box's columns into three pieces; each, clamped into the box and taken
    about the box's origin, adds ``∫ x dy``, ``∫ x^2 dy`` and ``∫ x y dy`` (closed form
    for a straight piece), times the weight ``w``. The box-0 bounding box grows by the
    u-range of the part inside its row band and the v-range of the part inside its
    column band (segments of weight 0 are not boundary and add nothing). The pieces'
    parameters and clamped ends are stored once per box (:func:`_stored`) and read by the
    three sums, which XLA would otherwise each recompute them for.
    """
    sums, (u_lo, v_lo, u_hi, v_hi) = carry
    x0, y0, x1, y1, ws = seg
    dx, dy = x1 - x0, y1 - y0
    ix, iy = _safe_div(1.0, dx), _safe_div(1.0, dy)
    big = jnp.asarray(_BIG, F32)
    zero = jnp.zeros((), F32)
    one = _opaque_one(ws)   # weights are finite
    new = []
    for j, ((lu, lv, hu, hv), (ou, ov)) in enumerate(zip(boxes, orig, strict=True)):
        r0, r1 = (lv - y0) * iy, (hv - y0) * iy
        ta = jnp.maximum(jnp.minimum(r0, r1), 0.0)
        tb = jnp.minimum(jnp.maximum(r0, r1), 1.0)
        c0, c1 = (lu - x0) * ix, (hu - x0) * ix
        cmin, cmax = jnp.minimum(c0, c1), jnp.maximum(c0, c1)
        if j == 0:
            real = ws != 0
            ua, ub = x0 + ta * dx, x0 + tb * dx
            uok = (ta <= tb) & real
            u_lo = jnp.minimum(u_lo, jnp.where(uok, jnp.minimum(ua, ub), big))
            u_hi = jnp.maximum(u_hi, jnp.where(uok, jnp.maximum(ua, ub), -big))
            sa, sb = jnp.maximum(cmin, 0.0), jnp.minimum(cmax, 1.0)
            va, vb = y0 + sa * dy, y0 + sb * dy
            vok = (sa <= sb) & real
            v_lo = jnp.minimum(v_lo, jnp.where(vok, jnp.minimum(va, vb), big))
            v_hi = jnp.maximum(v_hi, jnp.where(vok, jnp.maximum(va, vb), -big))
        tb = jnp.maximum(tb, ta)
        ts = [_stored(t, one) for t in (ta, jnp.clip(cmin, ta, tb), jnp.clip(cmax, ta, tb), tb)]
        xs = [_stored(jnp.clip(x0 + t * dx, lu, hu) - ou, one) for t in ts]
        ys = [_stored(jnp.clip(y0 + t * dy, lv, hv) - ov, one) for t in ts]
        a = m = n = zero
        for k in range(3):
            xa, xb, ya, yb = xs[k], xs[k + 1], ys[k], ys[k + 1]
            d = yb - ya
            a = a + (xa + xb) * d
            m = m + (xa * (xa + xb) + xb * xb) * d
            n = n + (xa * (ya + ya + yb) + xb * (ya + yb + yb)) * d
        sa_, sm, sn = sums[j]
        new.append((sa_ + ws * a, sm + ws * m, sn + ws * n))
    return tuple(new), (u_lo, v_lo, u_hi, v_hi)


def _green_region(carry, boxes, orig) -> Region:
    """The :class:`Region` of summed Green integrals (moments moved to the image origin)."""
    sums, (u_lo, v_lo, u_hi, v_hi) = carry
    area = jnp.stack([0.5 * a for a, _, _ in sums])
    mu = jnp.stack([m / 6.0 for _, m, _ in sums]) + jnp.stack([o[0] for o in orig]) * area
    mv = jnp.stack([n / 6.0 for _, _, n in sums]) + jnp.stack([o[1] for o in orig]) * area
    b0 = boxes[0]
    return Region(area=area, mu=mu, mv=mv,
                  lo=jnp.stack([jnp.maximum(u_lo, b0[0]), jnp.maximum(v_lo, b0[1])]),
                  hi=jnp.stack([jnp.minimum(u_hi, b0[2]), jnp.minimum(v_hi, b0[3])]))


def _green_scan(carry, p0, p1, w, boxes, orig):
    """:func:`_green_step` over segments ``p0 -> p1`` (S, 2) px, weights ``w`` (S,)."""
    def step(c, seg):
        return _green_step(c, seg, boxes, orig), None

    carry, _ = jax.lax.scan(step, carry, (p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1], w))
    return carry


def _chain_in_rects(p0, p1, w, lo, hi, origin) -> Region:
    """Signed area, first moments and bounding box of a region inside R boxes.

    The region is given by its boundary: directed segments ``p0 -> p1`` (S, 2) px with
    weights ``w`` (S,) (+1, -1, 0) that form closed cycles when summed, in any order.
    Boxes ``[lo[j], hi[j]]`` (R, 2). Exact (Green's theorem): the clamp onto a box is a
    retraction onto it, and the segment from a point to its clamp never enters the
    box's interior, so the clamped boundary winds around each interior point of the box
    as the boundary does; integrating over the clamped path integrates over region ∩
    box. With the forms ``x dy`` (area), ``x^2/2 dy`` and ``x y dy`` (first moments)
    only the part of each segment inside the box's row band ``lo_v <= v <= hi_v``
    counts (clamped elsewhere it runs along a box row, dy = 0); that part is split where
    it crosses the columns ``u = lo_u, hi_u`` into three straight pieces, clamped, each
    integrated in closed form (:func:`_green_step`). The bounding box of region ∩
    (box 0) comes from the same parts: its u-extent is the u-range of the segments'
    parts inside the row band, cut to the box's columns (likewise for v). Sums are
    taken about ``origin`` (2,) px clamped into each box (a point near the region keeps
    float32 sums small) and returned about the image origin, signed by the boundary's
    orientation.

    A ``lax.scan`` runs over the segments (each step: one segment, all boxes), so every
    operation works on one number per env and XLA vectorises it over the batch.
    Returns a :class:`Region`: area, mu, mv (R,); lo, hi (2,) of box 0 (lo > hi: empty).
    """
    boxes, orig = _boxes_and_origins(lo, hi, origin)
    carry = _green_scan(_green_init(len(boxes)), p0, p1, w, boxes, orig)
    return _green_region(carry, boxes, orig)


def _oriented(reg: Region, sign) -> Region:
    """Region with area and moments multiplied by ``sign`` (+-1: the boundary's turn)."""
    return reg.replace(area=sign * reg.area, mu=sign * reg.mu, mv=sign * reg.mv)


def _box_tables():
    """Static tables of a box's 12 edges from its 6 outward-oriented faces.

    Corners: signs ``(sx, sy, sz)`` of (half-length, half-width, height), sz in {0, 1};
    faces in the order +x, -x, +y, -y, top, bottom (local axes), each a corner cycle
    counter-clockwise seen from outside. Returns (edge start signs (12, 3), edge vectors
    in units of (half-length, half-width, height) (12, 3), face-runs-edge-forwards
    (6, 12), face-runs-edge-backwards (6, 12)), float32 numpy arrays.
    """
    sx = [1, -1, -1, 1, 1, -1, -1, 1]
    sy = [1, 1, -1, -1, 1, 1, -1, -1]
    sz = [0, 0, 0, 0, 1, 1, 1, 1]
    faces = [[0, 4, 7, 3], [1, 2, 6, 5], [0, 1, 5, 4], [3, 7, 6, 2], [4, 5, 6, 7],
             [0, 3, 2, 1]]
    edges, fwd, bwd = [], np.zeros((6, 12), np.float32), np.zeros((6, 12), np.float32)
    for f, cyc in enumerate(faces):
        for a, b in zip(cyc, cyc[1:] + cyc[:1], strict=True):
            if (b, a) in edges:
                bwd[f, edges.index((b, a))] = 1.0
            else:
                edges.append((a, b))
                fwd[f, len(edges) - 1] = 1.0
    sgn = np.array([sx, sy, sz], np.float32).T
    start = np.stack([sgn[a] for a, _ in edges])
    vec = np.stack([sgn[b] - sgn[a] for a, b in edges])
    return start, vec, fwd, bwd


_BOX_START, _BOX_VEC, _BOX_FWD, _BOX_BWD = _box_tables()


#: The box's edges by direction (local x, y, z), 4 each. An edge is silhouette when one of
#: its two faces is front and the other is not; per direction at most 2 edges are (a
#: face pair perpendicular to the direction has at most one front face per axis).
_BOX_CLASSES = tuple(tuple(int(e) for e in np.flatnonzero(np.abs(_BOX_VEC[:, a]) > 0))
                     for a in range(3))


def _pick(values, idx):
    """values[idx] for a short static list of per-env scalars and an int scalar index."""
    out = values[-1]
    for i in range(len(values) - 2, -1, -1):
        out = jnp.where(idx == i, values[i], out)
    return out


def _box_region(base_c, axes_c, front, cam: CameraParams, fu, fv, lo, hi, origin) -> Region:
    """The other robot's silhouette inside R boxes (see :func:`_chain_in_rects`).

    ``base_c`` (3,): the box's bottom centre in camera coordinates; ``axes_c`` (3, 3):
    rows = camera-frame vectors of half its length, half its width and its height;
    ``front`` (6,) bool: faces (order of :func:`_box_tables`) turned towards the camera;
    boxes ``lo``, ``hi`` (R, 2) px; ``origin`` (2,) px near the silhouette.

    The silhouette is the sum of the near-clipped front faces (disjoint for a convex
    body); its boundary is every edge between a front and a back face (weight
    ``front[f+] - front[f-]``: an edge between two front faces cancels) plus each front
    face's near-plane chord. One ``lax.scan`` over the 12 edges builds them (corners,
    near-plane clip, projection); selects pick the boundary's 9 slots (per edge direction
    its at most 2 edges of non-zero weight, per axis its front face's chord; see
    ``_BOX_CLASSES``) and :func:`_green_scan` adds them (building and adding in one step
    makes XLA recompute the edge in every loop that writes one of the step's outputs).
    """
    zn = jnp.asarray(cam.near_plane, F32)
    boxes, orig = _boxes_and_origins(lo, hi, origin)
    base = [base_c[i] for i in range(3)]
    axes = [[axes_c[k, i] for i in range(3)] for k in range(3)]
    fr = front.astype(F32)
    frs = [fr[f] for f in range(6)]

    def edge(carry, tab):
        st, vec, wf = tab
        pa = [base[i] + st[0] * axes[0][i] + st[1] * axes[1][i] + st[2] * axes[2][i]
              for i in range(3)]
        d = [vec[0] * axes[0][i] + vec[1] * axes[1][i] + vec[2] * axes[2][i]
             for i in range(3)]
        zb = pa[2] + d[2]
        ina, inb = pa[2] >= zn, zb >= zn
        t = _safe_div(zn - pa[2], d[2])
        cu, cv = fu * (pa[0] + t * d[0]) / zn, fv * (pa[1] + t * d[1]) / zn
        iza, izb = 1.0 / jnp.maximum(pa[2], zn), 1.0 / jnp.maximum(zb, zn)
        u0 = jnp.where(ina, fu * pa[0] * iza, cu)
        v0 = jnp.where(ina, fv * pa[1] * iza, cv)
        u1 = jnp.where(inb, fu * (pa[0] + d[0]) * izb, cu)
        v1 = jnp.where(inb, fv * (pa[1] + d[1]) * izb, cv)
        w = sum(frs[f] * wf[f] for f in range(6)) * (ina | inb).astype(F32)
        return carry, (u0, v0, u1, v1, w, cu, cv, (ina & ~inb).astype(F32),
                       (inb & ~ina).astype(F32))

    tables = (jnp.asarray(_BOX_START), jnp.asarray(_BOX_VEC),
              jnp.asarray((_BOX_FWD - _BOX_BWD).T))
    _, (u0, v0, u1, v1, w, cu, cv, xf, xb) = jax.lax.scan(edge, jnp.zeros((), F32), tables)
    # near-plane chords: face f leaves the near plane on one edge and returns on another
    ends = {k: [] for k in ("u0", "v0", "u1", "v1", "w")}
    for f in range(6):
        terms = [(e, _BOX_FWD[f, e] > 0) for e in range(12) if _BOX_FWD[f, e] + _BOX_BWD[f, e]]
        leave = [xf[e] if fw else xb[e] for e, fw in terms]
        back = [xb[e] if fw else xf[e] for e, fw in terms]
        ends["u0"].append(sum(m * cu[e] for m, (e, _) in zip(leave, terms, strict=True)))
        ends["v0"].append(sum(m * cv[e] for m, (e, _) in zip(leave, terms, strict=True)))
        ends["u1"].append(sum(m * cu[e] for m, (e, _) in zip(back, terms, strict=True)))
        ends["v1"].append(sum(m * cv[e] for m, (e, _) in zip(back, terms, strict=True)))
        ends["w"].append(frs[f] * jnp.minimum(sum(leave), 1.0))
    c = {k: jnp.stack(v) for k, v in ends.items()}
    # the boundary's segments of non-zero weight, picked without a gather (see
    # _BOX_CLASSES): per edge direction its (at most 2) silhouette edges, per axis its
    # front face's chord; picked slots of weight 0 add nothing
    cols = (u0, v0, u1, v1, w)
    segs = []
    for cls in _BOX_CLASSES:
        nz = [w[e] != 0 for e in cls]
        # slot 1: the first edge of weight != 0 (in class order), slot 2: the last one,
        # with weight 0 when it is the first one too
        idx1 = jnp.where(nz[0], 0, jnp.where(nz[1], 1, jnp.where(nz[2], 2, 3)))
        idx2 = jnp.where(nz[3], 3, jnp.where(nz[2], 2, jnp.where(nz[1], 1, 0)))
        for idx, dup in ((idx1, None), (idx2, idx1)):
            row = [_pick([col[e] for e in cls], idx) for col in cols]
            if dup is not None:
                row[4] = jnp.where(idx == dup, 0.0, row[4])
            segs.append(row)
    for ax in range(3):
        pos = front[2 * ax]
        segs.append([jnp.where(pos, c[k][2 * ax], c[k][2 * ax + 1])
                     for k in ("u0", "v0", "u1", "v1", "w")])
    segs = [jnp.stack(f) for f in zip(*segs, strict=True)]
    carry = _green_scan(_green_init(len(boxes)), jnp.stack(segs[:2], axis=-1),
                        jnp.stack(segs[2:4], axis=-1), segs[4], boxes, orig)
    return _green_region(carry, boxes, orig)


def _rect_inter(lo1, hi1, lo2, hi2):
    return jnp.maximum(lo1, lo2), jnp.minimum(hi1, hi2)


def _empty_rect():
    z = jnp.zeros((2,), F32)
    return z, z


def _sign(x):
    """+1 where x >= 0, else -1 (float32)."""
    return jnp.where(x < 0, jnp.float32(-1.0), jnp.float32(1.0))


def section3_features(robot_pose, ball_xy, ball_radius, goal_corners, other_pose, other_size,
                      cam: CameraParams, eps=None) -> Section3Obs:
    """Section 3 observation of one robot's camera (see ``docs/vision.md``).

    Args:
      robot_pose: (3,) this robot's ``(x, y, theta)``.
      ball_xy: (2,) m; ball_radius: scalar m.
      goal_corners: (4, 3) m, order left-bottom, left-top, right-top, right-bottom.
      other_pose: (3,) the other robot's ``(x, y, theta)``.
      other_size: (3,) the other robot as a box ``[length, width, height]`` m.
      cam: camera parameters.
      eps: optional (SEC3_NOISE_DIM,) float32 standard normals, the pixel noise in units of
        ``cam.pixel_noise_std`` (see :mod:`vbl.draws`); None = exact features.

    Returns:
      :class:`Section3Obs` with ``ball`` = (centroid u, v, bounding width, height) of the
      visible ball box; ``goal`` = the four ends' points (u, v) in corner order, area
      centroid (u, v) and visible area (px^2); ``other`` = area centroid (u, v), bounding
      width, height and visible area of the other robot's silhouette; ``visible`` and
      ``lost_side`` (ball, goal, other). Lost objects have all-zero features.
    """
    fu, fv = focal_lengths(cam)
    pose = jnp.asarray(robot_pose, F32)
    one = _opaque_one(pose[0])   # poses are finite
    frame = camera_frame(pose, cam, trig=(_stored(jnp.cos(pose[2]), one),
                                          _stored(jnp.sin(pose[2]), one)))
    hw = jnp.asarray(cam.image_width, F32) / 2
    hh = jnp.asarray(cam.image_height, F32) / 2
    img_lo, img_hi = jnp.stack([-hw, -hh]), jnp.stack([hw, hh])
    e_lo, e_hi = _empty_rect()
    # ball
    r = jnp.asarray(ball_radius, F32)
    bxy = jnp.asarray(ball_xy, F32)
    ball_w = jnp.stack([bxy[0], bxy[1], r])
    ball_c = _stored(to_camera(ball_w, frame), one)
    bi = ball_image(ball_c, r, cam)
    box = _stored(jnp.stack([bi.u_lo, bi.u_hi, bi.v_lo, bi.v_hi]), one)
    bi = bi.replace(u_lo=box[0], u_hi=box[1], v_lo=box[2], v_hi=box[3])
    b_lo = jnp.stack([bi.u_lo, bi.v_lo])
    b_hi = jnp.stack([bi.u_hi, bi.v_hi])
    # goal
    corners = jnp.asarray(goal_corners, F32)
    pc = _stored(to_camera(corners, frame), one)
    gseg = _goal_segments(pc, cam, fu, fv)
    ends = _goal_ends(gseg, cam)
    ends = ends.replace(bot=_stored(ends.bot, one), top=_stored(ends.top, one))
    # other robot: the box in its own frame (local axes along its heading)
    opose = jnp.asarray(other_pose, F32)
    osize = jnp.asarray(other_size, F32)
    c, s = _stored(jnp.cos(opose[2]), one), _stored(jnp.sin(opose[2]), one)
    half = jnp.stack([osize[0] / 2, osize[1] / 2, osize[2] / 2])
    ocen = jnp.stack([opose[0], opose[1], half[2]])

    def local(p):
        rel = p - ocen
        return jnp.stack([c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], rel[2]])

    locc = _stored(local(frame.c), one)
    front = jnp.stack([locc[0] > half[0], locc[0] < -half[0], locc[1] > half[1],
                       locc[1] < -half[1], locc[2] > half[2], locc[2] < -half[2]])
    zero = jnp.zeros((), F32)
    axes_w = jnp.stack([jnp.stack([c * half[0], s * half[0], zero]),
                        jnp.stack([-s * half[1], c * half[1], zero]),
                        jnp.stack([zero, zero, osize[2]])])
    axes_c = _stored(jnp.sum(axes_w[:, None, :] * frame.rot[None, :, :], axis=-1), one)
    base_c = _stored(to_camera(jnp.stack([opose[0], opose[1], zero]), frame), one)
    # depth order
    goal_cam_side = _plane_side(corners, frame.c)
    ball_before_goal = (_plane_side(corners, ball_w) * goal_cam_side > 0) & bi.valid
    robot_before_goal = _plane_side(corners, ocen) * goal_cam_side > 0
    # ball vs robot: the robot face plane the ball centre is farthest outside of separates
    loc = local(ball_w)
    ax = jnp.argmax(jnp.abs(loc) / half)
    cam_out = jnp.sign(loc[ax]) * locc[ax] > half[ax]
    ball_before_robot = cam_out & bi.valid
    # robot silhouette in the image, and inside the ball's box when the ball is in front
    occ_b = ball_before_robot & bi.visible
    ob_lo, ob_hi = _rect_inter(img_lo, img_hi, b_lo, b_hi)
    ob_lo, ob_hi = jnp.where(occ_b, ob_lo, e_lo), jnp.where(occ_b, ob_hi, e_hi)
    ocen_c = _stored(to_camera(ocen, frame), one)
    o_origin = _proj(ocen_c, fu, fv, jnp.asarray(cam.near_plane, F32))
    oreg = _box_region(base_c, axes_c, front, cam, fu, fv, jnp.stack([img_lo, ob_lo]),
                       jnp.stack([img_hi, ob_hi]), o_origin)
    oreg = _oriented(oreg, _sign(oreg.area[0]))
    o_full_lo, o_full_hi = oreg.lo, oreg.hi
    o_full_vis = (oreg.area[0] > 0) & jnp.all(o_full_hi > o_full_lo)
    o_full_lo = jnp.where(o_full_vis, o_full_lo, 0.0)
    o_full_hi = jnp.where(o_full_vis, o_full_hi, 0.0)
    # ball box occluded by the robot (bounding boxes)
    occ_r = ~ball_before_robot & o_full_vis
    ulo, uhi = _subtract_cover(b_lo, b_hi, o_full_lo, o_full_hi, occ_r)
    ball_vis = bi.visible & jnp.all(uhi > ulo)
    # robot occluded by the ball box
    o_in = jnp.where(o_full_vis, oreg.area[0], 0.0)
    o_occ = jnp.where(o_full_vis, oreg.area[1], 0.0)
    o_area = jnp.maximum(o_in - o_occ, 0.0)
    olo, ohi = _subtract_cover(o_full_lo, o_full_hi, b_lo, b_hi, occ_b & o_full_vis)
    other_vis = (o_area > _MIN_AREA) & jnp.all(ohi > olo)
    o_cu = _safe_div(oreg.mu[0] - oreg.mu[1], o_area)
    o_cv = _safe_div(oreg.mv[0] - oreg.mv[1], o_area)
    # goal area minus nearer occluders (bounding boxes; inclusion-exclusion)
    g1_lo, g1_hi = _rect_inter(img_lo, img_hi, b_lo, b_hi)
    g1_lo = jnp.where(ball_before_goal & bi.visible, g1_lo, e_lo)
    g1_hi = jnp.where(ball_before_goal & bi.visible, g1_hi, e_hi)
    g2_lo, g2_hi = _rect_inter(img_lo, img_hi, o_full_lo, o_full_hi)
    g2_lo = jnp.where(robot_before_goal & o_full_vis, g2_lo, e_lo)
    g2_hi = jnp.where(robot_before_goal & o_full_vis, g2_hi, e_hi)
    g12_lo, g12_hi = _rect_inter(g1_lo, g1_hi, g2_lo, g2_hi)
    gp0, gp1, gw = _goal_chain(gseg)
    gcen = jnp.mean(pc, axis=0)
    g_origin = _proj(gcen, fu, fv, jnp.asarray(cam.near_plane, F32))
    gr = _chain_in_rects(gp0, gp1, gw, jnp.stack([img_lo, g1_lo, g2_lo, g12_lo]),
                         jnp.stack([img_hi, g1_hi, g2_hi, g12_hi]), g_origin)
    sgn4 = jnp.array([1.0, -1.0, -1.0, 1.0], F32) * _sign(gr.area[0])
    g_area = jnp.maximum(jnp.sum(sgn4 * gr.area), 0.0)
    g_cu = _safe_div(jnp.sum(sgn4 * gr.mu), g_area)
    g_cv = _safe_div(jnp.sum(sgn4 * gr.mv), g_area)
    goal_vis = ends.visible & (g_area > _MIN_AREA)
    gpts = jnp.stack([ends.bot[0], ends.top[0], ends.top[1], ends.bot[1]]).reshape(-1)
    ball_f = jnp.stack([0.5 * (ulo[0] + uhi[0]), 0.5 * (ulo[1] + uhi[1]),
                        uhi[0] - ulo[0], uhi[1] - ulo[1]])
    goal_f = jnp.concatenate([gpts, jnp.stack([g_cu, g_cv, g_area])])
    other_f = jnp.stack([o_cu, o_cv, ohi[0] - olo[0], ohi[1] - olo[1], o_area])
    if eps is not None:
        eps = jnp.asarray(eps, F32)
        ball_f = add_pixel_noise(eps[:4], ball_f, cam, ball_vis)
        goal_f = goal_f.at[:10].set(add_pixel_noise(eps[4:14], goal_f[:10], cam, goal_vis))
        other_f = other_f.at[:4].set(add_pixel_noise(eps[14:18], other_f[:4], cam, other_vis))
        ball_f = ball_f.at[2:].set(jnp.maximum(ball_f[2:], 0.0))
        other_f = other_f.at[2:4].set(jnp.maximum(other_f[2:4], 0.0))
    vis = jnp.stack([ball_vis, goal_vis, other_vis])
    lost = jnp.where(vis, 0.0, jnp.stack([_lost_side(ball_c[0]), _lost_side(gcen[0]),
                                          _lost_side(ocen_c[0])]))
    return Section3Obs(ball=jnp.where(ball_vis, ball_f, 0.0).astype(F32),
                       goal=jnp.where(goal_vis, goal_f, 0.0).astype(F32),
                       other=jnp.where(other_vis, other_f, 0.0).astype(F32),
                       visible=vis.astype(F32), lost_side=lost.astype(F32))


def _subtract_cover(lo, hi, olo, ohi, occ):
    """Bounding box [lo, hi] (2,) minus an occluder box: an axis interval shrinks where the
    occluder covers the box's whole extent along the other axis and cuts off an end."""
    cov_v = (olo[1] <= lo[1]) & (ohi[1] >= hi[1])
    cov_u = (olo[0] <= lo[0]) & (ohi[0] >= hi[0])
    overlap = jnp.all(ohi > lo) & jnp.all(olo < hi)
    occ = occ & overlap
    ulo, uhi = _subtract_interval(lo[0], hi[0], olo[0], ohi[0], occ & cov_v)
    vlo, vhi = _subtract_interval(lo[1], hi[1], olo[1], ohi[1], occ & cov_u)
    full = occ & cov_u & cov_v
    nlo = jnp.stack([ulo, vlo])
    nhi = jnp.where(full, nlo, jnp.stack([uhi, vhi]))
    return nlo, nhi


def flatten_section3(obs: Section3Obs) -> jnp.ndarray:
    """(26,) float32: ball 4, goal 11, other 5, visible 3, lost_side 3."""
    return jnp.concatenate([obs.ball, obs.goal, obs.other, obs.visible,
                            obs.lost_side]).astype(F32)
