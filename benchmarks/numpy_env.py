"""A fair NumPy baseline of one shooting-env step: world physics + Section 2 features.

Benchmark baseline only (not a test oracle): what a straightforward CPU implementation
of the same model would do, one environment and one step at a time, in closed form.

* world: ``tests/reference/world_np.step_world`` (scalar Python/``math``, closed form);
* features: the closed-form Section 2 camera model of ``vbl/vision/section2.py``
  (sphere image ellipse clipped to the image, goal posts near-clipped, projected and
  clipped to the image, ball occluding the posts) written with scalar ``math`` — unlike
  the deliberately brute-force oracle ``tests/reference/camera_np.py``, which samples the
  ball outline numerically (~150 ms per call) and is no fair speed baseline.

:func:`run_episodes` runs whole episodes with random actions (auto-reset from starts drawn
by the caller) and returns the number of steps done; ``benchmarks/env_throughput.py``
checks on a few steps that :func:`section2_np` equals the JAX features.
"""

from __future__ import annotations

import math
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.reference import world_np  # noqa: E402

__all__ = ["section2_np", "run_episodes"]

_TINY = 1e-12
_BIG = 1e9


def _sdiv(a, b):
    if abs(b) < _TINY:
        b = -_TINY if b < 0 else _TINY
    return a / b


def _chord(p, xf, xb, z, k):
    a = k - xb * xb
    w = xf * p + z
    bh = xb * w
    c = w * w - k * (p * p + 1.0)
    disc = bh * bh + a * c
    sq = math.sqrt(max(disc, 0.0))
    return _sdiv(bh - sq, a), _sdiv(bh + sq, a), disc > 0


def _extent(xa, xb, z, r, ha, hb):
    """Extent along a of (sphere image ellipse) ∩ rectangle (normalised coordinates)."""
    k = xa * xa + xb * xb + z * z - r * r
    den = z * z - r * r
    q = xa * xa + z * z - r * r
    root = r * math.sqrt(max(q, 0.0))
    lo, hi, anyv = _BIG, -_BIG, False
    for i, a in enumerate((_sdiv(xa * z - root, den), _sdiv(xa * z + root, den))):
        b = _sdiv(xb * (xa * a + z), q)
        if abs(a) <= ha and abs(b) <= hb:
            anyv = True
            lo, hi = (min(lo, a), hi) if i == 0 else (lo, max(hi, a))
    for row in (-hb, hb):
        rl, rh, ex = _chord(row, xb, xa, z, k)
        rl, rh = max(rl, -ha), min(rh, ha)
        if ex and rl <= rh:
            anyv = True
            lo, hi = min(lo, rl), max(hi, rh)
    for i, col in enumerate((-ha, ha)):
        cl, ch, ex = _chord(col, xa, xb, z, k)
        if ex and max(cl, -hb) <= min(ch, hb):
            anyv = True
            lo, hi = (min(lo, -ha), hi) if i == 0 else (lo, max(hi, ha))
    return (lo, hi, True) if anyv else (0.0, 0.0, False)


def _clip_rect(p0, p1, lo, hi):
    d = (p1[0] - p0[0], p1[1] - p0[1])
    t0, t1, ok = 0.0, 1.0, True
    for pp, qq in ((-d[0], p0[0] - lo[0]), (-d[1], p0[1] - lo[1]),
                   (d[0], hi[0] - p0[0]), (d[1], hi[1] - p0[1])):
        if abs(pp) < _TINY:
            ok = ok and qq >= 0
        elif pp < 0:
            t0 = max(t0, qq / pp)
        else:
            t1 = min(t1, qq / pp)
    ok = ok and t0 <= t1
    return ((p0[0] + t0 * d[0], p0[1] + t0 * d[1]), (p0[0] + t1 * d[0], p0[1] + t1 * d[1]), ok)


