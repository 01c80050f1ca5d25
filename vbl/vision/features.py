"""Image features of the ball, the goal and another robot, by projecting geometry.

Nothing is rasterised: every feature is a closed-form function of the camera pose and
the object geometry (pure JAX, float32, jit/vmap-able). Exact definitions, clipping and
occlusion rules are in ``docs/vision.md``; in short

* the ball (a sphere) images to an ellipse (the cone of rays tangent to the sphere cut
  by the image plane); its visible part is that ellipse intersected with the image
  rectangle, and extents are computed exactly from the conic;
* straight edges (goal posts, crossbar, robot box edges) are clipped to the near plane
  in 3-D, projected, and clipped to the image rectangle (Liang-Barsky);
* areas and centroids of planar polygons use Green's theorem on the clipped boundary
  (the boundary of polygon-inside-rectangle is the polygon's edges clipped to the
  rectangle plus the rectangle's edges clipped to the polygon);
* an object the camera cannot see at all is *lost*; its lost side is -1 when its
  reference point lies left of the camera's vertical mid-plane (camera X < 0), else +1.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from vbl.vision.camera import F32, CameraParams, camera_frame, focal_lengths, to_camera
from vbl.vision.noise import add_pixel_noise

__all__ = [
    "SEC2_DIM", "SEC2_BALL_SIZE", "SEC2_BALL_POS", "SEC2_GOAL_SIZE", "SEC2_GOAL_POS",
    "SEC2_GOAL_ORIENT", "SEC2_BALL_VISIBLE", "SEC2_GOAL_VISIBLE", "SEC2_BALL_LOST_SIDE",
    "SEC2_GOAL_LOST_SIDE", "SEC3_BALL_DIM", "SEC3_GOAL_DIM", "SEC3_OTHER_DIM", "SEC3_DIM",
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

SEC3_BALL_DIM = 4
SEC3_GOAL_DIM = 11
SEC3_OTHER_DIM = 5
SEC3_DIM = SEC3_BALL_DIM + SEC3_GOAL_DIM + SEC3_OTHER_DIM + 3 + 3

_TINY = 1e-12


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


def _ellipse_extent(xa, xb, z, r, ha, hb):
    """Extent along axis ``a`` of (sphere image ellipse) ∩ ([-ha, ha] x [-hb, hb]).

    Normalised coordinates. Exact: the extreme points of the convex intersection are the
    ellipse's own extreme points inside the rectangle, the ends of its chords along the
    rectangle's edges ``b = ±hb``, or the rectangle's sides ``a = ±ha`` crossed by it.
    Returns (lo, hi, any).
    """
    k = xa * xa + xb * xb + z * z - r * r
    den = z * z - r * r
    root = r * jnp.sqrt(jnp.maximum(xa * xa + z * z - r * r, 0.0))
    a_ext = jnp.stack([_safe_div(xa * z - root, den), _safe_div(xa * z + root, den)])
    b_ext = _safe_div(xb * (xa * a_ext + z), xa * xa + z * z - r * r)
    ok_ext = (jnp.abs(a_ext) <= ha) & (jnp.abs(b_ext) <= hb)
    # chords along the rows b = -hb, +hb (free coordinate a)
    rows = jnp.stack([-hb, hb])
    rl, rh, rex = _chord(rows, xb, xa, z, k)
    rlo, rhi = jnp.maximum(rl, -ha), jnp.minimum(rh, ha)
    ok_row = rex & (rlo <= rhi)
    # chords along the columns a = -ha, +ha (free coordinate b)
    cols = jnp.stack([-ha, ha])
    cl, ch, cex = _chord(cols, xa, xb, z, k)
    ok_col = cex & (jnp.maximum(cl, -hb) <= jnp.minimum(ch, hb))
    big = jnp.asarray(1e9, F32)
    lo = jnp.minimum(jnp.where(ok_ext[0], a_ext[0], big),
                     jnp.minimum(jnp.min(jnp.where(ok_row, rlo, big)),
                                 jnp.where(ok_col[0], -ha, big)))
    hi = jnp.maximum(jnp.where(ok_ext[1], a_ext[1], -big),
                     jnp.maximum(jnp.max(jnp.where(ok_row, rhi, -big)),
                                 jnp.where(ok_col[1], ha, -big)))
    anyv = jnp.any(ok_ext) | jnp.any(ok_row) | jnp.any(ok_col)
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
    whose body keeps the ball away from the camera).
    """
    fu, fv = focal_lengths(cam)
    ht = jnp.asarray(cam.image_width, F32) / 2 / fu
    hs = jnp.asarray(cam.image_height, F32) / 2 / fv
    r = jnp.asarray(radius, F32)
    x, y, z = ball_cam[0], ball_cam[1], ball_cam[2]
    valid = z - r >= jnp.asarray(cam.near_plane, F32)
    zs = jnp.where(valid, z, r + 1.0)  # keep the algebra finite where invalid
    tlo, thi, tany = _ellipse_extent(x, y, zs, r, ht, hs)
    slo, shi, sany = _ellipse_extent(y, x, zs, r, hs, ht)
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

