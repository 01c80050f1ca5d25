"""The one tabular learner of the paper's comparison: Q-learning on any state map.

:func:`make_tabular_program` turns a :class:`~vbl.agents.state_maps.StateMap` and the
batched runner of :mod:`vbl.agents.qlearning` into an engine :class:`~vbl.engine.Program`
(one learner's run, chunked; the engine vmaps it over seeds x sweep values). Every state
space the paper compares (the 319-state grid, the current image features, the CVA state,
the velocity oracle) learns through it, with the same update rules, macro actions and
evaluation. Config sections: ``env`` (the task's params), ``agent``
(:class:`vbl.agents.qlearning.QRunnerParams`), ``train`` (:class:`TabularTrainParams`) and
the map's own (``grid``; ``cva``). Evaluation runs through the training step in evaluation
mode from starts drawn in ``init``, on key streams of its own (:data:`PREPARE_STREAM`,
:data:`EVAL_STREAM`), so it leaves training unchanged; so does the final evaluation, after
the last chunk (``Program.begin_final``), so the step is the one program that holds the
env and the learner step.

See docs/agents.md, "The tabular learner" (evaluation, the metrics per chunk and final).
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.agents.exploration import ScheduleParams, schedule_value
from vbl.agents.qlearning import Evaluation, QRunnerState, evaluation_stats, make_qlearning_runner
from vbl.agents.state_maps import StateMap
from vbl.engine.experiment import Program
from vbl.params import ParamError, param, section, validate

__all__ = ["TabularTrainParams", "TabularCarry", "FinalProgress", "make_tabular_program",
           "curve_metric", "decision_primitives", "EVAL_STREAM", "PREPARE_STREAM"]

F32 = jnp.float32
EVAL_STREAM = 0x5EED  #: fold_in tag of the evaluation keys (kept off the training stream)
PREPARE_STREAM = 0x9E9  #: fold_in tag of the map's fit (data collection, quantiser)
SUMMED = ("episodes", "successes", "primitives", "actions")  #: chunk totals of the runner


def curve_metric(curves: dict) -> str:
    """The learning curve a run has: ``eval_success`` (``train.eval_curve`` on), else
    ``train_success``."""
    return "eval_success" if "eval_success" in curves else "train_success"


def decision_primitives(res: Any, point: int) -> np.ndarray:
    """(seeds,) primitives per decision of sweep point ``point``'s training episodes over a
    finished run ``res`` (a RunResult): their primitives over their (macro) actions."""
    prims = np.asarray(res.curves["primitives"][point], np.float64).sum(axis=0)
    acts = np.asarray(res.curves["decisions"][point], np.float64).sum(axis=0)
    return prims / np.maximum(acts, 1.0)


@struct.dataclass
class TabularTrainParams:
    """Run length, evaluation and step-size schedule of the tabular learner (one chunk =
    ``agent.chunk_steps`` learner steps of ``agent.num_envs`` environments)."""

    num_chunks: int = param(40, doc="training chunks per run (a curve point and metrics "
                            "line every eval_every of them)", static=True, ge=1)
    eval_curve: bool = param(True, doc="evaluate the policy on fresh starts for the "
                             "eval_success curve (every eval_every chunks); off: no "
                             "eval_success curve (train_success is always recorded)",
                             static=True)
    eval_every: int = param(1, doc="training chunks per curve point: one engine chunk (a "
                            "metrics line, the checkpoint unit) trains this many chunks, then "
                            "evaluates once; num_chunks must be a multiple of it",
                            static=True, ge=1)
    eval_chunks: int = param(1, doc="chunks of agent.chunk_steps learner steps per "
                             "evaluation: each env's first episode from its fresh start "
                             "counts, one not finished by then is a failure (so "
                             "eval_chunks x chunk_steps should reach env.max_steps)",
                             static=True, ge=1)
    eval_difficulty: float = param(1.0, doc="start difficulty of evaluation episodes (1: fully "
                                   "random starts)", ge=0.0, le=1.0)
    eval_epsilon: float = param(0.05, doc="final evaluation: epsilon of the near-greedy "
                                "policy (greedy, but a uniform action with this probability: "
                                "breaks cycles between aliased states)", ge=0.0, le=1.0)
    curve_epsilon: float = param(0.0, doc="epsilon of the policy the eval_success curve "
                                 "evaluates (0: greedy; e.g. eval_epsilon: near-greedy)",
                                 ge=0.0, le=1.0)
    eval_rounds: int = param(4, doc="final evaluation: rounds of agent.num_envs fresh starts, "
                             "the same for the greedy, near-greedy and random policies",
                             static=True, ge=1)
    lr_scale: ScheduleParams = section(
        lambda: ScheduleParams(schedule="constant", init_value=1.0),
        doc="factor on agent.learning_rate in each training chunk, count = chunks done "
        "(default constant 1: the agent's step size throughout)")

    def check(self) -> None:
        if self.num_chunks % self.eval_every:
            raise ParamError(f"train.num_chunks={self.num_chunks} must be a multiple of "
                             f"train.eval_every={self.eval_every}")


@struct.dataclass
class FinalProgress:
    """Where the final evaluation stands. It runs through the training step: unit
    ``u = policy x eval_rounds + round`` (policies greedy, near-greedy, random) is one
    round's starts evaluated for ``eval_chunks`` sub-chunks."""

    done: jax.Array     #: () int32 sub-chunks of the final evaluation run; -1: training
    keys: jax.Array     #: (units, 2) uint32 each unit's evaluation key
    counts: jax.Array   #: (3,) int32 episodes, primitives, actions of the unit in progress
    results: dict       #: name -> (units,) float32 :func:`evaluation_stats` of each unit


