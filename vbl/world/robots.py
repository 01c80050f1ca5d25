"""The two robot bodies: action tables and kinematics.

Two-motor robot (Section 2)
    Left and right wheel motors, each ``m in {-1, 0, +1}`` (backward, stop, forward).
    Action index ``a = 3 * (m_left + 1) + (m_right + 1)`` (9 primitives, table
    :data:`TWO_MOTOR_MOTORS`). Wheel speeds ``v_l = m_l * wheel_speed``,
    ``v_r = m_r * wheel_speed``; body speed ``v = (v_l + v_r) / 2``, turn rate
    ``omega = (v_r - v_l) / track``.

Four-wheel-steering robot (Section 3.3)
    ``u = [v, phi]`` with ``v, phi in {-1, 0, +1}``; the 7 distinct actions are
    :data:`FOUR_WHEEL_U` (``phi`` is irrelevant when ``v = 0``, so (0, +-1) are
    dropped). Speed ``v * speed``; front and rear wheels steer in counter-phase by
    ``delta = phi * max_steer``, so the path curvature is ``2 tan(delta) / wheelbase``
    and ``omega = 2 * v * speed * tan(delta) / wheelbase`` (``phi = +1`` steers left).

Actuator noise (tire slip): each of the two commands of a robot (both wheel speeds,
or ``v`` and ``delta``) is multiplied by ``1 + slip_std * N(0, 1)``, drawn once per
action primitive.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "TWO_MOTOR_MOTORS",
    "TWO_MOTOR_LABELS",
    "FOUR_WHEEL_U",
    "FOUR_WHEEL_LABELS",
    "num_actions",
    "action_labels",
    "action_table",
]

#: (9, 2) motor commands (left, right) of the two-motor robot; row = action index.
TWO_MOTOR_MOTORS = np.array([(left, right) for left in (-1, 0, 1) for right in (-1, 0, 1)],
                            dtype=np.int32)
#: Plot labels of the 9 two-motor primitives: F/B = forward/backward, L/R = the
#: heading turns left (counter-clockwise) / right, TL/TR = spin in place, S = stop.
TWO_MOTOR_LABELS = ("B", "BL", "TL", "BR", "S", "FL", "TR", "FR", "F")

#: (7, 2) commands u = (v, phi) of the 4-wheel-steering robot; row = action index.
FOUR_WHEEL_U = np.array([(0, 0), (1, 0), (1, 1), (1, -1), (-1, 0), (-1, 1), (-1, -1)],
                        dtype=np.int32)
#: Plot labels of the 7 four-wheel primitives (L/R = steering left/right).
FOUR_WHEEL_LABELS = ("S", "F", "FL", "FR", "B", "BL", "BR")

_TABLES = {"two_motor": (TWO_MOTOR_MOTORS, TWO_MOTOR_LABELS),
           "four_wheel": (FOUR_WHEEL_U, FOUR_WHEEL_LABELS)}


def _get(kind: str):
    if kind not in _TABLES:
        raise ValueError(f"unknown robot kind {kind!r}; choose from {sorted(_TABLES)}")
    return _TABLES[kind]


def num_actions(kind: str) -> int:
    """Number of action primitives of a robot kind (9 two-motor, 7 four-wheel)."""
    return len(_get(kind)[1])


def action_labels(kind: str) -> tuple[str, ...]:
    """Short plot labels of the action primitives, indexed by action."""
    return _get(kind)[1]


def action_table(kind: str) -> np.ndarray:
    """(num_actions, 2) int32 commands: (left, right) motors or u = (v, phi)."""
    return _get(kind)[0]