def _near_clip(pa, pb, zn):
    """Clip the 3-D segment pa->pb (camera coords) to Z >= zn. Returns (pa', pb', ok)."""
    za, zb = pa[..., 2:3], pb[..., 2:3]
    ok = jnp.maximum(za, zb)[..., 0] >= zn
    t = _safe_div(zn - za, zb - za)
    pa2 = jnp.where(za < zn, pa + t * (pb - pa), pa)
    pb2 = jnp.where(zb < zn, pa + t * (pb - pa), pb)
    return pa2, pb2, ok


def _proj(p, fu, fv, zn):
    """Camera coords (..., 3) with Z >= zn -> px (..., 2)."""
    z = jnp.maximum(p[..., 2], zn)
    return jnp.stack([fu * p[..., 0] / z, fv * p[..., 1] / z], axis=-1)


def _clip_rect(p0, p1, lo, hi):
    """Liang-Barsky: clip 2-D segments p0->p1 (..., 2) to the box [lo, hi] (each (2,)).

    Returns clipped (q0, q1, ok).
    """
    d = p1 - p0
    # inequalities  -d t <= p0 - lo   and   d t <= hi - p0  per axis
    pp = jnp.concatenate([-d, d], axis=-1)
    qq = jnp.concatenate([p0 - lo, hi - p0], axis=-1)
    par = jnp.abs(pp) < _TINY
    ratio = _safe_div(qq, pp)
    t0 = jnp.max(jnp.where(~par & (pp < 0), ratio, 0.0), axis=-1)
    t1 = jnp.min(jnp.where(~par & (pp > 0), ratio, 1.0), axis=-1)
    ok = (t0 <= t1) & ~jnp.any(par & (qq < 0), axis=-1)
    q0 = p0 + t0[..., None] * d
    q1 = p0 + t1[..., None] * d
    return q0, q1, ok


def _interp_v(a, b, ok, u):
    """v of the image segment a->b at column u; (v, valid)."""
    du = b[..., 0] - a[..., 0]
    inside = ok & (jnp.minimum(a[..., 0], b[..., 0]) <= u) & (u <= jnp.maximum(
        a[..., 0], b[..., 0])) & (jnp.abs(du) > 1e-6)
    v = a[..., 1] + _safe_div(u - a[..., 0], du) * (b[..., 1] - a[..., 1])
    return v, inside


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


