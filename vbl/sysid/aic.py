"""AIC of Eq. (6) and its parameter counts lambda(n)."""

from __future__ import annotations

import jax.numpy as jnp

from vbl.sysid.linalg import x64_scope

__all__ = ["param_count", "aic"]


def param_count(n: jnp.ndarray, m: int, q: int, kind: str = "larimore") -> jnp.ndarray:
    """Number of free parameters lambda(n) of an order-n model with m inputs, q outputs.

    ``"larimore"``: n(2q + m) + qm + q(q + 1)/2 (A, B, C, D up to a similarity, the
    Kalman gain and the innovation covariance, Larimore's count).
    ``"sippy"``: n(q + m) + qm (SIPPY's ``K = nq + mn (+ qm)``, with D).
    """
    if kind not in ("larimore", "sippy"):
        raise ValueError(f"param_count kind {kind!r} unknown; choose 'larimore' or 'sippy'")
    with x64_scope():
        n = jnp.asarray(n)
        if kind == "larimore":
            return n * (2 * q + m) + q * m + q * (q + 1) / 2
        return n * (q + m) + q * m


def aic(logdet_r: jnp.ndarray, n: jnp.ndarray, n_samples: int | jnp.ndarray, m: int, q: int,
        kind: str = "larimore") -> jnp.ndarray:
    """Eq. (6): AIC(n) = (N - k - l + 1) log|R_hat(n)| + 2 lambda(n).

    Args:
      logdet_r: log det of the q x q output-residual covariance, any shape.
      n: state order(s), broadcastable with ``logdet_r``.
      n_samples: N - k - l + 1, the number of residuals averaged in R_hat.
    """
    with x64_scope():
        return n_samples * logdet_r + 2.0 * param_count(n, m, q, kind)
