"""Learning from Easy Missions (LEM): a start-difficulty curriculum driven by Q convergence.

Episodes start from easy situations first (``start_difficulty`` 0: goal large in
the image, ball near) and the start distribution moves outwards (towards 1: fully
random starts) whenever the Q-table has stopped changing.

Rule (checked once every ``window`` learner steps, pure functions on
:class:`LEMState`): let ``change`` be the max (or mean, ``statistic``) of
``|Q - Q_snapshot|`` over all entries, where the snapshot was taken at the
previous check. If ``change < threshold`` **and** Q has moved by at least
``threshold`` (same statistic) since the difficulty was last raised, the
difficulty rises by ``step`` (capped at ``max_difficulty``), provided also that the
training episodes that finished within the window succeeded at a rate of at least
``success_level`` (0: no such condition; at least one finished episode needed otherwise).
Then the snapshot is retaken and the window restarts. The success gate keeps the
curriculum from moving on merely because no reward arrives (Q then stops changing too).
The "moved since the last raise" condition keeps an untouched table (for example all
zeros because no reward has been seen yet) from counting as converged.

``statistic = "none"`` drops both Q-change conditions: the difficulty rises after every
window whose training success reaches ``success_level`` (> 0 required). With multi-step
returns and a constant step size Q never stops changing by the paper's criterion, so the
grid experiment uses this. ``backoff_level`` > 0 lowers the difficulty by ``step`` (never
below ``initial_difficulty``, so ``initial = max`` stays the run without curriculum) after a
window whose training success fell below it.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from vbl.params import ParamError, param

__all__ = ["LEMParams", "LEMState", "lem_init", "lem_update", "q_change"]


@struct.dataclass
class LEMParams:
    """On/off switch and thresholds of the Learning-from-Easy-Missions curriculum."""

    enabled: bool = param(True, doc="use the curriculum; off: episodes start at the env's "
                          "own start_difficulty (the difficulty metric reports it)",
                          static=True)
    initial_difficulty: float = param(0.0, doc="start difficulty of the first episodes "
                                      "(0 easiest, 1 fully random)", ge=0.0, le=1.0)
    max_difficulty: float = param(1.0, doc="difficulty the curriculum stops at", ge=0.0,
                                  le=1.0)
    step: float = param(0.1, doc="difficulty increase when Q has converged", gt=0.0, le=1.0)
    window: int = param(200, doc="learner steps between convergence checks", unit="steps",
                        ge=1)
    threshold: float = param(1e-3, doc="Q counts as converged when its change over a window "
                             "is below this", unit="Q", gt=0.0)
    success_level: float = param(0.0, doc="raise only if the training episodes finished in "
                                 "the window succeeded at least at this rate (0: no success "
                                 "condition)", ge=0.0, le=1.0)
    backoff_level: float = param(0.0, doc="lower the difficulty by `step` (not below "
                                 "initial_difficulty) after a window whose training episodes "
                                 "succeeded below this rate (0: never lower)", ge=0.0, le=1.0)
    statistic: str = param("max", doc="change statistic over the table: max or mean of "
                           "abs(delta Q); 'none': no Q-change conditions, raise whenever the "
                           "window's training success reaches success_level", static=True,
                           choices=("max", "mean", "none"))

    def check(self) -> None:
        import numpy as np

        if bool(np.any(np.asarray(self.backoff_level) > np.maximum(
                np.asarray(self.success_level), 0.0) * (np.asarray(self.backoff_level) > 0))):
            raise ParamError(f"lem.backoff_level={self.backoff_level} must be <= "
                             f"lem.success_level={self.success_level} (a window cannot both "
                             "raise and lower the difficulty)")
        if self.statistic == "none" and bool(np.any(np.asarray(self.success_level) <= 0)):
            raise ParamError("lem.statistic='none' drops the Q-change conditions, so it needs "
                             f"lem.success_level > 0 (got {self.success_level}): otherwise the "
                             "difficulty would rise every window")
        if not np.all(np.asarray(self.initial_difficulty) <= np.asarray(self.max_difficulty)):
            raise ParamError(f"lem.initial_difficulty={self.initial_difficulty} must be <= "
                             f"lem.max_difficulty={self.max_difficulty}")


@struct.dataclass
class LEMState:
    """Curriculum state of one learner."""

    difficulty: jax.Array   #: float32, current start_difficulty in [0, 1]
    q_snapshot: jax.Array   #: float32 (S, A), Q at the previous check
    q_at_raise: jax.Array   #: float32 (S, A), Q when the difficulty was last raised (or init)
    steps: jax.Array        #: int32, steps since the previous check
    raises: jax.Array       #: int32, how many times the difficulty rose
    win_episodes: jax.Array   #: float32, training episodes finished in the current window
    win_successes: jax.Array  #: float32, of those, successes


def q_change(q: jax.Array, ref: jax.Array, statistic: str) -> jax.Array:
    """max or mean of |q - ref| over all entries (float32 scalar)."""
    d = jnp.abs(q.astype(jnp.float32) - ref.astype(jnp.float32))
    if statistic == "max":
        return jnp.max(d)
    if statistic == "mean":
        return jnp.mean(d)
    raise ParamError(f"lem.statistic={statistic!r}; choose 'max' or 'mean'")


def lem_init(p: LEMParams, q: jax.Array) -> LEMState:
    """Initial curriculum state for the Q-table ``q`` (S, A).

    Disabled: the state is carried but unused (the env's own ``start_difficulty``
    applies); its difficulty is ``max_difficulty`` and never changes."""
    start = p.initial_difficulty if p.enabled else p.max_difficulty
    q = q.astype(jnp.float32)
    return LEMState(difficulty=jnp.asarray(start, jnp.float32), q_snapshot=q, q_at_raise=q,
                    steps=jnp.int32(0), raises=jnp.int32(0), win_episodes=jnp.float32(0.0),
                    win_successes=jnp.float32(0.0))


def lem_update(state: LEMState, q: jax.Array, p: LEMParams, episodes: Any = 0,
               successes: Any = 0) -> LEMState:
    """Advance one learner step with the current table ``q`` and the numbers of training
    episodes / successes that finished in this step; raise difficulty on convergence."""
    if not p.enabled:
        return state
    win_eps = state.win_episodes + jnp.asarray(episodes, jnp.float32)
    win_succ = state.win_successes + jnp.asarray(successes, jnp.float32)
    level = jnp.asarray(p.success_level, jnp.float32)
    succeeding = (level <= 0.0) | ((win_eps > 0.0) & (win_succ >= level * win_eps))
    steps = state.steps + 1
    check = steps >= jnp.asarray(p.window, jnp.int32)
    thr = jnp.asarray(p.threshold, jnp.float32)
    q = q.astype(jnp.float32)
    if p.statistic == "none":  # success-gated only (needs success_level > 0: check())
        converged = learned = jnp.bool_(True)
    else:
        converged = q_change(q, state.q_snapshot, p.statistic) < thr
        learned = q_change(q, state.q_at_raise, p.statistic) >= thr
    cap = jnp.asarray(p.max_difficulty, jnp.float32)
    can_rise = state.difficulty < cap
    raise_now = check & converged & learned & can_rise & succeeding
    step = jnp.asarray(p.step, jnp.float32)
    floor = jnp.asarray(p.initial_difficulty, jnp.float32)
    back = jnp.asarray(p.backoff_level, jnp.float32)
    lower = (check & (back > 0.0) & (win_eps > 0.0) & (win_succ < back * win_eps)
             & (state.difficulty > floor))
    difficulty = jnp.where(raise_now, jnp.minimum(state.difficulty + step, cap),
                           state.difficulty)
    difficulty = jnp.where(lower, jnp.maximum(state.difficulty - step, floor), difficulty)
    return LEMState(difficulty=difficulty,
                    q_snapshot=jnp.where(check, q, state.q_snapshot),
                    q_at_raise=jnp.where(raise_now | lower, q, state.q_at_raise),
                    steps=jnp.where(check, 0, steps).astype(jnp.int32),
                    raises=state.raises + raise_now.astype(jnp.int32),
                    win_episodes=jnp.where(check, 0.0, win_eps).astype(jnp.float32),
                    win_successes=jnp.where(check, 0.0, win_succ).astype(jnp.float32))
