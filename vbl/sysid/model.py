"""Filtering model from a CVA identification: state mu(t) and one-step prediction of y.

The model is a ``flax.struct`` pytree (float32 by default), jit-able inside an
environment loop. A batch of models (leading data-set axis) is used with ``jax.vmap``::

    hist = model.init_history()                      # before any sample
    hist = model.update_history(hist, u_prev, y_prev)  # after observing u(t-1), y(t-1)
    mu = model.state(hist)                           # (n_max,) mu(t), zero beyond n
    y_hat = model.predict(hist, u_t)                 # (q,) one-step prediction of y(t)

Shapes: ``n_max`` = orders swept, ``h`` = history length (the largest lag tried),
``m`` inputs, ``q`` outputs. ``mu(t) = U p(t)`` where ``p(t)`` stacks the last ``h``
normalised inputs then outputs; columns of ``U`` beyond the model's lag ``l`` are zero.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

__all__ = ["History", "CVAModel"]


@struct.dataclass
class History:
    """The last ``h`` normalised samples, most recent first."""

    u: jnp.ndarray       # (h, m)  u(t-1), u(t-2), ...
    y: jnp.ndarray       # (h, q)  y(t-1), y(t-2), ...
    count: jnp.ndarray   # () int32 samples seen (capped at h)


@struct.dataclass
class CVAModel:
    """Identified model ``[mu(t+1); y(t)] = Theta [mu(t); u(t)]`` in normalised units."""

    U: jnp.ndarray        # (n_max, h(m+q)) state map: mu(t) = U p(t)
    A: jnp.ndarray        # (n_max, n_max) Theta blocks (zero beyond n)
    B: jnp.ndarray        # (n_max, m)
    C: jnp.ndarray        # (q, n_max)
    D: jnp.ndarray        # (q, m)
    R: jnp.ndarray        # (q, q) one-step output residual covariance (normalised units)
    n: jnp.ndarray        # () int32 state order
    lag: jnp.ndarray      # () int32 past lag l
    u_mean: jnp.ndarray   # (m,)
    u_scale: jnp.ndarray  # (m,)
    y_mean: jnp.ndarray   # (q,)
    y_scale: jnp.ndarray  # (q,)

    @property
    def n_max(self) -> int:
        return self.A.shape[-1]

    @property
    def history_length(self) -> int:
        m, q = self.D.shape[-1], self.D.shape[-2]
        return self.U.shape[-1] // (m + q)

    def init_history(self) -> History:
        """Empty history (normalised zeros, i.e. the channel means)."""
        h, m, q = self.history_length, self.D.shape[-1], self.D.shape[-2]
        dt = self.U.dtype
        return History(u=jnp.zeros((h, m), dt), y=jnp.zeros((h, q), dt),
                       count=jnp.zeros((), jnp.int32))

    def update_history(self, hist: History, u: jnp.ndarray, y: jnp.ndarray) -> History:
        """Push the newest raw sample ``u (m,)``, ``y (q,)`` (time t-1 for the next state)."""
        un = ((u - self.u_mean) / self.u_scale).astype(hist.u.dtype)
        yn = ((y - self.y_mean) / self.y_scale).astype(hist.y.dtype)
        return History(u=jnp.concatenate([un[None], hist.u[:-1]]),
                       y=jnp.concatenate([yn[None], hist.y[:-1]]),
                       count=jnp.minimum(hist.count + 1, self.history_length))

    def ready(self, hist: History) -> jnp.ndarray:
        """True once ``lag`` samples have been pushed (before that mu uses zero padding)."""
        return hist.count >= self.lag

    def state(self, hist: History) -> jnp.ndarray:
        """mu(t) (n_max,) from the history; components beyond n are zero."""
        p = jnp.concatenate([hist.u.reshape(-1), hist.y.reshape(-1)])
        return self.U @ p

    def predict(self, hist: History, u: jnp.ndarray) -> jnp.ndarray:
        """One-step prediction of y(t) (q,) in raw units, given the current input u(t)."""
        un = ((u - self.u_mean) / self.u_scale).astype(self.U.dtype)
        yn = self.C @ self.state(hist) + self.D @ un
        return self.y_mean + self.y_scale * yn

    def predict_state(self, hist: History, u: jnp.ndarray) -> jnp.ndarray:
        """Model prediction of mu(t+1) = A mu(t) + B u(t) (n_max,)."""
        un = ((u - self.u_mean) / self.u_scale).astype(self.U.dtype)
        return self.A @ self.state(hist) + self.B @ un

    def poles(self):
        """Eigenvalues of A restricted to the first n states (NumPy, unbatched model only)."""
        import numpy as np

        n = int(self.n)
        return np.linalg.eigvals(np.asarray(self.A, np.float64)[:n, :n])
