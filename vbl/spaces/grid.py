"""The hand-designed grid state space of the lab's earlier work (the grid lines of Fig. 5).

Each Section-2 image feature is cut into three categories by two boundaries,
``lower`` and ``upper``: category 0 for ``x < lower``, 1 for ``lower <= x < upper``,
2 for ``x >= upper`` (a value on a boundary goes to the upper category).

* ball (11 states): position x2 {left, centre, right} x diameter x1 {small, medium,
  large} -> ``3 * pos + size`` in 0..8; lost to the left 9, lost to the right 10.
* goal (29 states): position x4 {l, c, r} x size x3 {s, m, l} x orientation x5
  {left, front, right} -> ``9 * pos + 3 * size + orient`` in 0..26; lost left 27,
  lost right 28. Orientation "left" is ``x5 < lower`` (the right post looks taller),
  "right" is ``x5 >= upper`` (the left post looks taller).
* state = ``29 * ball_state + goal_state``: 11 x 29 = 319 states.

An object is lost when its visibility flag (obs[5] ball, obs[6] goal) is 0; the
lost side is the sign of obs[7] / obs[8] (``> 0`` right, otherwise left: a lost
object with unknown side 0 counts as lost left). A partially observed object
(cut by the image border, flag 1) maps by its observed features like any other.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import ParamError, param

__all__ = [
    "GridParams",
    "NUM_BALL_STATES",
    "NUM_GOAL_STATES",
    "NUM_GRID_STATES",
    "categorise",
    "ball_state",
    "goal_state",
    "grid_state",
    "decode_state",
    "state_label",
]

NUM_BALL_STATES = 11  #: 3 positions x 3 sizes + lost left + lost right
NUM_GOAL_STATES = 29  #: 3 positions x 3 sizes x 3 orientations + lost left + lost right
NUM_GRID_STATES = NUM_BALL_STATES * NUM_GOAL_STATES  #: 319

# Section-2 observation indices (docs/architecture.md, "Observation layouts";
# vbl.vision.section2.SEC2_*).
_X1_BALL_DIAM, _X2_BALL_POS, _X3_GOAL_SIZE, _X4_GOAL_POS, _X5_GOAL_ORIENT = 0, 1, 2, 3, 4
_BALL_VIS, _GOAL_VIS, _BALL_SIDE, _GOAL_SIDE = 5, 6, 7, 8
_OBS_DIM = 9


@struct.dataclass
class GridParams:
    """Category boundaries of the grid (image of 512 x 480 px, origin at the centre).

    Defaults: positions cut the image width into thirds (+-512/6 px); sizes from the
    default camera (focal length ~387 px): the ball (0.22 m) is small beyond ~2 m and
    large within ~0.85 m; the goal posts (0.5 m) are small beyond ~4 m, large within
    ~2 m; the goal is frontal while the post heights differ by less than 10 %.
    """

    ball_pos_lower: float = param(-85.3, doc="ball x2 below this: left", unit="px")
    ball_pos_upper: float = param(85.3, doc="ball x2 at or above this: right", unit="px")
    ball_size_lower: float = param(40.0, doc="ball diameter x1 below this: small", unit="px",
                                   ge=0.0)
    ball_size_upper: float = param(100.0, doc="ball diameter x1 at or above this: large",
                                   unit="px", ge=0.0)
    goal_pos_lower: float = param(-85.3, doc="goal x4 below this: left", unit="px")
    goal_pos_upper: float = param(85.3, doc="goal x4 at or above this: right", unit="px")
    goal_size_lower: float = param(50.0, doc="goal size x3 below this: small", unit="px",
                                   ge=0.0)
    goal_size_upper: float = param(100.0, doc="goal size x3 at or above this: large",
                                   unit="px", ge=0.0)
    orient_lower: float = param(-0.1, doc="goal orientation x5 below this: left (right post "
                                "taller)", ge=-1.0, le=1.0)
    orient_upper: float = param(0.1, doc="goal orientation x5 at or above this: right (left "
                                "post taller)", ge=-1.0, le=1.0)

    @property
    def num_states(self) -> int:
        """319: the grid's state count (fixed by its structure, not by the boundaries)."""
        return NUM_GRID_STATES

    def check(self) -> None:
        for name in ("ball_pos", "ball_size", "goal_pos", "goal_size", "orient"):
            lo, hi = np.asarray(getattr(self, name + "_lower")), np.asarray(
                getattr(self, name + "_upper"))
            if not np.all(lo < hi):
                raise ParamError(f"grid.{name}_lower={lo} must be < grid.{name}_upper={hi}")