@struct.dataclass
class TabularCarry:
    """One learner between chunks."""

    learner: QRunnerState     #: the training runner's state
    fitted: Any               #: the map's fitted parameters (StateMap.prepare)
    starts: QRunnerState      #: (eval_rounds, ...) fresh evaluation starts
    evaluation: QRunnerState  #: the final evaluation's unit in progress (training: starts[0])
    final: FinalProgress

    def finishing(self) -> jax.Array:
        """() bool: the final evaluation has begun (a step runs its units, not training)."""
        return self.final.done >= 0


def _require(cfg: Any) -> None:
    missing = [n for n in ("env", "agent", "train") if not hasattr(cfg, n)]
    if missing:
        raise ParamError(f"a tabular program's config needs sections ['env', 'agent', "
                         f"'train']; {type(cfg).__name__} lacks {missing}")
    if not hasattr(cfg.env, "start_difficulty"):
        raise ParamError(f"the evaluation sets env.start_difficulty; {type(cfg.env).__name__} "
                         "has no such field")


def _where(flag: jax.Array, a: Any, b: Any) -> Any:
    return jax.tree.map(lambda x, y: jnp.where(flag, x, y), a, b)


def _stack(first: Any, rest: Any, n: int) -> Any:
    """Leaves ``[first, rest x n]`` along a new leading axis."""
    return jax.tree.map(lambda a, b: jnp.concatenate(
        [jnp.asarray(a)[None], jnp.broadcast_to(jnp.asarray(b), (n, *jnp.shape(b)))]),
        first, rest)


def _check_evaluation_length(train: TabularTrainParams, agent: Any, env: Any) -> None:
    """ParamError when an evaluation is shorter than the env's time limit."""
    steps = train.eval_chunks * agent.chunk_steps
    max_steps = getattr(env, "max_steps", None)
    if isinstance(max_steps, int) and steps < max_steps:
        raise ParamError(f"train.eval_chunks={train.eval_chunks} x agent.chunk_steps="
                         f"{agent.chunk_steps} must be >= env.max_steps={max_steps} (every "
                         "evaluation episode must be able to finish)")


