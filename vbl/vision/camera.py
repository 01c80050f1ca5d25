"""Pinhole camera on a robot: parameters, pose and point projection (pure JAX, float32).

Camera model (see ``docs/vision.md``): the camera sits ``forward_offset`` metres ahead of
the robot centre at ``height`` metres, looks along the robot heading tilted by
``tilt_deg`` (negative = down), with no roll. For a robot pose ``(x, y, theta)`` and
tilt ``tau`` the camera axes in world coordinates are

* forward ``f = (cos theta cos tau, sin theta cos tau, sin tau)``
* right   ``r = (sin theta, -cos theta, 0)``
* up      ``a = (-cos theta sin tau, -sin theta sin tau, cos tau)``

and a world point ``P`` has camera coordinates ``X = r.(P-C)``, ``Y = a.(P-C)``,
``Z = f.(P-C)`` (depth). The image point is ``u = fu X / Z``, ``v = fv Y / Z`` with
``fu = (W/2) / tan(hfov/2)``, ``fv = (H/2) / tan(vfov/2)``; the origin is the image
centre, ``u`` right, ``v`` up.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from vbl.params import ParamError, param

F32 = jnp.float32

__all__ = ["CameraParams", "CameraFrame", "camera_frame", "project_points", "to_camera",
           "focal_lengths"]


@struct.dataclass
class CameraParams:
    """Pinhole camera mounted on a robot (all traced: a sweep can vmap over them)."""

    height: float = param(0.35, doc="camera height above the floor", unit="m", gt=0.0)
    tilt_deg: float = param(-26.0, doc="camera tilt (negative = looking down)", unit="deg",
                            source="P", gt=-90.0, lt=90.0)
    hfov_deg: float = param(67.0, doc="horizontal field of view", unit="deg", source="P",
                            gt=0.0, lt=180.0)
    vfov_deg: float = param(60.0, doc="vertical field of view", unit="deg", source="P",
                            gt=0.0, lt=180.0)
    image_width: int = param(512, doc="image width W (u spans [-W/2, W/2])", unit="px",
                             source="P", gt=0)
    image_height: int = param(480, doc="image height H (v spans [-H/2, H/2])", unit="px",
                              source="P", gt=0)
    forward_offset: float = param(0.05, doc="camera position ahead of the robot centre "
                                  "(0.05 m makes a ball touching a 0.2 m-radius robot "
                                  "about 265 px wide, the paper's ~270 px maximum)",
                                  unit="m")
    pixel_noise_std: float = param(0.0, doc="std of Gaussian noise added to each pixel "
                                   "feature of a visible object (0 = off)", unit="px", ge=0.0)
    near_plane: float = param(0.01, doc="near clipping plane: geometry with depth below "
                              "this is clipped away before projection", unit="m", gt=0.0)

    def check(self) -> None:
        """Cross-field rules (called by :func:`vbl.params.validate`)."""
        if self.near_plane >= self.height:
            raise ParamError(f"near_plane={self.near_plane} must be < height={self.height}")


def focal_lengths(cam: CameraParams) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(fu, fv)`` in px: ``fu = (W/2)/tan(hfov/2)``, ``fv = (H/2)/tan(vfov/2)``."""
    fu = jnp.asarray(cam.image_width, F32) / 2 / jnp.tan(jnp.deg2rad(
        jnp.asarray(cam.hfov_deg, F32)) / 2)
    fv = jnp.asarray(cam.image_height, F32) / 2 / jnp.tan(jnp.deg2rad(
        jnp.asarray(cam.vfov_deg, F32)) / 2)
    return fu, fv


@struct.dataclass
class CameraFrame:
    """Camera centre ``c`` (3,) and world->camera rotation rows ``rot`` (3, 3) = [r; a; f]."""

    c: jnp.ndarray
    rot: jnp.ndarray


def camera_frame(robot_pose: jnp.ndarray, cam: CameraParams, trig=None) -> CameraFrame:
    """Camera centre and axes (rows right, up, forward) for a robot pose ``(x, y, theta)``.

    ``trig``: optional ``(cos theta, sin theta)`` of the pose, when the caller has them.
    """
    pose = jnp.asarray(robot_pose, F32)
    x, y, th = pose[0], pose[1], pose[2]
    tau = jnp.deg2rad(jnp.asarray(cam.tilt_deg, F32))
    off = jnp.asarray(cam.forward_offset, F32)
    ct, st = (jnp.cos(th), jnp.sin(th)) if trig is None else trig
    ca, sa = jnp.cos(tau), jnp.sin(tau)
    c = jnp.stack([x + off * ct, y + off * st, jnp.asarray(cam.height, F32)])
    zero = jnp.zeros((), F32)
    rot = jnp.stack([jnp.stack([st, -ct, zero]),
                     jnp.stack([-ct * sa, -st * sa, ca]),
                     jnp.stack([ct * ca, st * ca, sa])])
    return CameraFrame(c=c, rot=rot)


def to_camera(points: jnp.ndarray, frame: CameraFrame) -> jnp.ndarray:
    """World points (..., 3) -> camera coordinates (..., 3) = (X right, Y up, Z depth)."""
    d = jnp.asarray(points, F32) - frame.c
    # multiply-adds, not a matrix product: XLA on CPU runs a batch of 3x3 products as a
    # library call that fuses with nothing
    return jnp.stack([d[..., 0] * frame.rot[i, 0] + d[..., 1] * frame.rot[i, 1]
                      + d[..., 2] * frame.rot[i, 2] for i in range(3)], axis=-1)


def project_points(points: jnp.ndarray, robot_pose: jnp.ndarray,
                   cam: CameraParams) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Project world points into the image.

    Args:
      points: (..., 3) world coordinates, m.
      robot_pose: (3,) ``(x, y, theta)`` in m, m, rad.
      cam: camera parameters.

    Returns:
      ``uv`` (..., 2) float32 px (origin at the image centre, u right, v up) and ``depth``
      (...,) float32 m (camera-frame Z). ``uv`` is meaningful only where
      ``depth >= cam.near_plane``; for points nearer or behind the camera the depth is
      replaced by ``near_plane`` in the division (finite, never NaN).
    """
    p = to_camera(points, camera_frame(robot_pose, cam))
    fu, fv = focal_lengths(cam)
    z = p[..., 2]
    zs = jnp.maximum(z, jnp.asarray(cam.near_plane, F32))
    uv = jnp.stack([fu * p[..., 0] / zs, fv * p[..., 1] / zs], axis=-1)
    return uv.astype(F32), z.astype(F32)