def _goal_ends(pc, cam: CameraParams, fu, fv):
    """Visible ends of the goal from its corners in camera coordinates ``pc`` (4, 3).

    End rule: a post whose projected segment meets the image is its own end (clipped to
    the image); otherwise the end is the goal's extent on the image border column on that
    side (u = -W/2 for the left post, +W/2 for the right), between the projected
    bottom edge and crossbar, clipped to the image.
    """
    zn = jnp.asarray(cam.near_plane, F32)
    hw = jnp.asarray(cam.image_width, F32) / 2
    hh = jnp.asarray(cam.image_height, F32) / 2
    lo = jnp.stack([-hw, -hh])
    hi = jnp.stack([hw, hh])
    # segments: posts (bottom -> top) left, right; edges bottom (LB->RB), top (LT->RT)
    a = jnp.stack([pc[0], pc[3], pc[0], pc[1]])
    b = jnp.stack([pc[1], pc[2], pc[3], pc[2]])
    a2, b2, ok = _near_clip(a, b, zn)
    ia, ib = _proj(a2, fu, fv, zn), _proj(b2, fu, fv, zn)
    # posts clipped to the image
    qa, qb, qok = _clip_rect(ia[:2], ib[:2], lo, hi)
    post_ok = ok[:2] & qok
    # border columns for ends whose post is out of the image
    cols = jnp.stack([-hw, hw])
    vb, okb = _interp_v(ia[2], ib[2], ok[2], cols)
    vt, okt = _interp_v(ia[3], ib[3], ok[3], cols)
    col_lo = jnp.clip(jnp.minimum(vb, vt), -hh, hh)
    col_hi = jnp.clip(jnp.maximum(vb, vt), -hh, hh)
    col_ok = okb & okt & (col_hi > col_lo)
    # lower/upper point of each post segment
    post_low = jnp.where((qa[:, 1] <= qb[:, 1])[:, None], qa, qb)
    post_up = jnp.where((qa[:, 1] <= qb[:, 1])[:, None], qb, qa)
    col_low = jnp.stack([cols, col_lo], axis=-1)
    col_up = jnp.stack([cols, col_hi], axis=-1)
    end_ok = post_ok | col_ok
    m = end_ok[:, None]
    bot = jnp.where(m, jnp.where(post_ok[:, None], post_low, col_low), 0.0)
    top = jnp.where(m, jnp.where(post_ok[:, None], post_up, col_up), 0.0)
    visible = jnp.any(end_ok & (top[:, 1] > bot[:, 1]))
    return GoalEnds(bot=bot, top=top, visible=visible)


def _plane_side(corners, p):
    """Signed distance-like side of point(s) p w.r.t. the plane of the goal corners."""
    n = jnp.cross(corners[1] - corners[0], corners[3] - corners[0])
    return jnp.dot(p - corners[0], n)


# ----------------------------------------------------------------------------- section 2

def section2_features(robot_pose, ball_xy, ball_radius, goal_corners, cam: CameraParams,
                      key=None) -> jnp.ndarray:
    """Section 2 observation (9,) float32 of one robot's camera (layout ``SEC2_*``).

    Args:
      robot_pose: (3,) ``(x, y, theta)`` m, m, rad.
      ball_xy: (2,) ball centre on the floor, m (the centre is at height ``ball_radius``).
      ball_radius: scalar, m.
      goal_corners: (4, 3) world m, order left-bottom, left-top, right-top, right-bottom
        ("left" = +y post).
      cam: camera parameters.
      key: optional PRNG key for pixel noise of std ``cam.pixel_noise_std``; None = exact.
        The normals are drawn only when the std is > 0 (``lax.cond``), so a key with the
        noise off costs nothing and gives the exact features.

    Features (px unless stated; 0 when the object is lost):
      x1 ball diameter = horizontal extent of the visible part of the ball's image (for a
      wholly visible ball: the distance between the two vertical image lines tangent to
      its outline); x2 = centre of that extent. x3 = mean of the image heights (v extent)
      of the goal's left and right ends, x4 = mean of their u positions, x5 = (h_left -
      h_right) / x3 clipped to [-1, 1]. Flags and lost sides as in ``docs/vision.md``.
    """
    return _section2(robot_pose, ball_xy, ball_radius, goal_corners, cam, key)


def _sec2_noise(key, cam: CameraParams, fold_in=None):
    """(6,) float32 pixel-noise normals of Section 2 [ball w, u | goal h_l, h_r, u_l, u_r].

    Drawn (from ``split(key)``, after ``fold_in(key, fold_in)`` when given) only when
    ``cam.pixel_noise_std > 0``; zeros otherwise. One graph of the features serves both
    cases (the cond is around the draw only, not around the feature geometry).
    """
    def draw(k):
        if fold_in is not None:
            k = jax.random.fold_in(k, fold_in)
        kb, kg = jax.random.split(k)
        return jnp.concatenate([jax.random.normal(kb, (2,), F32),
                                jax.random.normal(kg, (4,), F32)])

    std = jnp.asarray(cam.pixel_noise_std, F32)
    return jax.lax.cond(std > 0, draw, lambda k: jnp.zeros((6,), F32), key)