def _training_metrics(t: dict, learner: QRunnerState, difficulty: jax.Array) -> dict:
    """A chunk's metrics (module docstring) from the runner metrics ``t`` of its training
    sub-chunks, each (eval_every, chunk_steps), and the learner after them."""
    tot = {k: jnp.sum(t[k]).astype(F32) for k in SUMMED}
    n = jnp.maximum(tot["episodes"], 1.0)
    return dict(episodes=tot["episodes"], successes=tot["successes"],
                train_success=tot["successes"] / n, mean_primitives=tot["primitives"] / n,
                primitives=tot["primitives"], decisions=tot["actions"],
                primitives_per_decision=tot["primitives"] / jnp.maximum(tot["actions"], 1.0),
                difficulty=difficulty.astype(F32), lem_raises=learner.lem.raises.astype(F32),
                epsilon=t["rate"][-1, -1],
                td_abs=jnp.mean(jnp.mean(t["td_abs"], axis=1)).astype(F32),
                learning_rate=t["learning_rate"][-1, -1].astype(F32))


POLICIES = 3  #: final evaluation: greedy, near-greedy (train.eval_epsilon), random
STATS = ("success_rate", "finished", "mean_primitives", "primitives_per_decision")
COUNTED = ("episodes", "primitives", "actions")  #: a unit's tallies (FinalProgress.counts)


def _first(tree: Any) -> Any:
    """The first entry along the leading axis of every leaf."""
    return jax.tree.map(lambda a: a[0], tree)


def _no_final(rounds: int) -> FinalProgress:
    """The final evaluation not begun (``done`` -1), for ``rounds`` rounds per policy."""
    units = POLICIES * rounds
    return FinalProgress(done=jnp.int32(-1), keys=jnp.zeros((units, 2), jnp.uint32),
                         counts=jnp.zeros((3,), jnp.int32),
                         results={k: jnp.zeros((units,), F32) for k in STATS})


def _unit_keys(key: jax.Array, rounds: int) -> jax.Array:
    """(POLICIES x rounds, 2) evaluation keys of the units: round r of policy p has
    ``split(split(key, POLICIES)[p], rounds)[r]``."""
    return jax.vmap(lambda k: jax.random.split(k, rounds))(
        jax.random.split(key, POLICIES)).reshape(POLICIES * rounds, -1)


def _round_mean(v: jax.Array) -> jax.Array:
    """(POLICIES,) float32 means of (POLICIES, rounds) results over the rounds, summed as
    the even rounds plus the odd rounds: the order in which XLA's vectorised reduction adds
    a short row, so that the means do not depend on where they are compiled."""
    return ((jnp.sum(v[:, 0::2], axis=1) + jnp.sum(v[:, 1::2], axis=1))
            / v.shape[1]).astype(F32)


def _evaluation_start(carry: TabularCarry, learner: QRunnerState, finishing: jax.Array,
                      u: jax.Array, rounds: int, c: Any) -> tuple[QRunnerState, jax.Array]:
    """(fresh state, epsilon) of a sub-chunk that begins an evaluation. Finishing: unit
    ``u``'s (round ``u % rounds``'s starts and the unit's key; policy ``u // rounds``'s
    table, the zero one for the random policy, and epsilon); else the curve's (the first
    starts, a key folded off the learner's, its table, ``train.curve_epsilon``)."""
    policy, rnd = u // rounds, u % rounds
    start = jax.tree.map(lambda a: a[jnp.where(finishing, rnd, 0)], carry.starts)
    fresh = start.replace(
        key=jnp.where(finishing, carry.final.keys[u],
                      jax.random.fold_in(learner.key, EVAL_STREAM)),
        q=jnp.where(finishing & (policy == POLICIES - 1), 0.0, learner.q))
    eps = jnp.where(finishing, jnp.where(policy == 1, c.train.eval_epsilon, 0.0),
                    c.train.curve_epsilon)
    return fresh, jnp.asarray(eps, F32)


def _tally(counts: jax.Array, results: dict, ev: QRunnerState, m: dict, begin: jax.Array,
           ended: jax.Array, u: jax.Array) -> tuple[jax.Array, dict]:
    """A unit's (counts, results) after a sub-chunk with runner metrics ``m`` and state
    ``ev``: the counts restart where ``begin``; where ``ended``, unit ``u``'s results are
    :func:`evaluation_stats` of its state and counts."""
    counts = jnp.where(begin, 0, counts) + jnp.stack(
        [jnp.sum(m[k], dtype=jnp.int32) for k in COUNTED])
    stats = evaluation_stats(ev, dict(zip(COUNTED, counts, strict=True)))
    return counts, {k: v.at[u].set(jnp.where(ended, stats[k], v[u]))
                    for k, v in results.items()}


