"""vbl.world: the soccer world (field, walls, goal, ball, robots) in pure JAX.

See ``docs/world.md`` for the model and its parameters.
"""

from vbl.world.params import (
    ROBOT_KINDS,
    BallParams,
    FieldParams,
    FourWheelParams,
    GoalParams,
    RobotBodyParams,
    TwoMotorParams,
    WorldParams,
)
from vbl.world.physics import (
    WorldEvents,
    WorldState,
    check_actions,
    goal_corners,
    kick_velocity,
    make_state,
    robot_commands,
    world_step,
    wrap_angle,
)
from vbl.world.robots import (
    FOUR_WHEEL_LABELS,
    FOUR_WHEEL_U,
    TWO_MOTOR_LABELS,
    TWO_MOTOR_MOTORS,
    action_labels,
    action_table,
    num_actions,
)

__all__ = [
    "ROBOT_KINDS", "BallParams", "FieldParams", "FourWheelParams", "GoalParams",
    "RobotBodyParams", "TwoMotorParams", "WorldParams", "WorldEvents", "WorldState",
    "check_actions", "goal_corners", "kick_velocity", "make_state", "robot_commands",
    "world_step", "wrap_angle",
    "FOUR_WHEEL_LABELS", "FOUR_WHEEL_U", "TWO_MOTOR_LABELS", "TWO_MOTOR_MOTORS",
    "action_labels", "action_table", "num_actions",
]
