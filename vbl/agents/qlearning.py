"""Batched tabular Q-learning: a batch of independent learners, each with E parallel envs.

One learner owns one float32 Q-table (S, A). Each learner step, its E environments act at
the same time and their E transitions update the one table in one batched scatter;
learners are independent, so a batch of learners (seeds x hyperparameter settings) is
``jax.vmap`` over everything here. ``learning_rate``, ``discount`` and ``trace.lam`` are
traced, so a sweep vmaps over them.

How the table learns is one strategy (:mod:`vbl.agents.updates`): one-step Q-learning
(:func:`q_update`, "mean" duplicate rule by default), eligibility traces of each kind
(:mod:`vbl.agents.traces`) or Monte Carlo (:mod:`vbl.agents.monte_carlo`), chosen by
the one field ``update`` (:func:`rule_of`).

:func:`make_qlearning_runner` is the reusable training building block: pure ``init`` /
``run_chunk`` / ``evaluate`` functions that ``lax.scan`` over learner steps of E parallel
environments. One learner step is: select (:func:`_select`), act (:func:`_act`: the env
under :class:`~vbl.envs.macro.MacroWrapper` runs every env's whole action, or in async
mode one primitive of every env's running action), truncation rule (:func:`_truncation`),
update (the rule), bookkeeping (:func:`_record`). An evaluation runs the same step
in evaluation mode (:class:`Evaluation`: epsilon-greedy at a fixed epsilon, step size 0)
from fresh starts; the runner's env counts each env's first episode
(:class:`~vbl.envs.wrappers.FirstEpisodeWrapper`), which :func:`evaluation_stats` reads.
Because the mode is traced, a program can run training and evaluation chunks through one
compiled ``run_chunk``.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.agents.exploration import ExplorationParams, schedule_value, select_action
from vbl.agents.lem import LEMParams, LEMState, lem_init, lem_update
from vbl.agents.one_step import init_q, q_update
from vbl.agents.traces import TraceParams
from vbl.agents.updates import RULES, Transition, UpdateRule, make_rule
from vbl.envs.macro import (
    MacroActionParams,
    MacroState,
    MacroWrapper,
    RunningAction,
    macro_env_params,
)
from vbl.envs.wrappers import EpisodeCounts, FirstEpisodeWrapper
from vbl.params import ParamError, param, section, validate
from vbl.spaces.macro_action import stop_key

__all__ = [
    "QRunnerParams",
    "QRunnerState",
    "QLearningRunner",
    "Evaluation",
    "evaluation_stats",
    "init_q",
    "q_update",
    "make_qlearning_runner",
    "learner_keys",
    "stack_for_learners",
]


@struct.dataclass
class QRunnerParams:
    """One tabular Q-learner (one float32 (S, A) table) and how it runs: its update rule,
    exploration, macro actions, curriculum and E parallel environments."""

    num_states: int = param(319, doc="number of discrete states S (319: the grid space)",
                            static=True, ge=1)
    num_actions: int = param(9, doc="number of actions A (9: two motors x {F, stop, B})",
                             static=True, ge=1)
    learning_rate: float = param(0.25, doc="Q-learning step size alpha", gt=0.0, le=1.0)
    discount: float = param(0.8, doc="discount factor gamma per primitive", ge=0.0, lt=1.0)
    q_init: float = param(0.0, doc="initial value of every Q entry", unit="Q")
    duplicates: str = param("mean", doc="several transitions of one step on the same (s, a): "
                            "apply the mean or the sum of their TD errors", static=True,
                            choices=("mean", "sum"))
    truncation: str = param("skip", doc="a transition that ends an episode by its time limit "
                            "(not terminal): skip it (no update), treat it as terminal, or "
                            "bootstrap from info['final_obs'] (the env must provide it)",
                            static=True, choices=("skip", "terminal", "bootstrap"))
    update: str = param("q_learning", doc="how the table learns (vbl.agents.updates): "
                        "'q_learning' (one-step), eligibility traces 'peng', 'naive', "
                        "'watkins' or 'sarsa' (lambda and window: `trace`), or 'monte_carlo' "
                        "(every decision of a trial moves towards discount^(primitives to the "
                        "goal) if the trial scored, else 0, when it ends; no bootstrapping)",
                        static=True, choices=RULES)
    mc_log: int = param(128, doc="monte_carlo: most decisions of one trial remembered per env "
                        "(later ones are not learned from)", static=True, ge=1)
    exploration: ExplorationParams = section(ExplorationParams, doc="action selection")
    trace: TraceParams = section(TraceParams, doc="eligibility traces (lambda, window) of "
                                 "the trace rules")
    macro: MacroActionParams = section(MacroActionParams, doc="one action = repeat a primitive")
    lem: LEMParams = section(LEMParams, doc="Learning from Easy Missions curriculum")
    num_envs: int = param(64, doc="parallel environments E per learner (all update one table)",
                          static=True, ge=1)
    chunk_steps: int = param(100, doc="learner steps per run_chunk call (a lax.scan)",
                             static=True, ge=1)


def rule_of(p: QRunnerParams) -> UpdateRule:
    """The :class:`~vbl.agents.updates.UpdateRule` of ``p`` (its static fields)."""
    return make_rule(p.update, duplicates=p.duplicates, trace_length=p.trace.length,
                     mc_length=p.mc_log, truncation=p.truncation)


# ---------------------------------------------------------------------------- runner


@struct.dataclass
class QRunnerState:
    """Carry of one learner between chunks (add a leading learner axis when batched)."""

    key: jax.Array
    q: jax.Array              #: (S, A) float32
    env_state: Any            #: env states with leading axis E
    obs: Any                  #: (E, ...) current observations
    s: jax.Array              #: (E,) int32 current discrete states
    steps: jax.Array          #: int32 learner steps so far
    episodes: jax.Array       #: int32 finished episodes (trials) so far
    ep_primitives: jax.Array  #: (E,) int32 primitives in the running episodes
    ep_actions: jax.Array     #: (E,) int32 (macro) actions in the running episodes
    perceived: jax.Array      #: (E,) int32 stop keys of the current observations
    lem: LEMState
    rule: Any                 #: the update rule's state (trace window, Monte Carlo log; E)
    macro: RunningAction      #: per-env running macro actions (E,) (macro.mode 'async')


class QLearningRunner(NamedTuple):
    """Pure functions of one learner (vmap them over learners; ``*_batch`` are jit(vmap))."""

    init: Callable       #: (key, params, env_params) -> QRunnerState
    run_chunk: Callable  #: (carry, params, env_params[, Evaluation]) -> (carry, metrics (T,))
    evaluate: Callable   #: (key, q, params, env_params, num_steps, epsilon[, start]) -> dict
    init_batch: Callable
    run_chunk_batch: Callable
    evaluate_batch: Callable
    params: QRunnerParams  #: the make-time params (their static fields fix the shapes)


def learner_keys(key_or_seed: Any, num_learners: int) -> jax.Array:
    """(L, 2) independent PRNG keys for L learners; L must be >= 1."""
    if not isinstance(num_learners, int | np.integer) or num_learners < 1:
        raise ParamError(f"num_learners={num_learners!r} must be an integer >= 1")
    key = (jax.random.PRNGKey(key_or_seed) if isinstance(key_or_seed, int | np.integer)
           else key_or_seed)
    return jax.random.split(key, int(num_learners))


def stack_for_learners(tree: Any, num_learners: int) -> Any:
    """Give every leaf of a params pytree a leading learner axis L (for ``*_batch``).

    Scalars are broadcast to (L,); arrays whose first axis is already L are kept (a
    sweep); other arrays are broadcast to (L, *shape). Python floats become float32,
    ints int32.
    """
    if not isinstance(num_learners, int | np.integer) or num_learners < 1:
        raise ParamError(f"num_learners={num_learners!r} must be an integer >= 1")
    n = int(num_learners)

    def leaf(x):
        if isinstance(x, bool):
            x = jnp.asarray(x, bool)
        elif isinstance(x, int):
            x = jnp.asarray(x, jnp.int32)
        elif isinstance(x, float):
            x = jnp.asarray(x, jnp.float32)
        x = jnp.asarray(x)
        if x.ndim >= 1 and x.shape[0] == n:
            return x
        return jnp.broadcast_to(x, (n, *x.shape))

    return jax.tree.map(leaf, tree)


@struct.dataclass
class Evaluation:
    """A traced evaluation mode of :func:`make_qlearning_runner`'s step: where ``active``,
    actions are epsilon-greedy at ``epsilon`` (ties broken at random) and the step size is 0
    (the table does not move); elsewhere the step trains as usual."""

    active: Any = True    #: () bool
    epsilon: Any = 0.0    #: () float32 epsilon of the evaluated policy (0: greedy)


class _Runner(NamedTuple):
    """The static parts of a runner (fixed at make time)."""

    env: MacroWrapper  #: the learner's env under the macro-action wrapper
    state_fn: Callable
    params: QRunnerParams
    rule: UpdateRule

    @property
    def num_envs(self) -> int:
        return self.params.num_envs


class _EnvStep(NamedTuple):
    """What one learner step's (macro) env steps gave, each (E,) unless noted."""

    obs: Any
    state: MacroState   #: the wrapper's state after the step
    term: jax.Array
    trunc: jax.Array
    info: Any
    macro: dict         #: ``info["macro"]``: the (ended) action's start, action, reward, n
    action_ended: Any   #: async: bool, the action ended here; sync: None
    primitives: Any     #: primitives run at this step (sync: n; async: 1)
    decisions: Any      #: decisions at this step (sync: 1; async: decided)


