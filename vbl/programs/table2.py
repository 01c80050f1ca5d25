"""Table 2 on the one tabular learner: the Figure 11 pipeline's state vectors (current
features, CVA state) in the two-robot env, with its defaults (docs/cva_learning.md,
"Choices and why"), and the labels of its rows.

:func:`table2_program` is :func:`vbl.programs.tabular.make_tabular_program` on a
:class:`~vbl.agents.state_maps.CVAMap` of :class:`vbl.envs.shoot_pass.ShootPassEnv` (under
:class:`~vbl.envs.wrappers.BallVelocityOracle` with ``ball_velocity``). With
``cva.state="select"`` both state vectors share one compilation per task, and the env's
``task="select"`` lets the traced ``env.task_pass`` pick the role, so task x state vector
is one compilation.

A config has ``task`` (static: "shoot", "pass" or "select"), ``ball_velocity`` (static),
``cva`` (:class:`~vbl.agents.cva_state.CVAStateParams`), ``agent``
(:class:`~vbl.agents.qlearning.QRunnerParams`), ``env``
(:class:`~vbl.envs.shoot_pass.ShootPassParams`) and ``train``
(:class:`~vbl.programs.tabular.TabularTrainParams`).
"""

from __future__ import annotations

from typing import Any

from vbl.agents.cva_state import CVAStateParams
from vbl.agents.exploration import ExplorationParams, ScheduleParams
from vbl.agents.lem import LEMParams
from vbl.agents.qlearning import QRunnerParams
from vbl.agents.state_maps import CVAMap
from vbl.engine.experiment import Program
from vbl.envs.macro import MacroActionParams
from vbl.envs.shoot_pass import ShootPassEnv
from vbl.envs.wrappers import BallVelocityOracle
from vbl.programs.tabular import TabularTrainParams, make_tabular_program
from vbl.spaces.quantize import QuantizerParams
from vbl.sysid.params import CVAParams

__all__ = ["table2_cva", "table2_agent", "table2_train", "table2_env", "table2_program",
           "task_label", "state_label", "POINT_KEYS", "VELOCITY"]

POINT_KEYS = ("task", "env.task_pass", "cva.use_cva", "cva.state", "ball_velocity")
"""Sweep paths that name a row's task and state vector (the others are extra settings)."""

VELOCITY = " + true velocity"
"""Suffix of a state vector's label when the ball's true velocity is among its features."""


def table2_cva() -> CVAStateParams:
    """State-construction defaults for the two-robot task: the ball's CVA state with the
    goal's and the other robot's current features (docs/cva_learning.md, "Choices and
    why")."""
    # The ball's CVA state, its 8 leading canonical components (keep_beyond_order: its AIC
    # order is 4, and components 5-8 carry its velocity), beside the goal's and the other
    # robot's current features: their CVA blocks (4 components each) lost 7-24 points of
    # greedy success against the velocity oracle (docs/findings/table2_shoot_pass.md,
    # "Where the CVA state loses information"). So the two rows differ in the ball alone.
    # One k-means codebook per block (product VQ): ball 64 x goal 8 x other robot 8 =
    # 4,096 states for both state vectors.
    return CVAStateParams(
        state="select", objects=("ball",), n_used=4, n_used_objects=(8,),
        keep_beyond_order=True, extra=("goal", "other"), collect_steps=3000,
        ident=CVAParams(lag=0, lag_max=3, lag_rule="paper", logdet_stop=-100.0),
        quantizer=QuantizerParams(method="product_vq", group_codes=(64, 8, 8),
                                  kmeans_iters=20))


def table2_agent() -> QRunnerParams:
    """Table 2's Q-learner, every value in one place (the library's QRunnerParams defaults
    for the rest): 7 primitive commands; asynchronous macro actions (repeat a primitive
    until what the state map perceives changes, a deviation:
    docs/findings/table2_shoot_pass.md, "Deviations"; every runner step is one primitive of
    every env and an env decides when its action ends, while a synchronous loop would run
    as long as the longest action of the batch); no LEM; 64 envs x 100 learner steps per
    chunk; epsilon-greedy, epsilon 1.0 -> 0.05 over 30,000 learner steps (about 75 % of the
    default run: num_chunks x chunk_steps); discount 0.99 per 0.1 s primitive (a goal 3-4 s
    after the start is still worth ~0.7) and step size 0.25, scaled per chunk by
    train.lr_scale (:func:`table2_train`): the best mean greedy success of the four rows in
    the engine's own 16-seed sweeps (docs/findings/table2_shoot_pass.md, "Step size and
    discount")."""
    return QRunnerParams(
        num_states=1, num_actions=7, discount=0.99, learning_rate=0.25,
        exploration=ExplorationParams(schedule="linear", init_value=1.0, end_value=0.05,
                                      transition_steps=30000.0),
        macro=MacroActionParams(enabled=True, mode="async"), lem=LEMParams(enabled=False),
        num_envs=64, chunk_steps=100)


def table2_train() -> TabularTrainParams:
    """400 training chunks; no learning curve; the final evaluation on 4 x 64 fresh starts
    of one chunk each (the env's 100-primitive time limit); step size factor 1 for the
    first 70 % of the chunks, then linearly down to 0.1 over the next 10 % (with the
    learning rate 0.25: 0.25 falling to 0.025; a decreasing step size lets the tabular Q
    estimates settle; docs/cva_learning.md, "Choices and why")."""
    return TabularTrainParams(
        num_chunks=400, eval_curve=False, eval_chunks=1, eval_rounds=4,
        lr_scale=ScheduleParams(schedule="linear", init_value=1.0, end_value=0.1,
                                transition_begin=280.0, transition_steps=40.0))


def table2_env(task: str, ball_velocity: bool) -> Any:
    """The two-robot env of ``task``; under the velocity oracle with ``ball_velocity``."""
    env = ShootPassEnv(task)
    return BallVelocityOracle(env) if ball_velocity else env


def table2_program(cfg: Any) -> Program:
    """The tabular learner on Table 2's state map of ``cfg`` (static fields)."""
    return make_tabular_program(CVAMap(table2_env(cfg.task, cfg.ball_velocity), cfg.cva), cfg)


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
