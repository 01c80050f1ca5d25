"""Soccer-world physics in pure JAX: robots, ball, walls, goal (equations in docs/world.md).

One call of :func:`world_step` advances one action primitive (``params.action_dt``)
in ``params.substeps`` equal sub-steps of length ``h``. Each sub-step, in order:

1. robots move with their commanded twist ``(v, omega)`` (midpoint heading),
2. robots are kept inside the field (disc of ``robot.radius`` clamped to the walls),
3. overlapping robot pairs are pushed apart symmetrically along their centre line,
4. robot-ball contact: the ball is pushed out of each touching robot (in robot
   order) and, if approaching, gets the impulse ``dv = -(1 + e_kick) (v_rel . n) n``
   from the robot's velocity (robots are infinitely heavy),
5. friction: speed ``s -> max(s - (rolling_decel + drag * s) h, 0)`` (capped at
   ``max_speed`` first), then the ball moves ``x += v h``,
6. walls (when ``field.walls``): reflection with restitution ``e_wall``; the +x end
   wall is open in the goal mouth, and a ball centre beyond the wall contact plane
   is kept inside the mouth by its posts,
7. goal: the ball centre crosses ``x = L/2`` with ``|y| <= goal.width / 2``; the ball
   then stays in the net (frozen) and ``scored`` latches, so a goal counts once.

:func:`kick_velocity` is the kick law a task applies when a robot kicks (its kicking face
moves along the heading; ``ball.kick_restitution``): the incoming velocity's
component across the heading is kept, the one along it is reflected off the moving face.

All arrays are float32 (int32 / bool for flags); the functions are jit/vmap-able.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.world.params import WorldParams
from vbl.world.robots import FOUR_WHEEL_U, TWO_MOTOR_MOTORS, num_actions

__all__ = [
    "WorldState",
    "WorldEvents",
    "make_state",
    "world_step",
    "goal_corners",
    "robot_commands",
    "wrap_angle",
    "kick_velocity",
]

F32 = jnp.float32


@struct.dataclass
class WorldState:
    """State of the world with R robots (R = len(params.robot_kinds)).

    robots: (R, 3) float32 poses (x, y, theta) [m, m, rad]; ball: (2,) float32 [m];
    ball_vel: (2,) float32 [m/s]; scored: () bool, the ball is in the goal;
    ball_out: () bool, the ball has left the field (walls off only).
    """

    robots: jax.Array
    ball: jax.Array
    ball_vel: jax.Array
    scored: jax.Array
    ball_out: jax.Array


@struct.dataclass
class WorldEvents:
    """What happened during one primitive: goal () bool (the ball entered the goal;
    true once per goal), ball_out () bool (left the field this primitive), touch (R,) bool
    (robot touched the ball)."""

    goal: jax.Array
    ball_out: jax.Array
    touch: jax.Array


def wrap_angle(theta: jax.Array) -> jax.Array:
    """Wrap angles to (-pi, pi]."""
    pi = jnp.asarray(np.pi, theta.dtype)
    return pi - jnp.mod(pi - theta, 2 * pi)


def make_state(robots, ball, ball_vel=None) -> WorldState:
    """A float32 WorldState from robot poses (R, 3) and ball position (2,) (velocity 0)."""
    robots = jnp.asarray(robots, F32)
    ball = jnp.asarray(ball, F32)
    if robots.ndim != 2 or robots.shape[-1] != 3:
        raise ValueError(f"robots must have shape (R, 3), got {robots.shape}")
    if ball.shape != (2,):
        raise ValueError(f"ball must have shape (2,), got {ball.shape}")
    vel = jnp.zeros(2, F32) if ball_vel is None else jnp.asarray(ball_vel, F32)
    return WorldState(robots=robots.at[:, 2].set(wrap_angle(robots[:, 2])), ball=ball,
                      ball_vel=vel, scored=jnp.zeros((), bool), ball_out=jnp.zeros((), bool))


def goal_corners(params: WorldParams) -> jax.Array:
    """(4, 3) float32 goal corners: left-bottom, left-top, right-top, right-bottom.

    "left" is the +y post (seen by a robot facing +x); the goal line is x = L/2.
    """
    x = jnp.asarray(params.field.length, F32) / 2
    w = jnp.asarray(params.goal.width, F32) / 2
    hgt = jnp.asarray(params.goal.height, F32)
    z0 = jnp.zeros((), F32)
    return jnp.stack([jnp.stack([x, w, z0]), jnp.stack([x, w, hgt]),
                      jnp.stack([x, -w, hgt]), jnp.stack([x, -w, z0])])


def robot_commands(kind: str, action: jax.Array, params: WorldParams,
                   noise: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """Body speed v [m/s] and turn rate omega [rad/s] (float32 scalars) of one robot.

    action: () int32 index; noise: (2,) float32 standard normals (tire slip) or None.
    """
    slip = jnp.asarray(params.robot.slip_std, F32)
    if kind == "two_motor":
        m = jnp.asarray(TWO_MOTOR_MOTORS, F32)[action]
        wheels = m * jnp.asarray(params.two_motor.wheel_speed, F32)
        if noise is not None:
            wheels = wheels * (1 + slip * noise)
        v = 0.5 * (wheels[0] + wheels[1])
        omega = (wheels[1] - wheels[0]) / jnp.asarray(params.two_motor.track, F32)
        return v, omega
    if kind == "four_wheel":
        u = jnp.asarray(FOUR_WHEEL_U, F32)[action]
        v = u[0] * jnp.asarray(params.four_wheel.speed, F32)
        delta = u[1] * jnp.deg2rad(jnp.asarray(params.four_wheel.max_steer_deg, F32))
        if noise is not None:
            v = v * (1 + slip * noise[0])
            delta = delta * (1 + slip * noise[1])
        omega = 2 * v * jnp.tan(delta) / jnp.asarray(params.four_wheel.wheelbase, F32)
        return v, omega
    raise ValueError(f"unknown robot kind {kind!r}")


def kick_velocity(ball_vel: jax.Array, heading: jax.Array, kick_speed: jax.Array,
                  restitution: jax.Array) -> jax.Array:
    """Ball velocity (2,) float32 after a kick along the unit vector ``heading`` (2,).

    The kicking face moves along ``heading`` at ``V = kick_speed / (1 + e)``, ``e`` =
    ``restitution``; the ball (velocity ``v``, the incoming one) bounces off it like off
    an infinitely heavy wall: ``v' = v + J heading`` with the impulse per unit mass
    ``J = max((1 + e) (V - v . heading), 0) = max(kick_speed - (1 + e) v . heading, 0)``.
    So a resting ball leaves at ``kick_speed`` along the heading, a ball coming head-on at
    speed ``s`` at ``kick_speed + e s``, the velocity across the heading is kept, and a ball
    moving away faster than the face is not touched (J = 0). jit/vmap-able.
    """
    v = jnp.asarray(ball_vel, F32)
    h = jnp.asarray(heading, F32)
    e = jnp.asarray(restitution, F32)
    j = jnp.maximum(jnp.asarray(kick_speed, F32) - (1 + e) * jnp.sum(v * h), 0.0)
    return v + j * h


def _reflect(p, v, lo, hi, e):
    """Reflect a coordinate p with velocity v into [lo, hi] (restitution e), then clip."""
    over = p > hi
    under = p < lo
    p = jnp.where(over, 2 * hi - p, jnp.where(under, 2 * lo - p, p))
    v = jnp.where(over | under, -e * v, v)
    return jnp.clip(p, lo, hi), v


class _Consts(NamedTuple):
    """The float32 constants of one world step (m, s, m/s, m/s^2, 1/m)."""

    h: jax.Array
    half_l: jax.Array
    half_w: jax.Array
    half_g: jax.Array
    rb: jax.Array
    rr: jax.Array
    e_wall: jax.Array
    e_kick: jax.Array
    decel: jax.Array
    drag: jax.Array
    vmax: jax.Array


def _consts(params: WorldParams) -> _Consts:
    fp, bp = params.field, params.ball
    return _Consts(
        h=jnp.asarray(params.action_dt, F32) / params.substeps,
        half_l=jnp.asarray(fp.length, F32) / 2, half_w=jnp.asarray(fp.width, F32) / 2,
        half_g=jnp.asarray(params.goal.width, F32) / 2, rb=jnp.asarray(bp.radius, F32),
        rr=jnp.asarray(params.robot.radius, F32),
        e_wall=jnp.asarray(bp.wall_restitution, F32),
        e_kick=jnp.asarray(bp.kick_restitution, F32),
        decel=jnp.asarray(bp.rolling_decel, F32), drag=jnp.asarray(bp.drag, F32),
        vmax=jnp.asarray(bp.max_speed, F32))


def _move_robots(robots, v_cmd, w_cmd, c: _Consts):
    """Steps 1-3: kinematics (midpoint heading), field bounds, robot-robot separation.
    Returns positions (R, 2), headings (R,) and velocities (R, 2)."""
    n_robots = robots.shape[0]
    th_mid = robots[:, 2] + 0.5 * c.h * w_cmd
    rvel = jnp.stack([v_cmd * jnp.cos(th_mid), v_cmd * jnp.sin(th_mid)], axis=-1)
    xy = robots[:, :2] + c.h * rvel
    th = wrap_angle(robots[:, 2] + c.h * w_cmd)
    lim = jnp.stack([c.half_l - c.rr, c.half_w - c.rr])
    xy = jnp.clip(xy, -lim, lim)
    for i in range(n_robots):  # push overlapping pairs apart, half each
        for j in range(i + 1, n_robots):
            d = xy[j] - xy[i]
            dist = jnp.sqrt(jnp.sum(d * d))
            n = jnp.where(dist > 0, d / jnp.maximum(dist, 1e-12), jnp.array([1.0, 0.0], F32))
            push = 0.5 * jnp.maximum(2 * c.rr - dist, 0.0)
            xy = xy.at[i].add(-push * n).at[j].add(push * n)
    if n_robots > 1:
        xy = jnp.clip(xy, -lim, lim)
    return xy, th, rvel


def _ball_contacts(ball, bvel, scored, xy, th, rvel, c: _Consts):
    """Step 4: each robot's body pushes the ball out of contact and reflects its relative
    normal velocity. Returns ball position, velocity and touches (R,) bool."""
    bx, bv = ball, bvel
    touches = []
    for i in range(xy.shape[0]):
        d = bx - xy[i]
        dist = jnp.sqrt(jnp.sum(d * d))
        heading = jnp.stack([jnp.cos(th[i]), jnp.sin(th[i])])
        n = jnp.where(dist > 0, d / jnp.maximum(dist, 1e-12), heading)
        hit = (dist < c.rr + c.rb) & ~scored
        vn = jnp.sum((bv - rvel[i]) * n)
        bv = jnp.where(hit & (vn < 0), bv - (1 + c.e_kick) * vn * n, bv)
        bx = jnp.where(hit, xy[i] + (c.rr + c.rb) * n, bx)
        touches.append(hit)
    return bx, bv, jnp.stack(touches)


def _roll(bv, c: _Consts):
    """Step 5: speed cap, rolling deceleration and drag over one sub-step."""
    s = jnp.sqrt(jnp.sum(bv * bv))
    s1 = jnp.minimum(s, c.vmax)
    s2 = jnp.maximum(s1 - (c.decel + c.drag * s1) * c.h, 0.0)
    return bv * jnp.where(s > 0, s2 / jnp.maximum(s, 1e-12), 0.0)


def _walls(bx, new, bv, c: _Consts):
    """Step 6: reflect the ball (moving from ``bx`` to ``new``) off the side and end walls;
    the +x wall is open in the goal mouth, whose posts keep the ball within it."""
    y, vy = _reflect(new[1], bv[1], -c.half_w + c.rb, c.half_w - c.rb, c.e_wall)
    x, vx = new[0], bv[0]
    plane = c.half_l - c.rb
    # crossing the +x wall contact plane: open in the goal mouth
    frac = (plane - bx[0]) / jnp.where(new[0] != bx[0], new[0] - bx[0], 1.0)
    y_plane = bx[1] + frac * (new[1] - bx[1])
    crossing = (new[0] > plane) & (bx[0] <= plane)
    enters = jnp.where(crossing, jnp.abs(y_plane) <= c.half_g, True)
    in_channel = (x > plane) & enters
    hi_x = jnp.where(in_channel, jnp.inf, plane)
    x, vx = _reflect(x, vx, -c.half_l + c.rb, hi_x, c.e_wall)
    # inside the mouth the posts keep the ball centre within |y| <= half_g - rb
    yc, vyc = _reflect(y, vy, -c.half_g + c.rb, c.half_g - c.rb, c.e_wall)
    y = jnp.where(in_channel, yc, y)
    vy = jnp.where(in_channel, vyc, vy)
    return jnp.stack([x, y]), jnp.stack([vx, vy])


def _goal_line(ball_before, bx, new, bv, scored, c: _Consts):
    """Step 7: a goal when the ball centre crosses x = L/2 inside the mouth; a scored ball
    stays where it was (in the net) with zero velocity."""
    crossed = (bx[0] <= c.half_l) & (new[0] > c.half_l)
    frac = (c.half_l - bx[0]) / jnp.where(crossed, new[0] - bx[0], 1.0)
    y_line = bx[1] + frac * (new[1] - bx[1])
    goal = crossed & (jnp.abs(y_line) <= c.half_g) & ~scored
    new = jnp.where(scored, ball_before, new)
    scored = scored | goal
    bv = jnp.where(scored, jnp.zeros_like(bv), bv)
    return new, bv, scored


@jax.jit
def world_step(state: WorldState, actions: jax.Array, params: WorldParams,
               slip_eps: jax.Array | None = None) -> tuple[WorldState, WorldEvents]:
    """Advance one action primitive.

    actions: (R,) int32 action indices, robot i interpreted by ``params.robot_kinds[i]``.
    slip_eps: optional (R, 2) float32 standard normals, the tire slip of this primitive in
    units of ``robot.slip_std`` (see :mod:`vbl.draws`); None = no slip.
    Returns the new state and the :class:`WorldEvents` of this primitive.
    """
    kinds = params.robot_kinds
    n_robots = len(kinds)
    c = _consts(params)
    noise = None if slip_eps is None else jnp.asarray(slip_eps, F32).reshape(n_robots, 2)
    vs, ws = [], []
    for i, kind in enumerate(kinds):
        v, w = robot_commands(kind, actions[i], params, None if noise is None else noise[i])
        vs.append(v)
        ws.append(w)
    v_cmd = jnp.stack(vs)
    w_cmd = jnp.stack(ws)

    def substep(_, carry):
        robots, ball, bvel, scored, touch = carry
        xy, th, rvel = _move_robots(robots, v_cmd, w_cmd, c)
        bx, bv, touches = _ball_contacts(ball, bvel, scored, xy, th, rvel, c)
        touch = touch | touches
        bv = _roll(bv, c)
        new = bx + c.h * bv
        if params.field.walls:
            new, bv = _walls(bx, new, bv, c)
        new, bv, scored = _goal_line(ball, bx, new, bv, scored, c)
        robots = jnp.concatenate([xy, th[:, None]], axis=-1)
        return robots, new, bv, scored, touch

    carry = (state.robots, state.ball, state.ball_vel, state.scored,
             jnp.zeros(n_robots, bool))
    # a rolled loop on purpose: its outputs are materialised, so consumers of the new state
    # (an auto-reset's per-leaf selects) read them instead of XLA re-deriving the last
    # sub-step inside each consumer (docs/findings/env_step_cost.md)
    robots, ball, bvel, scored, touch = jax.lax.fori_loop(
        0, params.substeps, substep, carry)
    outside = (jnp.abs(ball[0]) > c.half_l) | (jnp.abs(ball[1]) > c.half_w)
    out = (outside & ~scored) | state.ball_out
    new_state = WorldState(robots=robots, ball=ball, ball_vel=bvel, scored=scored,
                           ball_out=out)
    events = WorldEvents(goal=scored & ~state.scored, ball_out=out & ~state.ball_out,
                         touch=touch)
    return new_state, events


def check_actions(actions, params: WorldParams) -> np.ndarray:
    """Validate concrete actions (R,) for ``params.robot_kinds``; raise ValueError if bad."""
    kinds = params.robot_kinds
    a = np.asarray(actions)
    if a.shape != (len(kinds),):
        raise ValueError(f"actions must have shape ({len(kinds)},) (one per robot), got {a.shape}")
    if a.dtype.kind not in "iu":
        raise ValueError(f"actions must be integers, got dtype {a.dtype}")
    for i, kind in enumerate(kinds):
        if not 0 <= a[i] < num_actions(kind):
            raise ValueError(f"action {a[i]} of robot {i} ({kind}) out of range: "
                             f"must be in [0, {num_actions(kind) - 1}]")
    return a
