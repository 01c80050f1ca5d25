"""Closed-form images of the ball and the goal, shared by the Section 2 and Section 3
features (:mod:`vbl.vision.section2`, :mod:`vbl.vision.section3`).

Nothing is rasterised: every quantity is a closed-form function of the camera pose and
the object geometry (pure JAX, float32, jit/vmap-able, no data-dependent branches).
Exact definitions and clipping rules are in ``docs/vision.md``; in short

* the ball (a sphere) images to an ellipse (the cone of rays tangent to the sphere cut
  by the image plane); its visible part is that ellipse intersected with the image
  rectangle, and extents are computed exactly from the conic (:func:`ball_image`);
* straight edges (goal posts, crossbar) are clipped to the near plane in 3-D, projected,
  and clipped to the image rectangle (Liang-Barsky; :func:`goal_segments`), and the
  goal's visible ends are read from them (:func:`goal_ends`);
* an object the camera cannot see at all is *lost*; its lost side is -1 when its
  reference point lies left of the camera's vertical mid-plane (camera X < 0), else +1
  (:func:`lost_side`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.vision.camera import F32, CameraParams, focal_lengths

__all__ = ["BIG", "safe_div", "lost_side", "BallImage", "ball_image", "ball_column_chord",
           "project", "subtract_interval", "GoalEnds", "GoalSegs", "goal_segments",
           "goal_ends", "plane_side"]

#: Smallest |denominator| of a division; smaller ones are replaced by +-_TINY (no NaN).
_TINY = 1e-12
#: Stand-in for "no candidate" in min/max reductions over image coordinates, px.
BIG = 1e9


def safe_div(a, b):
    """a / b with b == 0 replaced by a tiny number of the same sign (finite, no NaN)."""
    tiny = jnp.asarray(_TINY, jnp.result_type(b))
    b = jnp.where(jnp.abs(b) < tiny, jnp.where(b < 0, -tiny, tiny), b)
    return a / b


def lost_side(x_cam):
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
    return safe_div(bh - sq, a), safe_div(bh + sq, a), exists


def _extremes(xa, xb, z, r, ha, hb):
    """The ellipse's two extreme points along axis ``a`` (normalised coordinates).

    Returns their ``a`` coordinates (2,) and whether each lies inside the rectangle
    ``[-ha, ha] x [-hb, hb]`` (2,) bool.
    """
    den = z * z - r * r
    root = r * jnp.sqrt(jnp.maximum(xa * xa + z * z - r * r, 0.0))
    a_ext = jnp.stack([safe_div(xa * z - root, den), safe_div(xa * z + root, den)])
    b_ext = safe_div(xb * (xa * a_ext + z), xa * xa + z * z - r * r)
    return a_ext, (jnp.abs(a_ext) <= ha) & (jnp.abs(b_ext) <= hb)


def _axis_extent(a_ext, ok_ext, lo_c, hi_c, ok_c, ok_side, ha):
    """Extent along axis ``a`` of (ellipse ∩ rectangle) from its candidates.

    Exact: the extreme points of the convex intersection are the ellipse's own extreme
    points inside the rectangle (``a_ext``, ``ok_ext``), the ends of its chords along the
    rectangle's edges ``b = ±hb`` clipped to ``|a| <= ha`` (``lo_c``, ``hi_c``, ``ok_c``,
    each (2,)), or the rectangle's sides ``a = -ha, +ha`` where the ellipse crosses them
    (``ok_side`` (2,)). Returns (lo, hi, any).
    """
    big = jnp.asarray(BIG, F32)
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


def ball_column_chord(bi: BallImage, u, cam: CameraParams):
    """v-interval (px) covered by the ball's image on image column ``u`` (px)."""
    fu, fv = focal_lengths(cam)
    x, y, z = bi.cam_xyz[0], bi.cam_xyz[1], bi.cam_xyz[2]
    r = bi.radius
    z = jnp.where(bi.valid, z, r + 1.0)
    k = x * x + y * y + z * z - r * r
    lo, hi, ex = _chord(u / fu, x, y, z, k)
    return fv * lo, fv * hi, ex & bi.valid


# ----------------------------------------------------------------------------- segments

def project(p, fu, fv, zn):
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
        ratio = safe_div(q, p)
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
    return a[1] + safe_div(u - a[0], du) * (b[1] - a[1]), inside


def subtract_interval(lo, hi, olo, ohi, occ):
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


def goal_segments(pc, cam: CameraParams, fu, fv) -> GoalSegs:
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
        t = safe_div(zn - pa[2], pb[2] - pa[2])
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


def goal_ends(seg: GoalSegs, cam: CameraParams) -> GoalEnds:
    """Visible ends of the goal from its projected segments (:func:`goal_segments`).

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



def plane_side(corners, p):
    """Signed distance-like side of point(s) p w.r.t. the plane of the goal corners."""
    n = jnp.cross(corners[1] - corners[0], corners[3] - corners[0])
    return jnp.dot(p - corners[0], n)