class _Learned(NamedTuple):
    """What one learner step's update gave."""

    q: jax.Array        #: (S, A) the table after the update
    rule_state: Any     #: the update rule's state after it
    lem: LEMState
    rate: jax.Array     #: the behaviour policy's epsilon (or temperature) at this step
    td_abs: jax.Array   #: mean |TD error| of the updated transitions


def _check(env: Any, params: QRunnerParams, env_params: Any) -> None:
    n_actions = getattr(env, "num_actions", None)
    if n_actions is not None and int(n_actions) != params.num_actions:
        raise ParamError(f"num_actions={params.num_actions} but the env has {n_actions} "
                         "actions")
    if params.lem.enabled:
        ep = env.default_params if env_params is None else env_params
        if not hasattr(ep, "start_difficulty"):
            raise ParamError("lem.enabled=True needs env params with a 'start_difficulty' "
                             f"field; {type(ep).__name__} has none (set lem.enabled=False)")


def _states(run: _Runner, obs: Any) -> jax.Array:
    return jnp.asarray(jax.vmap(run.state_fn)(obs), jnp.int32)


def _wrapper_params(run: _Runner, params: QRunnerParams, env_params, difficulty):
    """The macro wrapper's params, the env's at LEM's start ``difficulty`` (when on)."""
    if run.params.lem.enabled:
        env_params = env_params.replace(start_difficulty=difficulty)
    return macro_env_params(env_params, params.macro, params.discount)


