"""The two-robot shooting/passing task of Section 3.3 as a gymnax-1.0-style env.

:class:`ShootPassEnv` (``"shoot"``, ``"pass"``, or ``"select"`` with the role traced in
``params.task_pass``): two 4-wheel-steering robots (7 primitives, ``u =
FOUR_WHEEL_U[action]``), robot 0 the shooter and robot 1 the passer; one learns, the other
is scripted (:mod:`vbl.envs.other_agents`). Shooting: redirect a passed, rolling ball into
the goal; passing: kick a rolling ball to the waiting shooter. Reward 1.0 on success, else
0. :func:`apply_kicks` adds kicks to the world's pushes. Observation: the learner's Section
3 features (26,) float32 (slices :data:`OBS_SLICES`), with the noise model of
:mod:`vbl.envs.noise` when it is on. The API, the random layout and the input checks are
:class:`vbl.envs.base.TaskEnv`'s; ``info`` adds ``u`` (2,) float32, ``touched``,
``kicked`` and ``goal``.

See docs/two_robot_task.md, "The task" and docs/envs.md, "The interface" (start difficulty).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.draws import check_switched_off, uniform01
from vbl.envs.base import NoiseOn, Observer, TaskEnv
from vbl.envs.noise import (
    NoiseParams,
    advance_phase,
    eccentric_centroid,
    noisy_camera,
    noisy_world,
    perturb_ball_velocity,
)
from vbl.envs.other_agents import (
    ACT_DRAWS,
    MEMORY_DRAWS,
    AgentMemory,
    OtherAgentParams,
    act,
    init_memory,
)
from vbl.envs.pixels import (
    OBS_SOURCES,
    PixelObsParams,
    camera_image,
    check_obs_source,
    section3_from_image,
)
from vbl.params import ParamError, param, section
from vbl.vision.camera import CameraParams
from vbl.vision.section3 import SEC3_NOISE_DIM
from vbl.world.params import FourWheelParams, WorldParams
from vbl.world.physics import (
    WorldState,
    goal_corners,
    kick_velocity,
    world_step,
    wrap_angle,
)
from vbl.world.robots import FOUR_WHEEL_LABELS, FOUR_WHEEL_U

__all__ = ["TASKS", "ENV_TASKS", "OBS_SLICES", "OBS_DIM", "SHOOTER", "PASSER",
           "ShootPassStartParams", "ShootPassNoiseOn", "ShootPassParams", "ShootPassState",
           "ShootPassEnv",
           "apply_kicks", "EASY_SHOOT", "EASY_PASS", "observe", "default_world"]

F32 = jnp.float32
I32 = jnp.int32

TASKS = ("shoot", "pass")
#: Env constructor choices: a fixed task, or "select": the traced ``params.task_pass`` picks
#: the task per env, so one compiled program serves both (e.g. both columns of Table 2).
ENV_TASKS = (*TASKS, "select")

#: Random draws of this env (slices of one hash per call, :class:`vbl.draws.Words`).
START_DRAWS = 12  #: uniforms of a start draw (:meth:`ShootPassEnv.start_from_uniform`)
FRESH_DRAWS = START_DRAWS + MEMORY_DRAWS  #: uniforms of a fresh episode (start + memory)
#: standard normals of one transition, three blocks: tire slip (2 robots x 2), kick aim (2),
#: eccentric rolling (1)
SLIP_NORMALS, AIM_NORMALS, WOBBLE_NORMALS = 4, 2, 1
SHOOTER, PASSER = 0, 1
_ = float("nan")
#: Easy value of each start uniform (start_difficulty 0; nan = no easy value, the draw is
#: kept): [shooter x, shooter y, pass side, pass angle, pass distance, shooter heading
#: jitter, passer heading jitter, ball gap, ball lateral, ball direction, ball speed, -].
#: shoot: the shooter nearest the goal and centred, facing the goal/passer bisector; the
#: passer at the largest angle and distance (clear of the shot, the pass comes from in front
#: of the shooter), facing it; the ball nearest the passer. (A shooter that only drives
#: forward scores far more often from these starts than from the full draws:
#: tests/test_shoot_pass_env.py::test_easy_starts_are_easier.)
EASY_SHOOT = (1.0, 0.5, _, 1.0, 1.0, 0.5, 0.5, 0.0, _, _, _, _)
#: pass: the shooter nearest, the passer facing it, the ball rolling straight at the
#: passer, nearest and slowest.
EASY_PASS = (1.0, 0.5, _, 0.0, 0.0, 0.5, 0.5, 0.0, 0.5, 0.5, 0.0, _)
del _
OBS_DIM = 26
OBS_SLICES = dict(ball=slice(0, 4), goal=slice(4, 15), other=slice(15, 20),
                  visible=slice(20, 23), lost_side=slice(23, 26))


def default_world() -> WorldParams:
    """World with two 4-wheel-steering robots (0 shooter, 1 passer)."""
    return WorldParams(robot_kinds=("four_wheel", "four_wheel"))


@struct.dataclass
class ShootPassStartParams:
    """Start distribution (both tasks share the geometry; ``pass_*`` only for "pass").

    The shooter stands in front of the goal; the passer stands ``pass_dist`` away from it,
    ``pass_angle`` off the shooter-to-goal direction (side drawn at random), so it sees
    the goal and the passer at once: the shooter faces the bisector of the goal and the
    passer directions (+- jitter); the passer faces the shooter (+- jitter).
    """

    shooter_x_min: float = param(0.5, doc="shooter x range, lower end", unit="m")
    shooter_x_max: float = param(1.8, doc="shooter x range, upper end", unit="m")
    shooter_y_max: float = param(0.6, doc="shooter start range of abs(y)", unit="m", ge=0.0)
    shooter_jitter_deg: float = param(10.0, doc="uniform +- jitter of the shooter heading "
                                      "around the goal/passer bisector", unit="deg", ge=0.0,
                                      le=180.0)
    pass_dist_min: float = param(1.6, doc="shooter-passer centre distance, lower end",
                                 unit="m", gt=0.0)
    pass_dist_max: float = param(2.2, doc="shooter-passer centre distance, upper end",
                                 unit="m", gt=0.0)
    pass_angle_min_deg: float = param(10.0, doc="passer direction off the shooter-goal "
                                      "direction, lower end (the shot must turn the passed "
                                      "ball by about this angle, see docs/two_robot_task.md)",
                                      unit="deg", ge=0.0, le=90.0)
    pass_angle_max_deg: float = param(25.0, doc="passer direction off the shooter-goal "
                                      "direction, upper end", unit="deg", ge=0.0, le=90.0)
    passer_jitter_deg: float = param(10.0, doc="uniform +- jitter of the passer heading "
                                     "around the direction to the shooter", unit="deg",
                                     ge=0.0, le=180.0)
    pass_passer_jitter_deg: float = param(60.0, doc="pass: uniform +- jitter of the (learning)"
                                          " passer's heading around the direction to the "
                                          "shooter (it must turn while the ball comes)",
                                          unit="deg", ge=0.0, le=180.0)
    ball_gap_min: float = param(0.45, doc="shoot: ball centre distance from the passer "
                                "centre, on the passer-shooter line, lower end", unit="m",
                                gt=0.0)
    ball_gap_max: float = param(0.7, doc="shoot: same, upper end", unit="m", gt=0.0)
    pass_ball_gap_min: float = param(0.7, doc="pass: ball start distance from the passer "
                                     "along the passer-shooter line, lower end", unit="m",
                                     gt=0.0)
    pass_ball_gap_max: float = param(1.0, doc="pass: same, upper end", unit="m", gt=0.0)
    pass_ball_lateral: float = param(0.1, doc="pass: uniform +- sideways offset of the ball "
                                     "start", unit="m", ge=0.0)
    pass_ball_speed_min: float = param(0.4, doc="pass: initial ball speed, lower end",
                                       unit="m/s", ge=0.0)
    pass_ball_speed_max: float = param(0.8, doc="pass: initial ball speed, upper end",
                                       unit="m/s", ge=0.0)
    pass_ball_dir_jitter_deg: float = param(30.0, doc="pass: uniform +- jitter of the ball "
                                            "direction around 'towards the passer'",
                                            unit="deg", ge=0.0, le=180.0)
    margin: float = param(0.05, doc="robots and ball start at least this far from the walls "
                          "(beyond their radius)", unit="m", ge=0.0)


@struct.dataclass
class ShootPassNoiseOn(NoiseOn):
    """Static switches of the task's random noise sources: :class:`NoiseOn`'s and two of
    this task's (the centroid eccentricity draws nothing and has none)."""

    aim: bool = param(True, doc="the scripted passer's kick aim error is drawn "
                      "(other.aim_noise_deg; off: it must be 0)", static=True)
    wobble: bool = param(False, doc="the rolling ball's random turns are drawn "
                         "(noise.ecc_turn_std; off: it must be 0)", static=True)