def _next_carry(carry: TabularCarry, learner: QRunnerState, ev: QRunnerState,
                counts: jax.Array, results: dict, subs: int) -> TabularCarry:
    """The carry after a step of ``subs`` sub-chunks. A training carry keeps the first
    starts as its evaluation state (a function of the rest) and its final evaluation
    unbegun; a finishing one keeps the unit in progress and its tallies."""
    fin, finishing = carry.final, carry.finishing()
    fin = fin.replace(done=jnp.where(finishing, fin.done + subs, fin.done),
                      counts=jnp.where(finishing, counts, fin.counts), results=results)
    return carry.replace(learner=learner, evaluation=_where(finishing, ev, _first(carry.starts)),
                         final=fin)


def _policy_metrics(results: dict, rounds: int) -> dict:
    """The final evaluation's success metrics from its units' ``results``: the learned
    greedy policy, the learned near-greedy one and the zero table (uniformly random), each
    the mean over the same ``rounds`` rounds of starts."""
    mean = {k: _round_mean(v.reshape(POLICIES, rounds)) for k, v in results.items()}
    return dict(greedy_success=mean["success_rate"][0],
                near_greedy_success=mean["success_rate"][1],
                random_success=mean["success_rate"][2],
                greedy_primitives=mean["mean_primitives"][0],
                greedy_finished=mean["finished"][0],
                greedy_primitives_per_decision=mean["primitives_per_decision"][0])


def _runner(smap: StateMap, agent: Any, c: Any) -> Any:
    """The runner (static fields of ``agent``) whose state map reads the learner's config
    ``c``."""
    return make_qlearning_runner(smap.env, lambda o: smap.index(o, c), agent, None,
                                 lambda o: smap.perceived(o, c))


def _evaluation_setting(smap: StateMap, agent: Any, c: Any, fitted: Any) -> tuple:
    """(agent params, env params) of an evaluation: fresh starts at eval_difficulty."""
    d = jnp.asarray(c.train.eval_difficulty, F32)
    p = c.agent.replace(num_states=agent.num_states)
    if agent.lem.enabled:  # start (and stay) at the evaluation's difficulty
        p = p.replace(lem=p.lem.replace(initial_difficulty=d))
    return p, smap.env_params(fitted, c.env.replace(start_difficulty=d))


def _begin_final(rounds: int, carry: TabularCarry, c: Any, key: jax.Array) -> TabularCarry:
    """``Program.begin_final``: the final evaluation begun, its units' keys from ``key``."""
    return carry.replace(final=_no_final(rounds).replace(done=jnp.int32(0),
                                                         keys=_unit_keys(key, rounds)))


def _final(smap: StateMap, num_states: int, rounds: int, carry: TabularCarry, c: Any,
           key: jax.Array) -> dict:
    """``Program.final``: the policies' metrics from the finished evaluation's units, the
    table's size and the rows it moved from ``agent.q_init``, and the map's own."""
    q = carry.learner.q
    moved = jnp.any(q != jnp.asarray(c.agent.q_init, F32), axis=1)
    return dict(_policy_metrics(carry.final.results, rounds),
                num_states=jnp.asarray(num_states, F32),
                states_with_value=jnp.sum(moved).astype(F32),
                **smap.describe(carry.fitted))


