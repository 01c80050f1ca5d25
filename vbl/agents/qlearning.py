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
update (the rule), bookkeeping and LEM (:func:`_record`). An evaluation runs the same step
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


class _Spec(NamedTuple):
    """The static parts of a runner (fixed at make time)."""

    env: MacroWrapper  #: the learner's env under the macro-action wrapper
    state_fn: Callable
    params: QRunnerParams
    rule: UpdateRule

    @property
    def n_envs(self) -> int:
        return self.params.num_envs


class _Moved(NamedTuple):
    """What one learner step's (macro) env steps gave, each (E,) unless noted."""

    obs: Any
    state: MacroState   #: the wrapper's state after the step
    term: jax.Array
    trunc: jax.Array
    info: Any
    macro: dict         #: ``info["macro"]``: the (ended) action's start, action, reward, n
    advance: Any        #: async: bool, the action ended here; sync: None
    prims: Any          #: primitives run at this step (sync: n; async: 1)
    acts: Any           #: decisions at this step (sync: 1; async: decided)


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


def _states(sp: _Spec, obs: Any) -> jax.Array:
    return jnp.asarray(jax.vmap(sp.state_fn)(obs), jnp.int32)


def _env_params_at(sp: _Spec, env_params: Any, difficulty: jax.Array) -> Any:
    if sp.params.lem.enabled:
        return env_params.replace(start_difficulty=difficulty)
    return env_params


def _wrapper_params(sp: _Spec, params: QRunnerParams, env_params, difficulty):
    return macro_env_params(_env_params_at(sp, env_params, difficulty), params.macro,
                            params.discount)


def _init(sp: _Spec, key, params: QRunnerParams, env_params) -> QRunnerState:
    k_reset, key = jax.random.split(key)
    q = init_q(params)
    lem = lem_init(params.lem, q)
    obs, st = jax.vmap(sp.env.reset, in_axes=(0, None))(
        jax.random.split(k_reset, sp.n_envs), _wrapper_params(sp, params, env_params,
                                                              lem.difficulty))
    zeros = jnp.zeros((sp.n_envs,), jnp.int32)
    return QRunnerState(key=key, q=q, env_state=st.inner, obs=obs, s=st.index,
                        steps=jnp.int32(0), episodes=jnp.int32(0), ep_primitives=zeros,
                        ep_actions=zeros, perceived=st.key, lem=lem,
                        rule=sp.rule.init(sp.n_envs), macro=st.running)


def _count(sp: _Spec, steps: jax.Array, episodes: jax.Array) -> jax.Array:
    """The exploration schedule's count (learner steps or finished episodes)."""
    return steps if sp.params.exploration.count_unit == "steps" else episodes


def _select(sp: _Spec, k_act, c: QRunnerState, params: QRunnerParams,
            mode: Evaluation | None) -> tuple[jax.Array, jax.Array]:
    """(rate, action (E,)): the behaviour policy, or where ``mode`` is active the
    epsilon-greedy policy at its epsilon."""
    rate = schedule_value(params.exploration, _count(sp, c.steps, c.episodes))
    action = sp.rule.act(c.rule, select_action(k_act, c.q[c.s], rate,
                                               sp.params.exploration.policy))
    if mode is None:
        return rate, action
    eps = jnp.asarray(mode.epsilon, jnp.float32)
    greedy = select_action(k_act, c.q[c.s], eps, "epsilon_greedy")
    on = jnp.asarray(mode.active, bool)
    return jnp.where(on, eps, rate), jnp.where(on, greedy, action)


def _act(sp: _Spec, key, c: QRunnerState, action, params: QRunnerParams,
         env_params) -> _Moved:
    """Every env steps under the macro wrapper: its whole action (sync, or one primitive
    when macro actions are off), or one primitive of its running action (async)."""
    keys = jax.random.split(key, sp.n_envs)
    wp = _wrapper_params(sp, params, env_params, c.lem.difficulty)
    state = MacroState(inner=c.env_state, index=c.s, key=c.perceived, running=c.macro)
    obs, state, _, term, trunc, info = jax.vmap(sp.env.step, in_axes=(0, 0, 0, None))(
        keys, state, action, wp)
    mi = info["macro"]
    if sp.env.is_async:
        return _Moved(obs, state, term, trunc, info, mi, mi["ended"], 1,
                      mi["decided"].astype(jnp.int32))
    return _Moved(obs, state, term, trunc, info, mi, None, mi["num_primitives"], 1)


