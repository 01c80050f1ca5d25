"""The grid baseline: Q-learning on the programmer's 319-state grid (the earlier work the
paper compares against), as a preset that experiments share by reference.

``grid_shooting`` reports it with and without Learning from Easy Missions, Figure 5
compares the action-based map with it and Figure 9 with the on-line segmentation. Each
default below is a measured choice (docs/findings/grid_shooting.md).
"""

from __future__ import annotations

from typing import Any

from flax import struct

from vbl.agents.exploration import ScheduleParams
from vbl.agents.qlearning import QRunnerParams
from vbl.agents.state_maps import GridMap
from vbl.agents.traces import TraceParams
from vbl.envs.shooting import ShootingEnv, ShootingParams
from vbl.params import section
from vbl.programs.tabular import TabularTrainParams, make_tabular_program
from vbl.spaces.grid import GridParams

__all__ = ["GridBaseline", "GridLearner", "grid_program", "grid_env", "grid_space", "grid_agent",
           "grid_train", "TASK_DIFFICULTY"]

TASK_DIFFICULTY = 1.0
"""Start difficulty of the grid's task (evaluation, and the cap of the curriculum): fully
random starts. A hand-written table on the 319 grid states scores 0.648 there within 100 s
(random 0.004 on the same starts). One-step Q-learning did not learn it (0.00-0.05); with
multi-step returns (``TRACE``) and the success-gated curriculum it does."""

MIN_REPEATS = 3  #: primitives per macro action at least (0.3 s)

MAX_STEPS = 1000
"""Time limit of the grid's episodes, primitives (100 s; the env's default is 30 s). From
fully random starts 30 s is too short even for a hand-written table on the 319 grid states
(0.086); with 100 s it scores 0.648, and the random policy 0.004 on the same starts
(``benchmarks/probes/grid_hand_table.py``)."""

UPDATE = "peng"
TRACE = TraceParams(lam=0.9, length=32)
"""Multi-step returns (``UPDATE``: Peng's Q(lambda), lambda 0.9 per action, window 32
actions): the remedy for the grid's state aliasing, under which one-step Q-learning
unlearned even a good hand-written table."""

MACRO_MODE = "async"
"""How the robots run macro actions: asynchronously, so one learner step is one primitive of
every robot (a robot decides again when its action ends) and the step counts below count
primitives. A synchronous learner step runs every robot's whole action, i.e. as long as the
longest of 64 actions (often the cap of 20 primitives) while the mean action lasts 4-8
primitives; the transitions, the trace window and lambda (per action) are the same. Full
run: ~200 CPU-s against 1,878 s wall synchronously (docs/findings/grid_shooting.md)."""

MEAN_ACTION = 5
"""Primitives per macro action of the synchronous learner (whose step counts are in
actions; the counts below are those times this): measured 8.2 under the random policy of
the first chunks and 4-5.5 once epsilon has fallen (both arms, 40 chunks)."""

CHUNK_STEPS = 100 * MEAN_ACTION
"""Learner steps (primitives of each robot) per training chunk: the 100 actions of a
synchronous chunk, so ``NUM_CHUNKS`` and the per-chunk ``LR_SCALE`` keep their meaning."""

EVAL_CHUNKS = MAX_STEPS // CHUNK_STEPS
"""Chunks per evaluation (of ``CHUNK_STEPS`` learner steps, i.e. primitives): the
env's time limit, not the evaluation's length, ends an unfinished first episode."""

LEM_WINDOW = 100 * MEAN_ACTION
"""Learner steps (primitives) per LEM window: the synchronous learner's 100 actions."""

LEARNING_RATE = 0.05
"""Step size alpha. The "mean" duplicate rule averages the TD errors that one learner step
brings to a table entry: synchronously every robot's trace window arrives at every step,
asynchronously only those of the robots whose action ends (~1 in 5), so a shared entry
takes ~5x more averaged steps per primitive of experience. 0.05 against the synchronous
learner's 0.1 (with 0.25 there the training success collapsed once the curriculum raised
the difficulty); 4 seeds, 100 chunks, near-greedy success with LEM: 0.1: 0.505 (8 seeds),
0.05: 0.766, 0.025: 0.545; without LEM 0.140 / 0.244 / 0.312."""

EVAL_EPSILON = 0.1
"""Epsilon of the near-greedy policy (the final epsilon of training): on an aliased state
space the best memoryless policy can be stochastic, and the deterministic greedy one cycles
between look-alike states."""

EXPLORATION_STEPS = 3500.0
"""Learner steps (primitives) over which epsilon falls linearly from 1 to 0.1: 500 actions
of 7 primitives (the mean action while epsilon is high; library: 2,000 steps). With LEM the
easy episodes are short, so a slow decay (2,000 actions) spent ~1,300 trials at difficulty
0-0.1 while exploration kept the training success under the curriculum's 90 % gate; with
500 actions the curriculum median reached 30 % near-greedy success in 2,190 trials instead
of ~3,700."""

NUM_CHUNKS = 100
"""Training chunks (x ``CHUNK_STEPS`` primitives x 64 robots): without LEM the episodes at
the task difficulty mostly run to the time limit, so it finishes ~2x fewer trials than with
LEM (100 chunks: ~3,200 vs ~7,500). That covers LEM's crossings of 20 % and 30 % near-greedy
success (~2,300 and ~3,100 trials); to compare at 50 % (LEM ~4,600) run the no-LEM arm
longer (``--sweep agent.lem.initial_difficulty=1.0 --set train.num_chunks=132``)."""

