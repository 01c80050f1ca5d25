"""Parameters of the soccer world: field, goal, ball, the two robot bodies, time stepping.

Every constant of :mod:`vbl.world` is declared here with :func:`vbl.params.param`
(SI units; the steering angle in degrees, converted inside). ``docs/world.md``
lists them all (generated with :func:`vbl.params.markdown_table`).
"""

from __future__ import annotations

from flax import struct

from vbl.params import ParamError, param, section

__all__ = [
    "ROBOT_KINDS",
    "FieldParams",
    "GoalParams",
    "BallParams",
    "RobotBodyParams",
    "TwoMotorParams",
    "FourWheelParams",
    "WorldParams",
]

#: Robot bodies the world knows: Section 2's two-motor differential drive and
#: Section 3.3's 4-wheel-steering vehicle.
ROBOT_KINDS = ("two_motor", "four_wheel")


@struct.dataclass
class FieldParams:
    """The carpet and its walls (RoboCup-97 size)."""

    length: float = param(8.22, doc="field length along x (goal line to goal line)",
                          unit="m", gt=0.0)
    width: float = param(4.575, doc="field width along y (side wall to side wall)",
                         unit="m", gt=0.0)
    wall_height: float = param(0.5, doc="wall height (for rendering/vision; the physics is 2-D)",
                               unit="m", gt=0.0)
    walls: bool = param(True, doc="walls reflect the ball; off: the ball can leave the field",
                        static=True)


@struct.dataclass
class GoalParams:
    """The goal the learner attacks, centred in the +x end wall."""

    width: float = param(1.5, doc="goal mouth width (between the posts)", unit="m", gt=0.0)
    height: float = param(0.5, doc="goal mouth height (crossbar)", unit="m", gt=0.0)


@struct.dataclass
class BallParams:
    """The ball: a disc on the floor that rolls with friction and bounces."""

    radius: float = param(0.11, doc="ball radius", unit="m", gt=0.0)
    rolling_decel: float = param(0.2, doc="constant rolling-friction deceleration",
                                 unit="m/s^2", ge=0.0)
    drag: float = param(0.3, doc="speed-proportional drag rate (dv/dt = -drag * v)",
                        unit="1/s", ge=0.0)
    wall_restitution: float = param(0.6, doc="normal restitution of a ball-wall bounce",
                                    ge=0.0, le=1.0)
    kick_restitution: float = param(0.5, doc="normal restitution of a ball-robot contact "
                                    "(robot infinitely heavy): a push by the robot's body, "
                                    "and a kick by its kicking face (the kick law: "
                                    "docs/world.md, 'Kicks')", ge=0.0, le=1.0)
    max_speed: float = param(3.0, doc="ball speed cap (safety bound, never reached by "
                             "robots at default speeds)", unit="m/s", gt=0.0)


@struct.dataclass
class RobotBodyParams:
    """Shape and actuator noise shared by both robot kinds."""

    radius: float = param(0.2, doc="robot footprint: disc radius (collision shape)",
                          unit="m", gt=0.0)
    slip_std: float = param(0.0, doc="actuator noise (tire slip): relative std of each "
                            "motor command per primitive; 0 = off", ge=0.0, le=1.0)


@struct.dataclass
class TwoMotorParams:
    """Section 2 robot: two independent wheel motors, each {backward, stop, forward}."""

    wheel_speed: float = param(0.4, doc="wheel ground speed at full forward", unit="m/s",
                               gt=0.0)
    track: float = param(0.3, doc="track width (distance between the wheels)", unit="m",
                         gt=0.0)


@struct.dataclass
class FourWheelParams:
    """Section 3.3 robot: 4-wheel steering, u = [v, phi] in {-1, 0, 1}^2."""

    speed: float = param(0.4, doc="forward speed at v = 1", unit="m/s", gt=0.0)
    wheelbase: float = param(0.3, doc="wheelbase (front to rear axle)", unit="m", gt=0.0)
    max_steer_deg: float = param(30.0, doc="steering angle at phi = 1 (front and rear "
                                 "wheels steer in counter-phase)", unit="deg", gt=0.0, lt=90.0)


@struct.dataclass
class WorldParams:
    """The whole world; ``robot_kinds`` fixes the number and kind of robots (static)."""

    field: FieldParams = section(FieldParams, doc="field and walls")
    goal: GoalParams = section(GoalParams, doc="goal in the +x end wall")
    ball: BallParams = section(BallParams, doc="ball")
    robot: RobotBodyParams = section(RobotBodyParams, doc="robot body")
    two_motor: TwoMotorParams = section(TwoMotorParams, doc="two-motor robot (Section 2)")
    four_wheel: FourWheelParams = section(FourWheelParams, doc="4-wheel-steering robot (Sec 3.3)")
    robot_kinds: tuple = param(("two_motor",), doc="kind of each robot, one of "
                               + ", ".join(ROBOT_KINDS) + " (sets the robot count)",
                               static=True)
    action_dt: float = param(0.1, doc="duration of one action primitive", unit="s",
                             source="P/C", gt=0.0)
    substeps: int = param(2, doc="physics sub-steps per action primitive", static=True,
                          ge=1, le=1000)

    def check(self) -> None:
        """Cross-field rules (called by :func:`vbl.params.validate`)."""
        kinds = self.robot_kinds
        if not isinstance(kinds, tuple) or len(kinds) == 0:
            raise ParamError(f"robot_kinds={kinds!r} must be a non-empty tuple of "
                             f"{list(ROBOT_KINDS)}")
        for k in kinds:
            if k not in ROBOT_KINDS:
                raise ParamError(f"robot_kinds: unknown robot kind {k!r}; "
                                 f"choose from {list(ROBOT_KINDS)}")
        f, g, b, r = self.field, self.goal, self.ball, self.robot
        if g.width >= f.width:
            raise ParamError(f"goal.width={g.width} must be < field.width={f.width}")
        if g.height > f.wall_height:
            raise ParamError(f"goal.height={g.height} must be <= field.wall_height="
                             f"{f.wall_height}")
        if 2 * (r.radius + b.radius) >= min(f.length, f.width):
            raise ParamError("robot.radius + ball.radius too large for the field")
        h = self.action_dt / self.substeps
        if b.drag * h >= 1.0:
            raise ParamError(f"ball.drag * action_dt / substeps = {b.drag * h:g} must be < 1 "
                             "(increase substeps)")
        # no tunnelling: per sub-step relative travel below the contact distance
        v_robot = max(self.two_motor.wheel_speed, self.four_wheel.speed)
        if (b.max_speed + v_robot) * h >= r.radius + b.radius or 2 * v_robot * h >= r.radius:
            raise ParamError(
                f"(ball.max_speed + robot speed) * action_dt / substeps = "
                f"{(b.max_speed + v_robot) * h:g} m must be < robot.radius + ball.radius = "
                f"{r.radius + b.radius:g} m (and 2 * robot speed * dt < robot.radius) to rule "
                "out tunnelling; increase substeps")
