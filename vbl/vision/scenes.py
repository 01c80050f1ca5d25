"""Random camera scenes for checking and timing the pixel pipeline (NumPy, float32 out).

A scene is a camera robot's pose, the ball and the other robot, placed on the default
field without overlaps, in one of the kinds of :data:`SCENE_KINDS` (``docs/render.md``):
objects close to or far from the camera, cut by each image border, the ball behind the
other robot, or out of view. Used by ``tests/test_blobs.py``, ``tests/test_render.py`` and
``benchmarks/render_throughput.py``.
"""

from __future__ import annotations

import numpy as np

from vbl.world.params import WorldParams

__all__ = ["SCENE_KINDS", "random_scenes", "OTHER_HEIGHT"]

#: Scene kinds: where the ball (and the other robot) sit relative to the camera.
SCENE_KINDS = ("close", "far", "left", "right", "bottom", "goal_border", "occluded", "lost")
#: Height of the other robot's box, m (the two-robot task's ``robot_height`` default).
OTHER_HEIGHT = 0.3
#: Half the horizontal field of view used to aim at the image's side borders, deg.
_HALF_FOV = 33.5
#: Extra clearance between bodies beyond touching, m.
_GAP = 0.02


def _polar(origin, heading, bearing_deg, dist):
    ang = heading + np.deg2rad(bearing_deg)
    return origin + dist[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)


def _kind_params(kind, n, rng):
    """(ball bearing deg, ball distance m, other bearing deg, other distance m) (n,) each."""
    u = rng.uniform
    other_b, other_d = u(-60, 60, n), u(0.5, 4.0, n)
    if kind == "close":
        return u(-30, 30, n), u(0.33, 1.0, n), other_b, other_d
    if kind == "far":
        return u(-30, 30, n), u(2.5, 7.0, n), u(-30, 30, n), u(2.5, 7.0, n)
    if kind in ("left", "right"):
        sgn = 1.0 if kind == "left" else -1.0
        b = sgn * u(_HALF_FOV - 12, _HALF_FOV + 12, n)
        return b, u(0.4, 4.0, n), -sgn * u(_HALF_FOV - 12, _HALF_FOV + 12, n), u(0.6, 4.0, n)
    if kind == "bottom":
        return u(-35, 35, n), u(0.31 + _GAP, 0.5, n), other_b, u(0.45, 1.0, n)
    if kind == "goal_border":
        return u(-40, 40, n), u(0.35, 3.0, n), other_b, other_d
    if kind == "occluded":
        b, d = u(-25, 25, n), u(0.6, 2.5, n)
        return b + u(-8, 8, n), d + u(0.45, 2.5, n), b, d
    if kind == "lost":
        side = np.where(rng.uniform(size=n) < 0.5, -1.0, 1.0)
        return side * u(45, 180, n), u(0.4, 4.0, n), other_b, other_d
    raise ValueError(f"unknown scene kind {kind!r}; choose from {SCENE_KINDS}")


def random_scenes(n: int, kind: str, seed: int = 0, world: WorldParams | None = None):
    """``n`` scenes of ``kind`` (one of :data:`SCENE_KINDS`): dict of float32 arrays
    ``pose`` (n, 3), ``ball`` (n, 2), ``other`` (n, 3) (poses ``(x, y, theta)`` m, m, rad).

    The camera robot stands on the field facing the goal within +-60 deg (``goal_border``:
    near the goal, facing it within +-25-50 deg so the goal is cut by the image border);
    the ball and the other robot are placed at a bearing and distance from it that the
    kind sets. Bodies do not overlap (robot discs, the other robot's box and the ball keep
    a 2 cm gap) and stay on the field (the other robot's whole box: the analytic camera
    has no walls to hide a corner poking through one); scenes that break this are
    redrawn.
    """
    world = WorldParams() if world is None else world
    rng = np.random.default_rng(seed)
    L, W = world.field.length, world.field.width
    rr, rb = world.robot.radius, world.ball.radius
    box_half_diag = rr * np.sqrt(2.0)
    out = {k: np.zeros((0, 3 if k != "ball" else 2)) for k in ("pose", "ball", "other")}
    while out["pose"].shape[0] < n:
        m = 2 * n
        if kind == "goal_border":
            gx = rng.uniform(0.5, 2.0, m)
            xy = np.stack([L / 2 - gx, rng.uniform(-1.5, 1.5, m)], axis=1)
            off = np.where(rng.uniform(size=m) < 0.5, -1, 1) * rng.uniform(20, 50, m)
        else:
            xy = np.stack([rng.uniform(-L / 2 + 0.5, L / 2 - 0.8, m),
                           rng.uniform(-W / 2 + 0.4, W / 2 - 0.4, m)], axis=1)
            off = rng.uniform(-60, 60, m)
        to_goal = np.arctan2(-xy[:, 1], L / 2 - xy[:, 0])
        th = to_goal + np.deg2rad(off)
        bb, bd, ob, od = _kind_params(kind, m, rng)
        ball = _polar(xy, th, bb, bd)
        other_xy = _polar(xy, th, ob, od)
        oth = rng.uniform(-np.pi, np.pi, m)
        ok = (np.abs(ball[:, 0]) <= L / 2 - rb) & (np.abs(ball[:, 1]) <= W / 2 - rb)
        ok &= ((np.abs(other_xy[:, 0]) <= L / 2 - box_half_diag)
               & (np.abs(other_xy[:, 1]) <= W / 2 - box_half_diag))
        ok &= np.linalg.norm(ball - xy, axis=1) >= rr + rb + _GAP
        ok &= np.linalg.norm(other_xy - xy, axis=1) >= box_half_diag + rr + _GAP
        ok &= np.linalg.norm(ball - other_xy, axis=1) >= box_half_diag + rb + _GAP
        pose = np.concatenate([xy, th[:, None]], axis=1)[ok]
        other = np.concatenate([other_xy, oth[:, None]], axis=1)[ok]
        out = dict(pose=np.concatenate([out["pose"], pose]),
                   ball=np.concatenate([out["ball"], ball[ok]]),
                   other=np.concatenate([out["other"], other]))
    return {k: v[:n].astype(np.float32) for k, v in out.items()}