def _section2(robot_pose, ball_xy, ball_radius, goal_corners, cam: CameraParams, key,
              fold_in=None) -> jnp.ndarray:
    """:func:`section2_features`; ``fold_in`` (int or None) derives the noise key lazily."""
    fu, fv = focal_lengths(cam)
    frame = camera_frame(robot_pose, cam)
    r = jnp.asarray(ball_radius, F32)
    bxy = jnp.asarray(ball_xy, F32)
    ball_w = jnp.stack([bxy[0], bxy[1], r])
    ball_c = to_camera(ball_w, frame)
    bi = ball_image(ball_c, r, cam)
    corners = jnp.asarray(goal_corners, F32)
    pc = to_camera(corners, frame)
    ends = _goal_ends(pc, cam, fu, fv)
    # the ball hides the goal behind it when it is on the camera's side of the goal plane
    occ = (_plane_side(corners, ball_w) * _plane_side(corners, frame.c) > 0) & bi.valid
    u_end = 0.5 * (ends.bot[:, 0] + ends.top[:, 0])
    clo, chi, cex = jax.vmap(lambda u: _ball_column_chord(bi, u, cam))(u_end)
    vlo, vhi = _subtract_interval(ends.bot[:, 1], ends.top[:, 1], clo, chi, occ & cex)
    h = vhi - vlo
    bu = 0.5 * (bi.u_lo + bi.u_hi)
    bw = bi.u_hi - bi.u_lo
    if key is not None:
        eps = _sec2_noise(key, cam, fold_in)
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


def _near_clip_polygon(pc, zn):
    """Clip a convex planar polygon (N, 3) (camera coords) to Z >= zn.

    Fixed size output (2N, 3): each edge i contributes [V_i or filler, crossing point or
    copy]; removed vertices are replaced by a point of the near-plane chord, so the
    output is the clipped polygon with repeated / collinear extra vertices (which change
    neither its area nor its boundary). Returns (points, ok).
    """
    nxt = jnp.roll(pc, -1, axis=0)
    z0, z1 = pc[:, 2], nxt[:, 2]
    inside = z0 >= zn
    cross = (z0 >= zn) != (z1 >= zn)
    t = _safe_div(zn - z0, z1 - z0)[:, None]
    ipt = pc + t * (nxt - pc)
    filler = ipt[jnp.argmax(cross)]
    first = jnp.where(inside[:, None], pc, filler)
    second = jnp.where(cross[:, None], ipt, first)
    pts = jnp.stack([first, second], axis=1).reshape(-1, 3)
    return pts, jnp.any(inside)


def _seg_moments(q0, q1, w):
    """Green's-theorem area and first moments of directed segments (..., 2), weights w."""
    cr = q0[..., 0] * q1[..., 1] - q1[..., 0] * q0[..., 1]
    a = 0.5 * jnp.sum(w * cr)
    mu = jnp.sum(w * (q0[..., 0] + q1[..., 0]) * cr) / 6.0
    mv = jnp.sum(w * (q0[..., 1] + q1[..., 1]) * cr) / 6.0
    return a, mu, mv


@struct.dataclass
class Region:
    """Area (px^2), first moments (px^3) and bounding box (px) of a visible region."""

    area: jnp.ndarray
    mu: jnp.ndarray
    mv: jnp.ndarray
    lo: jnp.ndarray   # (2,) u_lo, v_lo
    hi: jnp.ndarray   # (2,) u_hi, v_hi

    @property
    def visible(self):
        return (self.area > 0) & jnp.all(self.hi > self.lo)