def _init(run: _Runner, key, params: QRunnerParams, env_params) -> QRunnerState:
    k_reset, key = jax.random.split(key)
    q = init_q(params)
    lem = lem_init(params.lem, q)
    obs, st = jax.vmap(run.env.reset, in_axes=(0, None))(
        jax.random.split(k_reset, run.num_envs),
        _wrapper_params(run, params, env_params, lem.difficulty))
    zeros = jnp.zeros((run.num_envs,), jnp.int32)
    return QRunnerState(key=key, q=q, env_state=st.inner, obs=obs, s=st.index,
                        steps=jnp.int32(0), episodes=jnp.int32(0), ep_primitives=zeros,
                        ep_actions=zeros, perceived=st.key, lem=lem,
                        rule=run.rule.init(run.num_envs, q.size), macro=st.running)


def _schedule_count(run: _Runner, steps: jax.Array, episodes: jax.Array) -> jax.Array:
    """The exploration schedule's count (learner steps or finished episodes)."""
    return steps if run.params.exploration.count_unit == "steps" else episodes


def _select(run: _Runner, k_act, carry: QRunnerState, params: QRunnerParams,
            mode: Evaluation | None) -> tuple[jax.Array, jax.Array]:
    """(rate, action (E,)): the behaviour policy, or where ``mode`` is active the
    epsilon-greedy policy at its epsilon."""
    rate = schedule_value(params.exploration,
                          _schedule_count(run, carry.steps, carry.episodes))
    values = carry.q[carry.s]
    action = run.rule.act(carry.rule, select_action(k_act, values, rate,
                                                    run.params.exploration.policy))
    if mode is None:
        return rate, action
    epsilon = jnp.asarray(mode.epsilon, jnp.float32)
    evaluated = select_action(k_act, values, epsilon, "epsilon_greedy")
    on = jnp.asarray(mode.active, bool)
    return jnp.where(on, epsilon, rate), jnp.where(on, evaluated, action)


