"""Table 2's program: the Figure 11 pipeline (CVA state vectors, vector quantisation,
tabular Q-learning) in the two-robot env, trained, then evaluated greedily through the
same compiled step; with its defaults (docs/cva_learning.md, "Choices and why").

Each learner (one seed) runs :mod:`vbl.agents.cva_state` in
:class:`vbl.envs.shoot_pass.ShootPassEnv`: random-action data collection, one CVA model per
observed object (ball, goal, other robot), filtering inside the env loop, vector
quantisation of the state vector, tabular Q-learning; then ``train.eval_chunks`` greedy
chunks from fresh starts (each env's first episode counts). ``cva.use_cva=False``
quantises the current features of the same objects instead; with ``cva.state="select"``
both state vectors share one compilation per task, and the env's ``task="select"`` lets the
traced ``env.task_pass`` pick the role, so task x state vector is one compilation.

A config for :func:`make_cva_program` has ``task`` (static: "shoot", "pass" or "select"),
``cva`` (:class:`~vbl.agents.cva_state.CVAStateParams`), ``q``
(:class:`~vbl.agents.qlearning.QRunnerParams`), ``env``
(:class:`~vbl.envs.shoot_pass.ShootPassParams`) and ``train`` (:class:`CVATrainParams`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from vbl.agents.cva_state import (
    CVAStateParams,
    first_episode_stats,
    greedy_params,
    make_cva_learner,
)
from vbl.agents.exploration import ExplorationParams, ScheduleParams, schedule_value
from vbl.agents.lem import LEMParams
from vbl.agents.qlearning import QRunnerParams
from vbl.engine.experiment import Program
from vbl.envs.macro import MacroActionParams
from vbl.envs.shoot_pass import OBS_DIM, OBS_SLICES, ShootPassEnv
from vbl.params import ParamError, param, section
from vbl.spaces.quantize import QuantizerParams
from vbl.sysid.params import CVAParams

__all__ = ["default_cva", "default_table2_q", "default_lr_scale", "CVATrainParams",
           "BallVelocityOracle", "make_cva_program", "task_label", "state_label",
           "POINT_KEYS", "VELOCITY"]

POINT_KEYS = ("task", "env.task_pass", "cva.use_cva", "cva.state", "ball_velocity")
"""Sweep paths that name a row's task and state vector (the others are extra settings)."""

VELOCITY = " + true velocity"
"""Suffix of a state vector's label when the ball's true velocity is among its features."""


def default_cva() -> CVAStateParams:
    """State-construction defaults for the two-robot task (docs/cva_learning.md, "Choices
    and why")."""
    # The ball's 8 leading canonical components (keep_beyond_order: its AIC order is 4,
    # and components 5-8 carry its approach velocity: docs/findings/table2_shoot_pass.md,
    # "What the CVA state carries (probe)"), the goal's and the other robot's 4 (with 2
    # their horizontal image position is poorly represented). No unfiltered lost-side
    # flags. One k-means codebook per object (product VQ): ball 64 x goal 8 x other
    # robot 8 = 4,096 states for both state vectors (docs/findings/table2_shoot_pass.md,
    # "How the passing result came about").
    return CVAStateParams(
        state="select", objects=("ball", "goal", "other"), n_used=4,
        n_used_objects=(8, 4, 4), keep_beyond_order=True, extra=(), collect_steps=3000,
        ident=CVAParams(lag=0, lag_max=3, lag_rule="paper", logdet_stop=-100.0),
        quantizer=QuantizerParams(method="product_vq", group_codes=(64, 8, 8),
                                  kmeans_iters=20))


