"""The lag rule of Sec. 3.1.2 on per-lag identification results (jit/vmap-able).

The paper's procedure: "From l = 1, ..., identify the obtained data. (a) If log|R| < 0, stop
the procedure and determine n based on AIC(n), (b) else, increment l until the condition (a)
is satisfied or AIC(n) does not decrease." Each identified l is tested in that order:

1. (a) ``log det R(n*) < stop`` at l: stop and keep l (whatever its AIC);
2. (b) ``l > 1`` and ``AIC(n*)`` at l is not lower than at l - 1: stop and keep l - 1;
3. otherwise try l + 1; when the lags run out, keep the last one identified.

Table 1's goal (l = 1, log det R = -0.001) and move-to-the-ball agent (l = 3, -0.463) stopped
by (a), the ball (l = 2, 0.232) and the random walk (l = 3, 1.22) by (b).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["select_lag"]


def select_lag(logdet: jax.Array, aic: jax.Array, stop) -> tuple[jax.Array, jax.Array]:
    """Pick the lag from ``logdet``, ``aic`` ``(..., L)`` (column j is l = j + 1).

    ``logdet`` = log det R(n*) and ``aic`` = AIC(n*) at each lag; NaN in either marks a lag
    not identified (the rule never looks past the first such lag). ``stop``: the log det
    threshold of (a) (the paper's 0), a scalar (may be traced).

    Returns ``(index (...,) int32 of the chosen lag, decided (...,) bool)``: ``decided`` is
    False when neither (a) nor (b) fired before the identified lags ran out (then the last
    identified lag is chosen; index 0 when none was).
    """
    logdet, aic = jnp.asarray(logdet), jnp.asarray(aic)
    ok = ~jnp.isnan(logdet) & ~jnp.isnan(aic)
    done = jnp.cumsum(~ok, axis=-1) == 0                     # identified, and all before it
    hit = done & (logdet < stop)                              # (a) at l: keep l
    prev = jnp.concatenate([aic[..., :1], aic[..., :-1]], axis=-1)   # AIC at l - 1
    worse = done & (jnp.arange(aic.shape[-1]) > 0) & (aic >= prev)   # (b) at l: keep l - 1
    event = hit | worse
    first = jnp.argmax(event, axis=-1)
    decided = jnp.any(event, axis=-1)
    hit_first = jnp.take_along_axis(hit, first[..., None], axis=-1)[..., 0]
    at_event = jnp.where(hit_first, first, first - 1)
    last = jnp.maximum(jnp.sum(done, axis=-1) - 1, 0)
    return jnp.where(decided, at_event, last).astype(jnp.int32), decided
