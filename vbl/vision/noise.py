"""Optional pixel noise on image features (default off: ``CameraParams.pixel_noise_std = 0``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from vbl.vision.camera import F32, CameraParams

__all__ = ["add_pixel_noise"]


def add_pixel_noise(key, values, cam: CameraParams, visible) -> jnp.ndarray:
    """Add i.i.d. Gaussian noise of std ``cam.pixel_noise_std`` (px) to ``values`` (n,).

    Only where ``visible`` (bool, broadcastable) is true: a lost object stays exactly 0.
    With std 0 the values are returned unchanged (bit-exact).
    """
    values = jnp.asarray(values, F32)
    std = jnp.asarray(cam.pixel_noise_std, F32)
    eps = jax.random.normal(key, values.shape, F32)
    return values + jnp.where(visible, std * eps, 0.0).astype(F32)