def default_table2_q() -> QRunnerParams:
    """Table 2's Q-learner, every value in one place (the library's QRunnerParams defaults
    for the rest): 7 primitive commands; asynchronous macro actions (repeat a primitive
    until the quantised state changes, a deviation: docs/findings/table2_shoot_pass.md,
    "Deviations"; every runner step is one primitive of every env and an env decides when
    its action ends, while a synchronous loop would run as long as the longest action of
    the batch); no LEM; 64 envs x 100 learner steps per chunk; epsilon-greedy, epsilon 1.0
    -> 0.05 over 30,000 learner steps (about 75 % of the default run: num_chunks x
    chunk_steps); discount 0.99 per 0.1 s primitive (a goal 3-4 s after the start is still
    worth ~0.7) and step size 0.25, scaled per chunk by train.lr_scale (default_lr_scale):
    the best mean greedy success of the four rows in the engine's own 16-seed sweeps
    (docs/findings/table2_shoot_pass.md, "Step size and discount")."""
    return QRunnerParams(
        num_states=1, num_actions=7, discount=0.99, learning_rate=0.25,
        exploration=ExplorationParams(schedule="linear", init_value=1.0, end_value=0.05,
                                      transition_steps=30000.0),
        macro=MacroActionParams(enabled=True, mode="async"), lem=LEMParams(enabled=False),
        num_envs=64, chunk_steps=100)


def default_lr_scale() -> ScheduleParams:
    """Factor on the learning rate per training chunk: 1 for the first 70 % of the default
    400 chunks, then linearly down to 0.1 over the next 10 % (with the learning rate 0.25:
    0.25 falling to 0.025; a decreasing step size lets the tabular Q estimates settle;
    docs/cva_learning.md, "Choices and why")."""
    return ScheduleParams(schedule="linear", init_value=1.0, end_value=0.1,
                          transition_begin=280.0, transition_steps=40.0)


@struct.dataclass
class CVATrainParams:
    """Run length, greedy evaluation and step-size schedule of :func:`make_cva_program`."""

    num_chunks: int = param(400, doc="training chunks per run (each q.chunk_steps "
                            "learner steps)", static=True, ge=1)
    eval_chunks: int = param(1, doc="greedy evaluation chunks after training: all envs restart "
                             "fresh, no learning, no exploration; each env's first finished "
                             "episode counts (chunks x chunk_steps must be >= env.max_steps)",
                             static=True, ge=1)
    lr_scale: ScheduleParams = section(default_lr_scale, doc="factor on q.learning_rate "
                                       "per training chunk, count = training chunks done "
                                       "(as the Q programs' train.lr_scale)")


@struct.dataclass
class Carry:
    """One learner's state between chunks."""

    runner: object       # QRunnerState of the learner
    fparams: object      # params of the filtered env (CVA models, quantiser)
    chunk: jax.Array     # () int32 chunks done
    fresh: object        # QRunnerState of the evaluation's restart (its envs' fresh starts)


class BallVelocityOracle:
    """A control, not the paper's method: the two-robot env whose observation also holds the
    ball's true velocity in the learner's frame (forward, lateral; m/s), zero while the ball
    is not in the learner's image, right after the ball's 4 features: obs (28,), the ball's
    slice ``0:6`` (so the quantiser puts it in the ball's codes), the other slices moved by
    2. Everything else is the wrapped env's (:class:`vbl.envs.shoot_pass.ShootPassEnv`)."""

    def __init__(self, env: ShootPassEnv):
        self._env = env
        b = OBS_SLICES["ball"]
        self.obs_slices = {k: sl if k == "ball" else slice(sl.start + 2, sl.stop + 2)
                           for k, sl in OBS_SLICES.items()}
        self.obs_slices["ball"] = slice(b.start, b.stop + 2)
        self.observation_shape = (OBS_DIM + 2,)

    def __getattr__(self, name):
        return getattr(self._env, name)

    def get_obs(self, state, params, eps) -> jax.Array:
        obs = self._env.get_obs(state, params, eps)
        me = self._env.roles(params)[0]
        th = state.world.robots[me, 2]
        v = state.world.ball_vel
        c, s = jnp.cos(th), jnp.sin(th)
        seen = obs[OBS_SLICES["visible"].start]  # the ball's visibility flag
        vel = jnp.stack([c * v[0] + s * v[1], -s * v[0] + c * v[1]]) * seen
        end = OBS_SLICES["ball"].stop
        return jnp.concatenate([obs[:end], vel.astype(obs.dtype), obs[end:]])

    def reset(self, key, params=None):
        params = self._env.default_params if params is None else params
        state, eps = self._env.reset_state(key, params)
        return self.get_obs(state, params, eps), state

    def step(self, key, state, action, params=None):
        params = self._env.default_params if params is None else params
        state, eps, reward, terminated, truncated, info = self._env.step_state(
            key, state, action, params)
        return self.get_obs(state, params, eps), state, reward, terminated, truncated, info