def _poly_in_rect(poly, ok, lo, hi) -> Region:
    """Exact area, moments and bbox of (convex polygon ``poly`` (N, 2) px) ∩ box [lo, hi].

    The boundary of the intersection is the polygon's edges clipped to the box
    (Liang-Barsky) plus the box's edges clipped to the polygon (Cyrus-Beck); Green's
    theorem sums them segment by segment. Repeated vertices are allowed.
    """
    nxt = jnp.roll(poly, -1, axis=0)
    e = nxt - poly
    elen = jnp.sqrt(jnp.sum(e * e, axis=-1))
    real = elen > 1e-6
    signed = 0.5 * jnp.sum(poly[:, 0] * nxt[:, 1] - nxt[:, 0] * poly[:, 1])
    o = jnp.where(signed < 0, jnp.float32(-1.0), jnp.float32(1.0))
    box_ok = ok & jnp.all(hi > lo) & (jnp.abs(signed) > 1e-6)
    # polygon edges clipped to the box
    q0, q1, qok = _clip_rect(poly, nxt, lo, hi)
    w1 = (qok & real & box_ok).astype(F32) * o
    a1, mu1, mv1 = _seg_moments(q0, q1, w1)
    # box edges (counter-clockwise) clipped to the polygon
    corners = jnp.stack([lo, jnp.stack([hi[0], lo[1]]), hi, jnp.stack([lo[0], hi[1]])])
    rnext = jnp.roll(corners, -1, axis=0)
    nrm = o * jnp.stack([-e[:, 1], e[:, 0]], axis=-1) / jnp.maximum(elen, 1e-6)[:, None]
    # constraint per (box edge j, polygon edge i): nrm_i . (a_j + t d_j - p_i) >= 0
    d = rnext - corners
    num = jnp.einsum("ik,jik->ji", nrm, corners[:, None, :] - poly[None, :, :])
    den = jnp.einsum("ik,jk->ji", nrm, d)
    par = (jnp.abs(den) < 1e-9) | ~real[None, :]
    tt = _safe_div(-num, den)
    t0 = jnp.max(jnp.where(~par & (den > 0), tt, 0.0), axis=1)
    t1 = jnp.min(jnp.where(~par & (den < 0), tt, 1.0), axis=1)
    rok = (t0 < t1) & ~jnp.any(par & real[None, :] & (num < 0), axis=1)
    r0 = corners + t0[:, None] * d
    r1 = corners + t1[:, None] * d
    w2 = (rok & box_ok).astype(F32)
    a2, mu2, mv2 = _seg_moments(r0, r1, w2)
    big = jnp.asarray(1e9, F32)
    m1 = (w1 != 0)[:, None]
    m2 = (w2 != 0)[:, None]
    lo_b = jnp.minimum(jnp.min(jnp.where(m1, jnp.minimum(q0, q1), big), axis=0),
                       jnp.min(jnp.where(m2, jnp.minimum(r0, r1), big), axis=0))
    hi_b = jnp.maximum(jnp.max(jnp.where(m1, jnp.maximum(q0, q1), -big), axis=0),
                       jnp.max(jnp.where(m2, jnp.maximum(r0, r1), -big), axis=0))
    area = a1 + a2
    anyv = box_ok & (area > 0)
    z = jnp.zeros((), F32)
    return Region(area=jnp.where(anyv, area, z), mu=jnp.where(anyv, mu1 + mu2, z),
                  mv=jnp.where(anyv, mv1 + mv2, z), lo=jnp.where(anyv, lo_b, 0.0),
                  hi=jnp.where(anyv, hi_b, 0.0))


def _project_polygon(pc, cam, fu, fv):
    zn = jnp.asarray(cam.near_plane, F32)
    pts, ok = _near_clip_polygon(pc, zn)
    return _proj(pts, fu, fv, zn), ok


def _box_corners_world(pose, size):
    """(8, 3) corners of a robot box: footprint length x width around (x, y), z in [0, h]."""
    x, y, th = pose[0], pose[1], pose[2]
    hl, hw, h = size[0] / 2, size[1] / 2, size[2]
    c, s = jnp.cos(th), jnp.sin(th)
    sx = jnp.array([1, -1, -1, 1, 1, -1, -1, 1], F32) * hl
    sy = jnp.array([1, 1, -1, -1, 1, 1, -1, -1], F32) * hw
    sz = jnp.array([0, 0, 0, 0, 1, 1, 1, 1], F32) * h
    return jnp.stack([x + c * sx - s * sy, y + s * sx + c * sy, sz], axis=-1)


# faces of the box as corner indices (any consistent winding; orientation is recomputed)
_BOX_FACES = jnp.array([[0, 1, 2, 3], [4, 5, 6, 7], [0, 3, 7, 4], [1, 2, 6, 5],
                        [0, 1, 5, 4], [3, 2, 6, 7]], jnp.int32)


def _rect_inter(lo1, hi1, lo2, hi2):
    return jnp.maximum(lo1, lo2), jnp.minimum(hi1, hi2)


def _empty_rect():
    z = jnp.zeros((2,), F32)
    return z, z