def _act(run: _Runner, key, carry: QRunnerState, action, params: QRunnerParams,
         env_params) -> _EnvStep:
    """Every env steps under the macro wrapper: its whole action (sync, or one primitive
    when macro actions are off), or one primitive of its running action (async)."""
    keys = jax.random.split(key, run.num_envs)
    wrapper_params = _wrapper_params(run, params, env_params, carry.lem.difficulty)
    state = MacroState(inner=carry.env_state, index=carry.s, key=carry.perceived,
                       running=carry.macro)
    obs, state, _, term, trunc, info = jax.vmap(run.env.step, in_axes=(0, 0, 0, None))(
        keys, state, action, wrapper_params)
    macro = info["macro"]
    if run.env.is_async:
        return _EnvStep(obs, state, term, trunc, info, macro, action_ended=macro["ended"],
                        primitives=1, decisions=macro["decided"].astype(jnp.int32))
    return _EnvStep(obs, state, term, trunc, info, macro, action_ended=None,
                    primitives=macro["num_primitives"], decisions=1)


def _truncation(run: _Runner, moved: _EnvStep) -> tuple[Any, Any, Any]:
    """(terminal, weight, s_boot) of the transitions under ``truncation``."""
    mode = run.params.truncation
    cut, s_next = moved.trunc & ~moved.term, moved.state.index
    if mode == "skip":
        return moved.term, ~cut, s_next
    if mode == "terminal":
        return moved.term | moved.trunc, None, s_next
    if "final_obs" not in moved.info:
        raise ParamError("truncation='bootstrap' needs info['final_obs'] from the env")
    return moved.term, None, jnp.where(cut, _states(run, moved.info["final_obs"]), s_next)


def _next_action(run: _Runner, k_act, carry: QRunnerState, moved: _EnvStep,
                 params: QRunnerParams) -> jax.Array:
    """Sarsa: the action each env takes next in ``s_next`` (pre-update table, next rate)."""
    n_done = jnp.sum(moved.term | moved.trunc, dtype=jnp.int32)
    rate = schedule_value(params.exploration,
                          _schedule_count(run, carry.steps + 1, carry.episodes + n_done))
    return select_action(jax.random.fold_in(k_act, 1), carry.q[moved.state.index], rate,
                         run.params.exploration.policy)


def _transition(run: _Runner, k_act, carry: QRunnerState, moved: _EnvStep,
                params: QRunnerParams) -> Transition:
    """The rule's view of this step's transitions."""
    terminal, weight, s_boot = _truncation(run, moved)
    done = moved.term | moved.trunc
    a_next = _next_action(run, k_act, carry, moved, params) if run.rule.next_action else None
    macro = moved.macro
    return Transition(s=macro["start"], a=macro["action"], r=macro["reward"],
                      n=macro["num_primitives"], s_boot=s_boot, terminal=terminal, done=done,
                      truncated=moved.trunc & ~moved.term, weight=weight,
                      advance=moved.action_ended, decided=macro["decided"],
                      clock=carry.ep_primitives,
                      last_clock=carry.ep_primitives + moved.primitives - 1,
                      scored=jnp.asarray(moved.info["success"]).astype(bool) & done,
                      a_next=a_next)