@struct.dataclass
class ShootPassParams:
    """Parameters of the two-robot task (``vbl.params`` fields)."""

    world: WorldParams = section(default_world, doc="physics (robot 0 shooter, 1 passer)")
    shooter_camera: CameraParams = section(CameraParams, doc="shooter's camera")
    passer_camera: CameraParams = section(
        lambda: CameraParams(tilt_deg=-20.0),
        doc="passer's camera (tilted 6 deg less than the shooter's: a hand-mounted camera "
            "bracket; docs/two_robot_task.md, Bodies)")
    passer_body: FourWheelParams = section(
        lambda: FourWheelParams(speed=0.3, max_steer_deg=22.0),
        doc="passer's drive: motor 25 % slower, steering limit 8 deg smaller than the "
            "shooter's world.four_wheel (hand-built robots; docs/two_robot_task.md, "
            "Bodies); used when the passer collects identification data "
            "(vbl.envs.collect). The world physics has one body for all robots, so inside "
            "this env both robots use world.four_wheel")
    noise: NoiseParams = section(NoiseParams, doc="Section 3.4.2 noise model (default off)")
    other: OtherAgentParams = section(OtherAgentParams, doc="the scripted robot")
    start: ShootPassStartParams = section(ShootPassStartParams, doc="start distribution")
    shooter_kick_speed: float = param(2.0, doc="ball speed of a shooter kick (along its "
                                      "heading)", unit="m/s", ge=0.0)
    passer_kick_speed: float = param(1.6, doc="ball speed of a learning passer's kick (along "
                                     "its heading)", unit="m/s", ge=0.0)
    kick_cone_deg: float = param(45.0, doc="a touch kicks only when the ball is within +- "
                                 "this of the robot heading (docs/two_robot_task.md)",
                                 unit="deg", ge=0.0, le=180.0)
    receive_distance: float = param(0.45, doc="pass: success when the ball centre comes "
                                    "this close to the shooter centre", unit="m", gt=0.0)
    rest_speed: float = param(0.05, doc="the ball is at rest below this speed", unit="m/s",
                              ge=0.0)
    end_on_rest: bool = param(True, doc="end the episode (failure) when the ball comes to "
                              "rest after the pass/kick (shoot) or at all (pass)")
    robot_height: float = param(0.3, doc="height of a robot body (what the other camera "
                                "sees)", unit="m", gt=0.0)
    max_steps: int = param(100, doc="time limit: primitives per episode (each "
                           "world.action_dt long; the library default 100 is 10 s)",
                           unit="primitives", static=True, ge=1)
    start_difficulty: float = param(1.0, doc="start distribution: 0 easy (shoot: shooter "
                                    "nearest the goal and centred, the passer clear of the "
                                    "shot, no heading jitter; pass: shooter nearest, "
                                    "passer facing it, the ball rolling straight at the "
                                    "passer), 1 the full start draw (bit for bit); each "
                                    "start uniform is interpolated between its easy value "
                                    "and its draw (traced, so a curriculum can move it)",
                                    ge=0.0, le=1.0)
    task_pass: bool = param(False, doc="env task 'select' only: False = shoot (learner = "
                            "shooter), True = pass (learner = passer); traced, so one "
                            "compiled program serves both tasks (ignored by a fixed task)")
    noise_on: ShootPassNoiseOn = section(ShootPassNoiseOn, doc="static switches of the noise "
                                         "sources")
    obs_source: str = param("analytic", doc="features from the analytic camera, or from the "
                            "rendered camera image (with noise.pixel_std) through the "
                            "colour-blob detector", static=True, choices=OBS_SOURCES)
    pixels: PixelObsParams = section(PixelObsParams, doc="camera image size and blob "
                                     "thresholds (obs_source='pixels', get_pixels)")

    def check(self) -> None:
        on, nz = self.noise_on, self.noise
        check_obs_source(self.obs_source, {
            "noise.image_std": nz.image_std,
            "shooter_camera.pixel_noise_std": self.shooter_camera.pixel_noise_std,
            "passer_camera.pixel_noise_std": self.passer_camera.pixel_noise_std},
            {"noise.pixel_std": nz.pixel_std})
        check_switched_off(on.slip, "noise_on.slip", {
            "world.robot.slip_std": self.world.robot.slip_std, "noise.slip_std": nz.slip_std})
        check_switched_off(on.aim, "noise_on.aim",
                           {"other.aim_noise_deg": self.other.aim_noise_deg})
        check_switched_off(on.wobble, "noise_on.wobble", {"noise.ecc_turn_std": nz.ecc_turn_std})
        check_switched_off(on.pixel, "noise_on.pixel", {
            "noise.image_std": nz.image_std, "noise.pixel_std": nz.pixel_std,
            "shooter_camera.pixel_noise_std": self.shooter_camera.pixel_noise_std,
            "passer_camera.pixel_noise_std": self.passer_camera.pixel_noise_std})
        s = self.start
        for lo, hi in (("shooter_x_min", "shooter_x_max"), ("pass_dist_min", "pass_dist_max"),
                       ("pass_angle_min_deg", "pass_angle_max_deg"),
                       ("ball_gap_min", "ball_gap_max"),
                       ("pass_ball_gap_min", "pass_ball_gap_max"),
                       ("pass_ball_speed_min", "pass_ball_speed_max")):
            if np.any(np.asarray(getattr(s, lo)) > np.asarray(getattr(s, hi))):
                raise ParamError(f"start.{lo}={getattr(s, lo)} must be <= start.{hi}="
                                 f"{getattr(s, hi)}")
        rr = self.world.robot.radius
        rb = self.world.ball.radius
        if np.any(np.asarray(s.ball_gap_min) <= rr + rb):
            raise ParamError(f"start.ball_gap_min={s.ball_gap_min} must exceed robot.radius + "
                             f"ball.radius = {rr + rb} (ball would start inside the passer)")
        if np.any(np.asarray(s.pass_dist_min) - np.asarray(s.pass_ball_gap_max)
                  - np.asarray(s.pass_ball_lateral) <= np.asarray(self.receive_distance)):
            raise ParamError("start.pass_dist_min - start.pass_ball_gap_max - "
                             "start.pass_ball_lateral must exceed receive_distance (a pass "
                             "episode would start as a success)")
        if self.world.robot_kinds != ("four_wheel", "four_wheel"):
            raise ParamError(f"world.robot_kinds={self.world.robot_kinds!r} must be "
                             "('four_wheel', 'four_wheel') (shooter, passer)")