def section3_features(robot_pose, ball_xy, ball_radius, goal_corners, other_pose, other_size,
                      cam: CameraParams, key=None) -> Section3Obs:
    """Section 3 observation of one robot's camera (see ``docs/vision.md``).

    Args:
      robot_pose: (3,) this robot's ``(x, y, theta)``.
      ball_xy: (2,) m; ball_radius: scalar m.
      goal_corners: (4, 3) m, order left-bottom, left-top, right-top, right-bottom.
      other_pose: (3,) the other robot's ``(x, y, theta)``.
      other_size: (3,) the other robot as a box ``[length, width, height]`` m.
      cam: camera parameters; key: optional PRNG key for pixel noise.

    Returns:
      :class:`Section3Obs` with ``ball`` = (centroid u, v, bounding width, height) of the
      visible ball box; ``goal`` = the four ends' points (u, v) in corner order, area
      centroid (u, v) and visible area (px^2); ``other`` = area centroid (u, v), bounding
      width, height and visible area of the other robot's silhouette; ``visible`` and
      ``lost_side`` (ball, goal, other). Lost objects have all-zero features.
    """
    fu, fv = focal_lengths(cam)
    frame = camera_frame(robot_pose, cam)
    hw = jnp.asarray(cam.image_width, F32) / 2
    hh = jnp.asarray(cam.image_height, F32) / 2
    img_lo, img_hi = jnp.stack([-hw, -hh]), jnp.stack([hw, hh])
    # ball
    r = jnp.asarray(ball_radius, F32)
    bxy = jnp.asarray(ball_xy, F32)
    ball_w = jnp.stack([bxy[0], bxy[1], r])
    ball_c = to_camera(ball_w, frame)
    bi = ball_image(ball_c, r, cam)
    b_lo = jnp.stack([bi.u_lo, bi.v_lo])
    b_hi = jnp.stack([bi.u_hi, bi.v_hi])
    # goal
    corners = jnp.asarray(goal_corners, F32)
    pc = to_camera(corners, frame)
    ends = _goal_ends(pc, cam, fu, fv)
    gpoly, gok = _project_polygon(pc, cam, fu, fv)
    # other robot: front-facing faces
    opose = jnp.asarray(other_pose, F32)
    osize = jnp.asarray(other_size, F32)
    bw = _box_corners_world(opose, osize)
    faces_w = bw[_BOX_FACES]                                      # (6, 4, 3)
    fcen = jnp.mean(faces_w, axis=1)
    ocen = jnp.mean(bw, axis=0)
    front = jnp.sum((fcen - ocen) * (frame.c - fcen), axis=-1) > 0
    faces_c = to_camera(faces_w, frame)
    fpoly, fok = jax.vmap(lambda q: _project_polygon(q, cam, fu, fv))(faces_c)
    fok = fok & front

    def robot_region(lo, hi):
        regs = jax.vmap(lambda p, k: _poly_in_rect(p, k, lo, hi))(fpoly, fok)
        m = (regs.area > 0)[:, None]
        big = jnp.asarray(1e9, F32)
        rlo = jnp.min(jnp.where(m, regs.lo, big), axis=0)
        rhi = jnp.max(jnp.where(m, regs.hi, -big), axis=0)
        anyv = jnp.any(m)
        return Region(area=jnp.sum(regs.area), mu=jnp.sum(regs.mu), mv=jnp.sum(regs.mv),
                      lo=jnp.where(anyv, rlo, 0.0), hi=jnp.where(anyv, rhi, 0.0))

    o_full = robot_region(img_lo, img_hi)
    # depth order
    goal_cam_side = _plane_side(corners, frame.c)
    ball_before_goal = (_plane_side(corners, ball_w) * goal_cam_side > 0) & bi.valid
    robot_before_goal = _plane_side(corners, ocen) * goal_cam_side > 0
    # ball vs robot: the robot face plane the ball centre is farthest outside of separates
    c, s = jnp.cos(opose[2]), jnp.sin(opose[2])
    rel = ball_w - ocen
    loc = jnp.stack([c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], rel[2]])
    half = jnp.stack([osize[0] / 2, osize[1] / 2, osize[2] / 2])
    excess = jnp.abs(loc) / half
    ax = jnp.argmax(excess)
    sgn = jnp.sign(loc[ax])
    relc = frame.c - ocen
    locc = jnp.stack([c * relc[0] + s * relc[1], -s * relc[0] + c * relc[1], relc[2]])
    cam_out = sgn * locc[ax] > half[ax]
    ball_before_robot = cam_out & bi.valid
    # ball box occluded by the robot (bounding boxes)
    occ_r = ~ball_before_robot & o_full.visible
    ulo, uhi = _subtract_cover(b_lo, b_hi, o_full.lo, o_full.hi, occ_r)
    ball_vis = bi.visible & jnp.all(uhi > ulo)
    # robot occluded by the ball box
    occ_b = ball_before_robot & bi.visible
    e_lo, e_hi = _empty_rect()
    ob_lo, ob_hi = _rect_inter(img_lo, img_hi, b_lo, b_hi)
    ob_lo, ob_hi = jnp.where(occ_b, ob_lo, e_lo), jnp.where(occ_b, ob_hi, e_hi)
    o_occ = robot_region(ob_lo, ob_hi)
    o_area = jnp.maximum(o_full.area - o_occ.area, 0.0)
    olo, ohi = _subtract_cover(o_full.lo, o_full.hi, b_lo, b_hi, occ_b & o_full.visible)
    other_vis = (o_area > 1e-6) & jnp.all(ohi > olo)
    o_cu = _safe_div(o_full.mu - o_occ.mu, o_area)
    o_cv = _safe_div(o_full.mv - o_occ.mv, o_area)
    # goal area minus nearer occluders (bounding boxes; inclusion-exclusion)
    g1_lo, g1_hi = _rect_inter(img_lo, img_hi, b_lo, b_hi)
    g1_lo = jnp.where(ball_before_goal & bi.visible, g1_lo, e_lo)
    g1_hi = jnp.where(ball_before_goal & bi.visible, g1_hi, e_hi)
    g2_lo, g2_hi = _rect_inter(img_lo, img_hi, o_full.lo, o_full.hi)
    g2_lo = jnp.where(robot_before_goal & o_full.visible, g2_lo, e_lo)
    g2_hi = jnp.where(robot_before_goal & o_full.visible, g2_hi, e_hi)
    g12_lo, g12_hi = _rect_inter(g1_lo, g1_hi, g2_lo, g2_hi)
    los = jnp.stack([img_lo, g1_lo, g2_lo, g12_lo])
    his = jnp.stack([img_hi, g1_hi, g2_hi, g12_hi])
    gr = jax.vmap(lambda lo, hi: _poly_in_rect(gpoly, gok, lo, hi))(los, his)
    sgn4 = jnp.array([1.0, -1.0, -1.0, 1.0], F32)
    g_area = jnp.maximum(jnp.sum(sgn4 * gr.area), 0.0)
    g_cu = _safe_div(jnp.sum(sgn4 * gr.mu), g_area)
    g_cv = _safe_div(jnp.sum(sgn4 * gr.mv), g_area)
    goal_vis = ends.visible & (g_area > 1e-6)
    gpts = jnp.stack([ends.bot[0], ends.top[0], ends.top[1], ends.bot[1]]).reshape(-1)
    ball_f = jnp.stack([0.5 * (ulo[0] + uhi[0]), 0.5 * (ulo[1] + uhi[1]),
                        uhi[0] - ulo[0], uhi[1] - ulo[1]])
    goal_f = jnp.concatenate([gpts, jnp.stack([g_cu, g_cv, g_area])])
    other_f = jnp.stack([o_cu, o_cv, ohi[0] - olo[0], ohi[1] - olo[1], o_area])
    if key is not None:
        kb, kg, ko = jax.random.split(key, 3)
        ball_f = add_pixel_noise(kb, ball_f, cam, ball_vis)
        goal_f = goal_f.at[:10].set(add_pixel_noise(kg, goal_f[:10], cam, goal_vis))
        other_f = other_f.at[:4].set(add_pixel_noise(ko, other_f[:4], cam, other_vis))
        ball_f = ball_f.at[2:].set(jnp.maximum(ball_f[2:], 0.0))
        other_f = other_f.at[2:4].set(jnp.maximum(other_f[2:4], 0.0))
    vis = jnp.stack([ball_vis, goal_vis, other_vis])
    gcen = jnp.mean(pc, axis=0)
    ocen_c = to_camera(ocen, frame)
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