def _record(carry: QRunnerState, moved: _EnvStep, key, learned: _Learned):
    """Episode bookkeeping: (new carry, metrics)."""
    done = moved.term | moved.trunc
    success = jnp.asarray(moved.info["success"]).astype(bool) & done
    ep_primitives = carry.ep_primitives + moved.primitives
    ep_actions = carry.ep_actions + moved.decisions
    metrics = dict(
        episodes=jnp.sum(done, dtype=jnp.int32),
        successes=jnp.sum(success, dtype=jnp.int32),
        primitives=jnp.sum(jnp.where(done, ep_primitives, 0), dtype=jnp.int32),
        actions=jnp.sum(jnp.where(done, ep_actions, 0), dtype=jnp.int32),
        td_abs=learned.td_abs, rate=jnp.asarray(learned.rate, jnp.float32),
        difficulty=carry.lem.difficulty, lem_raises=learned.lem.raises)
    new = QRunnerState(key=key, q=learned.q, env_state=moved.state.inner, obs=moved.obs,
                       s=moved.state.index, steps=carry.steps + 1,
                       episodes=carry.episodes + metrics["episodes"],
                       ep_primitives=jnp.where(done, 0, ep_primitives),
                       ep_actions=jnp.where(done, 0, ep_actions),
                       perceived=moved.state.key, lem=learned.lem,
                       rule=learned.rule_state, macro=moved.state.running)
    return new, metrics


def _step(run: _Runner, carry: QRunnerState, params: QRunnerParams, env_params,
          mode: Evaluation | None = None):
    """One learner step: select, act, update (step size 0 where ``mode`` is active),
    record."""
    key, k_act, k_env = jax.random.split(carry.key, 3)
    rate, action = _select(run, k_act, carry, params, mode)
    moved = _act(run, k_env, carry, action, params, env_params)
    t = _transition(run, k_act, carry, moved, params)
    learning = params if mode is None else params.replace(learning_rate=jnp.where(
        jnp.asarray(mode.active, bool), 0.0, params.learning_rate).astype(jnp.float32))
    q, rule_state, td_abs = run.rule.update(carry.q, carry.rule, t, learning)
    lem = lem_update(carry.lem, q, params.lem, jnp.sum(t.done), jnp.sum(t.scored))
    return _record(carry, moved, key, _Learned(q, rule_state, lem, rate, td_abs))


def _run_chunk(run: _Runner, carry: QRunnerState, params: QRunnerParams, env_params,
               mode: Evaluation | None = None):
    return jax.lax.scan(lambda c, _: _step(run, c, params, env_params, mode), carry, None,
                        length=run.params.chunk_steps)


def evaluation_stats(carry: QRunnerState, metrics: dict) -> dict[str, jax.Array]:
    """What an evaluation from fresh starts gave, as float32 scalars: ``success_rate``
    (fraction of the E envs whose first episode since the starts scored; one not finished
    counts as a failure), ``finished`` (fraction that finished one), ``mean_primitives``
    (mean length of the episodes that finished, primitives) and
    ``primitives_per_decision`` (their primitives per (macro) action); ``metrics`` are the
    step metrics of the evaluation (any leading axes), ``carry`` the runner state after it."""
    counts: EpisodeCounts = carry.env_state
    done = counts.episodes > 0
    f32 = jnp.float32
    episodes = jnp.sum(metrics["episodes"]).astype(f32)
    primitives = jnp.sum(metrics["primitives"]).astype(f32)
    return dict(success_rate=jnp.mean((counts.first_success & done).astype(f32)),
                finished=jnp.mean(done.astype(f32)),
                mean_primitives=primitives / jnp.maximum(episodes, 1.0),
                primitives_per_decision=primitives / jnp.maximum(
                    jnp.sum(metrics["actions"]).astype(f32), 1.0))


