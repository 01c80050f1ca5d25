"""Optional pixel noise on image features (default off: ``CameraParams.pixel_noise_std = 0``)."""

from __future__ import annotations

import jax.numpy as jnp

from vbl.vision.camera import F32, CameraParams

__all__ = ["add_pixel_noise"]


def add_pixel_noise(eps, values, cam: CameraParams, visible) -> jnp.ndarray:
    """Add Gaussian noise of std ``cam.pixel_noise_std`` (px) to ``values`` (n,).

    eps: (n,) float32 standard normal draws (the caller draws them: see :mod:`vbl.draws`).
    Only where ``visible`` (bool, broadcastable) is true: a lost object stays exactly 0.
    With std 0 the values are returned unchanged (bit-exact).
    """
    values = jnp.asarray(values, F32)
    std = jnp.asarray(cam.pixel_noise_std, F32)
    return values + jnp.where(visible, std * jnp.asarray(eps, F32), 0.0).astype(F32)
