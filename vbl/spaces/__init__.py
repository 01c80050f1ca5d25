"""vbl.spaces: state-space builders (the hand-designed grid) and macro actions."""

from vbl.spaces.grid import NUM_GRID_STATES, GridParams, grid_state
from vbl.spaces.macro_action import MacroActionParams, MacroOutcome, macro_step, make_macro_step

__all__ = [
    "NUM_GRID_STATES",
    "GridParams",
    "grid_state",
    "MacroActionParams",
    "MacroOutcome",
    "macro_step",
    "make_macro_step",
]