def section2_np(pose, ball, radius, corners, cam) -> np.ndarray:
    """Section 2 features (9,) float64 of one camera (layout of ``vbl.vision.section2``)."""
    x, y, th = pose
    tau = math.radians(cam.tilt_deg)
    ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(tau), math.sin(tau)
    c = (x + cam.forward_offset * ct, y + cam.forward_offset * st, cam.height)
    rot = ((st, -ct, 0.0), (-ct * sa, -st * sa, ca), (ct * ca, st * ca, sa))

    def cam_xyz(p):
        d = (p[0] - c[0], p[1] - c[1], p[2] - c[2])
        return tuple(r[0] * d[0] + r[1] * d[1] + r[2] * d[2] for r in rot)

    hw, hh = cam.image_width / 2, cam.image_height / 2
    fu = hw / math.tan(math.radians(cam.hfov_deg) / 2)
    fv = hh / math.tan(math.radians(cam.vfov_deg) / 2)
    zn = cam.near_plane
    # ball
    bw = (ball[0], ball[1], radius)
    bx, by, bz = cam_xyz(bw)
    valid = bz - radius >= zn
    zs = bz if valid else radius + 1.0
    tlo, thi, tany = _extent(bx, by, zs, radius, hw / fu, hh / fv)
    slo, shi, sany = _extent(by, bx, zs, radius, hh / fv, hw / fu)
    bvis = valid and tany and sany and thi > tlo and shi > slo
    u_lo, u_hi = (fu * tlo, fu * thi) if bvis else (0.0, 0.0)
    # goal: posts (left, right), bottom edge, crossbar, near-clipped and projected
    pc = [cam_xyz(p) for p in corners]
    segs = [(pc[0], pc[1]), (pc[3], pc[2]), (pc[0], pc[3]), (pc[1], pc[2])]
    img = []
    for a, b in segs:
        ok = max(a[2], b[2]) >= zn
        t = _sdiv(zn - a[2], b[2] - a[2])
        m = tuple(a[i] + t * (b[i] - a[i]) for i in range(3))
        a2, b2 = (m if a[2] < zn else a), (m if b[2] < zn else b)
        proj = [(fu * p[0] / max(p[2], zn), fv * p[1] / max(p[2], zn)) for p in (a2, b2)]
        img.append((proj[0], proj[1], ok))
    bots, tops, oks = [], [], []
    for side, col in ((0, -hw), (1, hw)):
        qa, qb, qok = _clip_rect(img[side][0], img[side][1], (-hw, -hh), (hw, hh))
        if img[side][2] and qok:
            lo_pt, up_pt = (qa, qb) if qa[1] <= qb[1] else (qb, qa)
            bots.append(lo_pt)
            tops.append(up_pt)
            oks.append(True)
            continue
        vs = []
        for a, b, ok in img[2:]:
            du = b[0] - a[0]
            if ok and min(a[0], b[0]) <= col <= max(a[0], b[0]) and abs(du) > 1e-6:
                vs.append(a[1] + _sdiv(col - a[0], du) * (b[1] - a[1]))
        if len(vs) == 2:
            lo_v = min(max(min(vs), -hh), hh)
            hi_v = min(max(max(vs), -hh), hh)
            if hi_v > lo_v:
                bots.append((col, lo_v))
                tops.append((col, hi_v))
                oks.append(True)
                continue
        bots.append((0.0, 0.0))
        tops.append((0.0, 0.0))
        oks.append(False)
    gvis = any(oks[i] and tops[i][1] > bots[i][1] for i in range(2))
    # the ball hides the post behind it (ball on the camera's side of the goal plane)
    e1 = [corners[1][i] - corners[0][i] for i in range(3)]
    e2 = [corners[3][i] - corners[0][i] for i in range(3)]
    n = np.cross(e1, e2)
    side_b = float(np.dot(np.subtract(bw, corners[0]), n))
    side_c = float(np.dot(np.subtract(c, corners[0]), n))
    occ = side_b * side_c > 0 and valid
    k = bx * bx + by * by + zs * zs - radius * radius
    h, u_end = [], []
    for i in range(2):
        u = 0.5 * (bots[i][0] + tops[i][0])
        lo, hi = bots[i][1], tops[i][1]
        clo, chi, ex = _chord(u / fu, bx, by, zs, k)
        clo, chi = fv * clo, fv * chi
        if occ and ex and valid:
            nlo = min(chi, hi) if (clo <= lo < chi) else lo
            nhi = max(clo, lo) if (chi >= hi > clo) else hi
            lo, hi = nlo, max(nhi, nlo)
        h.append(hi - lo)
        u_end.append(u)
    x3 = 0.5 * (h[0] + h[1])
    x5 = min(max(_sdiv(h[0] - h[1], x3), -1.0), 1.0)
    gcx = sum(p[0] for p in pc) / 4
    return np.array([
        u_hi - u_lo if bvis else 0.0, 0.5 * (u_lo + u_hi) if bvis else 0.0,
        x3 if gvis else 0.0, 0.5 * (u_end[0] + u_end[1]) if gvis else 0.0,
        x5 if gvis and x3 > 0 else 0.0, float(bvis), float(gvis),
        0.0 if bvis else (-1.0 if bx < 0 else 1.0), 0.0 if gvis else (-1.0 if gcx < 0 else 1.0)])


def run_episodes(starts, params, n_actions: int, seconds: float, seed: int = 0) -> dict:
    """Run episodes one by one with uniform random actions for about ``seconds``.

    starts: list of start dicts (``robots``, ``ball``) drawn by the caller (the JAX env's
    start distribution); each env step = ``world_np.step_world`` + :func:`section2_np`.
    Returns dict(steps, episodes, seconds, steps_per_s).
    """
    rng = np.random.default_rng(seed)
    wp = params.world
    corners = world_np.goal_corners_np(wp).tolist()
    rb = wp.ball.radius
    n_steps = n_ep = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        st = starts[n_ep % len(starts)]
        s = dict(robots=[list(st["robots"])], ball=list(st["ball"]), vel=[0.0, 0.0],
                 scored=False, out=False)
        for _ in range(params.max_steps):
            s, ev = world_np.step_world(s, [int(rng.integers(0, n_actions))], wp)
            section2_np(s["robots"][0], s["ball"], rb, corners, params.camera)
            n_steps += 1
            if ev["goal"] or ev["ball_out"]:
                break
        n_ep += 1
    dt = time.perf_counter() - t0
    return dict(steps=n_steps, episodes=n_ep, seconds=dt, steps_per_s=n_steps / dt)