def _truncation(sp: _Spec, m: _Moved) -> tuple[Any, Any, Any]:
    """(terminal, weight, s_boot) of the transitions under ``truncation``."""
    mode = sp.params.truncation
    cut, s_next = m.trunc & ~m.term, m.state.index
    if mode == "skip":
        return m.term, ~cut, s_next
    if mode == "terminal":
        return m.term | m.trunc, None, s_next
    if "final_obs" not in m.info:
        raise ParamError("truncation='bootstrap' needs info['final_obs'] from the env")
    return m.term, None, jnp.where(cut, _states(sp, m.info["final_obs"]), s_next)


def _next_action(sp: _Spec, k_act, c: QRunnerState, m: _Moved,
                 params: QRunnerParams) -> jax.Array:
    """Sarsa: the action each env takes next in ``s_next`` (pre-update table, next rate)."""
    n_done = jnp.sum(m.term | m.trunc, dtype=jnp.int32)
    rate = schedule_value(params.exploration, _count(sp, c.steps + 1, c.episodes + n_done))
    return select_action(jax.random.fold_in(k_act, 1), c.q[m.state.index], rate,
                         sp.params.exploration.policy)


def _transition(sp: _Spec, k_act, c: QRunnerState, m: _Moved,
                params: QRunnerParams) -> Transition:
    """The rule's view of this step's transitions."""
    terminal, weight, s_boot = _truncation(sp, m)
    done = m.term | m.trunc
    a_next = _next_action(sp, k_act, c, m, params) if sp.rule.next_action else None
    return Transition(s=m.macro["start"], a=m.macro["action"], r=m.macro["reward"],
                      n=m.macro["num_primitives"], s_boot=s_boot, terminal=terminal, done=done,
                      truncated=m.trunc & ~m.term, weight=weight, advance=m.advance,
                      decided=m.macro["decided"], clock=c.ep_primitives,
                      last_clock=c.ep_primitives + m.prims - 1,
                      scored=jnp.asarray(m.info["success"]).astype(bool) & done, a_next=a_next)


def _record(c: QRunnerState, m: _Moved, key, q, rule_state, lem, rate, td_abs):
    """Episode bookkeeping: (new carry, metrics)."""
    done = m.term | m.trunc
    success = jnp.asarray(m.info["success"]).astype(bool) & done
    ep_prim = c.ep_primitives + m.prims
    ep_act = c.ep_actions + m.acts
    metrics = dict(
        episodes=jnp.sum(done, dtype=jnp.int32),
        successes=jnp.sum(success, dtype=jnp.int32),
        primitives=jnp.sum(jnp.where(done, ep_prim, 0), dtype=jnp.int32),
        actions=jnp.sum(jnp.where(done, ep_act, 0), dtype=jnp.int32),
        td_abs=td_abs, rate=jnp.asarray(rate, jnp.float32),
        difficulty=c.lem.difficulty, lem_raises=lem.raises)
    new = QRunnerState(key=key, q=q, env_state=m.state.inner, obs=m.obs, s=m.state.index,
                       steps=c.steps + 1, episodes=c.episodes + metrics["episodes"],
                       ep_primitives=jnp.where(done, 0, ep_prim),
                       ep_actions=jnp.where(done, 0, ep_act), perceived=m.state.key, lem=lem,
                       rule=rule_state, macro=m.state.running)
    return new, metrics