@struct.dataclass
class ShootPassState:
    """world: :class:`WorldState` (robots (2, 3): 0 shooter, 1 passer); step () int32;
    memory: the scripted robot's :class:`AgentMemory`; touched () bool: the learner touched
    the ball this episode; kicked () bool: the ball was kicked this episode; phase ()
    float32: rolling phase of the ball (noise model), rad."""

    world: WorldState
    step: jax.Array
    memory: AgentMemory
    touched: jax.Array
    kicked: jax.Array
    phase: jax.Array


def apply_kicks(eps: jax.Array, world: WorldState, touch: jax.Array, actions: jax.Array,
                speeds: jax.Array, aim_at: jax.Array, aim_noise: jax.Array,
                cone_deg: jax.Array, *, incoming: jax.Array,
                restitution: jax.Array) -> tuple[WorldState, jax.Array]:
    """Kicks after a world step.

    touch: (R,) bool (robot touched the ball this step); actions: (R,) int32;
    speeds: (R,) float32 kick speeds (m/s; 0 = this robot never kicks);
    aim_at: (R,) int32, -1 = kick along the own heading by the kick law
    (:func:`vbl.world.physics.kick_velocity` of the ``incoming`` ball velocity (2,), the one
    before the step, with ``restitution``; a resting ball leaves at the kick speed),
    j >= 0 = a pass at the kick speed towards robot j's centre;
    aim_noise: (R,) float32 std of the kick direction, rad; eps: (R,) float32 standard
    normals (the aim error in units of ``aim_noise``) or None (no aim error); cone_deg: ()
    half-angle, deg.
    A robot kicks when it touched the ball, drives forward (v > 0) and the ball is within
    the cone around its heading. When several kick, the last robot index wins.
    Returns (world with the new ball velocity, kicked (R,) bool).
    """
    n = world.robots.shape[0]
    v_sign = jnp.asarray(FOUR_WHEEL_U, I32)[actions, 0]
    noise = None if eps is None else jnp.asarray(eps, F32).reshape(n) * aim_noise
    cone = jnp.deg2rad(jnp.asarray(cone_deg, F32))
    vel = world.ball_vel
    kicked = []
    for i in range(n):
        pose = world.robots[i]
        d = world.ball - pose[:2]
        bearing = wrap_angle(jnp.arctan2(d[1], d[0]) - pose[2])
        target = world.robots[jnp.maximum(aim_at[i], 0), :2] - world.ball
        ang = jnp.where(aim_at[i] >= 0, jnp.arctan2(target[1], target[0]), pose[2])
        if noise is not None:
            ang = ang + noise[i]
        k = touch[i] & (v_sign[i] > 0) & (jnp.abs(bearing) <= cone) & (speeds[i] > 0) \
            & ~world.scored
        unit = jnp.stack([jnp.cos(ang), jnp.sin(ang)])
        kicked_vel = jnp.where(aim_at[i] >= 0, speeds[i] * unit,
                               kick_velocity(incoming, unit, speeds[i], restitution))
        vel = jnp.where(k, kicked_vel, vel)
        kicked.append(k)
    return world.replace(ball_vel=vel.astype(F32)), jnp.stack(kicked)


