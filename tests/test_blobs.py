"""Colour-blob features from rendered pixels (vbl.vision.blobs) against the analytic camera
(vbl.vision.section2, vbl.vision.section3) on random scenes of every kind of
vbl.vision.scenes: close, far, cut by the left / right / bottom border, the goal cut by the
image border, the ball behind the other robot, objects out of view. The bounds and why they
hold: docs/render.md ("Accuracy against the analytic features").

CI runs ``SCENES_FAST`` scenes per kind at 512 x 480; ``-m slow`` runs ``SCENES_SLOW`` per
kind (8 kinds: 1,024 scenes).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.vision.blobs import (
    MASK_OTHER,
    BlobParams,
    blob_stats,
    colour_masks,
    rgb_to_hsv,
    section2_from_pixels,
    section3_flat_from_pixels,
    track_lost_side,
)
from vbl.vision.camera import CameraParams, camera_frame, to_camera
from vbl.vision.projection import ball_image
from vbl.vision.render import RenderParams, render_camera, to_uint8
from vbl.vision.scenes import OTHER_HEIGHT, SCENE_KINDS, random_scenes
from vbl.vision.section2 import SEC2_DIM, section2_features
from vbl.vision.section3 import SEC3_DIM, flatten_section3, section3_features
from vbl.world import WorldParams, goal_corners

SCENES_FAST = 16
SCENES_SLOW = 128
CHUNK = 16            # scenes per compiled call (bounds the memory of 512 x 480 images)
WORLD = WorldParams()
CAM = CameraParams()
BP = BlobParams()
HW, HH = 256.0, 240.0

#: Bounds (px, or px^2 for areas; x5 is dimensionless) at 512 x 480, per feature.
#: Why: docs/render.md ("Accuracy against the analytic features").
BOUND = dict(
    ball_width=1.5,      # both ends of an extent quantised to a pixel edge (<= 0.5 + a sliver)
    ball_centre=1.0,     # half the width bound
    goal_end_v=3.0,      # an end point's v: pixel edge (0.5) + the corner wedge (<= 2.5)
    goal_end_u=2.0,      # an end's u: the post line through the outermost pixel centre (< 1)
    goal_height=3.0,     # two end points
    centroid=2.0,        # area centroid of a blob of >= MIN_AREA px^2
)
#: Smallest analytic area (px^2) whose centroid is compared (a sliver's centroid moves
#: with every pixel it gains or loses).
MIN_AREA = 1000.0
#: An end whose visible post piece is shorter than this (px) is not compared: the pixels
#: cannot tell a short post piece from the corner of a goal cut by the image border.
MIN_POST = 12.0
#: A blob's extent along one axis is compared when it is at least this wide (px) across
#: the other and does not touch a border across it: at a border the extent is read on the
#: pixel centre line half a pixel inside, where an outline of slope m spans m / 2 px less
#: (a 2 px sliver of a round ball, a box edge running steeply into the border).
SLIVER = 4.0
#: Gap (px) between an occluder's box and a region for the region to count as unoccluded.
CLEAR = 3.0


def area_bound(w, h):
    """|pixel count area - exact area| bound (px^2) of a convex blob of bounding box w x h
    px: half its perimeter (the pixels its boundary crosses, counted in or out) plus 2."""
    return 0.5 * 2 * (w + h) + 2.0


@functools.cache
def _program(width, height):
    rp = RenderParams(width=width, height=height)
    gc = goal_corners(WORLD)
    size = jnp.asarray([2 * WORLD.robot.radius, 2 * WORLD.robot.radius, OTHER_HEIGHT])
    r = WORLD.ball.radius

    def one(pose, ball, other):
        img2 = to_uint8(render_camera(pose, ball, r, gc, WORLD.field, CAM, rp))
        img3 = to_uint8(render_camera(pose, ball, r, gc, WORLD.field, CAM, rp, other, size))
        a2 = section2_features(pose, ball, r, gc, CAM)
        a3 = flatten_section3(section3_features(pose, ball, r, gc, other, size, CAM))
        bw = jnp.stack([ball[0], ball[1], jnp.asarray(r, jnp.float32)])
        bi = ball_image(to_camera(bw, camera_frame(pose, CAM)), r, CAM)
        box = jnp.stack([bi.u_lo, bi.u_hi, bi.v_lo, bi.v_hi])
        yb = blob_stats(colour_masks(img3, BP)[MASK_OTHER], CAM)
        ybox = jnp.where(yb.visible, jnp.stack([yb.u_lo, yb.u_hi, yb.v_lo, yb.v_hi]), 1e6)
        return (section2_from_pixels(img2, CAM, BP, a2[7:9]), a2,
                section3_flat_from_pixels(img3, CAM, BP, a3[23:26]), a3, box, ybox)

    return jax.jit(jax.vmap(one))


def run_scenes(kind: str, n: int, seed: int = 0, width: int = 512, height: int = 480):
    """Pixel and analytic features of ``n`` scenes of ``kind``: dict of NumPy arrays p2, a2
    (n, 9), p3, a3 (n, 26), ball_box (n, 4) (the unoccluded analytic ball box u_lo, u_hi,
    v_lo, v_hi) and other_box (n, 4) (the box of the other robot's yellow pixel squares,
    1e6 when none: the occluder box; the analytic Section 3 vector gives the robot's area
    centroid, not its box's centre)."""
    s = random_scenes(n, kind, seed=seed, world=WORLD)
    prog = _program(width, height)
    outs = []
    for i in range(0, n, CHUNK):
        sl = slice(i, i + CHUNK)
        outs.append([np.asarray(x) for x in prog(s["pose"][sl], s["ball"][sl],
                                                  s["other"][sl])])
    keys = ("p2", "a2", "p3", "a3", "ball_box", "other_box")
    return {k: np.concatenate([o[j] for o in outs]) for j, k in enumerate(keys)}


# ----------------------------------------------------------------------------- comparisons

def _boxes_apart(a_lo, a_hi, b_lo, b_hi, gap):
    """(n,) True where box a and box b (each (n, 2) lo / hi) are more than ``gap`` apart."""
    return np.any((a_hi + gap < b_lo) | (b_hi + gap < a_lo), axis=1)


def _other_box(box):
    return box[:, [0, 2]], box[:, [1, 3]]


def _ball_box(box):
    lo, hi = box[:, [0, 2]], box[:, [1, 3]]
    empty = (hi[:, 0] <= lo[:, 0])
    return np.where(empty[:, None], -1e6, lo), np.where(empty[:, None], -1e6, hi)


def _touches(box, axis):
    """(n,) True where a (centre u, v, width, height) box (n, 4) touches the image's side
    borders (axis "u") or its top / bottom borders (axis "v")."""
    k, half = (0, HW) if axis == "u" else (1, HH)
    return np.abs(box[:, k]) + 0.5 * box[:, 2 + k] >= half - 1e-3


def _end_masks(a3, clear_of=()):
    """Per end (n, 2) bool: the analytic end is a post piece >= MIN_POST px or a border
    column, and clear of every occluder box in ``clear_of`` [(lo, hi)]."""
    pts = a3[:, 4:12].reshape(-1, 4, 2)          # LB, LT, RT, RB
    ends = [(pts[:, 0], pts[:, 1]), (pts[:, 3], pts[:, 2])]
    out = []
    for bot, top in ends:
        height = top[:, 1] - bot[:, 1]
        border = (np.abs(bot[:, 0]) >= HW - 1e-3) & (np.abs(top[:, 0]) >= HW - 1e-3)
        ok = (a3[:, 21] > 0) & (height > 0) & (border | (height >= MIN_POST))
        lo, hi = np.minimum(bot, top), np.maximum(bot, top)
        for olo, ohi in clear_of:
            ok &= _boxes_apart(lo, hi, olo, ohi, CLEAR)
        out.append(ok)
    return np.stack(out, axis=1)


def errors(r) -> dict[str, np.ndarray]:
    """Absolute errors of the features that must agree, each over the scenes where it is
    defined alike (see docs/render.md): name -> (k,) errors."""
    p2, a2, p3, a3 = r["p2"], r["a2"], r["p3"], r["a3"]
    blo, bhi = _ball_box(r["ball_box"])
    olo, ohi = _other_box(r["other_box"])
    e = {}
    # Section 2: no other robot; the goal never hides the ball
    both = (p2[:, 5] > 0) & (a2[:, 5] > 0)
    e["s2 x1 ball width"] = np.abs(p2[both, 0] - a2[both, 0])
    e["s2 x2 ball centre"] = np.abs(p2[both, 1] - a2[both, 1])
    ends2 = _end_masks(a3, [(blo, bhi)])
    g2 = ends2.all(axis=1) & (p2[:, 6] > 0)
    e["s2 x3 goal size"] = np.abs(p2[g2, 2] - a2[g2, 2])
    e["s2 x4 goal position"] = np.abs(p2[g2, 3] - a2[g2, 3])
    big = g2 & (a2[:, 2] >= 20.0)
    e["s2 x5 goal orientation / bound"] = (np.abs(p2[big, 4] - a2[big, 4])
                                           / (3 * BOUND["goal_height"] / a2[big, 2]))
    # Section 3 ball: not behind the other robot's box
    ball_clear = _boxes_apart(blo, bhi, olo, ohi, CLEAR)
    b3 = ball_clear & (p3[:, 20] > 0) & (a3[:, 20] > 0)
    e["s3 ball centre u"] = np.abs(p3[b3, 0] - a3[b3, 0])
    e["s3 ball centre v"] = np.abs(p3[b3, 1] - a3[b3, 1])
    # a sliver's extent along the border is sampled on the pixel centre line, inside it
    wide = b3 & (a3[:, 3] >= SLIVER) & ~_touches(a3[:, 0:4], "v")
    tall = b3 & (a3[:, 2] >= SLIVER) & ~_touches(a3[:, 0:4], "u")
    e["s3 ball width"] = np.abs(p3[wide, 2] - a3[wide, 2])
    e["s3 ball height"] = np.abs(p3[tall, 3] - a3[tall, 3])
    # Section 3 goal ends: not occluded by the ball or the other robot
    ends3 = _end_masks(a3, [(blo, bhi), (olo, ohi)])
    pts_p, pts_a = p3[:, 4:12].reshape(-1, 4, 2), a3[:, 4:12].reshape(-1, 4, 2)
    for k, name in enumerate(("LB", "LT", "RT", "RB")):
        ok = ends3[:, 0 if k < 2 else 1] & (p3[:, 21] > 0)
        e[f"s3 goal {name} u"] = np.abs(pts_p[ok, k, 0] - pts_a[ok, k, 0])
        e[f"s3 goal {name} v"] = np.abs(pts_p[ok, k, 1] - pts_a[ok, k, 1])
    # Section 3 goal area and centroid: no occluder box near the goal's ends
    g_lo, g_hi = pts_a.min(axis=1), pts_a.max(axis=1)
    g_clear = ((a3[:, 21] > 0) & (p3[:, 21] > 0) & _boxes_apart(g_lo, g_hi, blo, bhi, CLEAR)
               & _boxes_apart(g_lo, g_hi, olo, ohi, CLEAR))
    gw, gh = (g_hi - g_lo)[:, 0], (g_hi - g_lo)[:, 1]
    e["s3 goal area / bound"] = (np.abs(p3[g_clear, 14] - a3[g_clear, 14])
                                 / area_bound(gw[g_clear], gh[g_clear]))
    gc = g_clear & (a3[:, 14] >= MIN_AREA)
    e["s3 goal centroid"] = np.max(np.abs(p3[gc, 12:14] - a3[gc, 12:14]), axis=1)
    # Section 3 other robot: not behind the ball's box (the goal never hides it)
    o3 = (_boxes_apart(olo, ohi, blo, bhi, CLEAR) & (p3[:, 22] > 0) & (a3[:, 22] > 0))
    wide = o3 & (a3[:, 18] >= SLIVER) & ~_touches(a3[:, 15:19], "v")
    tall = o3 & (a3[:, 17] >= SLIVER) & ~_touches(a3[:, 15:19], "u")
    e["s3 other width"] = np.abs(p3[wide, 17] - a3[wide, 17])
    e["s3 other height"] = np.abs(p3[tall, 18] - a3[tall, 18])
    e["s3 other area / bound"] = (np.abs(p3[o3, 19] - a3[o3, 19])
                                  / area_bound(a3[o3, 17], a3[o3, 18]))
    oc = o3 & (a3[:, 19] >= MIN_AREA)
    e["s3 other centroid"] = np.max(np.abs(p3[oc, 15:17] - a3[oc, 15:17]), axis=1)
    return e


#: Bound of each error of :func:`errors` (ratios to a bound: 1.0).
ERROR_BOUND = {
    "s2 x1 ball width": BOUND["ball_width"], "s2 x2 ball centre": BOUND["ball_centre"],
    "s2 x3 goal size": BOUND["goal_height"], "s2 x4 goal position": BOUND["goal_end_u"],
    "s2 x5 goal orientation / bound": 1.0,
    "s3 ball centre u": BOUND["ball_centre"], "s3 ball centre v": BOUND["ball_centre"],
    "s3 ball width": BOUND["ball_width"], "s3 ball height": BOUND["ball_width"],
    **{f"s3 goal {c} {x}": BOUND[f"goal_end_{x}"] for c in ("LB", "LT", "RT", "RB")
       for x in ("u", "v")},
    "s3 goal area / bound": 1.0, "s3 goal centroid": BOUND["centroid"],
    "s3 other width": BOUND["ball_width"], "s3 other height": BOUND["ball_width"],
    "s3 other area / bound": 1.0, "s3 other centroid": BOUND["centroid"],
}


def flags_disagree(r) -> dict[str, np.ndarray]:
    """Scenes whose visibility flags break the rules of docs/render.md: a coloured pixel
    means the analytic object is visible (unoccluded objects); an analytic object at
    least 2 px wide and high has a pixel; lost sides are the caller's hint."""
    p2, a2, p3, a3 = r["p2"], r["a2"], r["p3"], r["a3"]
    blo, bhi = _ball_box(r["ball_box"])
    olo, ohi = _other_box(r["other_box"])
    bw, bh = (bhi - blo)[:, 0], (bhi - blo)[:, 1]
    out = {
        "s2 ball pixel without analytic ball": (p2[:, 5] > 0) & (a2[:, 5] == 0),
        "s2 analytic ball >= 2 px without pixel": ((a2[:, 5] > 0) & (bw >= 2) & (bh >= 2)
                                                    & (p2[:, 5] == 0)),
        "s2 goal pixel without analytic goal": (p2[:, 6] > 0) & (a2[:, 6] == 0),
        "s2 lost sides": (p2[:, 7:9] != a2[:, 7:9]) & (p2[:, 5:7] == a2[:, 5:7]),
        "s3 lost sides": (p3[:, 23:26] != a3[:, 23:26]) & (p3[:, 20:23] == a3[:, 20:23]),
    }
    clear = _boxes_apart(olo, ohi, blo, bhi, CLEAR) | (a3[:, 22] == 0)
    out["s3 other pixel without analytic other (clear of the ball)"] = (
        clear & (p3[:, 22] > 0) & (a3[:, 22] == 0))
    big = (a3[:, 22] > 0) & (a3[:, 17] >= 2) & (a3[:, 18] >= 2) & (a3[:, 19] >= 4)
    out["s3 analytic other >= 2 px without pixel (clear)"] = clear & big & (p3[:, 22] == 0)
    return {k: np.asarray(v).reshape(len(p2), -1).any(axis=1) for k, v in out.items()}


def report(results) -> str:
    """Max error per feature over all kinds (for the docs and the slow test's output)."""
    lines = []
    for name, bound in ERROR_BOUND.items():
        errs = np.concatenate([errors(r)[name] for r in results.values()])
        worst = float(errs.max()) if errs.size else float("nan")
        lines.append(f"{name}: max {worst:.3f} (bound {bound}) over {errs.size} scenes")
    return "\n".join(lines)


def _check(results):
    bad = []
    for name, bound in ERROR_BOUND.items():
        for kind, r in results.items():
            err = errors(r)[name]
            if err.size and err.max() > bound:
                bad.append(f"{kind}: {name} max {err.max():.3f} > {bound}")
    for kind, r in results.items():
        for name, mask in flags_disagree(r).items():
            if mask.any():
                bad.append(f"{kind}: {name} in {int(mask.sum())} scenes")
    assert not bad, "\n".join(bad)


@pytest.fixture(scope="module")
def fast_results():
    return {kind: run_scenes(kind, SCENES_FAST, seed=11) for kind in SCENE_KINDS}


def test_output_layout_matches_the_analytic_functions(fast_results):
    r = fast_results["close"]
    assert r["p2"].shape[1] == r["a2"].shape[1] == SEC2_DIM
    assert r["p3"].shape[1] == r["a3"].shape[1] == SEC3_DIM
    assert r["p2"].dtype == r["p3"].dtype == np.float32


def test_blobs_agree_with_the_analytic_camera(fast_results):
    _check(fast_results)


def test_every_feature_is_compared(fast_results):
    """Each compared feature has scenes where it is defined alike (the scene kinds
    exercise it)."""
    empty = [name for name in ERROR_BOUND
             if sum(errors(r)[name].size for r in fast_results.values()) < 5]
    assert not empty, f"features compared on fewer than 5 scenes: {empty}"


def test_scene_kinds_reach_their_cases(fast_results):
    """Partial at every border, occluded and lost scenes really occur."""
    a = {k: r["a3"] for k, r in fast_results.items()}
    box = {k: r["ball_box"] for k, r in fast_results.items()}
    assert np.any(np.isclose(box["left"][:, 0], -HW))
    assert np.any(np.isclose(box["right"][:, 1], HW))
    assert np.any(np.isclose(box["bottom"][:, 2], -HH))
    pts = a["goal_border"][:, 4:12].reshape(-1, 4, 2)
    assert np.any(np.isclose(pts[..., 0], -HW)) and np.any(np.isclose(pts[..., 0], HW))
    assert np.any(np.isclose(pts[..., 1], HH))
    lost = fast_results["lost"]
    assert np.mean(lost["a3"][:, 20] == 0) > 0.5 and np.all(lost["p3"][:, 20] == lost["a3"][:, 20])
    occ = fast_results["occluded"]
    hidden = occ["p3"][:, 2] * occ["p3"][:, 3] < (occ["ball_box"][:, 1] - occ["ball_box"][:, 0]) \
        * (occ["ball_box"][:, 3] - occ["ball_box"][:, 2]) - 1.0
    assert hidden.mean() > 0.3


def test_occluded_regions_keep_at_least_the_analytic_area(fast_results):
    """The analytic camera hides what lies behind an occluder's bounding box; the pixels
    hide only what lies behind its silhouette: the pixel area is at least the analytic
    area (up to the area bound)."""
    bad = []
    for kind, r in fast_results.items():
        p3, a3 = r["p3"], r["a3"]
        for name, ia, vis in (("goal", 14, 21), ("other", 19, 22)):
            both = (p3[:, vis] > 0) & (a3[:, vis] > 0)
            w = np.where(name == "other", a3[:, 17], 512.0)
            h = np.where(name == "other", a3[:, 18], 480.0)
            short = a3[:, ia] - p3[:, ia] - area_bound(w, h)
            if np.any(both & (short > 0)):
                bad.append(f"{kind} {name}: pixel area short by {short[both].max():.1f} px^2")
    assert not bad, bad


def test_smaller_images_scale_the_bounds():
    """At 128 x 120 (pixels 4 camera px wide) the features are in camera px and agree
    within 4x the bounds (Section 2: ball and goal)."""
    rp = RenderParams(width=128, height=120)
    gc, r = goal_corners(WORLD), WORLD.ball.radius

    def one(pose, ball):
        img = to_uint8(render_camera(pose, ball, r, gc, WORLD.field, CAM, rp))
        return section2_from_pixels(img, CAM, BP), section2_features(pose, ball, r, gc, CAM)

    s = random_scenes(32, "close", seed=5, world=WORLD)
    p2, a2 = (np.asarray(x) for x in jax.jit(jax.vmap(one))(s["pose"], s["ball"]))
    both = (p2[:, 5] > 0) & (a2[:, 5] > 0)
    assert both.sum() > 16
    assert np.max(np.abs(p2[both, :2] - a2[both, :2])) <= 4 * BOUND["ball_width"]
    goal = (p2[:, 6] > 0) & (a2[:, 6] > 0) & (a2[:, 2] > 40)
    assert goal.sum() > 8
    assert np.median(np.abs(p2[goal, 2:4] - a2[goal, 2:4])) <= 4 * BOUND["goal_end_u"]


@pytest.mark.slow
def test_blobs_agree_on_1024_scenes():
    results = {kind: run_scenes(kind, SCENES_SLOW, seed=23) for kind in SCENE_KINDS}
    print("\n" + report(results))
    _check(results)


def test_hsv_and_masks():
    rgb = np.array([[[230, 38, 25], [25, 64, 217], [242, 217, 25], [33, 115, 46],
                     [217, 217, 209], [0, 0, 0]]], np.uint8)
    h, s, v = (np.asarray(x) for x in rgb_to_hsv(jnp.asarray(rgb)))
    np.testing.assert_allclose(h[0, :4], [3.8, 228.0, 53.0, 130.0], atol=1.0)
    assert np.all(s[0, 4:] < 0.1) and v[0, 5] == 0
    m = np.asarray(colour_masks(jnp.asarray(rgb), BP))
    np.testing.assert_array_equal(m[:, 0], [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0],
                                            [0, 0, 1, 0, 0, 0]])