# shape: a program factory in the purejaxrl mould: init and step are short closures over
# the static config, and the factory's length is theirs.
def make_tabular_program(smap: StateMap, cfg: Any) -> Program:
    """An engine :class:`~vbl.engine.Program` training one tabular learner on ``smap``.

    ``cfg`` is the experiment's resolved config (sections ``env``, ``agent``, ``train`` and
    the map's); only its static fields shape the program. ``agent.num_states`` is set to
    the map's. Metrics in the module docstring; ParamError for a bad config.
    """
    _require(cfg)
    train = validate(cfg.train, "train.")
    agent = validate(cfg.agent.replace(num_states=int(smap.num_states)), "agent.")
    _check_evaluation_length(train, agent, cfg.env)
    n_train, n_eval, rounds = train.eval_every, train.eval_chunks, train.eval_rounds
    subs = n_train + (n_eval if train.eval_curve else 0)  # sub-chunks per step
    units = POLICIES * rounds

    runner = partial(_runner, smap, agent)
    eval_setting = partial(_evaluation_setting, smap, agent)

    def params(c):
        return c.agent.replace(num_states=agent.num_states)

    def init(key, c) -> TabularCarry:
        fitted = smap.prepare(jax.random.fold_in(key, PREPARE_STREAM), c)
        p_eval, e_eval = eval_setting(c, fitted)
        keys = jnp.concatenate([key[None], jax.random.split(jax.random.fold_in(
            key, EVAL_STREAM), rounds)])
        # the training runner and the evaluation starts in one vmapped init: the env's
        # reset (its camera) is compiled once
        both = jax.vmap(runner(c).init)(keys, _stack(params(c), p_eval, rounds),
                                        _stack(smap.env_params(fitted, c.env), e_eval, rounds))
        starts = jax.tree.map(lambda a: a[1:], both)
        return TabularCarry(_first(both), fitted, starts, _first(starts), _no_final(rounds))

    def step(carry: TabularCarry, c):
        run = runner(c)
        p_eval, e_eval = eval_setting(c, carry.fitted)
        e_train = smap.env_params(carry.fitted, c.env)
        fin, finishing = carry.final, carry.finishing()

        def chunk(state, j):
            """Sub-chunk j: training, a curve point's evaluation or (finishing) a unit of the
            final evaluation; one compiled run_chunk."""
            learner, ev, counts, results = state
            g = fin.done + j                     # the final evaluation's sub-chunk
            u = jnp.minimum(g // n_eval, units - 1)
            evaluating = finishing | (j >= n_train)
            begin = jnp.where(finishing, g % n_eval == 0, j == n_train)
            fresh, eps = _evaluation_start(carry, learner, finishing, u, rounds, c)
            ev = _where(begin, fresh, ev)
            lr = c.agent.learning_rate * schedule_value(
                c.train.lr_scale, learner.steps // agent.chunk_steps)
            cur, m = run.run_chunk(
                _where(evaluating, ev, learner), _where(evaluating, p_eval, params(c).replace(
                    learning_rate=jnp.asarray(lr, F32))), _where(evaluating, e_eval, e_train),
                Evaluation(evaluating, eps))
            learner, ev = _where(evaluating, learner, cur), _where(evaluating, cur, ev)
            ended = finishing & (g % n_eval == n_eval - 1) & (g < units * n_eval)
            counts, results = _tally(counts, results, ev, m, begin, ended, u)
            return (learner, ev, counts, results), dict(
                m, learning_rate=jnp.full_like(m["rate"], lr))

        (learner, ev, counts, results), ms = jax.lax.scan(
            chunk, (carry.learner, carry.evaluation, fin.counts, fin.results),
            jnp.arange(subs))
        out = _training_metrics(jax.tree.map(lambda a: a[:n_train], ms), learner,
                                learner.lem.difficulty if agent.lem.enabled else
                                jnp.asarray(c.env.start_difficulty))
        if train.eval_curve:
            e = jax.tree.map(lambda a: a[n_train:], ms)
            out["eval_success"] = evaluation_stats(ev, e)["success_rate"]
        return _next_carry(carry, learner, ev, counts, results, subs), out

    return Program(init=init, step=step, num_chunks=train.num_chunks // train.eval_every,
                   final=partial(_final, smap, agent.num_states, rounds),
                   begin_final=partial(_begin_final, rounds),
                   final_steps=-(-units * n_eval // subs),
                   progress_metric="eval_success" if train.eval_curve else "train_success")