def observe(world: WorldState, me: int, cam: CameraParams, world_params: WorldParams,
            noise: NoiseParams, robot_height: jax.Array, phase: jax.Array,
            eps: jax.Array | None) -> jax.Array:
    """Section 3 features (26,) float32 of robot ``me`` (static int) seeing the ball, the
    goal and the other robot ``1 - me`` (seen as a box of length and width = the robot's
    diameter and height ``robot_height``),
    with image noise and ball centroid eccentricity from ``noise``.
    ``cam``: that robot's camera (before noise); ``phase``: the ball's rolling phase, rad;
    ``eps``: (SEC3_NOISE_DIM,) float32 standard normals of the pixel noise (None: exact
    features)."""
    from vbl.vision.section3 import flatten_section3, section3_features

    other = 1 - me
    cam = noisy_camera(cam, noise)
    d = 2 * jnp.asarray(world_params.robot.radius, F32)
    other_size = jnp.stack([d, d, jnp.asarray(robot_height, F32)])
    obs = section3_features(world.robots[me], world.ball,
                            jnp.asarray(world_params.ball.radius, F32),
                            goal_corners(world_params), world.robots[other], other_size,
                            cam, eps=eps)
    flat = flatten_section3(obs).astype(F32)
    ball = eccentric_centroid(flat[OBS_SLICES["ball"]], flat[OBS_SLICES["visible"]][0], phase,
                              noise)
    return flat.at[OBS_SLICES["ball"]].set(ball)