def test_track_lost_side():
    prev = jnp.asarray([1.0, -1.0, 1.0])
    u = jnp.asarray([-5.0, 3.0, 0.0])
    vis = jnp.asarray([True, True, False])
    np.testing.assert_array_equal(np.asarray(track_lost_side(prev, u, vis)), [-1, 1, 1])


def test_hue_distance_wraps_around_zero():
    """The hue distance is circular: a red of hue 355.6 deg is within 20 deg of a class
    hue of 4 deg, and a red of 4.4 deg within 20 deg of 350 deg (hues from colorsys)."""
    import colorsys

    rgb = np.array([[[230, 25, 40], [230, 40, 25], [240, 20, 80], [235, 60, 20]]], np.uint8)
    hue = np.array([colorsys.rgb_to_hsv(*(c / 255.0))[0] * 360.0 for c in rgb[0]])
    h, _, _ = (np.asarray(x) for x in rgb_to_hsv(jnp.asarray(rgb)))
    np.testing.assert_allclose(h[0], hue, atol=1e-3)
    for ball_hue in (4.0, 350.0):
        m = np.asarray(colour_masks(jnp.asarray(rgb), BlobParams(ball_hue=ball_hue)))[0, 0]
        dist = np.abs((hue - ball_hue + 180.0) % 360.0 - 180.0)
        np.testing.assert_array_equal(m, dist <= BP.hue_tol, err_msg=f"ball_hue {ball_hue}")
    assert m.tolist() == [True, True, True, False]     # 355.6, 4.4, 343.6 deg within 20


