"""Section 3 image features: the ball, the goal and the other robot as image regions.

:func:`section3_features` builds a :class:`Section3Obs` (flattened by
:func:`flatten_section3`) from the ball and goal images of :mod:`vbl.vision.projection`
and the other robot's silhouette. Areas and centroids of planar regions (the goal mouth,
the other robot's silhouette) use Green's theorem on their boundary, a set of directed
segments in any order (the robot's silhouette edges, the near plane's chords), mapped
into a rectangle by the clamp onto it (:func:`_chain_in_rects`). Nearer objects hide
farther ones through their bounding boxes. Definitions: ``docs/vision.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.vision.camera import (
    F32,
    CameraFrame,
    CameraParams,
    camera_frame,
    focal_lengths,
    to_camera,
)
from vbl.vision.fusion import opaque_one, stored
from vbl.vision.noise import add_pixel_noise
from vbl.vision.projection import (
    BIG,
    BallImage,
    GoalSegs,
    ball_image,
    goal_ends,
    goal_segments,
    lost_side,
    plane_side,
    project,
    safe_div,
    subtract_interval,
)

__all__ = ["SEC3_NOISE_DIM", "SEC3_BALL_DIM", "SEC3_GOAL_DIM", "SEC3_OTHER_DIM", "SEC3_DIM",
           "Section3Obs", "section3_features", "flatten_section3"]

SEC3_BALL_DIM = 4
SEC3_GOAL_DIM = 11
SEC3_OTHER_DIM = 5
SEC3_DIM = SEC3_BALL_DIM + SEC3_GOAL_DIM + SEC3_OTHER_DIM + 3 + 3
#: Standard normals one Section 3 observation's pixel noise takes: the ball's 4 features,
#: the goal's 4 end points (8) and area centroid (2), the other robot's centroid and extent.
SEC3_NOISE_DIM = 4 + 10 + 4
#: Smallest visible area of a region (goal, other robot), px^2: below it the object is lost.
_MIN_AREA = 1e-6
#: The goal mouth's boundary cycle LB->LT->RT->RB->LB: (segment, runs it forwards).
_GOAL_CYCLE = ((0, True), (3, True), (1, False), (2, False))


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
    zero, big = jnp.zeros((), F32), jnp.asarray(BIG, F32)
    return tuple((zero, zero, zero) for _ in range(n_box)), (big, big, -big, -big)


def _green_step(carry, seg, boxes, orig):
    """Add one directed segment ``(x0, y0, x1, y1, w)`` (scalars, px) to the sums.

    See :func:`_chain_in_rects`: the part of the segment inside each box's row band is
    split at the box's columns into three pieces; each, clamped into the box and taken
    about the box's origin, adds ``∫ x dy``, ``∫ x^2 dy`` and ``∫ x y dy`` (closed form
    for a straight piece), times the weight ``w``. The box-0 bounding box grows by the
    u-range of the part inside its row band and the v-range of the part inside its
    column band (segments of weight 0 are not boundary and add nothing). The pieces'
    parameters and clamped ends are stored once per box (:func:`stored`) and read by the
    three sums, which XLA would otherwise each recompute them for.
    """
    sums, (u_lo, v_lo, u_hi, v_hi) = carry
    x0, y0, x1, y1, ws = seg
    dx, dy = x1 - x0, y1 - y0
    ix, iy = safe_div(1.0, dx), safe_div(1.0, dy)
    big = jnp.asarray(BIG, F32)
    zero = jnp.zeros((), F32)
    one = opaque_one(ws)   # weights are finite
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
        ts = [stored(t, one) for t in (ta, jnp.clip(cmin, ta, tb), jnp.clip(cmax, ta, tb), tb)]
        xs = [stored(jnp.clip(x0 + t * dx, lu, hu) - ou, one) for t in ts]
        ys = [stored(jnp.clip(y0 + t * dy, lv, hv) - ov, one) for t in ts]
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


def _box_edges(base_c, axes_c, frs, zn, fu, fv):
    """The box's 12 edges (order of :func:`_box_tables`) near-clipped and projected, one
    ``lax.scan`` step per edge: (u0, v0, u1, v1) (12,) px, the clipped edge's image; w
    (12,), its boundary weight ``front[f+] - front[f-]`` (0 wholly behind the near
    plane); (cu, cv) (12,) px, the image of its crossing with the near plane; xf, xb
    (12,), 1.0 where it leaves (start in front, end behind) / returns through that plane.
    ``frs``: the 6 faces' front flags as float32 scalars."""
    base = [base_c[i] for i in range(3)]
    axes = [[axes_c[k, i] for i in range(3)] for k in range(3)]

    def edge(carry, tab):
        st, vec, wf = tab
        pa = [base[i] + st[0] * axes[0][i] + st[1] * axes[1][i] + st[2] * axes[2][i]
              for i in range(3)]
        d = [vec[0] * axes[0][i] + vec[1] * axes[1][i] + vec[2] * axes[2][i]
             for i in range(3)]
        zb = pa[2] + d[2]
        ina, inb = pa[2] >= zn, zb >= zn
        t = safe_div(zn - pa[2], d[2])
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
    return jax.lax.scan(edge, jnp.zeros((), F32), tables)[1]