EVAL_EVERY = 4
"""Training chunks per point of the learning curve: an evaluation runs ``EVAL_CHUNKS``
chunks, so after every chunk it would double the run; after every fourth chunk (25 curve
points over 100 chunks, each from the 64 robots' fresh starts) it adds half."""

LR_SCALE = ScheduleParams(schedule="linear", init_value=1.0, end_value=0.2,
                          transition_begin=60.0, transition_steps=20.0)
"""Step size over training (factor on the learning rate, per chunk): 0.1 for 60 chunks,
then linearly down to 0.02 by chunk 80 (a decreasing step size lets the tabular estimates
settle; with a constant 0.1 the learned policy kept swinging between 0.0 and 0.66)."""


def grid_env() -> ShootingParams:
    """The shooting env's defaults with the time limit ``MAX_STEPS`` (100 s)."""
    return ShootingParams(max_steps=MAX_STEPS)


def grid_space() -> GridParams:
    """Orientation cut at +-0.3 (library: +-0.1): measured x5 quartiles are about +-0.13
    both at easy starts (robot on the goal axis: truly frontal) and at random ones, so
    +-0.1 split frontal views into left/right by noise of the projected post heights."""
    return GridParams(orient_lower=-0.3, orient_upper=0.3)


def grid_agent() -> QRunnerParams:
    """The library's Q-learner with: asynchronous macro actions (``MACRO_MODE``: a learner
    step is one primitive of every robot, ``CHUNK_STEPS`` per chunk) of at least
    ``MIN_REPEATS`` primitives (with one, a turn in place flipped the goal's orientation
    category every primitive and the greedy policy cycled between two look-alike states);
    epsilon from 1 to 0.1 over ``EXPLORATION_STEPS`` learner steps; discount 0.98 per
    primitive (0.8 would make a goal more than ~3 s away worth < 0.8**30 = 1e-3); step size
    ``LEARNING_RATE``; multi-step returns ``TRACE``; LEM from difficulty 0 to
    ``TASK_DIFFICULTY``, raised by 0.1 after every window of ``LEM_WINDOW`` learner steps
    whose training episodes succeed at >= 90 % (``lem.statistic = "none"``: with traces and
    a constant step size Q never stopped changing by the paper's criterion) and lowered by
    0.1 after one below 50 % (``lem.backoff_level``: without it the near-greedy success fell
    once the difficulty reached 0.8-0.9). LEM off = ``initial_difficulty = max_difficulty``."""
    a = QRunnerParams()
    lem = a.lem.replace(statistic="none", window=LEM_WINDOW, step=0.1, success_level=0.9,
                        backoff_level=0.5, max_difficulty=TASK_DIFFICULTY)
    return a.replace(discount=0.98, learning_rate=LEARNING_RATE, update=UPDATE, trace=TRACE,
                     exploration=a.exploration.replace(transition_steps=EXPLORATION_STEPS),
                     macro=a.macro.replace(min_repeats=MIN_REPEATS, mode=MACRO_MODE), lem=lem,
                     num_envs=64, chunk_steps=CHUNK_STEPS)


def grid_train() -> TabularTrainParams:
    """Evaluation at the task difficulty; the near-greedy policy (epsilon ``EVAL_EPSILON``)
    beside the greedy one draws the learning curve; step size ``LR_SCALE``."""
    return TabularTrainParams(num_chunks=NUM_CHUNKS, eval_every=EVAL_EVERY,
                              eval_difficulty=TASK_DIFFICULTY, eval_chunks=EVAL_CHUNKS,
                              eval_epsilon=EVAL_EPSILON, curve_epsilon=EVAL_EPSILON,
                              lr_scale=LR_SCALE)


@struct.dataclass
class GridBaseline:
    """The grid baseline's sections (an experiment config may hold them at its top level,
    as ``grid_shooting`` does, or as one section)."""

    env: ShootingParams = section(grid_env, doc="shooting task (Section 2), 100 s time limit")
    grid: GridParams = section(grid_space, doc="grid boundaries (319 states)")
    agent: QRunnerParams = section(grid_agent, doc="Q-learning, macro actions, LEM")
    train: TabularTrainParams = section(grid_train, doc="run length and evaluation")


@struct.dataclass
class GridLearner:
    """The grid baseline's learner sections without an env: an experiment that compares
    with the grid on its own env holds these as one section (``baseline.grid``,
    ``baseline.agent``, ``baseline.train``) and runs :func:`grid_program` on :meth:`on` its env."""

    grid: GridParams = section(grid_space, doc="grid boundaries (319 states)")
    agent: QRunnerParams = section(grid_agent, doc="Q-learning, macro actions, LEM")
    train: TabularTrainParams = section(grid_train, doc="run length and evaluation")

    def on(self, env: ShootingParams) -> GridBaseline:
        """The full baseline config on ``env``."""
        return GridBaseline(env=env, grid=self.grid, agent=self.agent, train=self.train)


def grid_program(cfg: Any):
    """The engine program training one grid learner (the tabular learner on
    :class:`~vbl.agents.state_maps.GridMap`); ``cfg`` has the sections of
    :class:`GridBaseline` (``env``, ``grid``, ``agent``, ``train``)."""
    return make_tabular_program(GridMap(ShootingEnv()), cfg)