def make_cva_program(cfg) -> Program:
    """Training chunks, then ``eval_chunks`` greedy chunks through the same compiled step.
    With ``cfg.ball_velocity`` (static; a control) the env is :class:`BallVelocityOracle`."""
    env = ShootPassEnv(cfg.task)
    if getattr(cfg, "ball_velocity", False):
        env = BallVelocityOracle(env)
    lrn = make_cva_learner(env, cfg.cva, cfg.q, m=2)
    n_train, n_eval = cfg.train.num_chunks, cfg.train.eval_chunks
    if n_eval * cfg.q.chunk_steps < cfg.env.max_steps:
        raise ParamError(f"train.eval_chunks={n_eval} x q.chunk_steps="
                         f"{cfg.q.chunk_steps} must be >= env.max_steps="
                         f"{cfg.env.max_steps} (every evaluation episode must finish)")

    def init(key, c):
        k_prep, k_run, k_eval = jax.random.split(key, 3)
        fp = lrn.prepare(k_prep, c.cva, c.env)
        # the training runner and the evaluation's restart in one vmapped init: the env's
        # reset (its camera) is compiled once, and the step program holds none
        both = jax.vmap(lambda k: lrn.runner.init(k, lrn.runner_params(c.q), fp))(
            jnp.stack([k_run, k_eval]))
        rs, fresh = (jax.tree.map(lambda a, i=i: a[i], both) for i in (0, 1))
        return Carry(rs, fp, jnp.int32(0), fresh)

    def step(carry, c):
        rp = lrn.runner_params(c.q)
        rp = rp.replace(learning_rate=rp.learning_rate * schedule_value(c.train.lr_scale,
                                                                        carry.chunk))
        rs = carry.runner
        # at the first evaluation chunk every env restarts fresh (counters reset), Q kept
        fresh = carry.fresh.replace(key=rs.key, q=rs.q, steps=rs.steps, episodes=rs.episodes)
        rs = jax.tree.map(lambda a, b: jnp.where(carry.chunk == n_train, a, b), fresh, rs)
        rs, m = lrn.runner.run_chunk(rs, greedy_params(rp, carry.chunk >= n_train),
                                     carry.fparams)
        eps = jnp.sum(m["episodes"]).astype(jnp.float32)
        sr = jnp.sum(m["successes"]).astype(jnp.float32) / jnp.maximum(eps, 1.0)
        return Carry(rs, carry.fparams, carry.chunk + 1, carry.fresh), {
            "episodes": eps, "chunk_success": sr, "epsilon": m["rate"][-1]}

    def final(carry, c, key):
        ev = first_episode_stats(carry.runner.env_state)
        out = {"greedy_success_rate": ev["success_rate"], "greedy_finished": ev["finished"]}
        for name, mod in zip(cfg.cva.objects, carry.fparams.inner.filters, strict=False):
            out[f"lag_{name}"] = mod.lag.astype(jnp.float32)
            out[f"n_{name}"] = mod.n.astype(jnp.float32)
        return out

    return Program(init=init, step=step, num_chunks=n_train + n_eval, final=final)


def task_label(pt: dict, config) -> str:
    """"shoot" or "pass": the role of the learners of sweep point ``pt``."""
    if config.task != "select" and "task" not in pt:
        return config.task
    if "task" in pt and pt["task"] != "select":
        return pt["task"]
    return "pass" if pt.get("env.task_pass", config.env.task_pass) else "shoot"


def state_label(pt: dict, config) -> str:
    """"cva" or "current" (or the static ``cva.state``) of sweep point ``pt``, followed by
    :data:`VELOCITY` when the ball's true velocity is among the features."""
    if "cva.use_cva" in pt or config.cva.state == "select":
        label = "cva" if pt.get("cva.use_cva", config.cva.use_cva) else "current"
    else:
        label = pt.get("cva.state", config.cva.state)
    return label + (VELOCITY if pt.get("ball_velocity", getattr(config, "ball_velocity", False))
                    else "")