def _box_chords(frs, cu, cv, xf, xb):
    """Each face's near-plane chord from its edges' crossings (:func:`_box_edges`): a face
    leaves the near plane on one edge and returns on another. Returns a dict of (6,)
    arrays u0, v0 (where it leaves), u1, v1 (where it returns), px, and w (the face's
    front flag where it crosses the near plane, else 0)."""
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
    return {k: jnp.stack(v) for k, v in ends.items()}


def _box_boundary(cols, chords, front):
    """The silhouette boundary's 9 segment slots, picked without a gather (see
    ``_BOX_CLASSES``): per edge direction its (at most 2) edges of non-zero weight, per
    axis its front face's chord; picked slots of weight 0 add nothing. ``cols``: the
    edges' (u0, v0, u1, v1, w) (12,) each; ``chords``: :func:`_box_chords`. Returns
    [u0, v0, u1, v1, w] (9,) each."""
    w = cols[4]
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
        segs.append([jnp.where(pos, chords[k][2 * ax], chords[k][2 * ax + 1])
                     for k in ("u0", "v0", "u1", "v1", "w")])
    return [jnp.stack(f) for f in zip(*segs, strict=True)]


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
    near-plane clip, projection: :func:`_box_edges`); selects pick the boundary's 9 slots
    (:func:`_box_chords`, :func:`_box_boundary`) and :func:`_green_scan` adds them
    (building and adding in one step makes XLA recompute the edge in every loop that
    writes one of the step's outputs).
    """
    zn = jnp.asarray(cam.near_plane, F32)
    boxes, orig = _boxes_and_origins(lo, hi, origin)
    fr = front.astype(F32)
    frs = [fr[f] for f in range(6)]
    u0, v0, u1, v1, w, cu, cv, xf, xb = _box_edges(base_c, axes_c, frs, zn, fu, fv)
    chords = _box_chords(frs, cu, cv, xf, xb)
    segs = _box_boundary((u0, v0, u1, v1, w), chords, front)
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


class _View(NamedTuple):
    """One robot's camera: its frame, focal lengths (px) and image rectangle (px)."""

    frame: CameraFrame
    one: jnp.ndarray      # exactly 1, not known to the compiler (:func:`stored`)
    fu: jnp.ndarray
    fv: jnp.ndarray
    img_lo: jnp.ndarray   # (2,) -W/2, -H/2
    img_hi: jnp.ndarray   # (2,) W/2, H/2


class _Ball(NamedTuple):
    """The ball seen by a :class:`_View`."""

    world: jnp.ndarray    # (3,) centre, world m
    cam: jnp.ndarray      # (3,) centre, camera m
    image: BallImage
    lo: jnp.ndarray       # (2,) its visible image box (u_lo, v_lo), px
    hi: jnp.ndarray       # (2,) (u_hi, v_hi), px


class _Box(NamedTuple):
    """The other robot as a box, in its own frame (local axes along its heading) and in
    the camera's."""

    cos: jnp.ndarray      # cosine and sine of its heading
    sin: jnp.ndarray
    half: jnp.ndarray     # (3,) half length, half width, half height, m
    centre: jnp.ndarray   # (3,) box centre, world m
    cam_local: jnp.ndarray  # (3,) the camera centre in the box's frame, m
    front: jnp.ndarray    # (6,) bool: faces (order of :func:`_box_tables`) the camera sees
    axes_c: jnp.ndarray   # (3, 3) camera-frame half length, half width, height vectors
    base_c: jnp.ndarray   # (3,) bottom centre, camera m


def _view(robot_pose, cam: CameraParams) -> _View:
    """The camera of the robot at ``robot_pose``; its heading's cosine and sine stored."""
    fu, fv = focal_lengths(cam)
    pose = jnp.asarray(robot_pose, F32)
    one = opaque_one(pose[0])   # poses are finite
    frame = camera_frame(pose, cam, trig=(stored(jnp.cos(pose[2]), one),
                                          stored(jnp.sin(pose[2]), one)))
    hw = jnp.asarray(cam.image_width, F32) / 2
    hh = jnp.asarray(cam.image_height, F32) / 2
    return _View(frame, one, fu, fv, jnp.stack([-hw, -hh]), jnp.stack([hw, hh]))


def _ball(ball_xy, ball_radius, view: _View, cam: CameraParams) -> _Ball:
    """The ball and its visible image box (:func:`ball_image`), stored."""
    r = jnp.asarray(ball_radius, F32)
    bxy = jnp.asarray(ball_xy, F32)
    ball_w = jnp.stack([bxy[0], bxy[1], r])
    ball_c = stored(to_camera(ball_w, view.frame), view.one)
    bi = ball_image(ball_c, r, cam)
    box = stored(jnp.stack([bi.u_lo, bi.u_hi, bi.v_lo, bi.v_hi]), view.one)
    bi = bi.replace(u_lo=box[0], u_hi=box[1], v_lo=box[2], v_hi=box[3])
    return _Ball(ball_w, ball_c, bi, jnp.stack([bi.u_lo, bi.v_lo]),
                 jnp.stack([bi.u_hi, bi.v_hi]))


def _to_local(p, box_cos, box_sin, centre):
    """World point ``p`` (3,) in the box's frame (origin at its centre)."""
    rel = p - centre
    return jnp.stack([box_cos * rel[0] + box_sin * rel[1],
                      -box_sin * rel[0] + box_cos * rel[1], rel[2]])


def _box(other_pose, other_size, view: _View) -> _Box:
    """The other robot's box: its faces the camera sees and its camera-frame axes."""
    opose = jnp.asarray(other_pose, F32)
    osize = jnp.asarray(other_size, F32)
    c, s = stored(jnp.cos(opose[2]), view.one), stored(jnp.sin(opose[2]), view.one)
    half = jnp.stack([osize[0] / 2, osize[1] / 2, osize[2] / 2])
    ocen = jnp.stack([opose[0], opose[1], half[2]])
    locc = stored(_to_local(view.frame.c, c, s, ocen), view.one)
    front = jnp.stack([locc[0] > half[0], locc[0] < -half[0], locc[1] > half[1],
                       locc[1] < -half[1], locc[2] > half[2], locc[2] < -half[2]])
    zero = jnp.zeros((), F32)
    axes_w = jnp.stack([jnp.stack([c * half[0], s * half[0], zero]),
                        jnp.stack([-s * half[1], c * half[1], zero]),
                        jnp.stack([zero, zero, osize[2]])])
    rot = view.frame.rot
    axes_c = stored(jnp.sum(axes_w[:, None, :] * rot[None, :, :], axis=-1), view.one)
    base_c = stored(to_camera(jnp.stack([opose[0], opose[1], zero]), view.frame), view.one)
    return _Box(c, s, half, ocen, locc, front, axes_c, base_c)


def _depth_order(corners, ball: _Ball, box: _Box, view: _View):
    """(ball before goal, robot before goal, ball before robot), bool scalars: the depth
    order of ``docs/vision.md`` ("Section 3 features")."""
    goal_cam_side = plane_side(corners, view.frame.c)
    ball_before_goal = (plane_side(corners, ball.world) * goal_cam_side > 0) & ball.image.valid
    robot_before_goal = plane_side(corners, box.centre) * goal_cam_side > 0
    # ball vs robot: the robot face plane the ball centre is farthest outside of separates
    loc = _to_local(ball.world, box.cos, box.sin, box.centre)
    ax = jnp.argmax(jnp.abs(loc) / box.half)
    cam_out = jnp.sign(loc[ax]) * box.cam_local[ax] > box.half[ax]
    return ball_before_goal, robot_before_goal, cam_out & ball.image.valid


def _robot_region(box: _Box, ball: _Ball, occ_b, view: _View, cam: CameraParams):
    """The other robot's silhouette inside the image and, where the ball is in front
    (``occ_b``), inside the ball's box: (region oriented positive, its camera-frame
    centre, its bounding box lo, hi (2,) in the image (0 when not visible), visible)."""
    e_lo, e_hi = _empty_rect()
    ob_lo, ob_hi = _rect_inter(view.img_lo, view.img_hi, ball.lo, ball.hi)
    ob_lo, ob_hi = jnp.where(occ_b, ob_lo, e_lo), jnp.where(occ_b, ob_hi, e_hi)
    ocen_c = stored(to_camera(box.centre, view.frame), view.one)
    o_origin = project(ocen_c, view.fu, view.fv, jnp.asarray(cam.near_plane, F32))
    oreg = _box_region(box.base_c, box.axes_c, box.front, cam, view.fu, view.fv,
                       jnp.stack([view.img_lo, ob_lo]), jnp.stack([view.img_hi, ob_hi]),
                       o_origin)
    oreg = _oriented(oreg, _sign(oreg.area[0]))
    o_full_lo, o_full_hi = oreg.lo, oreg.hi
    o_full_vis = (oreg.area[0] > 0) & jnp.all(o_full_hi > o_full_lo)
    o_full_lo = jnp.where(o_full_vis, o_full_lo, 0.0)
    o_full_hi = jnp.where(o_full_vis, o_full_hi, 0.0)
    return oreg, ocen_c, o_full_lo, o_full_hi, o_full_vis


def _goal_area(gseg: GoalSegs, pc, ball: _Ball, ball_in_front, robot_lo, robot_hi,
               robot_in_front, view: _View, cam: CameraParams):
    """The goal mouth's visible area (px^2) and its centroid (u, v) px: its area inside
    the image minus the nearer occluders' boxes (inclusion-exclusion). Returns (area,
    cu, cv, camera-frame goal centre)."""
    e_lo, e_hi = _empty_rect()
    img_lo, img_hi = view.img_lo, view.img_hi
    g1_lo, g1_hi = _rect_inter(img_lo, img_hi, ball.lo, ball.hi)
    g1_lo = jnp.where(ball_in_front, g1_lo, e_lo)
    g1_hi = jnp.where(ball_in_front, g1_hi, e_hi)
    g2_lo, g2_hi = _rect_inter(img_lo, img_hi, robot_lo, robot_hi)
    g2_lo = jnp.where(robot_in_front, g2_lo, e_lo)
    g2_hi = jnp.where(robot_in_front, g2_hi, e_hi)
    g12_lo, g12_hi = _rect_inter(g1_lo, g1_hi, g2_lo, g2_hi)
    gp0, gp1, gw = _goal_chain(gseg)
    gcen = jnp.mean(pc, axis=0)
    g_origin = project(gcen, view.fu, view.fv, jnp.asarray(cam.near_plane, F32))
    gr = _chain_in_rects(gp0, gp1, gw, jnp.stack([img_lo, g1_lo, g2_lo, g12_lo]),
                         jnp.stack([img_hi, g1_hi, g2_hi, g12_hi]), g_origin)
    sgn4 = jnp.array([1.0, -1.0, -1.0, 1.0], F32) * _sign(gr.area[0])
    g_area = jnp.maximum(jnp.sum(sgn4 * gr.area), 0.0)
    g_cu = safe_div(jnp.sum(sgn4 * gr.mu), g_area)
    g_cv = safe_div(jnp.sum(sgn4 * gr.mv), g_area)
    return g_area, g_cu, g_cv, gcen


def _add_noise(ball_f, goal_f, other_f, eps, vis, cam: CameraParams):
    """The features with pixel noise ``eps`` (SEC3_NOISE_DIM,) on every pixel coordinate
    and size of a visible object (``vis``: ball, goal, other); sizes clipped at 0."""
    eps = jnp.asarray(eps, F32)
    ball_f = add_pixel_noise(eps[:4], ball_f, cam, vis[0])
    goal_f = goal_f.at[:10].set(add_pixel_noise(eps[4:14], goal_f[:10], cam, vis[1]))
    other_f = other_f.at[:4].set(add_pixel_noise(eps[14:18], other_f[:4], cam, vis[2]))
    ball_f = ball_f.at[2:].set(jnp.maximum(ball_f[2:], 0.0))
    other_f = other_f.at[2:4].set(jnp.maximum(other_f[2:4], 0.0))
    return ball_f, goal_f, other_f


@jax.jit
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
    view = _view(robot_pose, cam)
    ball = _ball(ball_xy, ball_radius, view, cam)
    bi = ball.image
    corners = jnp.asarray(goal_corners, F32)
    pc = stored(to_camera(corners, view.frame), view.one)
    gseg = goal_segments(pc, cam, view.fu, view.fv)
    ends = goal_ends(gseg, cam)
    ends = ends.replace(bot=stored(ends.bot, view.one), top=stored(ends.top, view.one))
    box = _box(other_pose, other_size, view)
    ball_before_goal, robot_before_goal, ball_before_robot = _depth_order(corners, ball,
                                                                          box, view)
    # robot silhouette in the image, and inside the ball's box when the ball is in front
    occ_b = ball_before_robot & bi.visible
    oreg, ocen_c, o_full_lo, o_full_hi, o_full_vis = _robot_region(box, ball, occ_b, view,
                                                                   cam)
    # ball box occluded by the robot (bounding boxes)
    occ_r = ~ball_before_robot & o_full_vis
    ulo, uhi = _subtract_cover(ball.lo, ball.hi, o_full_lo, o_full_hi, occ_r)
    ball_vis = bi.visible & jnp.all(uhi > ulo)
    # robot occluded by the ball box
    o_in = jnp.where(o_full_vis, oreg.area[0], 0.0)
    o_occ = jnp.where(o_full_vis, oreg.area[1], 0.0)
    o_area = jnp.maximum(o_in - o_occ, 0.0)
    olo, ohi = _subtract_cover(o_full_lo, o_full_hi, ball.lo, ball.hi, occ_b & o_full_vis)
    other_vis = (o_area > _MIN_AREA) & jnp.all(ohi > olo)
    o_cu = safe_div(oreg.mu[0] - oreg.mu[1], o_area)
    o_cv = safe_div(oreg.mv[0] - oreg.mv[1], o_area)
    g_area, g_cu, g_cv, gcen = _goal_area(gseg, pc, ball, ball_before_goal & bi.visible,
                                          o_full_lo, o_full_hi,
                                          robot_before_goal & o_full_vis, view, cam)
    goal_vis = ends.visible & (g_area > _MIN_AREA)
    gpts = jnp.stack([ends.bot[0], ends.top[0], ends.top[1], ends.bot[1]]).reshape(-1)
    ball_f = jnp.stack([0.5 * (ulo[0] + uhi[0]), 0.5 * (ulo[1] + uhi[1]),
                        uhi[0] - ulo[0], uhi[1] - ulo[1]])
    goal_f = jnp.concatenate([gpts, jnp.stack([g_cu, g_cv, g_area])])
    other_f = jnp.stack([o_cu, o_cv, ohi[0] - olo[0], ohi[1] - olo[1], o_area])
    if eps is not None:
        ball_f, goal_f, other_f = _add_noise(ball_f, goal_f, other_f, eps,
                                             (ball_vis, goal_vis, other_vis), cam)
    vis = jnp.stack([ball_vis, goal_vis, other_vis])
    lost = jnp.where(vis, 0.0, jnp.stack([lost_side(ball.cam[0]), lost_side(gcen[0]),
                                          lost_side(ocen_c[0])]))
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
    ulo, uhi = subtract_interval(lo[0], hi[0], olo[0], ohi[0], occ & cov_v)
    vlo, vhi = subtract_interval(lo[1], hi[1], olo[1], ohi[1], occ & cov_u)
    full = occ & cov_u & cov_v
    nlo = jnp.stack([ulo, vlo])
    nhi = jnp.where(full, nlo, jnp.stack([uhi, vhi]))
    return nlo, nhi


def flatten_section3(obs: Section3Obs) -> jnp.ndarray:
    """(26,) float32: ball 4, goal 11, other 5, visible 3, lost_side 3."""
    return jnp.concatenate([obs.ball, obs.goal, obs.other, obs.visible,
                            obs.lost_side]).astype(F32)
