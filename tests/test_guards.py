"""Guards for behaviours that a rework of the random draws or of the physics could break
silently.

* The goal mouth with walls off is exactly the goal's width: a ball crossing the goal line
  just inside a post scores once; one crossing just outside it (but closer to the post than
  the ball radius) does not score and leaves the field (RoboCup-97 goal, 1.5 m wide,
  ``docs/world.md``).
* A Q-learning program's final evaluation draws from its own random stream: the registered
  ``grid_shooting`` experiment's program at a tiny size, run as the engine runs it (keys
  from :func:`vbl.engine.sweep.learner_keys`, one vmapped call over the seeds), with an
  env that records every key and episode start it is given. No key of the final
  evaluation is a training key, its starts differ from training's first starts, and its
  draws depend on the final key alone, not on the training carry's key.
"""

from __future__ import annotations

from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from vbl.engine.config import apply_overrides, stack_traced
from vbl.engine.registry import load_script
from vbl.engine.sweep import learner_keys
from vbl.world.params import FieldParams, WorldParams
from vbl.world.physics import make_state, world_step

ROOT = Path(__file__).resolve().parents[1]

# ----------------------------------------------------------------------- goal mouth, walls off

GOAL_WIDTH = 1.5  #: RoboCup-97 goal mouth, m (docs/world.md)
MARGIN = 0.02  #: m inside / outside a post
STOP = 4  #: two-motor primitive (0, 0)


def test_goal_mouth_without_walls_is_the_goal_width():
    """Walls off: a ball whose centre crosses the goal line ``x = L/2`` at ``|y|`` just
    inside the half goal width scores exactly one goal; just outside it (still within half
    width + ball radius of the centre line) it scores none and leaves the field once.
    Crossings straight on and at a slant (crossing point from the straight path)."""
    p = WorldParams(field=FieldParams(walls=False))
    assert p.goal.width == GOAL_WIDTH
    half_l, half_g, rb = p.field.length / 2, GOAL_WIDTH / 2, p.ball.radius
    assert MARGIN < rb  # "outside" is still within half width + ball radius
    cases = []  # (start (2,), velocity (2,), scores)
    for side in (1.0, -1.0):
        for y_cross, scores in ((half_g - MARGIN, True), (half_g + MARGIN, False),
                                (half_g + rb - MARGIN, False)):
            y = side * y_cross
            cases.append(([half_l - 0.05, y], [1.0, 0.0], scores))  # straight on
            # slanted (dy/dx = slope), crossing x = L/2 at y: starts 0.3 m before the line
            slope = -0.3 * side
            d = np.array([1.0, slope]) / np.hypot(1.0, slope)
            cases.append(([half_l - 0.3, y - 0.3 * slope], list(1.5 * d), scores))
    start = np.array([c[0] for c in cases], np.float32)
    vel = np.array([c[1] for c in cases], np.float32)
    scores = np.array([c[2] for c in cases])
    robot = np.broadcast_to(np.array([[-3.0, 0.0, 0.0]], np.float32), (len(cases), 1, 3))

    def rollout(state):
        def body(st, _):
            st, ev = world_step(st, jnp.array([STOP], jnp.int32), p)
            return st, (ev.goal, ev.ball_out)

        return jax.lax.scan(body, state, None, length=8)

    states = jax.vmap(make_state)(jnp.asarray(robot), jnp.asarray(start), jnp.asarray(vel))
    final, (goal, out) = jax.jit(jax.vmap(rollout))(states)
    goals = np.asarray(goal).sum(axis=1)
    outs = np.asarray(out).sum(axis=1)
    for i, (s, v, want) in enumerate(cases):
        what = f"ball from {s} at {v}"
        if want:
            assert goals[i] == 1 and bool(final.scored[i]) and outs[i] == 0, what
        else:
            assert goals[i] == 0 and not bool(final.scored[i]) and outs[i] == 1, what
    assert scores.sum() == 4 and (~scores).sum() == 8


# ----------------------------------------------------------------------- evaluation stream

# 2 chunks of 3 learner steps x 4 robots, the final evaluation on 3 x 4 fresh starts;
# training and evaluation start at the same difficulty (the experiment's task difficulty,
# LEM off), so their start distributions are the same
TINY = {"agent.num_envs": 4, "agent.chunk_steps": 3, "train.num_chunks": 2, "train.eval_every": 1,
        "train.eval_chunks": 7, "train.eval_rounds": 1,
        "train.eval_curve": False, "env.max_steps": 20,
        "agent.lem.initial_difficulty": 1.0, "train.eval_difficulty": 1.0}
SEEDS = 2


