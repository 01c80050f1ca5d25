"""Colour-blob image features from pixels (pure JAX, float32): RGB -> HSV -> per-colour
masks -> the Section 2 and Section 3 feature vectors of :mod:`vbl.vision.section3`.

The outputs have exactly the analytic functions' layouts (``SEC2_*`` indices; the flat
Section 3 vector ball 4, goal 11, other 5, visible 3, lost side 3), in the analytic
camera's px (origin at the image centre, u right, v up, ``cam.image_width x
cam.image_height`` whatever the size of the image), so the two can be swapped. Every step
is a whole-image array operation (masks, row and column reductions); a batch of images is
a ``jax.vmap``. Definitions, the differences from the analytic features and their bounds:
``docs/render.md``.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from vbl.params import param
from vbl.vision.camera import F32, CameraParams, focal_lengths
from vbl.vision.fusion import stored_once
from vbl.vision.render import pixel_grid
from vbl.vision.section3 import Section3Obs, flatten_section3

__all__ = ["BlobParams", "Blob", "rgb_to_hsv", "colour_masks", "blob_stats",
           "goal_ends", "section2_from_pixels", "section3_from_pixels",
           "section3_flat_from_pixels", "track_lost_side", "MASK_BALL", "MASK_GOAL",
           "MASK_OTHER"]

#: Order of the colour masks returned by :func:`colour_masks`.
MASK_BALL, MASK_GOAL, MASK_OTHER = 0, 1, 2
#: Stand-in for "no pixel" in min/max reductions, px.
_BIG = 1e9


@struct.dataclass
class BlobParams:
    """HSV thresholds of the three colour classes and the goal-end rules."""

    ball_hue: float = param(4.0, doc="hue of the ball (red)", unit="deg", ge=0.0, lt=360.0)
    goal_hue: float = param(228.0, doc="hue of the goal (blue)", unit="deg", ge=0.0,
                            lt=360.0)
    other_hue: float = param(53.0, doc="hue of the other robot (yellow)", unit="deg",
                             ge=0.0, lt=360.0)
    hue_tol: float = param(20.0, doc="a pixel is of a class when its hue is within this "
                           "of the class hue", unit="deg", gt=0.0, le=60.0)
    sat_min: float = param(0.5, doc="smallest saturation of a coloured pixel", ge=0.0,
                           le=1.0)
    val_min: float = param(0.25, doc="smallest value (brightness) of a coloured pixel",
                           ge=0.0, le=1.0)
    post_band: float = param(1.0, doc="goal post pixels: blue pixels within this many "
                             "image pixels (horizontally) of the outermost vertical world "
                             "line through a blue pixel", unit="pixel", gt=0.0)
    min_post: float = param(8.0, doc="a post band shorter than this many image pixels (v "
                            "extent) is a corner of a goal cut by the image border, not a "
                            "post: the end is then the border column", unit="pixel",
                            ge=0.0)


def rgb_to_hsv(img):
    """RGB (..., 3) (uint8 0-255 or float in [0, 1]) -> hue (deg in [0, 360)),
    saturation, value (each (...) float32 in [0, 1])."""
    x = jnp.asarray(img)
    x = x.astype(F32) / 255.0 if x.dtype == jnp.uint8 else x.astype(F32)
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    mx = jnp.maximum(jnp.maximum(r, g), b)
    mn = jnp.minimum(jnp.minimum(r, g), b)
    delta = mx - mn
    safe = jnp.where(delta > 0, delta, 1.0)
    h = jnp.where(mx == r, (g - b) / safe,
                  jnp.where(mx == g, 2.0 + (b - r) / safe, 4.0 + (r - g) / safe))
    h = jnp.where(delta > 0, jnp.mod(60.0 * h, 360.0), 0.0)
    s = jnp.where(mx > 0, delta / jnp.where(mx > 0, mx, 1.0), 0.0)
    return h, s, mx


def colour_masks(img, bp: BlobParams):
    """Boolean masks (3, H, W) of ball (red), goal (blue) and other robot (yellow)
    pixels: hue within ``hue_tol`` of the class hue (circular), saturation >= ``sat_min``,
    value >= ``val_min``. Order ``MASK_BALL, MASK_GOAL, MASK_OTHER``."""
    hsv = jnp.stack(rgb_to_hsv(img))
    # stored once: otherwise XLA fuses the HSV conversion (and the image it reads, e.g. a
    # renderer fused into the same program) into the masks' computation, where each mask
    # and colour channel recomputes it per pixel (30 times slower with traced parameters)
    h, s, v = stored_once(hsv)
    coloured = (s >= bp.sat_min) & (v >= bp.val_min)
    out = []
    for hue in (bp.ball_hue, bp.goal_hue, bp.other_hue):
        dh = jnp.abs(jnp.mod(h - hue + 180.0, 360.0) - 180.0)
        out.append(coloured & (dh <= bp.hue_tol))
    masks = jnp.stack(out).astype(F32)
    # stored once (see vbl.vision.fusion.stored_once): otherwise XLA recomputes the masks,
    # and a renderer fused into the same program, inside every reduction that reads them
    return stored_once(masks) > 0.5


@struct.dataclass
class Blob:
    """Statistics of one mask in camera px: pixel count area (px^2), area centroid, and the
    bounding box of the pixels' squares ``[u_lo, u_hi] x [v_lo, v_hi]``."""

    visible: jnp.ndarray   # bool: at least one pixel
    area: jnp.ndarray
    cu: jnp.ndarray
    cv: jnp.ndarray
    u_lo: jnp.ndarray
    u_hi: jnp.ndarray
    v_lo: jnp.ndarray
    v_hi: jnp.ndarray


