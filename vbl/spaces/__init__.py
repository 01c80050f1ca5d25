"""vbl.spaces: state-space builders (the hand-designed grid) and the grid's macro-action
stop rules (the macro-action wrapper itself is :mod:`vbl.envs.macro`)."""

from vbl.spaces.grid import NUM_GRID_STATES, GridParams, grid_state
from vbl.spaces.macro_action import STOP_RULES, grid_search_key

__all__ = [
    "NUM_GRID_STATES",
    "GridParams",
    "grid_state",
    "STOP_RULES",
    "grid_search_key",
]