_DEFAULT = GridParams()


def categorise(x: jax.Array, lower: Any, upper: Any) -> jax.Array:
    """0 for x < lower, 1 for lower <= x < upper, 2 for x >= upper; int32, shape of x."""
    return ((x >= lower).astype(jnp.int32) + (x >= upper).astype(jnp.int32))


def _lost_index(side: jax.Array, base: int) -> jax.Array:
    return jnp.where(side > 0, base + 1, base).astype(jnp.int32)


def ball_state(obs: jax.Array, p: GridParams | None = None) -> jax.Array:
    """Ball state in 0..10 from Section-2 observations (..., 9); int32 (...)."""
    p = _DEFAULT if p is None else p
    pos = categorise(obs[..., _X2_BALL_POS], p.ball_pos_lower, p.ball_pos_upper)
    size = categorise(obs[..., _X1_BALL_DIAM], p.ball_size_lower, p.ball_size_upper)
    seen = 3 * pos + size
    lost = _lost_index(obs[..., _BALL_SIDE], 9)
    return jnp.where(obs[..., _BALL_VIS] > 0.5, seen, lost).astype(jnp.int32)


def goal_state(obs: jax.Array, p: GridParams | None = None) -> jax.Array:
    """Goal state in 0..28 from Section-2 observations (..., 9); int32 (...)."""
    p = _DEFAULT if p is None else p
    pos = categorise(obs[..., _X4_GOAL_POS], p.goal_pos_lower, p.goal_pos_upper)
    size = categorise(obs[..., _X3_GOAL_SIZE], p.goal_size_lower, p.goal_size_upper)
    orient = categorise(obs[..., _X5_GOAL_ORIENT], p.orient_lower, p.orient_upper)
    seen = 9 * pos + 3 * size + orient
    lost = _lost_index(obs[..., _GOAL_SIDE], 27)
    return jnp.where(obs[..., _GOAL_VIS] > 0.5, seen, lost).astype(jnp.int32)


def grid_state(obs: jax.Array, p: GridParams | None = None) -> jax.Array:
    """State index ``29 * ball_state + goal_state`` in 0..318; obs (..., 9) -> int32 (...)."""
    obs = jnp.asarray(obs)
    if obs.shape[-1:] != (_OBS_DIM,):
        raise ValueError(f"grid_state needs Section-2 observations of shape (..., {_OBS_DIM}), "
                         f"got {obs.shape}")
    return (NUM_GOAL_STATES * ball_state(obs, p) + goal_state(obs, p)).astype(jnp.int32)


_POS = ("left", "centre", "right")
_SIZE = ("small", "medium", "large")
_ORIENT = ("left", "front", "right")


def decode_state(index: int) -> tuple[int, int]:
    """(ball_state, goal_state) of a grid state index (Python ints)."""
    if not 0 <= int(index) < NUM_GRID_STATES:
        raise ValueError(f"grid state index {index} outside 0..{NUM_GRID_STATES - 1}")
    return divmod(int(index), NUM_GOAL_STATES)


def state_label(index: int) -> str:
    """Human-readable name, e.g. ``ball(centre,large) goal(centre,medium,front)``."""
    b, g = decode_state(index)
    ball = ("lost-left" if b == 9 else "lost-right" if b == 10
            else f"{_POS[b // 3]},{_SIZE[b % 3]}")
    goal = ("lost-left" if g == 27 else "lost-right" if g == 28
            else f"{_POS[g // 9]},{_SIZE[(g // 3) % 3]},{_ORIENT[g % 3]}")
    return f"ball({ball}) goal({goal})"
