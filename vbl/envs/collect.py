"""Batched identification-data collection (Section 3.1, step 1 of Figure 11).

A learner (robot 0, 4-wheel steering, the observer) moves with random actions that keep
its ``focus`` object in view while its camera observes the goal, the ball and another
robot (a scripted behaviour of :mod:`vbl.envs.other_agents`); an invisible third party
kicks the ball through the view. One data set is the motor commands ``u(t) =
FOUR_WHEEL_U[a(t)]`` (N, 2) and the Section 3 features of each object (ball (N, 4), goal
(N, 11), other robot (N, 5), in px / px^2), ``y(t)`` observed before ``u(t)`` is applied;
:func:`collect` vmaps a ``lax.scan`` over B data sets. The features are analytic or from
the rendered camera image (``obs_source``).

See docs/two_robot_task.md, "Identification data" (the observer's policy, the kicks) and
docs/render.md, "Pixel observations".
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.draws import Words, normal, uniform01, uniform_index
from vbl.envs.noise import NoiseParams, advance_phase, noisy_world, perturb_ball_velocity
from vbl.envs.other_agents import (
    ACT_DRAWS,
    BEHAVIOURS,
    MEMORY_DRAWS,
    OtherAgentParams,
    act_by_id,
    init_memory,
)
from vbl.envs.pixels import (
    OBS_SOURCES,
    PixelObsParams,
    check_obs_source,
    image_noise_shape,
    section3_pixels,
)
from vbl.envs.shoot_pass import OBS_SLICES, default_world, observe
from vbl.params import ParamError, param, section, validate
from vbl.vision.camera import CameraParams
from vbl.vision.section3 import SEC3_NOISE_DIM
from vbl.world.params import WorldParams
from vbl.world.physics import WorldState, world_step, wrap_angle
from vbl.world.robots import FOUR_WHEEL_U

__all__ = ["FOCUS", "OTHER_BEHAVIOURS", "CollectParams", "CollectData", "collect_one",
           "collect_scenarios", "collect", "collect_many", "observer_action", "id_outputs",
           "object_outputs", "AREA_COLUMN", "PIXEL_STREAM"]

F32 = jnp.float32
I32 = jnp.int32

FOCUS = ("goal", "ball", "other")
OTHER_BEHAVIOURS = ("stationary", "random_walk", "move_to_ball")

#: Random draws of one data set: the start (6 uniforms and the other robot's memory), then
#: per step (one row of random words per step, :class:`vbl.draws.Words`): pixel noise,
#: the observer's action, the other robot's action, tire slip (2 robots x 2), the kick
#: (4 uniforms), eccentric rolling.
START_DRAWS = 6 + MEMORY_DRAWS
STEP_WORDS = SEC3_NOISE_DIM + 1 + ACT_DRAWS + 4 + 4 + 1
#: ``fold_in`` data of the image-noise key of pixel observations (a stream of its own).
PIXEL_STREAM = 0x706978


@struct.dataclass
class CollectParams:
    """What one identification run looks like (robot 0 observes, robot 1 is scripted)."""

    world: WorldParams = section(default_world, doc="physics; world.four_wheel is the "
                                 "observer's body (and the other robot's)")
    camera: CameraParams = section(CameraParams, doc="the observer's camera")
    noise: NoiseParams = section(NoiseParams, doc="Section 3.4.2 noise model (default off)")
    other: OtherAgentParams = section(OtherAgentParams, doc="the scripted other robot")
    other_behaviour: str = param("random_walk", doc="behaviour of the other robot",
                                 static=True, choices=OTHER_BEHAVIOURS)
    focus: str = param("goal", doc="object the observer keeps in view", static=True,
                       choices=FOCUS)
    num_steps: int = param(500, doc="N: samples per data set", static=True, ge=2)
    keep_bearing_deg: float = param(20.0, doc="observer turns towards the focus object when "
                                    "its bearing exceeds this", unit="deg", gt=0.0, le=180.0)
    min_dist: float = param(0.8, doc="observer does not drive forward when the focus centre "
                            "is closer than this", unit="m", ge=0.0)
    max_dist: float = param(2.5, doc="observer does not drive backward when the focus centre "
                            "is farther than this", unit="m", gt=0.0)
    start_x_min: float = param(-0.5, doc="observer start x range, lower end", unit="m")
    start_x_max: float = param(1.5, doc="observer start x range, upper end", unit="m")
    start_y_max: float = param(1.0, doc="observer start range of abs(y)", unit="m", ge=0.0)
    start_jitter_deg: float = param(10.0, doc="observer start heading: towards the focus "
                                    "+- this", unit="deg", ge=0.0, le=180.0)
    other_dist_min: float = param(1.2, doc="other robot start distance ahead of the observer,"
                                  " lower end", unit="m", gt=0.0)
    other_dist_max: float = param(2.0, doc="same, upper end", unit="m", gt=0.0)
    other_bearing_deg: float = param(20.0, doc="other robot start bearing from the observer "
                                     "heading, uniform +- this", unit="deg", ge=0.0, le=180.0)
    ball_dist: float = param(1.2, doc="ball start distance ahead of the observer", unit="m",
                             gt=0.0)
    kick_prob: float = param(0.1, doc="probability per step of a kick of a slow ball",
                             ge=0.0, le=1.0)
    kick_below_speed: float = param(0.2, doc="only a ball slower than this is kicked",
                                    unit="m/s", ge=0.0)
    kick_speed_min: float = param(0.4, doc="kick speed, lower end", unit="m/s", ge=0.0)
    kick_speed_max: float = param(1.0, doc="kick speed, upper end", unit="m/s", ge=0.0)
    aim_ahead: float = param(1.2, doc="kicks aim around this point ahead of the observer",
                             unit="m", ge=0.0)
    aim_radius: float = param(0.8, doc="radius of the disc of kick aim points", unit="m",
                              ge=0.0)
    robot_height: float = param(0.3, doc="height of the other robot's body", unit="m", gt=0.0)
    obs_source: str = param("analytic", doc="features from the analytic camera, or from the "
                            "rendered image (with noise.pixel_std) through the colour-blob "
                            "detector (vbl.envs.pixels)", static=True, choices=OBS_SOURCES)
    pixels: PixelObsParams = section(PixelObsParams, doc="image size and blob thresholds of "
                                     "obs_source='pixels'")

    def check(self) -> None:
        check_obs_source(self.obs_source, {
            "noise.image_std": self.noise.image_std,
            "camera.pixel_noise_std": self.camera.pixel_noise_std},
            {"noise.pixel_std": self.noise.pixel_std})
        for lo, hi in (("start_x_min", "start_x_max"), ("other_dist_min", "other_dist_max"),
                       ("kick_speed_min", "kick_speed_max"), ("min_dist", "max_dist")):
            if np.any(np.asarray(getattr(self, lo)) > np.asarray(getattr(self, hi))):
                raise ParamError(f"{lo}={getattr(self, lo)} must be <= {hi}={getattr(self, hi)}")
        if self.world.robot_kinds != ("four_wheel", "four_wheel"):
            raise ParamError(f"world.robot_kinds={self.world.robot_kinds!r} must be "
                             "('four_wheel', 'four_wheel') (observer, other)")


@struct.dataclass
class CollectData:
    """One data set (leading (B,) axis when batched), float32, time axis N.

    u (N, 2) motor commands [v, phi]; ball (N, 4), goal (N, 11), other (N, 5) features
    (px, px^2); visible (N, 3) flags (ball, goal, other)."""

    u: jax.Array
    ball: jax.Array
    goal: jax.Array
    other: jax.Array
    visible: jax.Array

    def y(self, obj: str) -> jax.Array:
        """Features of ``obj`` in ("goal", "ball", "other")."""
        if obj not in FOCUS:
            raise ValueError(f"object {obj!r} unknown; choose one of {list(FOCUS)}")
        return getattr(self, obj)


def _focus_point(world: WorldState, params: CollectParams, focus_id: jax.Array) -> jax.Array:
    goal = jnp.stack([jnp.asarray(params.world.field.length, F32) / 2, jnp.zeros((), F32)])
    pts = jnp.stack([goal, world.ball, world.robots[1, :2]])
    return pts[jnp.asarray(focus_id, I32)]


def _ids(params: CollectParams) -> tuple[jax.Array, jax.Array]:
    return (jnp.asarray(BEHAVIOURS.index(params.other_behaviour), I32),
            jnp.asarray(FOCUS.index(params.focus), I32))


def observer_action(u: jax.Array, world: WorldState, params: CollectParams,
                    focus_id: jax.Array | None = None) -> jax.Array:
    """The observer's random view-keeping action () int32 (see the module docstring), drawn
    uniformly among the allowed actions with ``u``, a () uniform draw in [0, 1);
    ``focus_id`` (traced index into :data:`FOCUS`) overrides ``params.focus``."""
    if focus_id is None:
        focus_id = _ids(params)[1]
    pose = world.robots[0]
    d = _focus_point(world, params, focus_id) - pose[:2]
    b = wrap_angle(jnp.arctan2(d[1], d[0]) - pose[2])
    dist = jnp.sqrt(jnp.sum(d * d))
    tab = jnp.asarray(FOUR_WHEEL_U, I32)
    v, turn = tab[:, 0], tab[:, 0] * tab[:, 1]
    lim = jnp.deg2rad(jnp.asarray(params.keep_bearing_deg, F32))
    ok = jnp.where(b > lim, turn > 0, jnp.where(b < -lim, turn < 0, True))
    ok = ok & jnp.where(dist > jnp.asarray(params.max_dist, F32), v >= 0, True)
    ok = ok & jnp.where(dist < jnp.asarray(params.min_dist, F32), v <= 0, True)
    ok = jnp.where(jnp.any(ok), ok, True)
    n_ok = jnp.sum(ok.astype(I32))
    k = uniform_index(u, n_ok)
    return jnp.argmax(ok & (jnp.cumsum(ok.astype(I32)) == k + 1)).astype(I32)


def _start(u: jax.Array, params: CollectParams) -> WorldState:
    """Start world from (6,) uniform draws in [0, 1)."""
    half = jnp.stack([jnp.asarray(params.world.field.length, F32),
                      jnp.asarray(params.world.field.width, F32)]) / 2
    lim = half - jnp.asarray(params.world.robot.radius, F32) - 0.05
    xy = jnp.stack([params.start_x_min + (params.start_x_max - params.start_x_min) * u[0],
                    params.start_y_max * (2 * u[1] - 1)]).astype(F32)
    goal = jnp.stack([half[0], jnp.zeros((), F32)])
    th = jnp.arctan2(goal[1] - xy[1], goal[0] - xy[0]) + jnp.deg2rad(
        jnp.asarray(params.start_jitter_deg, F32)) * (2 * u[2] - 1)
    od = params.other_dist_min + (params.other_dist_max - params.other_dist_min) * u[3]
    ob = th + jnp.deg2rad(jnp.asarray(params.other_bearing_deg, F32)) * (2 * u[4] - 1)
    oxy = jnp.clip(xy + od * jnp.stack([jnp.cos(ob), jnp.sin(ob)]), -lim, lim)
    oth = jnp.pi * (2 * u[5] - 1)
    bd = jnp.asarray(params.ball_dist, F32)
    bxy = jnp.clip(xy + bd * jnp.stack([jnp.cos(th), jnp.sin(th)]), -lim, lim)
    robots = jnp.stack([jnp.concatenate([xy, th[None]]),
                        jnp.concatenate([oxy, jnp.reshape(oth, (1,))])]).astype(F32)
    return WorldState(robots=robots, ball=bxy.astype(F32), ball_vel=jnp.zeros(2, F32),
                      scored=jnp.zeros((), bool), ball_out=jnp.zeros((), bool))


def _kick(u: jax.Array, world: WorldState, params: CollectParams) -> WorldState:
    """A random kick from (4,) uniform draws in [0, 1): [kick or not, speed, aim radius,
    aim angle]."""
    speed = jnp.sqrt(jnp.sum(world.ball_vel ** 2))
    go = (speed < jnp.asarray(params.kick_below_speed, F32)) & (
        u[0] < jnp.asarray(params.kick_prob, F32))
    pose = world.robots[0]
    head = jnp.stack([jnp.cos(pose[2]), jnp.sin(pose[2])])
    r = jnp.asarray(params.aim_radius, F32) * jnp.sqrt(u[2])
    a = 2 * jnp.pi * u[3]
    target = pose[:2] + jnp.asarray(params.aim_ahead, F32) * head + r * jnp.stack(
        [jnp.cos(a), jnp.sin(a)])
    d = target - world.ball
    n = d / jnp.maximum(jnp.sqrt(jnp.sum(d * d)), 1e-6)
    s = params.kick_speed_min + (params.kick_speed_max - params.kick_speed_min) * u[1]
    vel = jnp.where(go, s * n, world.ball_vel).astype(F32)
    return world.replace(ball_vel=vel)


def _net(world: WorldState, params: CollectParams) -> WorldState:
    """No goals while collecting: a ball past the goal line bounces back off the net."""
    edge = jnp.asarray(params.world.field.length, F32) / 2 - jnp.asarray(
        params.world.ball.radius, F32)
    out = world.ball[0] > edge
    ball = jnp.where(out, jnp.stack([edge, world.ball[1]]), world.ball)
    vel = jnp.where(out, world.ball_vel * jnp.array([-0.5, 1.0], F32), world.ball_vel)
    return world.replace(ball=ball.astype(F32), ball_vel=vel.astype(F32),
                         scored=jnp.zeros((), bool), ball_out=jnp.zeros((), bool))


def collect_one(key: jax.Array, params: CollectParams, behaviour_id: jax.Array | None = None,
                focus_id: jax.Array | None = None) -> CollectData:
    """One data set of ``params.num_steps`` samples (pure; jit/vmap-able).

    ``behaviour_id`` (index into :data:`vbl.envs.other_agents.BEHAVIOURS`) and ``focus_id``
    (index into :data:`FOCUS`), when given as traced () int32, override the static
    ``params.other_behaviour`` / ``params.focus`` (one compilation serves every scenario).
    """
    b_id, f_id = _ids(params)
    behaviour_id = b_id if behaviour_id is None else behaviour_id
    focus_id = f_id if focus_id is None else focus_id
    k_start, k_run = jax.random.split(key)
    u0 = jax.random.uniform(k_start, (START_DRAWS,), F32)
    world0 = _start(u0[:6], params)
    mem0 = init_memory(u0[6:], params.other)
    wp = noisy_world(params.world, params.noise)
    rb = jnp.asarray(params.world.ball.radius, F32)
    pixels = params.obs_source == "pixels"

    def body(carry, xs):
        world, mem, phase = carry
        words, k_img = xs
        w = Words(words)
        eps = normal(w.take(SEC3_NOISE_DIM))
        if pixels:
            img_eps = jax.random.normal(k_img, image_noise_shape(params.pixels), F32)
            y = section3_pixels(world, 0, params.camera, params.world, params.noise,
                                params.robot_height, phase, params.pixels, img_eps)
        else:
            y = observe(world, 0, params.camera, params.world, params.noise,
                        params.robot_height, phase, eps)
        a_me = observer_action(uniform01(w.take(1))[0], world, params, focus_id)
        a_other, mem = act_by_id(behaviour_id, uniform01(w.take(ACT_DRAWS)), world, mem, 1,
                                 params.other)
        new, _ = world_step(world, jnp.stack([a_me, a_other]), wp,
                            slip_eps=normal(w.take(4)).reshape(2, 2))
        new = _net(new, params)
        rolled = jnp.sqrt(jnp.sum((new.ball - world.ball) ** 2))
        u_kick = uniform01(w.take(4))
        new = new.replace(ball_vel=perturb_ball_velocity(normal(w.take(1))[0], new.ball_vel,
                                                         rolled, rb, params.noise))
        w.done()
        phase = advance_phase(phase, world.ball, new.ball, rb)
        new = _kick(u_kick, new, params)
        u = jnp.asarray(FOUR_WHEEL_U, F32)[a_me]
        return (new, mem, phase), (u, y)

    n = params.num_steps
    k_img = (jax.random.split(jax.random.fold_in(key, PIXEL_STREAM), n) if pixels
             else jnp.zeros((n,), jnp.uint32))
    _, (u, y) = jax.lax.scan(body, (world0, mem0, jnp.zeros((), F32)),
                             (jax.random.bits(k_run, (n, STEP_WORDS), jnp.uint32), k_img))
    return CollectData(u=u, ball=y[:, OBS_SLICES["ball"]], goal=y[:, OBS_SLICES["goal"]],
                       other=y[:, OBS_SLICES["other"]], visible=y[:, OBS_SLICES["visible"]])


@jax.jit
def _collect_jit(keys, params, behaviour_ids, focus_ids):
    """keys (S, B, 2); params with a leading (S,) axis on traced leaves; ids (S,)."""
    per_set = jax.vmap(collect_one, in_axes=(0, None, None, None))
    return jax.vmap(per_set, in_axes=(0, 0, 0, 0))(keys, params, behaviour_ids, focus_ids)


def _canonical(scenarios, check: bool) -> list[CollectParams]:
    """``scenarios`` with other_behaviour/focus set to one value (they travel as traced ids),
    so that they stack; ``check``: validate each (concrete values only). ParamError when a
    scenario is not CollectParams or differs from the first in another static field."""
    canon = []
    for i, sc in enumerate(scenarios):
        if not isinstance(sc, CollectParams):
            raise ParamError(f"scenarios[{i}] must be CollectParams, got {type(sc).__name__}")
        if check:
            validate(sc)
        canon.append(sc.replace(other_behaviour="random_walk", focus="goal"))
    struct0 = jax.tree_util.tree_structure(canon[0])
    for i, c in enumerate(canon[1:], 1):
        if jax.tree_util.tree_structure(c) != struct0:
            raise ParamError(f"scenarios[{i}] differs from scenarios[0] in a static field "
                             "other than other_behaviour/focus (e.g. num_steps); collect them "
                             "separately")
    return canon


def _stack(canon: list[CollectParams]) -> CollectParams:
    """Canonical scenarios (:func:`_canonical`) as one params tree with a leading (S,) axis."""
    return jax.tree_util.tree_map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *canon)


def collect_scenarios(key: jax.Array, scenarios: list[CollectParams]) -> CollectData:
    """One data set per scenario (leading (S,) axis): scenario ``s`` is
    ``collect_one(fold_in(key, s), scenarios[s])`` (pure; jit/vmap-able: one learner's data
    sets inside an engine program, :mod:`vbl.programs.identification`).

    The scenarios may hold traced values and differ in any of them and in
    ``other_behaviour`` / ``focus`` (traced ids: one trace of :func:`collect_one` serves
    every scenario); other static fields must be equal (ParamError). Not validated here
    (values may be traced): validate concrete scenarios first.
    """
    if not scenarios:
        raise ValueError("scenarios must be a non-empty list of CollectParams")
    canon = _canonical(scenarios, check=False)
    stacked = _stack(canon)
    ids = jnp.asarray([_ids(sc) for sc in scenarios], I32)            # (S, 2)
    keys = jax.vmap(lambda s: jax.random.fold_in(key, s))(jnp.arange(len(canon)))
    return jax.vmap(collect_one)(keys, stacked, ids[:, 0], ids[:, 1])


def _check_batch(batch) -> int:
    if not isinstance(batch, int | np.integer) or isinstance(batch, bool) or batch < 1:
        raise ValueError(f"batch must be an int >= 1, got {batch!r}")
    return int(batch)


COLLECT_GROUP = 4  #: scenarios per compiled collection call (see :func:`collect_many`)


def collect_many(key: jax.Array, scenarios: list[CollectParams], batch: int,
                 group: int = COLLECT_GROUP) -> list[CollectData]:
    """B = ``batch`` data sets for each of S scenarios, ``group`` scenarios per call of one
    compiled computation.

    The scenarios may differ in any traced value (cameras, bodies, noise, ...) and in
    ``other_behaviour`` / ``focus``; every other static field (``num_steps``,
    ``world.robot_kinds``, ...) must be equal. Scenario s uses keys
    ``split(fold_in(key, s), batch)`` whatever the grouping, so the data do not depend on
    ``group``. A fixed group size (the last group padded with copies of its last scenario)
    lets callers with different S share one compiled program (and the persistent
    compilation cache). The data sets of one learner inside a program are
    :func:`collect_scenarios`'s (other keys). Returns one
    :class:`CollectData` (leading (B,) axis) per scenario. Validates every scenario
    (ParamError).
    """
    batch = _check_batch(batch)
    if not isinstance(group, int) or isinstance(group, bool) or group < 1:
        raise ValueError(f"group must be an int >= 1, got {group!r}")
    if not scenarios:
        raise ValueError("scenarios must be a non-empty list of CollectParams")
    canon = _canonical(scenarios, check=True)
    n = len(scenarios)
    ids = [_ids(sc) for sc in scenarios]
    keys = [jax.random.split(jax.random.fold_in(key, s), batch) for s in range(n)]
    size = min(group, n)
    pad = -n % size
    canon, ids, keys = canon + canon[-1:] * pad, ids + ids[-1:] * pad, keys + keys[-1:] * pad
    result = []
    for g0 in range(0, n + pad, size):
        sl = slice(g0, g0 + size)
        out = _collect_jit(jnp.stack(keys[sl]), _stack(canon[sl]),
                           jnp.stack([i[0] for i in ids[sl]]), jnp.stack([i[1] for i in ids[sl]]))
        result += [jax.tree_util.tree_map(lambda x, s=s: x[s], out) for s in range(size)]
    return result[:n]


def collect(key: jax.Array, params: CollectParams, batch: int) -> CollectData:
    """B = ``batch`` independent data sets: u (B, N, 2), ball (B, N, 4), goal (B, N, 11),
    other (B, N, 5), visible (B, N, 3), float32. Validates ``params`` (ParamError).
    Equals ``collect_many(key, [params], batch)[0]``."""
    if not isinstance(params, CollectParams):
        raise ParamError(f"params must be CollectParams, got {type(params).__name__}")
    return collect_many(key, [params], batch)[0]


#: Column of the visible-area feature (px^2) of each object, or None.
AREA_COLUMN = {"ball": None, "goal": 10, "other": 4}


def id_outputs(data: CollectData, obj: str, y_unit: float) -> np.ndarray:
    """Identification outputs (B, N, q) float64 of ``obj`` in units of ``y_unit`` px.

    Areas (px^2) become side lengths ``sqrt(area)`` (px) first, so every channel is in px
    and one unit makes ``log det R`` comparable between objects (``log det R < 0`` means
    a geometric-mean residual below ``y_unit`` px).
    """
    if not y_unit > 0:
        raise ValueError(f"y_unit={y_unit!r} must be > 0 (px)")
    return object_outputs(np.asarray(data.y(obj), np.float64), obj, float(y_unit))


def object_outputs(y, obj: str, y_unit):
    """:func:`id_outputs` of the features ``y (..., q)`` of ``obj`` (no checks): the area
    column as ``sqrt(area)``, every channel divided by ``y_unit`` (px). NumPy in, NumPy out;
    a JAX array in, a JAX array out (pure, jit/vmap-able; ``y_unit`` may be traced)."""
    xp = np if isinstance(y, np.ndarray) else jnp
    col = AREA_COLUMN[obj]
    if col is not None:
        side = xp.sqrt(xp.maximum(y[..., col:col + 1], 0.0))
        y = xp.concatenate([y[..., :col], side, y[..., col + 1:]], axis=-1)
    return y / y_unit