class ShootPassEnv(TaskEnv, params=ShootPassParams, state=ShootPassState,
                   fresh_words=FRESH_DRAWS, pixel_noise_dim=SEC3_NOISE_DIM,
                   option=("task", ENV_TASKS)):
    """Two-robot task: ``task="shoot"`` (learner = shooter), ``"pass"`` (learner = passer)
    or ``"select"`` (the traced ``params.task_pass`` picks); ``params``: see
    :class:`~vbl.envs.base.TaskEnv`."""

    num_actions = 7
    action_labels = FOUR_WHEEL_LABELS
    obs_slices = OBS_SLICES
    observation_shape = (OBS_DIM,)
    #: Length of ``info["u"]``, the learner's motor command (left, right wheel).
    command_dim = FOUR_WHEEL_U.shape[1]

    def __init__(self, task: str = "shoot", params: ShootPassParams | None = None):
        self.task = task
        super().__init__(task, params)
        #: the learner's robot index for a fixed task (None for "select": see roles())
        self.learner = {"shoot": SHOOTER, "pass": PASSER}.get(task)

    @property
    def name(self) -> str:
        return f"ShootPass-{self.task}"

    # ------------------------------------------------------------------ roles
    def is_pass(self, params: ShootPassParams) -> jax.Array:
        """() bool: the learner is the passer (a constant for a fixed task, else the traced
        ``params.task_pass``)."""
        if self.task == "select":
            return jnp.asarray(params.task_pass, bool)
        return jnp.asarray(self.task == "pass", bool)

    def roles(self, params: ShootPassParams) -> tuple[jax.Array, jax.Array]:
        """(learner, other) robot indices, () int32 (0 shooter, 1 passer)."""
        me = jnp.where(self.is_pass(params), PASSER, SHOOTER).astype(I32)
        return me, (1 - me).astype(I32)

    # ------------------------------------------------------------------ start
    def sample_start(self, key: jax.Array, params: ShootPassParams) -> WorldState:
        """Draw the start world state of this task (see :class:`ShootPassStartParams`)."""
        return self.start_from_uniform(jax.random.uniform(key, (START_DRAWS,), F32), params)

    def eased_uniform(self, u: jax.Array, params: ShootPassParams) -> jax.Array:
        """The start uniforms at ``params.start_difficulty`` d: ``e + d * (u - e)`` for the
        draws with an easy value e (:data:`EASY_SHOOT` / :data:`EASY_PASS`), ``u`` itself
        for the others and for every draw at d >= 1 (the full start draw, bit for bit)."""
        u = jnp.asarray(u, F32)
        d = jnp.asarray(params.start_difficulty, F32)
        easy = jnp.where(self.is_pass(params), jnp.asarray(EASY_PASS, F32),
                         jnp.asarray(EASY_SHOOT, F32))
        e = jnp.where(jnp.isnan(easy), u, easy)
        return jnp.where(d >= 1.0, u, e + d * (u - e))

    def start_from_uniform(self, u: jax.Array, params: ShootPassParams) -> WorldState:
        """The start world state for ``u``, (START_DRAWS,) float32 uniform draws in [0, 1),
        at ``params.start_difficulty`` (:meth:`eased_uniform`)."""
        sp, wp = params.start, params.world
        half = jnp.stack([jnp.asarray(wp.field.length, F32),
                          jnp.asarray(wp.field.width, F32)]) / 2
        rr = jnp.asarray(wp.robot.radius, F32)
        rb = jnp.asarray(wp.ball.radius, F32)
        mg = jnp.asarray(sp.margin, F32)
        u = self.eased_uniform(u, params)

        def lerp(lo, hi, x):
            return jnp.asarray(lo, F32) + (jnp.asarray(hi, F32) - jnp.asarray(lo, F32)) * x

        def unit(a):
            return jnp.stack([jnp.cos(a), jnp.sin(a)])

        lim_r = half - rr - mg
        s_xy = jnp.stack([lerp(sp.shooter_x_min, sp.shooter_x_max, u[0]),
                          lerp(-sp.shooter_y_max, sp.shooter_y_max, u[1])])
        s_xy = jnp.clip(s_xy, -lim_r, lim_r)
        goal = jnp.stack([half[0], jnp.zeros((), F32)])
        to_goal = jnp.arctan2(goal[1] - s_xy[1], goal[0] - s_xy[0])
        side = jnp.where(u[2] < 0.5, -1.0, 1.0).astype(F32)
        alpha = jnp.deg2rad(lerp(sp.pass_angle_min_deg, sp.pass_angle_max_deg, u[3])) * side
        dist = lerp(sp.pass_dist_min, sp.pass_dist_max, u[4])
        p_xy = jnp.clip(s_xy + dist * unit(to_goal + alpha), -lim_r, lim_r)
        # headings
        to_p = jnp.arctan2(p_xy[1] - s_xy[1], p_xy[0] - s_xy[0])
        bis = to_goal + 0.5 * wrap_angle(to_p - to_goal)
        s_th = wrap_angle(bis + jnp.deg2rad(jnp.asarray(sp.shooter_jitter_deg, F32))
                          * (2 * u[5] - 1))
        back = wrap_angle(to_p + jnp.pi)  # passer -> shooter
        is_pass = self.is_pass(params)
        p_jit = jnp.where(is_pass, jnp.asarray(sp.pass_passer_jitter_deg, F32),
                          jnp.asarray(sp.passer_jitter_deg, F32))
        p_th = wrap_angle(back + jnp.deg2rad(jnp.asarray(p_jit, F32)) * (2 * u[6] - 1))
        lim_b = half - rb - mg
        # shoot: the ball lies still in front of the passer
        gap_s = lerp(sp.ball_gap_min, sp.ball_gap_max, u[7])
        ball_s = p_xy + gap_s * unit(back)
        # pass: the ball rolls towards the passer
        gap = lerp(sp.pass_ball_gap_min, sp.pass_ball_gap_max, u[7])
        lat = jnp.asarray(sp.pass_ball_lateral, F32) * (2 * u[8] - 1)
        ball_p = p_xy + gap * unit(back) + lat * unit(back + jnp.pi / 2)
        to_passer = jnp.arctan2(p_xy[1] - ball_p[1], p_xy[0] - ball_p[0])
        d_ang = to_passer + jnp.deg2rad(jnp.asarray(sp.pass_ball_dir_jitter_deg, F32)) * (
            2 * u[9] - 1)
        vel_p = lerp(sp.pass_ball_speed_min, sp.pass_ball_speed_max, u[10]) * unit(d_ang)
        ball = jnp.where(is_pass, ball_p, ball_s)
        vel = jnp.where(is_pass, vel_p, jnp.zeros(2, F32))
        ball = jnp.clip(ball, -lim_b, lim_b)
        robots = jnp.stack([jnp.concatenate([s_xy, s_th[None]]),
                            jnp.concatenate([p_xy, p_th[None]])]).astype(F32)
        return WorldState(robots=robots, ball=ball.astype(F32), ball_vel=vel.astype(F32),
                          scored=jnp.zeros((), bool), ball_out=jnp.zeros((), bool))

    def _fresh(self, words: jax.Array, params: ShootPassParams) -> ShootPassState:
        """A fresh episode's state from (FRESH_DRAWS,) uint32 random words."""
        u = uniform01(words)
        return ShootPassState(world=self.start_from_uniform(u[:START_DRAWS], params),
                              step=jnp.zeros((), I32),
                              memory=init_memory(u[START_DRAWS:], params.other),
                              touched=jnp.zeros((), bool), kicked=jnp.zeros((), bool),
                              phase=jnp.zeros((), F32))

    # ------------------------------------------------------------------ obs
    def learner_camera(self, params: ShootPassParams) -> CameraParams:
        """The learner's camera (the passer's when the learner is the passer)."""
        if self.task != "select":
            return params.passer_camera if self.task == "pass" else params.shooter_camera
        ip = self.is_pass(params)
        return jax.tree.map(lambda a, b: jnp.where(ip, a, b), params.passer_camera,
                            params.shooter_camera)

    def _me(self, params: ShootPassParams):
        """The learner's robot index (static for a fixed task, traced for "select")."""
        return self.roles(params)[0] if self.task == "select" else self.learner

    def observer(self, params: ShootPassParams) -> Observer:
        """The learner's camera: Section 3 features (26,) float32, analytic (``eps``:
        (SEC3_NOISE_DIM,) float32 standard normals of the pixel noise, or None) or from its
        image of the ball, goal and the other robot (as the analytic camera's box), with the
        ball centroid's eccentricity of ``params.noise`` and image noise
        ``noise.pixel_std``."""
        me, cam, wp = self._me(params), self.learner_camera(params), params.world
        noise, height = params.noise, params.robot_height
        return Observer(
            features=lambda state, eps: observe(state.world, me, cam, wp, noise, height,
                                                state.phase, eps),
            image=lambda state: camera_image(state.world, me, cam, wp, height,
                                             params.pixels.render),
            from_image=lambda img, state: section3_from_image(
                img, state.world, me, cam, wp, noise, height, state.phase, params.pixels),
            image_noise_std=noise.pixel_std)

    # ------------------------------------------------------------------ dynamics
    def transition_blocks(self, params: ShootPassParams) -> tuple[tuple[int, bool], ...]:
        """The transition's draw blocks: tire slip (4,), kick aim (2,), eccentric rolling
        (1,)."""
        on = params.noise_on
        return (SLIP_NORMALS, on.slip), (AIM_NORMALS, on.aim), (WOBBLE_NORMALS, on.wobble)

    def _transition(self, eps, state: ShootPassState, action, params: ShootPassParams):
        """One primitive; ``eps``: standard normals (tire slip (4,), kick aim (2,), eccentric
        rolling (1,)), each float32 or None (that source off)."""
        slip_eps, aim_eps, wobble_eps = eps
        # the passer and the waiter draw nothing (no random walk): zero uniforms
        no_draws = jnp.zeros((ACT_DRAWS,), F32)
        is_pass = self.is_pass(params)
        me, other = self.roles(params)
        # the scripted robot: the passer (shoot task; robot 1) or a waiting shooter (pass)
        a_passer, memory = act("passer", no_draws, state.world, state.memory, PASSER,
                               params.other)
        a_other = jnp.where(is_pass, act("waiter", no_draws, state.world, state.memory, SHOOTER,
                                         params.other)[0], a_passer).astype(I32)
        memory = memory.replace(action=a_other)
        a_me = jnp.asarray(action, I32).reshape(())
        actions = (jnp.zeros(2, I32).at[me].set(a_me).at[other].set(a_other))
        wp = noisy_world(params.world, params.noise)
        world, events = world_step(state.world, actions, wp, slip_eps=None if slip_eps is None
                                   else slip_eps.reshape(2, 2))
        # kicks
        # shoot: learning shooter kicks along its heading, scripted passer aims at the
        # shooter; pass: the waiting shooter never kicks, learning passer along its heading
        speeds = jnp.where(is_pass,
                           jnp.stack([jnp.zeros((), F32),
                                      jnp.asarray(params.passer_kick_speed, F32)]),
                           jnp.stack([jnp.asarray(params.shooter_kick_speed, F32),
                                      jnp.asarray(params.other.kick_speed, F32)]))
        aim_at = jnp.where(is_pass, jnp.array([-1, -1], I32), jnp.array([-1, SHOOTER], I32))
        aim_noise = jnp.where(is_pass, jnp.zeros(2, F32), jnp.stack([
            jnp.zeros((), F32), jnp.deg2rad(jnp.asarray(params.other.aim_noise_deg, F32))]))
        world, kicks = apply_kicks(aim_eps, world, events.touch, actions, speeds, aim_at,
                                   aim_noise, params.kick_cone_deg,
                                   incoming=state.world.ball_vel,
                                   restitution=params.world.ball.kick_restitution)
        # eccentric rolling (noise model)
        rb = jnp.asarray(params.world.ball.radius, F32)
        if wobble_eps is not None:
            rolled = jnp.sqrt(jnp.sum((world.ball - state.world.ball) ** 2))
            world = world.replace(ball_vel=perturb_ball_velocity(
                wobble_eps[0], world.ball_vel, rolled, rb, params.noise))
        phase = advance_phase(state.phase, state.world.ball, world.ball, rb)
        memory = memory.replace(kicked=memory.kicked | kicks[other])
        touched = state.touched | events.touch[me]
        kicked = state.kicked | jnp.any(kicks)
        # outcome
        speed = jnp.sqrt(jnp.sum(world.ball_vel ** 2))
        speed0 = jnp.sqrt(jnp.sum(state.world.ball_vel ** 2))
        rest_speed = jnp.asarray(params.rest_speed, F32)
        came_to_rest = (speed < rest_speed) & (speed0 >= rest_speed) & ~world.scored
        d = world.ball - world.robots[SHOOTER, :2]
        near = jnp.sqrt(jnp.sum(d * d)) <= jnp.asarray(params.receive_distance, F32)
        success = jnp.where(is_pass, (near | events.touch[SHOOTER]) & ~world.scored,
                            events.goal & touched)
        rest_fail = came_to_rest & (is_pass | kicked)
        rest_fail = rest_fail & jnp.asarray(params.end_on_rest, bool)
        step = state.step + 1
        terminated = success | events.goal | events.ball_out | rest_fail
        truncated = (step >= params.max_steps) & ~terminated
        reward = success.astype(F32)
        info = dict(success=success, episode_done=terminated | truncated, episode_length=step,
                    u=jnp.asarray(FOUR_WHEEL_U, F32)[a_me], touched=touched, kicked=kicked,
                    goal=events.goal)
        nstate = ShootPassState(world=world, step=step, memory=memory, touched=touched,
                                kicked=kicked, phase=phase)
        return nstate, reward, terminated, truncated, info
