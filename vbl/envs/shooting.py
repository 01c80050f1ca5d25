"""The shooting task of Section 2 as a gymnax-1.0-style functional environment.

:class:`ShootingEnv`: one robot (two-motor by default), a ball and the goal in the +x end
wall. The robot sees the Section 2 features (9,) float32 of its camera
(:func:`vbl.vision.section2.section2_features`). Reward 1.0 when the ball enters the goal,
else 0; an episode ends on a goal or the ball leaving the field (terminated) or after
``max_steps`` primitives (truncated). A start interpolates between an easy and a full
draw by the traced ``start_difficulty`` in [0, 1], so a curriculum can move it. The API,
the random layout, the noise switches (tire slip, pixel noise; off by default) and the
input checks are :class:`vbl.envs.base.TaskEnv`'s; ``info`` adds ``ball_out``.

See docs/world.md, "The shooting task" and docs/envs.md, "The interface".
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.draws import check_switched_off
from vbl.envs.base import NoiseOn, Observer, TaskEnv
from vbl.envs.pixels import (
    OBS_SOURCES,
    PixelObsParams,
    camera_image,
    check_obs_source,
    section2_from_image,
)
from vbl.params import ParamError, param, section
from vbl.vision.camera import CameraParams
from vbl.vision.section2 import SEC2_DIM, SEC2_NOISE_DIM, section2_features
from vbl.world.params import ROBOT_KINDS, WorldParams
from vbl.world.physics import WorldState, goal_corners, world_step, wrap_angle
from vbl.world.robots import action_labels, num_actions

__all__ = ["ShootingStartParams", "ShootingParams", "ShootingState",
           "ShootingEnv"]

F32 = jnp.float32
#: Random draws of this env (slices of one hash per call, :class:`vbl.draws.Words`).
START_WORDS = 5  #: random words of a start draw (10 uniforms of 16 bits)
SLIP_NORMALS = 2  #: standard normals of one transition's tire slip (one robot)


@struct.dataclass
class ShootingStartParams:
    """Start distribution of the shooting task (see the module docstring)."""

    margin: float = param(0.3, doc="full draw: distance of robot and ball centres from the "
                          "walls", unit="m", ge=0.0)
    easy_goal_dist: float = param(1.0, doc="easy draw: robot centre distance in front of the "
                                  "goal line (robot on the goal axis facing it)", unit="m",
                                  gt=0.0)
    easy_ball_gap: float = param(0.05, doc="easy draw: gap between robot and ball, ball "
                                 "straight ahead", unit="m", ge=0.0)
    easy_jitter_xy: float = param(0.1, doc="easy draw: uniform +- jitter of robot and ball "
                                  "positions", unit="m", ge=0.0)
    easy_jitter_deg: float = param(10.0, doc="easy draw: uniform +- jitter of the heading",
                                   unit="deg", ge=0.0, le=180.0)
    min_gap: float = param(0.02, doc="minimum start gap between ball and robot surfaces",
                           unit="m", ge=0.0)


@struct.dataclass
class ShootingParams:
    """Parameters of the shooting task."""

    world: WorldParams = section(WorldParams, doc="physics")
    camera: CameraParams = section(CameraParams, doc="robot camera")
    start: ShootingStartParams = section(ShootingStartParams, doc="start distribution")
    start_difficulty: float = param(1.0, doc="start distribution: 0 easy (near the goal, "
                                    "ball in front), 1 full random; interpolated between",
                                    ge=0.0, le=1.0)
    max_steps: int = param(300, doc="time limit: action primitives per episode (each "
                           "world.action_dt long; the library default 300 is 30 s)",
                           unit="primitives", static=True, ge=1)
    noise_on: NoiseOn = section(NoiseOn, doc="static switches of the random "
                                        "noise sources")
    obs_source: str = param("analytic", doc="features from the analytic camera, or from the "
                            "rendered camera image through the colour-blob detector (no "
                            "image noise in this task)", static=True, choices=OBS_SOURCES)
    pixels: PixelObsParams = section(PixelObsParams, doc="camera image size and blob "
                                     "thresholds (obs_source='pixels', get_pixels)")

    def check(self) -> None:
        check_obs_source(self.obs_source, {"camera.pixel_noise_std":
                                           self.camera.pixel_noise_std}, {})
        check_switched_off(self.noise_on.slip, "noise_on.slip",
                           {"world.robot.slip_std": self.world.robot.slip_std})
        check_switched_off(self.noise_on.pixel, "noise_on.pixel",
                           {"camera.pixel_noise_std": self.camera.pixel_noise_std})


@struct.dataclass
class ShootingState:
    """world: :class:`WorldState` with one robot; step: () int32 primitives taken so far."""

    world: WorldState
    step: jax.Array


def _uniform16(words: jax.Array) -> jax.Array:
    """(2 n,) float32 uniform in [-1, 1) with 16-bit resolution from (n,) uint32 words, two
    per word (half the random words of full resolution; a resolution of 2**-15 of the field
    half-length is 0.1 mm, far below any start scale)."""
    words = jnp.asarray(words, jnp.uint32)
    halves = jnp.concatenate([words >> 16, words & 0xFFFF])
    return halves.astype(F32) * np.float32(2.0 / 65536) - 1.0


class ShootingEnv(TaskEnv, params=ShootingParams, state=ShootingState, fresh_words=START_WORDS,
                  pixel_noise_dim=SEC2_NOISE_DIM, option=("robot_kind", ROBOT_KINDS)):
    """Shooting task: drive the ball into the goal (Section 2). ``robot_kind``:
    "two_motor" (Section 2, 9 actions, default) or "four_wheel" (7 actions); ``params``: see
    :class:`~vbl.envs.base.TaskEnv`."""

    observation_shape = (SEC2_DIM,)

    def __init__(self, robot_kind: str = "two_motor", params: ShootingParams | None = None):
        self.robot_kind = robot_kind
        super().__init__(robot_kind, params)

    def defaults(self) -> ShootingParams:
        params = ShootingParams()
        return params.replace(world=params.world.replace(robot_kinds=(self.robot_kind,)))

    # ------------------------------------------------------------------ metadata
    @property
    def num_actions(self) -> int:
        """Number of discrete action primitives (9 two-motor, 7 four-wheel)."""
        return num_actions(self.robot_kind)

    @property
    def action_labels(self) -> tuple[str, ...]:
        return action_labels(self.robot_kind)

    @property
    def name(self) -> str:
        return "Shooting-" + self.robot_kind

    # ------------------------------------------------------------------ checks
    def check_params(self, params: ShootingParams) -> None:
        if params.world.robot_kinds != (self.robot_kind,):
            raise ParamError(f"world.robot_kinds={params.world.robot_kinds!r} must be "
                             f"({self.robot_kind!r},) for this {self.name} env")

    # ------------------------------------------------------------------ core
    def sample_start(self, key: jax.Array, params: ShootingParams) -> WorldState:
        """Draw a start world state (see the module docstring)."""
        return self.start_from_words(jax.random.bits(key, (START_WORDS,), jnp.uint32), params)

    def start_from_words(self, words: jax.Array, params: ShootingParams) -> WorldState:
        """The start world state for (START_WORDS,) uint32 random words."""
        wp, sp = params.world, params.start
        half = jnp.stack([jnp.asarray(wp.field.length, F32), jnp.asarray(wp.field.width, F32)]) / 2
        rr = jnp.asarray(wp.robot.radius, F32)
        rb = jnp.asarray(wp.ball.radius, F32)
        d = jnp.asarray(params.start_difficulty, F32)
        u = _uniform16(words)
        # easy draw
        jit_xy = jnp.asarray(sp.easy_jitter_xy, F32)
        th_e = jnp.deg2rad(jnp.asarray(sp.easy_jitter_deg, F32)) * u[0]
        r_e = jnp.stack([half[0] - jnp.asarray(sp.easy_goal_dist, F32), jnp.zeros((), F32)])
        r_e = r_e + jit_xy * u[1:3]
        reach = rr + rb + jnp.asarray(sp.easy_ball_gap, F32)
        b_e = r_e + reach * jnp.stack([jnp.cos(th_e), jnp.sin(th_e)]) + jit_xy * u[3:5]
        # full draw
        box = half - jnp.asarray(sp.margin, F32)
        r_f = box * u[5:7]
        th_f = np.float32(np.pi) * u[7]
        b_f = box * u[8:10]
        # interpolate
        r = (1 - d) * r_e + d * r_f
        th = wrap_angle(th_e + d * wrap_angle(th_f - th_e))
        b = (1 - d) * b_e + d * b_f
        # keep both inside the field, then separate ball from robot
        r = jnp.clip(r, -(half - rr), half - rr)
        lim_b = half - rb
        b = jnp.clip(b, -lim_b, lim_b)
        off = b - r
        dist = jnp.sqrt(jnp.sum(off * off))
        need = rr + rb + jnp.asarray(sp.min_gap, F32)
        heading = jnp.stack([jnp.cos(th), jnp.sin(th)])
        n = jnp.where(dist > 1e-6, off / jnp.maximum(dist, 1e-6), heading)
        b = jnp.where(dist < need, jnp.clip(r + need * n, -lim_b, lim_b), b)
        robots = jnp.concatenate([r, th[None]])[None, :]
        return WorldState(robots=robots, ball=b, ball_vel=jnp.zeros(2, F32),
                          scored=jnp.zeros((), bool), ball_out=jnp.zeros((), bool))

    def observer(self, params: ShootingParams) -> Observer:
        """The robot's camera: Section 2 features (9,) float32, analytic (``eps``: optional
        (SEC2_NOISE_DIM,) float32 standard normals of the pixel noise) or from its image of
        the ball and goal; no image noise in this task (its pixel noise is the analytic
        camera's)."""
        cam, wp = params.camera, params.world

        def features(state: ShootingState, eps: jax.Array | None) -> jax.Array:
            world = state.world
            return section2_features(world.robots[0], world.ball,
                                     jnp.asarray(wp.ball.radius, F32), goal_corners(wp), cam,
                                     eps)

        return Observer(
            features=features,
            image=lambda state: camera_image(state.world, 0, cam, wp, 0.0,
                                             params.pixels.render),
            from_image=lambda img, state: section2_from_image(img, state.world, cam, wp,
                                                              params.pixels))

    def transition_blocks(self, params: ShootingParams) -> tuple[tuple[int, bool], ...]:
        """The transition's draw blocks: tire slip (SLIP_NORMALS,)."""
        return ((SLIP_NORMALS, params.noise_on.slip),)

    def _fresh(self, words: jax.Array, params: ShootingParams) -> ShootingState:
        """A fresh episode's state from (START_WORDS,) uint32 random words."""
        return ShootingState(world=self.start_from_words(words, params),
                             step=jnp.zeros((), jnp.int32))

    def _transition(self, eps, state: ShootingState, action, params: ShootingParams):
        """One primitive; ``eps``: (tire slip,), (SLIP_NORMALS,) float32 standard normals or
        None (slip off)."""
        (slip_eps,) = eps
        world, events = world_step(state.world, jnp.reshape(action, (1,)).astype(jnp.int32),
                                   params.world, slip_eps=None if slip_eps is None else
                                   jnp.reshape(slip_eps, (1, 2)))
        step = state.step + 1
        terminated = events.goal | events.ball_out
        truncated = (step >= params.max_steps) & ~terminated
        reward = events.goal.astype(F32)
        info = dict(success=events.goal, ball_out=events.ball_out,
                    episode_done=terminated | truncated, episode_length=step)
        return ShootingState(world=world, step=step), reward, terminated, truncated, info
