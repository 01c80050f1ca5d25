"""Scripted behaviours of the other robots of Section 3 (pure JAX, 4-wheel steering).

Every behaviour is a pure function

    act(u, world, memory, me, params) -> (action () int32, memory)

of ``u``, (ACT_DRAWS,) float32 uniform draws in [0, 1) (see :mod:`vbl.draws`), the
:class:`vbl.world.WorldState`, the agent's small
:class:`AgentMemory` (the previous action, its step counter, whether it has kicked),
the agent's robot index ``me`` (a static Python int) and :class:`OtherAgentParams`.
Actions index :data:`vbl.world.FOUR_WHEEL_U` (0 stop, 1 F, 2 FL, 3 FR, 4 B, 5 BL, 6 BR).
:func:`act` dispatches on a static behaviour name from :data:`BEHAVIOURS`:

* ``"stationary"``: always stop (0).
* ``"random_walk"``: with probability ``walk_switch_prob`` draw a new uniformly random
  action, else repeat the previous one (``walk_switch_prob = 1``: i.i.d. actions).
* ``"move_to_ball"``: drive forward, steering towards the ball: bearing ``b`` of the ball
  centre in the robot frame; ``|b| <= steer_deadband_deg``: F, else FL (``b > 0``) or FR;
  stop when the centre distance is below ``stop_distance`` (0 = never stop).
* ``"passer"``: wait (stop) for ``memory.delay`` steps, then ``move_to_ball`` until it
  has kicked (``memory.kicked``, set by the environment, see
  :func:`vbl.envs.shoot_pass.apply_kicks`), then stop and wait. The kick itself (the ball
  sent towards the shooter at ``kick_speed``) is made by the environment.
* ``"waiter"``: the scripted shooter of the passing task: stop and wait.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from vbl.draws import uniform_index
from vbl.params import param
from vbl.world.physics import WorldState, wrap_angle

__all__ = ["BEHAVIOURS", "ACT_DRAWS", "MEMORY_DRAWS", "OtherAgentParams", "AgentMemory",
           "init_memory", "act", "act_by_id",
           "ball_bearing", "STOP", "FORWARD", "FORWARD_LEFT", "FORWARD_RIGHT"]

F32 = jnp.float32
I32 = jnp.int32

BEHAVIOURS = ("stationary", "random_walk", "move_to_ball", "passer", "waiter")

#: Indices into FOUR_WHEEL_U used by the controllers.
STOP, FORWARD, FORWARD_LEFT, FORWARD_RIGHT = 0, 1, 2, 3
NUM_ACTIONS = 7
#: Uniform draws one :func:`act` call takes (random walk: switch or not, the new action).
ACT_DRAWS = 2
#: Uniform draws :func:`init_memory` takes (the passer's delay, the first action).
MEMORY_DRAWS = 2


@struct.dataclass
class OtherAgentParams:
    """Parameters of the scripted behaviours (all traced)."""

    walk_switch_prob: float = param(1.0, doc="random walk: probability per step of drawing a "
                                    "new uniformly random action (1 = i.i.d. actions)",
                                    ge=0.0, le=1.0)
    steer_deadband_deg: float = param(10.0, doc="move-to-ball/passer: drive straight when the "
                                      "ball bearing is within +- this, else steer towards it",
                                      unit="deg", ge=0.0, le=180.0)
    stop_distance: float = param(0.0, doc="move-to-ball: stop when the robot-ball centre "
                                 "distance is below this (0 = never stop, keeps pushing)",
                                 unit="m", ge=0.0)
    kick_speed: float = param(1.6, doc="passer: speed the ball gets when the passer kicks it "
                              "towards the shooter", unit="m/s", ge=0.0)
    aim_noise_deg: float = param(5.0, doc="passer: std of the kick direction around the "
                                 "direction from the ball to the shooter", unit="deg", ge=0.0)
    max_delay: int = param(15, doc="passer: waits a uniform number of steps in [0, max_delay] "
                           "before approaching the ball (random pass timing)", ge=0)


@struct.dataclass
class AgentMemory:
    """Per-agent memory: previous action () int32, steps taken () int32, delay () int32
    (passer waiting time, steps), kicked () bool (the passer has kicked the ball)."""

    action: jax.Array
    t: jax.Array
    delay: jax.Array
    kicked: jax.Array


def init_memory(u: jax.Array, params: OtherAgentParams) -> AgentMemory:
    """Fresh memory: the passer delay uniformly in [0, max_delay] and a uniformly random
    first action from ``u``, (MEMORY_DRAWS,) float32 uniform draws in [0, 1)."""
    u = jnp.asarray(u, F32)
    delay = uniform_index(u[0], jnp.asarray(params.max_delay, I32) + 1)
    action = uniform_index(u[1], NUM_ACTIONS)
    return AgentMemory(action=action, t=jnp.zeros((), I32), delay=delay,
                       kicked=jnp.zeros((), bool))


def ball_bearing(world: WorldState, me: int) -> tuple[jax.Array, jax.Array]:
    """Bearing (rad, (-pi, pi], counter-clockwise from the heading) and centre distance (m)
    of the ball seen from robot ``me``."""
    pose = world.robots[me]
    d = world.ball - pose[:2]
    bearing = wrap_angle(jnp.arctan2(d[1], d[0]) - pose[2])
    return bearing.astype(F32), jnp.sqrt(jnp.sum(d * d)).astype(F32)


def _to_ball(world: WorldState, me: int, params: OtherAgentParams,
             use_stop: bool = True) -> jax.Array:
    bearing, dist = ball_bearing(world, me)
    dead = jnp.deg2rad(jnp.asarray(params.steer_deadband_deg, F32))
    a = jnp.where(jnp.abs(bearing) <= dead, FORWARD,
                  jnp.where(bearing > 0, FORWARD_LEFT, FORWARD_RIGHT))
    if not use_stop:
        return a.astype(I32)
    stop = jnp.asarray(params.stop_distance, F32)
    return jnp.where(dist < stop, STOP, a).astype(I32)


def act(behaviour: str, u: jax.Array, world: WorldState, memory: AgentMemory, me: int,
        params: OtherAgentParams) -> tuple[jax.Array, AgentMemory]:
    """Action () int32 of robot ``me`` under ``behaviour`` and the updated memory
    (``u``: (ACT_DRAWS,) float32 uniform draws in [0, 1), used by the random walk)."""
    if behaviour in ("stationary", "waiter"):
        a = jnp.asarray(STOP, I32)
    elif behaviour == "random_walk":
        u = jnp.asarray(u, F32)
        switch = u[0] < jnp.asarray(params.walk_switch_prob, F32)
        new = uniform_index(u[1], NUM_ACTIONS)
        a = jnp.where(switch, new, memory.action)
    elif behaviour == "move_to_ball":
        a = _to_ball(world, me, params)
    elif behaviour == "passer":
        a = jnp.where((memory.t < memory.delay) | memory.kicked, STOP,
                      _to_ball(world, me, params, use_stop=False))
    else:
        raise ValueError(f"unknown behaviour {behaviour!r}; choose one of {list(BEHAVIOURS)}")
    a = jnp.asarray(a, I32)
    return a, memory.replace(action=a, t=memory.t + 1)


def act_by_id(behaviour_id: jax.Array, u: jax.Array, world: WorldState, memory: AgentMemory,
              me: int, params: OtherAgentParams) -> tuple[jax.Array, AgentMemory]:
    """:func:`act` with a *traced* behaviour index into :data:`BEHAVIOURS` (() int32), so
    several behaviours run in one compiled computation (all are evaluated, one is kept)."""
    outs = [act(b, u, world, memory, me, params)[0] for b in BEHAVIOURS]
    a = jnp.stack(outs)[jnp.asarray(behaviour_id, I32)]
    return a, memory.replace(action=a, t=memory.t + 1)