def _extent(any_px, centres, size):
    """Pixel-square extent [lo, hi] (px) of the pixels ``any_px`` (n,) bool at ``centres``
    (n,) px of size ``size`` px; (0, 0) when there are none."""
    lo = jnp.min(jnp.where(any_px, centres, _BIG)) - 0.5 * size
    hi = jnp.max(jnp.where(any_px, centres, -_BIG)) + 0.5 * size
    ok = jnp.any(any_px)
    return jnp.where(ok, lo, 0.0), jnp.where(ok, hi, 0.0)


def blob_stats(mask, cam: CameraParams) -> Blob:
    """:class:`Blob` of a mask (H, W) bool (row 0 = image top), in the camera's px."""
    h, w = mask.shape
    u, v, (su, sv) = pixel_grid(cam, w, h)
    m = mask.astype(F32)
    cols = jnp.sum(m, axis=0)          # (W,) pixels per column
    rows = jnp.sum(m, axis=1)          # (H,) pixels per row
    n = jnp.sum(cols)
    vis = n > 0
    inv = 1.0 / jnp.where(vis, n, 1.0)
    u_lo, u_hi = _extent(cols > 0, u, su)
    v_lo, v_hi = _extent(rows > 0, v, sv)
    return Blob(visible=vis, area=n * su * sv, cu=jnp.sum(cols * u) * inv,
                cv=jnp.sum(rows * v) * inv, u_lo=u_lo, u_hi=u_hi, v_lo=v_lo, v_hi=v_hi)


def _lateral(cam: CameraParams, u, v):
    """Per-pixel lateral slope ``q`` (H, W) of the pixel rays and the row factor ``g`` (H, 1).

    A world-vertical line (a goal post) images to a line of constant
    ``q = t / (cos tau - s sin tau)`` (``t = u/fu``, ``s = v/fv``, ``tau`` the tilt): q is
    the tangent of the ray's horizontal bearing. At row v, ``u = fu q g`` with
    ``g = cos tau - s sin tau``, so a difference dq is ``fu g dq`` px horizontally."""
    fu, _ = focal_lengths(cam)
    g = _row_factor(cam, v)[:, None]
    return (u / fu)[None, :] / g, g


def _row_factor(cam: CameraParams, v):
    """``g = cos tau - (v / fv) sin tau`` at image rows ``v`` (px): the horizontal px per
    unit of bearing slope ``q`` is ``fu g`` (:func:`_lateral`)."""
    _, fv = focal_lengths(cam)
    tau = jnp.deg2rad(jnp.asarray(cam.tilt_deg, F32))
    return jnp.cos(tau) - (v / fv) * jnp.sin(tau)