class Recorder:
    """Keys and episode starts an env is given, labelled by the phase of the run."""

    def __init__(self):
        self.label = None
        self.keys: dict[str, list] = {}
        self.starts: dict[str, list] = {}

    @contextmanager
    def phase(self, label: str):
        self.label = label
        self.keys.setdefault(label, [])
        self.starts.setdefault(label, [])
        try:
            yield
        finally:
            jax.effects_barrier()
            self.label = None

    def key(self, key):
        self.keys[self.label] += [tuple(k) for k in np.asarray(key).reshape(-1, 2).tolist()]

    def start(self, robots, ball):
        rows = np.concatenate([np.asarray(robots).reshape(-1, 3),
                               np.asarray(ball).reshape(-1, 2)], axis=1)
        self.starts[self.label] += [tuple(r) for r in rows.tolist()]


class RecordingEnv:
    """Wraps an env; records the key of every reset and step and every reset's start."""

    def __init__(self, env, rec: Recorder):
        self._env, self._rec = env, rec

    def __getattr__(self, name):
        return getattr(self._env, name)

    def reset(self, key, params=None):
        obs, state = self._env.reset(key, params)
        jax.debug.callback(self._rec.key, key)
        jax.debug.callback(self._rec.start, state.world.robots, state.world.ball)
        return obs, state

    def step(self, key, state, action, params=None):
        jax.debug.callback(self._rec.key, key)
        return self._env.step(key, state, action, params)


@pytest.mark.slow  # compile-bound: about 65 s on 2 quiet cores
def test_final_evaluation_draws_from_its_own_stream(monkeypatch):
    """The grid_shooting program (``vbl.programs.baselines.grid_program``) with the engine's
    per-seed training and final keys: the evaluation's fresh starts (drawn at init) are none
    of training's first starts, the final evaluation's env keys are disjoint from every
    training env key, and the final evaluation is a function of the final key only (the
    same with the training carry's key replaced, different with another final key)."""
    from vbl.programs import baselines

    gs = load_script(ROOT / "experiments" / "grid_shooting.py")
    cfg = apply_overrides(gs.EXPERIMENT.default_config, TINY)
    rec = Recorder()
    env = baselines.ShootingEnv()
    monkeypatch.setattr(baselines, "ShootingEnv", lambda: RecordingEnv(env, rec))
    prog = gs.EXPERIMENT.make_program(cfg)
    cfgs = stack_traced([cfg], SEEDS)
    init_keys, final_keys = learner_keys(0, SEEDS)
    assert not {tuple(k) for k in init_keys.tolist()} & {tuple(k) for k in final_keys.tolist()}
    init = jax.jit(jax.vmap(prog.init))
    step = jax.jit(jax.vmap(prog.step))
    final = jax.jit(jax.vmap(prog.final))

    with rec.phase("init"):
        carry = jax.block_until_ready(init(jnp.asarray(init_keys), cfgs))
    with rec.phase("train"):
        for _ in range(prog.num_chunks):
            carry, _ = step(carry, cfgs)
        jax.block_until_ready(carry)
    with rec.phase("final"):
        out = jax.block_until_ready(final(carry, cfgs, jnp.asarray(final_keys)))
    other = carry.learner.replace(key=jax.random.split(jax.random.PRNGKey(123), SEEDS))
    with rec.phase("final, training key replaced"):
        same = jax.block_until_ready(final(carry.replace(learner=other), cfgs,
                                           jnp.asarray(final_keys)))
    other_final = learner_keys(1, SEEDS)[1]
    with rec.phase("final, another final key"):
        jax.block_until_ready(final(carry, cfgs, jnp.asarray(other_final)))

    starts = rec.starts["init"]  # training's first starts and the evaluation's
    train_keys = set(rec.keys["init"]) | set(rec.keys["train"])
    eval_keys = set(rec.keys["final"])
    per_seed = (1 + cfg.train.eval_rounds) * cfg.agent.num_envs
    assert len(rec.keys["init"]) == SEEDS * per_seed
    assert len(rec.keys["train"]) >= SEEDS * prog.num_chunks * cfg.agent.chunk_steps \
        * cfg.agent.num_envs
    # every start distinct: the evaluation's are none of training's first ones
    assert len(starts) == SEEDS * per_seed == len(set(starts))
    # the evaluation's starts are the carry's, drawn once at init: the final resets no env
    # beyond its episodes' own auto-resets
    np.testing.assert_array_equal(np.asarray(carry.starts.env_state.inner.world.robots).shape[:3],
                                  (SEEDS, cfg.train.eval_rounds, cfg.agent.num_envs))
    # no key of the final evaluation is a training key
    assert eval_keys and not train_keys & eval_keys
    # the final evaluation reads nothing of the training stream (the carry's key) ...
    assert Counter(rec.keys["final, training key replaced"]) == Counter(rec.keys["final"])
    for k in out:
        np.testing.assert_array_equal(np.asarray(out[k]), np.asarray(same[k]))
    # ... but draws everything from its own key
    assert not set(rec.keys["final, another final key"]) & eval_keys

