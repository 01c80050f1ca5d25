"""Plain NumPy/Python REFERENCE of the soccer-world physics (tests and benchmarks only).

Written from the model in ``docs/world.md`` with scalar loops and ``math``, in float64,
one environment at a time. It is deliberately simple and slow; it is the independent
truth the JAX implementation in ``vbl/world/physics.py`` is compared with.

Parameters are read from the same ``WorldParams`` dataclass (plain attribute access).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["wrap", "commands", "step_world", "goal_corners_np", "run_episode", "kick_np"]

# action index -> (left motor, right motor); index = 3 * (left + 1) + (right + 1)
TWO_MOTOR = {3 * (lm + 1) + (rm + 1): (lm, rm) for lm in (-1, 0, 1) for rm in (-1, 0, 1)}
# action index -> (v, phi): stop, F, FL, FR, B, BL, BR
FOUR_WHEEL = [(0, 0), (1, 0), (1, 1), (1, -1), (-1, 0), (-1, 1), (-1, -1)]


def wrap(a: float) -> float:
    """Angle to (-pi, pi]."""
    while a > math.pi:
        a -= 2 * math.pi
    while a <= -math.pi:
        a += 2 * math.pi
    return a


def commands(kind, action, p, noise=(0.0, 0.0)):
    """(v, omega) of one robot for an action index."""
    s = p.robot.slip_std
    if kind == "two_motor":
        lm, rm = TWO_MOTOR[int(action)]
        vl = lm * p.two_motor.wheel_speed * (1 + s * noise[0])
        vr = rm * p.two_motor.wheel_speed * (1 + s * noise[1])
        return (vl + vr) / 2, (vr - vl) / p.two_motor.track
    v_cmd, phi = FOUR_WHEEL[int(action)]
    v = v_cmd * p.four_wheel.speed * (1 + s * noise[0])
    delta = phi * math.radians(p.four_wheel.max_steer_deg) * (1 + s * noise[1])
    return v, 2 * v * math.tan(delta) / p.four_wheel.wheelbase


def kick_np(vel, heading: float, kick_speed: float, e: float) -> tuple[float, float]:
    """Ball velocity after a kick (docs/world.md, "Kicks"), in the frame of the kicking
    face: the face moves along the heading angle at ``kick_speed / (1 + e)``; the ball's
    velocity relative to the face, split into the component along the heading and the one
    across it; if the ball approaches the face, the along component is reversed and scaled
    by ``e``; back to the ground frame."""
    c, s = math.cos(heading), math.sin(heading)
    face = kick_speed / (1 + e)
    along = vel[0] * c + vel[1] * s - face  # relative to the face
    across = -vel[0] * s + vel[1] * c
    if along < 0:
        along = -e * along
    along += face
    return along * c - across * s, along * s + across * c


def goal_corners_np(p) -> np.ndarray:
    x, w, h = p.field.length / 2, p.goal.width / 2, p.goal.height
    return np.array([[x, w, 0.0], [x, w, h], [x, -w, h], [x, -w, 0.0]])


def _bounce(pos, vel, lo, hi, e):
    if pos > hi:
        pos, vel = 2 * hi - pos, -e * vel
    elif pos < lo:
        pos, vel = 2 * lo - pos, -e * vel
    return min(max(pos, lo), hi), vel


def step_world(state: dict, actions, p, noise=None) -> tuple[dict, dict]:
    """One action primitive. state: dict robots [[x, y, th], ...], ball [x, y],
    vel [vx, vy], scored, out (Python floats/bools). Returns (new state, events)."""
    kinds = p.robot_kinds
    nr = len(kinds)
    robots = [list(r) for r in state["robots"]]
    bx, by = state["ball"]
    vx, vy = state["vel"]
    scored, out0 = state["scored"], state["out"]
    hl, hw, hg = p.field.length / 2, p.field.width / 2, p.goal.width / 2
    rb, rr = p.ball.radius, p.robot.radius
    h = p.action_dt / p.substeps
    cmd = [commands(kinds[i], actions[i], p, (0.0, 0.0) if noise is None else noise[i])
           for i in range(nr)]
    touch = [False] * nr
    for _ in range(p.substeps):
        rvel = []
        for i in range(nr):
            v, w = cmd[i]
            x, y, th = robots[i]
            mid = th + 0.5 * h * w
            rvel.append((v * math.cos(mid), v * math.sin(mid)))
            x = min(max(x + h * rvel[i][0], -(hl - rr)), hl - rr)
            y = min(max(y + h * rvel[i][1], -(hw - rr)), hw - rr)
            robots[i] = [x, y, wrap(th + h * w)]
        for i in range(nr):
            for j in range(i + 1, nr):
                dx, dy = robots[j][0] - robots[i][0], robots[j][1] - robots[i][1]
                d = math.hypot(dx, dy)
                if d < 2 * rr:
                    nx, ny = (dx / d, dy / d) if d > 0 else (1.0, 0.0)
                    push = (2 * rr - d) / 2
                    robots[i][0] -= push * nx
                    robots[i][1] -= push * ny
                    robots[j][0] += push * nx
                    robots[j][1] += push * ny
        if nr > 1:
            for r in robots:
                r[0] = min(max(r[0], -(hl - rr)), hl - rr)
                r[1] = min(max(r[1], -(hw - rr)), hw - rr)
        # robot-ball contacts, robot by robot
        for i in range(nr):
            dx, dy = bx - robots[i][0], by - robots[i][1]
            d = math.hypot(dx, dy)
            if d < rr + rb and not scored:
                if d > 0:
                    nx, ny = dx / d, dy / d
                else:
                    nx, ny = math.cos(robots[i][2]), math.sin(robots[i][2])
                rel = (vx - rvel[i][0]) * nx + (vy - rvel[i][1]) * ny
                if rel < 0:
                    vx -= (1 + p.ball.kick_restitution) * rel * nx
                    vy -= (1 + p.ball.kick_restitution) * rel * ny
                bx, by = robots[i][0] + (rr + rb) * nx, robots[i][1] + (rr + rb) * ny
                touch[i] = True
        # friction
        speed = math.hypot(vx, vy)
        if speed > 0:
            s1 = min(speed, p.ball.max_speed)
            s2 = max(s1 - (p.ball.rolling_decel + p.ball.drag * s1) * h, 0.0)
            vx, vy = vx * s2 / speed, vy * s2 / speed
        nx_, ny_ = bx + h * vx, by + h * vy
        if p.field.walls:
            e = p.ball.wall_restitution
            ny_, vy = _bounce(ny_, vy, -hw + rb, hw - rb, e)
            plane = hl - rb
            # does the ball go past the +x wall's contact plane inside the goal mouth?
            if nx_ > plane:
                if bx <= plane:
                    t = (plane - bx) / (nx_ - bx)
                    channel = abs(by + t * (ny_ - by)) <= hg
                else:
                    channel = True
            else:
                channel = False
            nx_, vx = _bounce(nx_, vx, -hl + rb, math.inf if channel else plane, e)
            if channel:
                ny_, vy = _bounce(ny_, vy, -hg + rb, hg - rb, e)
        if not scored and bx <= hl < nx_:
            t = (hl - bx) / (nx_ - bx)
            if abs(by + t * (ny_ - by)) <= hg:
                scored = True
                bx, by = nx_, ny_
        if scored:
            vx = vy = 0.0
        else:
            bx, by = nx_, ny_
    outside = abs(bx) > hl or abs(by) > hw
    out = (outside and not scored) or out0
    new = dict(robots=robots, ball=[bx, by], vel=[vx, vy], scored=scored, out=out)
    events = dict(goal=scored and not state["scored"], ball_out=out and not out0, touch=touch)
    return new, events


def run_episode(state: dict, actions, p, max_steps: int, obs_fn=None):
    """Shooting episode without reset from ``state`` with a sequence of action indices.

    Stops after a goal, the ball leaving the field, or ``max_steps`` primitives (the
    step counter starts at ``state["step"]``). Returns per-step lists of states,
    rewards, terminated, truncated and (if ``obs_fn(state) -> (9,)`` is given) obs.
    """
    out = dict(states=[], reward=[], terminated=[], truncated=[], obs=[])
    step = state.get("step", 0)
    for a in actions:
        state, ev = step_world(state, [a], p)
        step += 1
        term = ev["goal"] or ev["ball_out"]
        trunc = step >= max_steps and not term
        out["states"].append(state)
        out["reward"].append(1.0 if ev["goal"] else 0.0)
        out["terminated"].append(term)
        out["truncated"].append(trunc)
        if obs_fn is not None:
            out["obs"].append(obs_fn(state))
        if term or trunc:
            break
    return out