def _evaluate(run: _Runner, key, q, params: QRunnerParams, env_params, num_steps: int = 200,
              epsilon: Any = 0.0, start: QRunnerState | None = None):
    """The epsilon-greedy policy of table ``q`` (``epsilon`` 0: greedy; may be traced; > 0
    breaks cycles between aliased states) from fresh starts, ``num_steps`` (static) learner
    steps in evaluation mode; :func:`evaluation_stats`. The starts are ``start`` (a state
    from ``init``; its key replaced by ``key``) or drawn from ``key`` at ``env_params``'
    start difficulty (LEM's pinned to it)."""
    if start is None:
        if run.params.lem.enabled:  # start (and stay) at env_params' own difficulty
            d = jnp.asarray(env_params.start_difficulty, jnp.float32)
            params = params.replace(lem=params.lem.replace(initial_difficulty=d))
        key, k_init = jax.random.split(key)
        start = _init(run, k_init, params, env_params)
    carry = start.replace(key=key, q=jnp.asarray(q, jnp.float32))
    mode = Evaluation(active=jnp.bool_(True), epsilon=jnp.asarray(epsilon, jnp.float32))
    carry, metrics = jax.lax.scan(lambda c, _: _step(run, c, params, env_params, mode), carry,
                                  None, length=num_steps)
    return evaluation_stats(carry, metrics)


def make_qlearning_runner(env: Any, state_fn: Callable, params: QRunnerParams,
                          env_params: Any = None,
                          perceive_fn: Callable | None = None) -> QLearningRunner:
    """Build the pure training functions of one learner for a gymnax-style ``env``.

    Args:
      env: ``reset(key, env_params) -> (obs, state)``, ``step(key, state, action,
        env_params) -> (obs, state, reward, terminated, truncated, info)`` with
        auto-reset and ``info["success"]``; optional ``num_actions``. The runner counts
        each env's first episode around it (:class:`~vbl.envs.wrappers.FirstEpisodeWrapper`).
      state_fn: observation(s) (..., obs_dim) -> int32 discrete state in [0, S).
      params: validated here; its static fields (S, A, E, T, kinds) fix the shapes.
      env_params: used only to check that LEM can set ``start_difficulty``
        (default ``env.default_params``).
      perceive_fn: observation -> int32 what the state map perceives of the world; a macro
        action ends when it changes (default ``state_fn``; ``macro.stop_on`` applies on top).

    Returns a :class:`QLearningRunner`. ``run_chunk(carry, params, env_params, mode=None)``
    runs ``params.chunk_steps`` learner steps (in evaluation mode where the traced
    :class:`Evaluation` ``mode`` is active); its metrics (each of shape (T,)) are
    ``episodes`` (finished in that step), ``successes``, ``primitives`` and ``actions``
    (summed lengths of the finished episodes), ``td_abs`` (mean |TD error| of the updated
    transitions), ``rate`` (epsilon or temperature), ``difficulty`` (LEM start difficulty)
    and ``lem_raises``. ``evaluate(key, q, params, env_params, num_steps=200, epsilon=0,
    start=None)`` runs the epsilon-greedy policy of ``q`` (random tie-breaking, no learning)
    for ``num_steps`` learner steps and returns :func:`evaluation_stats`.
    """
    validate(params)
    _check(env, params, env_params)
    mp = params.macro
    run = _Runner(env=MacroWrapper(FirstEpisodeWrapper(env), state_fn, mp,
                                   stop_key(mp.stop_on), perceive_fn),
                  state_fn=state_fn, params=params, rule=rule_of(params))
    init, run_chunk, evaluate = (partial(_init, run), partial(_run_chunk, run),
                                 partial(_evaluate, run))
    init_batch = jax.jit(jax.vmap(init, in_axes=(0, 0, 0)))
    run_chunk_batch = jax.jit(jax.vmap(run_chunk, in_axes=(0, 0, 0)))

    def evaluate_many(keys, q, params, env_params, num_steps: int = 200, epsilon: Any = 0.0):
        return jax.vmap(evaluate, in_axes=(0, 0, 0, 0, None, None))(
            keys, q, params, env_params, num_steps, epsilon)

    evaluate_batch = jax.jit(evaluate_many, static_argnums=(4,))
    return QLearningRunner(init=init, run_chunk=run_chunk, evaluate=evaluate,
                           init_batch=init_batch, run_chunk_batch=run_chunk_batch,
                           evaluate_batch=evaluate_batch, params=params)