@pytest.mark.parametrize("width,height", [(128, 120), (64, 120)])
def test_blob_stats_are_in_camera_px_at_any_image_size(width, height):
    """A rectangle of pixels, rows 10-19 and columns 30-49 of a W' x H' image: its box,
    centroid and area in the 512 x 480 camera's px (pixels 512 / W' px wide, 480 / H'
    px high), written out from the pixel edges ``u = j 512 / W' - 256``, ``v = 240 -
    i 480 / H'``."""
    mask = np.zeros((height, width), bool)
    mask[10:20, 30:50] = True
    su, sv = 512.0 / width, 480.0 / height
    b = jax.jit(blob_stats)(jnp.asarray(mask), CAM)
    want = dict(u_lo=30 * su - 256, u_hi=50 * su - 256, v_lo=240 - 20 * sv,
                v_hi=240 - 10 * sv, area=200 * su * sv)
    want.update(cu=0.5 * (want["u_lo"] + want["u_hi"]), cv=0.5 * (want["v_lo"] + want["v_hi"]))
    got = {k: float(getattr(b, k)) for k in want}
    np.testing.assert_allclose([got[k] for k in want], list(want.values()), rtol=1e-6,
                               atol=1e-3, err_msg=str(got))


def test_dark_pixels_are_no_colour():
    """A fully saturated red pixel darker than ``val_min`` (a shadow, the image's black
    border) is in no mask; the same hue at full brightness is the ball's. The values are
    the HSV definition's (V = max channel / 255)."""
    bp = BlobParams()
    below = int(255 * bp.val_min) - 2   # V just under val_min
    above = int(255 * bp.val_min) + 2
    img = np.zeros((1, 3, 3), np.uint8)
    img[0, 0] = (below, 0, 0)
    img[0, 1] = (above, 0, 0)
    img[0, 2] = (255, 0, 0)
    masks = np.asarray(colour_masks(jnp.asarray(img), bp))
    assert masks.shape == (3, 1, 3)
    assert not masks[:, 0, 0].any()                  # dark: no colour at all
    assert masks[0, 0, 1] and masks[0, 0, 2]         # bright enough: the ball's red
    assert not masks[1:, 0, 1:].any()