def _clip_post(q_post, v_end, cam: CameraParams, su):
    """Point (u, v) px of the post line ``q = q_post`` at row ``v_end``, moved along the
    line onto the image's side border when it lies beyond the centre of the last pixel
    column (pixels ``su`` px wide). The analytic ends are clipped to the image; a post
    leaving the image through a side border at a slant of ``m`` px per px has no pixel
    centres beyond that centre line, so its band stops up to ``su / 2 / m`` px short of
    the border."""
    fu, fv = focal_lengths(cam)
    hw = 0.5 * jnp.asarray(cam.image_width, F32)
    u = fu * q_post * _row_factor(cam, v_end)
    tau = jnp.deg2rad(jnp.asarray(cam.tilt_deg, F32))
    # the row where the line meets u = +-W/2: g(v) = W/2 / (fu |q|)
    g_edge = hw / (fu * jnp.maximum(jnp.abs(q_post), 1e-9))
    sin_t = jnp.where(jnp.abs(jnp.sin(tau)) > 1e-9, jnp.sin(tau), 1e-9)
    v_edge = fv * (jnp.cos(tau) - g_edge) / sin_t
    out = jnp.abs(u) > hw - 0.5 * su
    return jnp.where(out, jnp.sign(u) * hw, u), jnp.where(out, v_edge, v_end)


def goal_ends(mask, cam: CameraParams, bp: BlobParams):
    """The goal's two ends from its mask (H, W) bool: ``bot`` (2, 2) and ``top`` (2, 2)
    points (u, v) px of the [left, right] ends, and ``ok`` (2,) bool.

    An end is the goal's post: the blue pixels within ``post_band`` image pixels
    (horizontally) of the outermost image line of a world-vertical line through a blue
    pixel (the least / greatest bearing ``q``, :func:`_lateral`); its points are that line
    at the band's lowest and highest pixel edges. A band shorter than ``min_post`` image
    pixels in v is the corner of a goal cut by the image border: the end is then the
    border column (u = -W/2 left, +W/2 right) with the v extent of the blue pixels in the
    image's first (last) pixel column, as the analytic end rule (``docs/vision.md``) uses
    the border column when the post is out of the image. Both widths are in image pixels,
    so the rule is the same at every image size (a band 1 px wide would be a quarter of a
    pixel at 128 x 120 and cut the posts short).
    """
    h, w = mask.shape
    u, v, (su, sv) = pixel_grid(cam, w, h)
    fu, _ = focal_lengths(cam)
    q, g = _lateral(cam, u, v)
    hw = 0.5 * jnp.asarray(cam.image_width, F32)
    bots, tops, oks = [], [], []
    for side, col, edge in ((-1.0, 0, -hw), (1.0, w - 1, hw)):
        q_end = side * jnp.max(jnp.where(mask, side * q, -_BIG))
        dist = side * (q_end - q) * fu * g             # >= 0 inside, px
        band = mask & (dist <= bp.post_band * su)       # image pixels -> px
        b_lo, b_hi = _extent(jnp.any(band, axis=1), v, sv)
        c_lo, c_hi = _extent(mask[:, col], v, sv)
        has_col = jnp.any(mask[:, col])
        post = jnp.any(band) & (~has_col | (b_hi - b_lo >= bp.min_post * sv))
        (ub, b_lo), (ut, b_hi) = (_clip_post(q_end, x, cam, su) for x in (b_lo, b_hi))
        ok = post | has_col
        bu = jnp.where(post, ub, edge)
        tu = jnp.where(post, ut, edge)
        bv = jnp.where(post, b_lo, c_lo)
        tv = jnp.where(post, b_hi, c_hi)
        bots.append(jnp.where(ok, jnp.stack([bu, bv]), 0.0))
        tops.append(jnp.where(ok, jnp.stack([tu, tv]), 0.0))
        oks.append(ok)
    return jnp.stack(bots), jnp.stack(tops), jnp.stack(oks)


def track_lost_side(prev_side, u, visible):
    """Lost side memory for pixel features: -1 / +1 = the image half (u < 0 / >= 0) where an
    object was last seen (``u`` px, ``visible`` bool; arrays of equal shape), else
    ``prev_side`` (an image cannot show where a lost object is)."""
    return jnp.where(visible, jnp.where(u < 0, -1.0, 1.0), prev_side).astype(F32)


def _side(hint, n):
    return jnp.ones((n,), F32) if hint is None else jnp.asarray(hint, F32)


