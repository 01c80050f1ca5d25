"""Section 2 image features: the ball and the goal seen by one robot's camera.

:func:`section2_features` builds the (9,) observation (layout ``SEC2_*``) from the closed-
form ball and goal images of :mod:`vbl.vision.projection`; :func:`check_inputs` validates
the inputs of both sections' feature functions outside ``jit``. Definitions:
``docs/vision.md``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from vbl.vision.camera import F32, CameraParams, camera_frame, focal_lengths, to_camera
from vbl.vision.projection import (
    ball_column_chord,
    ball_image,
    goal_ends,
    goal_segments,
    lost_side,
    plane_side,
    safe_div,
    subtract_interval,
)

__all__ = [
    "SEC2_DIM", "SEC2_BALL_SIZE", "SEC2_BALL_POS", "SEC2_GOAL_SIZE", "SEC2_GOAL_POS",
    "SEC2_GOAL_ORIENT", "SEC2_BALL_VISIBLE", "SEC2_GOAL_VISIBLE", "SEC2_BALL_LOST_SIDE",
    "SEC2_GOAL_LOST_SIDE", "SEC2_NOISE_DIM", "section2_features", "check_inputs",
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


@jax.jit
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
    ends = goal_ends(goal_segments(pc, cam, fu, fv), cam)
    # the ball hides the goal behind it when it is on the camera's side of the goal plane
    occ = (plane_side(corners, ball_w) * plane_side(corners, frame.c) > 0) & bi.valid
    u_end = 0.5 * (ends.bot[:, 0] + ends.top[:, 0])
    clo, chi, cex = ball_column_chord(bi, u_end, cam)
    vlo, vhi = subtract_interval(ends.bot[:, 1], ends.top[:, 1], clo, chi, occ & cex)
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
    x5 = jnp.clip(safe_div(h[0] - h[1], x3), jnp.float32(-1.0), jnp.float32(1.0))
    bvis, gvis = bi.visible, ends.visible
    gcen = jnp.mean(pc, axis=0)
    out = jnp.stack([
        jnp.where(bvis, bw, 0.0), jnp.where(bvis, bu, 0.0),
        jnp.where(gvis, x3, 0.0), jnp.where(gvis, x4, 0.0),
        jnp.where(gvis & (x3 > 0), x5, 0.0),
        bvis.astype(F32), gvis.astype(F32),
        jnp.where(bvis, 0.0, lost_side(ball_c[0])),
        jnp.where(gvis, 0.0, lost_side(gcen[0])),
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