def _step(sp: _Spec, c: QRunnerState, params: QRunnerParams, env_params,
          mode: Evaluation | None = None):
    """One learner step: select, act, update (step size 0 where ``mode`` is active),
    record."""
    key, k_act, k_env = jax.random.split(c.key, 3)
    rate, action = _select(sp, k_act, c, params, mode)
    m = _act(sp, k_env, c, action, params, env_params)
    t = _transition(sp, k_act, c, m, params)
    learning = params if mode is None else params.replace(learning_rate=jnp.where(
        jnp.asarray(mode.active, bool), 0.0, params.learning_rate).astype(jnp.float32))
    q, rule_state, td_abs = sp.rule.update(c.q, c.rule, t, learning)
    lem = lem_update(c.lem, q, params.lem, jnp.sum(t.done), jnp.sum(t.scored))
    return _record(c, m, key, q, rule_state, lem, rate, td_abs)


def _run_chunk(sp: _Spec, carry: QRunnerState, params: QRunnerParams, env_params,
               mode: Evaluation | None = None):
    return jax.lax.scan(lambda c, _: _step(sp, c, params, env_params, mode), carry, None,
                        length=sp.params.chunk_steps)


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
    eps = jnp.sum(metrics["episodes"]).astype(f32)
    prims = jnp.sum(metrics["primitives"]).astype(f32)
    return dict(success_rate=jnp.mean((counts.first_success & done).astype(f32)),
                finished=jnp.mean(done.astype(f32)),
                mean_primitives=prims / jnp.maximum(eps, 1.0),
                primitives_per_decision=prims / jnp.maximum(
                    jnp.sum(metrics["actions"]).astype(f32), 1.0))


def _evaluate(sp: _Spec, key, q, params: QRunnerParams, env_params, num_steps: int = 200,
              epsilon: Any = 0.0, start: QRunnerState | None = None):
    """The epsilon-greedy policy of table ``q`` (``epsilon`` 0: greedy; may be traced; > 0
    breaks cycles between aliased states) from fresh starts, ``num_steps`` (static) learner
    steps in evaluation mode; :func:`evaluation_stats`. The starts are ``start`` (a state
    from ``init``; its key replaced by ``key``) or drawn from ``key`` at ``env_params``'
    start difficulty (LEM's pinned to it)."""
    if start is None:
        if sp.params.lem.enabled:  # start (and stay) at env_params' own difficulty
            d = jnp.asarray(env_params.start_difficulty, jnp.float32)
            params = params.replace(lem=params.lem.replace(initial_difficulty=d))
        key, k_init = jax.random.split(key)
        start = _init(sp, k_init, params, env_params)
    c = start.replace(key=key, q=jnp.asarray(q, jnp.float32))
    mode = Evaluation(active=jnp.bool_(True), epsilon=jnp.asarray(epsilon, jnp.float32))
    c, m = jax.lax.scan(lambda c, _: _step(sp, c, params, env_params, mode), c, None,
                        length=num_steps)
    return evaluation_stats(c, m)


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
    sp = _Spec(env=MacroWrapper(FirstEpisodeWrapper(env), state_fn, mp, stop_key(mp.stop_on),
                                perceive_fn),
               state_fn=state_fn, params=params, rule=rule_of(params))
    init, run_chunk, evaluate = (partial(_init, sp), partial(_run_chunk, sp),
                                 partial(_evaluate, sp))
    init_batch = jax.jit(jax.vmap(init, in_axes=(0, 0, 0)))
    run_chunk_batch = jax.jit(jax.vmap(run_chunk, in_axes=(0, 0, 0)))

    def evaluate_many(keys, q, params, env_params, num_steps: int = 200, epsilon: Any = 0.0):
        return jax.vmap(evaluate, in_axes=(0, 0, 0, 0, None, None))(
            keys, q, params, env_params, num_steps, epsilon)

    evaluate_batch = jax.jit(evaluate_many, static_argnums=(4,))
    return QLearningRunner(init=init, run_chunk=run_chunk, evaluate=evaluate,
                           init_batch=init_batch, run_chunk_batch=run_chunk_batch,
                           evaluate_batch=evaluate_batch, params=params)