def test_blob_area_centroid_and_extent_count_oblong_pixels_in_camera_px():
    """On a 64 x 30 image each pixel is 8 x 16 camera px: two pixels of row 2, columns 10
    and 11, have area 2 x 128 px^2, centroid u = -256 + 8 x 11 = -168 and v = 240 - 16 x
    2.5 = 200, and box [-176, -160] x [192, 208]."""
    from vbl.vision.blobs import blob_stats

    mask = jnp.zeros((30, 64), bool).at[2, 10:12].set(True)
    b = blob_stats(mask, CameraParams())
    got = [float(x) for x in (b.area, b.cu, b.cv, b.u_lo, b.u_hi, b.v_lo, b.v_hi)]
    assert bool(b.visible) and got == [256.0, -168.0, 200.0, -176.0, -160.0, 192.0, 208.0]
    empty = blob_stats(jnp.zeros((30, 64), bool), CameraParams())
    assert not bool(empty.visible) and float(empty.area) == 0.0


def test_a_goal_corner_cut_by_the_right_border_ends_at_the_last_columns_blue_pixels():
    """Blue pixels against the right border of a 64 x 60 image (8 px pixels): the last
    column holds rows 10-14, as do columns 50-59. The band along the outermost post
    line is the last column's 5 pixels (< min_post 8): no post, so the right end is
    the border u = +256 with the v extent of the last column's pixels: rows 10-14 span v
    from 240 - 8 x 15 = 120 to 240 - 8 x 10 = 160 (docs/render.md, the goal-end rule)."""
    from vbl.vision.blobs import goal_ends

    mask = np.zeros((60, 64), bool)
    mask[10:15, 63] = True
    mask[10:15, 50:60] = True
    bot, top, ok = (np.asarray(x) for x in goal_ends(jnp.asarray(mask), CAM, BP))
    assert ok.tolist() == [True, True]
    np.testing.assert_allclose(bot[1], [256.0, 120.0], atol=1e-3)
    np.testing.assert_allclose(top[1], [256.0, 160.0], atol=1e-3)
