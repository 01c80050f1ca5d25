"""The shooting task of Section 2 as a gymnax-1.0-style functional environment.

One robot (two-motor by default), a ball and the goal in the +x end wall. The
robot sees the Section 2 feature vector (9,) float32 of its camera
(:func:`vbl.vision.features.section2_features`). Reward 1.0 when the ball enters
the goal, else 0. An episode ends on a goal (terminated), the ball leaving the
field (terminated; only possible with ``world.field.walls=False``), or after
``max_steps`` primitives (truncated).

Start distribution (``start_difficulty`` d in [0, 1], traced so a sweep or a
curriculum can move it): an *easy* draw puts the robot ``start.easy_goal_dist`` in
front of the goal centre facing it, the ball just in front of the robot, both
jittered by ``start.easy_jitter_*``; a *full* draw puts the robot and the ball
uniformly in the field (``start.margin`` from the walls) with a uniform heading.
The start is the interpolation ``(1 - d) * easy + d * full`` of positions and of the
heading (full heading taken relative to the easy one, in (-pi, pi]). If the ball
then overlaps the robot it is pushed radially to ``start.min_gap`` from it.

API::

    env = ShootingEnv()                         # static options
    params = env.default_params
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)
    state, eps = env.reset_state(key, params)   # the same without the observation:
    obs = env.get_obs(state, params, eps)       # reset == get_obs(reset_state)

``step`` auto-resets with a fresh start draw; ``step_env`` does not. ``reset_state`` /
``step_state`` are ``reset`` / ``step`` without the observation (the dynamics, the
auto-reset and every random draw; ``eps`` are the pixel noise's normals), so a loop that
observes inside its body (:func:`vbl.agents.cva_state.collect`, the brax adapter) holds
the camera once in its compiled program. Tire slip (``world.robot.slip_std``) and pixel noise
(``camera.pixel_noise_std``) are drawn only when switched on in the static
``params.noise_on`` (:class:`ShootingNoiseOn`; off by default, and a std above 0 with its
switch off is refused by validation, which ``jit`` with traced parameters skips).

``info``: ``success`` (goal this step), ``ball_out``, ``episode_done``, ``episode_length``
(primitives in the episode that just ended or is running, before the reset).

Errors: the constructor and :meth:`ShootingEnv.validate` check parameters
(:class:`vbl.params.ParamError`); ``reset``/``step`` called outside ``jit`` with
concrete values also check the parameters and the action (ValueError naming the
allowed range). Inside ``jit``/``vmap`` the checks are skipped (values are traced).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.draws import check_switched_off, draw_blocks, normals
from vbl.envs.checks import check_action_index
from vbl.params import ParamError, param, section, validate
from vbl.vision.camera import CameraParams
from vbl.vision.features import SEC2_DIM, SEC2_NOISE_DIM, section2_features
from vbl.world.params import ROBOT_KINDS, WorldParams
from vbl.world.physics import WorldState, goal_corners, world_step, wrap_angle
from vbl.world.robots import action_labels, num_actions

__all__ = ["StartParams", "ShootingNoiseOn", "ShootingParams", "ShootingState", "ShootingEnv"]

F32 = jnp.float32
#: Random draws of this env (slices of one hash per call, :class:`vbl.draws.Words`).
START_WORDS = 5  #: random words of a start draw (10 uniforms of 16 bits)
SLIP_NORMALS = 2  #: standard normals of one transition's tire slip (one robot)


@struct.dataclass
class StartParams:
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
class ShootingNoiseOn:
    """Static switches of the task's random noise sources. A source that is off draws no
    random numbers and computes nothing (its std must then be 0); one that is on draws them
    whatever its std, so a sweep over the std (0 included) is one compiled program. The
    draws of a source are the same whichever other sources are on
    (:func:`vbl.draws.draw_blocks`)."""

    slip: bool = param(False, doc="tire slip is drawn (world.robot.slip_std; off: it must "
                       "be 0)", static=True)
    pixel: bool = param(False, doc="pixel noise is drawn (camera.pixel_noise_std; off: it "
                        "must be 0)", static=True)


@struct.dataclass
class ShootingParams:
    """Parameters of the shooting task."""

    world: WorldParams = section(WorldParams, doc="physics")
    camera: CameraParams = section(CameraParams, doc="robot camera")
    start: StartParams = section(StartParams, doc="start distribution")
    start_difficulty: float = param(1.0, doc="start distribution: 0 easy (near the goal, "
                                    "ball in front), 1 full random; interpolated between",
                                    ge=0.0, le=1.0)
    max_steps: int = param(300, doc="time limit: action primitives per episode (each "
                           "world.action_dt long; the library default 300 is 30 s)",
                           unit="primitives", static=True, ge=1)
    noise_on: ShootingNoiseOn = section(ShootingNoiseOn, doc="static switches of the random "
                                        "noise sources")

    def check(self) -> None:
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


def _is_traced(tree: Any) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(tree))


class ShootingEnv:
    """Shooting task: drive the ball into the goal (Section 2).

    Args:
      robot_kind: "two_motor" (Section 2, 9 actions, default) or "four_wheel" (7 actions).
      params: default parameters (validated); ``None`` uses the defaults.
    """

    def __init__(self, robot_kind: str = "two_motor", params: ShootingParams | None = None):
        if robot_kind not in ROBOT_KINDS:
            raise ValueError(f"robot_kind={robot_kind!r} is not allowed; choose one of "
                             f"{list(ROBOT_KINDS)}")
        self.robot_kind = robot_kind
        if params is None:
            params = ShootingParams()
            params = params.replace(world=params.world.replace(robot_kinds=(robot_kind,)))
        self._default_params = self.validate(params)

    # ------------------------------------------------------------------ metadata
    @property
    def default_params(self) -> ShootingParams:
        return self._default_params

    @property
    def num_actions(self) -> int:
        """Number of discrete action primitives (9 two-motor, 7 four-wheel)."""
        return num_actions(self.robot_kind)

    @property
    def action_labels(self) -> tuple[str, ...]:
        return action_labels(self.robot_kind)

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (SEC2_DIM,)

    @property
    def name(self) -> str:
        return "Shooting-" + self.robot_kind

    # ------------------------------------------------------------------ checks
    def validate(self, params: ShootingParams) -> ShootingParams:
        """Check parameter types, bounds and consistency; raise ParamError. Returns params."""
        if not isinstance(params, ShootingParams):
            raise ParamError(f"params must be ShootingParams, got {type(params).__name__}")
        validate(params)  # fields and every section's check() rule
        if params.world.robot_kinds != (self.robot_kind,):
            raise ParamError(f"world.robot_kinds={params.world.robot_kinds!r} must be "
                             f"({self.robot_kind!r},) for this {self.name} env")
        return params

    def check_action(self, action: Any) -> None:
        """Raise ValueError unless ``action`` is a () integer in [0, num_actions)."""
        check_action_index(action, self.num_actions, self.name, self.action_labels)

    def _check_state(self, state: ShootingState) -> None:
        if not isinstance(state, ShootingState):
            raise ValueError(f"state must be ShootingState, got {type(state).__name__}")
        if np.shape(state.world.robots) != (1, 3) or np.shape(state.world.ball) != (2,):
            raise ValueError(f"state has robots {np.shape(state.world.robots)} / ball "
                             f"{np.shape(state.world.ball)}; expected (1, 3) / (2,) (one env; "
                             "vmap for a batch)")

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

    def get_obs(self, state: ShootingState, params: ShootingParams,
                eps: jax.Array | None = None) -> jax.Array:
        """Section 2 features (9,) float32 of the robot's camera in ``state``; ``eps``:
        optional (SEC2_NOISE_DIM,) float32 standard normals of the pixel noise (None =
        exact, what ``noise_on.pixel`` off gives)."""
        world = state.world
        return section2_features(world.robots[0], world.ball,
                                 jnp.asarray(params.world.ball.radius, F32),
                                 goal_corners(params.world), params.camera, eps)

    def reset_state(self, key: jax.Array, params: ShootingParams | None = None
                    ) -> tuple[ShootingState, jax.Array | None]:
        """:meth:`reset` without the observation: (state, eps), where ``get_obs(state,
        params, eps)`` is the obs :meth:`reset` returns (``eps``: the pixel noise's
        (SEC2_NOISE_DIM,) standard normals, None when off). A loop that observes inside its
        body then holds the camera once in its compiled program."""
        params = self._default_params if params is None else params
        if not _is_traced(params):
            self.validate(params)
        start, pixel = draw_blocks(key, START_WORDS, (SEC2_NOISE_DIM, params.noise_on.pixel))
        state = ShootingState(world=self.start_from_words(start, params),
                              step=jnp.zeros((), jnp.int32))
        return state, normals(pixel)

    def reset(self, key: jax.Array, params: ShootingParams | None = None
              ) -> tuple[jax.Array, ShootingState]:
        """Fresh episode: (obs (9,) float32, state)."""
        params = self._default_params if params is None else params
        state, eps = self.reset_state(key, params)
        return self.get_obs(state, params, eps), state

    def _transition(self, slip_eps, state: ShootingState, action, params: ShootingParams):
        """One primitive; ``slip_eps``: (SLIP_NORMALS,) float32 standard normals of the tire
        slip, or None (slip off)."""
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

    def _check_inputs(self, state, action, params):
        if not _is_traced((action, state)):
            self.check_action(action)
            self._check_state(state)
        if not _is_traced(params):
            self.validate(params)

    def step_env(self, key: jax.Array, state: ShootingState, action: jax.Array,
                 params: ShootingParams | None = None):
        """One primitive without auto-reset: (obs, state, reward, terminated, truncated, info)."""
        params = self._default_params if params is None else params
        self._check_inputs(state, action, params)
        on = params.noise_on
        slip, pixel = draw_blocks(key, (SLIP_NORMALS, on.slip), (SEC2_NOISE_DIM, on.pixel))
        state, reward, terminated, truncated, info = self._transition(
            normals(slip), state, action, params)
        obs = self.get_obs(state, params, normals(pixel))
        return obs, state, reward, terminated, truncated, info

    def step_state(self, key: jax.Array, state: ShootingState, action: jax.Array,
                   params: ShootingParams | None = None):
        """:meth:`step` without the observation: (state, eps, reward, terminated,
        truncated, info), where ``get_obs(state, params, eps)`` is the obs :meth:`step`
        returns (see :meth:`reset_state`). The auto-reset selects the state, so the
        observation is computed once, from the selected state."""
        params = self._default_params if params is None else params
        self._check_inputs(state, action, params)
        on = params.noise_on
        slip, start, pixel = draw_blocks(key, (SLIP_NORMALS, on.slip), START_WORDS,
                                         (SEC2_NOISE_DIM, on.pixel))
        nstate, reward, terminated, truncated, info = self._transition(
            normals(slip), state, action, params)
        done = info["episode_done"]
        fresh = ShootingState(world=self.start_from_words(start, params),
                              step=jnp.zeros((), jnp.int32))
        nstate = jax.tree_util.tree_map(lambda a, b: jnp.where(done, a, b), fresh, nstate)
        return nstate, normals(pixel), reward, terminated, truncated, info

    def step(self, key: jax.Array, state: ShootingState, action: jax.Array,
             params: ShootingParams | None = None):
        """One primitive with auto-reset (fresh start draw when the episode ended).

        Returns (obs (9,) float32, state, reward () float32, terminated () bool,
        truncated () bool, info dict); obs is the first observation of the new episode
        when it reset, while reward/terminated/truncated/info describe the finished step.
        The key is hashed once: tire slip, the start draw and the pixel noise are blocks of
        those bits (:func:`vbl.draws.draw_blocks`; a noise source switched off in
        ``params.noise_on`` is not drawn).
        """
        params = self._default_params if params is None else params
        nstate, eps, reward, terminated, truncated, info = self.step_state(key, state, action,
                                                                          params)
        return self.get_obs(nstate, params, eps), nstate, reward, terminated, truncated, info

    def __repr__(self) -> str:
        fields = [f.name for f in dataclasses.fields(ShootingParams)]
        return f"ShootingEnv(robot_kind={self.robot_kind!r}, params={fields})"