def section2_from_pixels(img, cam: CameraParams, bp: BlobParams,
                         lost_side=None) -> jnp.ndarray:
    """Section 2 observation (9,) float32 (layout ``SEC2_*``) from an image (H, W, 3).

    x1 = u extent of the red pixels' squares, x2 its centre; x3 = mean v extent of the
    goal's two ends (:func:`goal_ends`), x4 = mean of their u (an end's u = the mean of its
    two points' u), x5 = ``(h_left - h_right) / x3`` clipped to [-1, 1]. Visible = at least
    one pixel of the colour. ``lost_side`` (2,): the side (-1 / +1) reported for a lost
    ball and goal (an image does not show it; keep it with :func:`track_lost_side`);
    None: +1.
    """
    masks = colour_masks(img, bp)
    ball = blob_stats(masks[MASK_BALL], cam)
    bot, top, ok = goal_ends(masks[MASK_GOAL], cam, bp)
    gvis = jnp.any(masks[MASK_GOAL])
    hgt = jnp.where(ok, top[:, 1] - bot[:, 1], 0.0)
    u_end = 0.5 * (bot[:, 0] + top[:, 0])
    x3 = 0.5 * (hgt[0] + hgt[1])
    x4 = 0.5 * (u_end[0] + u_end[1])
    x5 = jnp.clip((hgt[0] - hgt[1]) / jnp.where(x3 > 0, x3, 1.0), -1.0, 1.0)
    side = _side(lost_side, 2)
    bvis = ball.visible
    out = jnp.stack([jnp.where(bvis, ball.u_hi - ball.u_lo, 0.0),
                     jnp.where(bvis, 0.5 * (ball.u_lo + ball.u_hi), 0.0),
                     jnp.where(gvis, x3, 0.0), jnp.where(gvis, x4, 0.0),
                     jnp.where(gvis & (x3 > 0), x5, 0.0),
                     bvis.astype(F32), gvis.astype(F32),
                     jnp.where(bvis, 0.0, side[0]), jnp.where(gvis, 0.0, side[1])])
    return out.astype(F32)


def section3_from_pixels(img, cam: CameraParams, bp: BlobParams,
                         lost_side=None) -> Section3Obs:
    """Section 3 observation from an image (H, W, 3) (the layout of
    :func:`vbl.vision.section3.section3_features`).

    ball (4) = centre u, v and width, height of the red pixels' bounding box; goal (11) =
    the ends' points left-bottom, left-top, right-top, right-bottom (:func:`goal_ends`),
    the blue pixels' centroid u, v and area (px^2); other (5) = the yellow pixels'
    centroid u, v, bounding width, height and area. ``lost_side`` (3,) as in
    :func:`section2_from_pixels` (ball, goal, other). Lost objects have all-zero features.
    """
    masks = colour_masks(img, bp)
    ball = blob_stats(masks[MASK_BALL], cam)
    goal = blob_stats(masks[MASK_GOAL], cam)
    oth = blob_stats(masks[MASK_OTHER], cam)
    bot, top, _ = goal_ends(masks[MASK_GOAL], cam, bp)
    ball_f = jnp.stack([0.5 * (ball.u_lo + ball.u_hi), 0.5 * (ball.v_lo + ball.v_hi),
                        ball.u_hi - ball.u_lo, ball.v_hi - ball.v_lo])
    gpts = jnp.stack([bot[0], top[0], top[1], bot[1]]).reshape(-1)
    goal_f = jnp.concatenate([gpts, jnp.stack([goal.cu, goal.cv, goal.area])])
    other_f = jnp.stack([oth.cu, oth.cv, oth.u_hi - oth.u_lo, oth.v_hi - oth.v_lo, oth.area])
    vis = jnp.stack([ball.visible, goal.visible, oth.visible])
    side = _side(lost_side, 3)
    return Section3Obs(ball=jnp.where(vis[0], ball_f, 0.0).astype(F32),
                       goal=jnp.where(vis[1], goal_f, 0.0).astype(F32),
                       other=jnp.where(vis[2], other_f, 0.0).astype(F32),
                       visible=vis.astype(F32),
                       lost_side=jnp.where(vis, 0.0, side).astype(F32))


def section3_flat_from_pixels(img, cam: CameraParams, bp: BlobParams,
                              lost_side=None) -> jnp.ndarray:
    """(26,) float32: :func:`section3_from_pixels` flattened as
    :func:`vbl.vision.section3.flatten_section3`."""
    return flatten_section3(section3_from_pixels(img, cam, bp, lost_side))
