"""Batched tabular Q-learning: a batch of independent learners, each with E parallel envs.

One learner owns one float32 Q-table (S, A). Each learner step, its E environments
act at the same time and the E transitions update the one table in a single
batched scatter (:func:`q_update`); learners are independent, so a batch of
learners (seeds x hyperparameter settings) is ``jax.vmap`` over everything here.
``learning_rate`` and ``discount`` are traced, so a sweep vmaps over them.

Update rule (synchronous, "mean" duplicate rule by default). For the transitions
``(s_i, a_i, r_i, s'_i, n_i)`` of one step, all TD errors use the table Q from before
the step::

    target_i = r_i + discount**n_i * (1 - terminal_i) * max_b Q[s'_i, b]
    delta_i  = target_i - Q[s_i, a_i]
    Q[s, a] += lr * mean_{i: (s_i, a_i) = (s, a)} delta_i      (duplicates="mean")
    Q[s, a] += lr * sum_{i: (s_i, a_i) = (s, a)} delta_i       (duplicates="sum")

``n_i`` is the number of primitives of a macro action (1 without macro actions;
the macro reward ``r_i`` is already discounted inside the action). "mean" equals
one ordinary Q-learning update towards the averaged target, so the step size
stays ``lr`` however many environments visit the same pair; "sum" equals applying
the single updates one after another with frozen targets, and can overshoot when
``lr * count > 1``. Transitions with weight 0 (see ``truncation``) do not count.

With ``agent.trace.enabled`` the runner applies each TD error to the environment's last
``trace.length`` actions instead (multi-step returns, :mod:`vbl.agents.traces`; off by
default; lambda = 0 gives exactly the update above).

:func:`make_qlearning_runner` is the reusable training building block: pure
``init`` / ``run_chunk`` / ``evaluate`` functions that ``lax.scan`` over steps of E
parallel environments (act, env step or macro step, update, LEM, record episodes).
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
from vbl.agents.monte_carlo import MCLog, mc_init, mc_log, mc_update
from vbl.agents.traces import TraceParams, TraceState, trace_init, trace_update
from vbl.params import ParamError, param, section, validate
from vbl.spaces.macro_action import (
    MacroActionParams,
    MacroCarry,
    async_macro_advance,
    macro_carry_init,
    macro_step,
)

__all__ = [
    "QLearningParams",
    "QRunnerParams",
    "QRunnerState",
    "QLearningRunner",
    "init_q",
    "q_update",
    "make_qlearning",
    "make_qlearning_runner",
    "learner_keys",
    "stack_for_learners",
]


@struct.dataclass
class QLearningParams:
    """Tabular Q-learning of one learner (one (S, A) table)."""

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
    update: str = param("q_learning", doc="how the table learns: 'q_learning' (the one-step "
                        "rule above, or traces) or 'monte_carlo' (every decision of a trial "
                        "moves towards discount^(primitives to the goal) if the trial scored, "
                        "else 0, when it ends: vbl.agents.monte_carlo; no bootstrapping)",
                        static=True, choices=("q_learning", "monte_carlo"))
    mc_log: int = param(128, doc="monte_carlo: most decisions of one trial remembered per env "
                        "(later ones are not learned from)", static=True, ge=1)
    exploration: ExplorationParams = section(ExplorationParams, doc="action selection")
    trace: TraceParams = section(TraceParams, doc="multi-step returns (eligibility traces "
                                 "over the last `length` actions); off by default")


@struct.dataclass
class QRunnerParams:
    """Everything a Q-learning run needs besides the env's own params."""

    agent: QLearningParams = section(QLearningParams, doc="Q-learning")
    macro: MacroActionParams = section(MacroActionParams, doc="one action = repeat a primitive")
    lem: LEMParams = section(LEMParams, doc="Learning from Easy Missions curriculum")
    num_envs: int = param(64, doc="parallel environments E per learner (all update one table)",
                          static=True, ge=1)
    chunk_steps: int = param(100, doc="learner steps per run_chunk call (a lax.scan)",
                             static=True, ge=1)


def init_q(p: QLearningParams) -> jax.Array:
    """A fresh table (S, A) float32 filled with ``q_init``."""
    return jnp.full((p.num_states, p.num_actions), jnp.asarray(p.q_init, jnp.float32),
                    jnp.float32)


def q_update(q: jax.Array, s: jax.Array, a: jax.Array, r: jax.Array, s_next: jax.Array,
             terminal: jax.Array, learning_rate: Any, discount: Any, *,
             duplicates: str = "mean", weight: jax.Array | None = None,
             num_primitives: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """One synchronous batched Q-learning update of one table (rule in the module doc).

    Args:
      q: (S, A) float32 table.
      s, a, s_next: (N,) int32 state, action, next state of N transitions.
      r: (N,) reward (for a macro action: the discounted sum over its primitives).
      terminal: (N,) bool, no bootstrap.
      learning_rate, discount: scalars (may be traced).
      duplicates: "mean" or "sum" (static), see the module doc.
      weight: (N,) optional 0/1 (or bool) mask; 0 = ignore the transition.
      num_primitives: (N,) optional int, bootstrap with ``discount ** n``.

    Returns:
      (new table (S, A) float32, TD errors (N,) float32 (0 where weight is 0)).
    """
    n_states, n_actions = q.shape
    q = q.astype(jnp.float32)
    lr = jnp.asarray(learning_rate, jnp.float32)
    gamma = jnp.asarray(discount, jnp.float32)
    s = jnp.asarray(s, jnp.int32)
    a = jnp.asarray(a, jnp.int32)
    s_next = jnp.asarray(s_next, jnp.int32)
    w = (jnp.ones(s.shape, jnp.float32) if weight is None
         else jnp.asarray(weight).astype(jnp.float32))
    g = gamma if num_primitives is None else gamma ** jnp.asarray(num_primitives, jnp.float32)
    boot = jnp.where(jnp.asarray(terminal, bool), 0.0, g * jnp.max(q[s_next], axis=-1))
    target = jnp.asarray(r, jnp.float32) + boot
    delta = (target - q[s, a]) * w
    flat = s * n_actions + a
    if duplicates == "mean":
        counts = jnp.zeros(n_states * n_actions, jnp.float32).at[flat].add(w)
        step = delta / jnp.maximum(counts[flat], 1.0)
    elif duplicates == "sum":
        step = delta
    else:
        raise ParamError(f"duplicates={duplicates!r}; choose 'mean' or 'sum'")
    new = q.reshape(-1).at[flat].add(lr * step).reshape(n_states, n_actions)
    return new, delta


def make_qlearning(p: QLearningParams) -> tuple[Callable, Callable]:
    """Validated ``(init_q, update)`` pair for one learner; ``update(q, s, a, r, s_next,
    terminal, params, weight=None, num_primitives=None)`` reads lr / discount from params."""
    validate(p, "agent.")
    duplicates = p.duplicates

    def update(q, s, a, r, s_next, terminal, params: QLearningParams, weight=None,
               num_primitives=None):
        return q_update(q, s, a, r, s_next, terminal, params.learning_rate, params.discount,
                        duplicates=duplicates, weight=weight, num_primitives=num_primitives)

    return (lambda params: init_q(params)), update


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
    lem: LEMState
    trace: TraceState         #: per-env trace window (E, L); L = 1 and unused when off
    macro: MacroCarry         #: per-env running macro actions (E,) (macro.mode 'async')
    mc: MCLog                 #: per-env decisions of the running trial (E, L); L = 1 unless
    #:                           agent.update is 'monte_carlo'


class QLearningRunner(NamedTuple):
    """Pure functions of one learner (vmap them over learners; ``*_batch`` are jit(vmap))."""

    init: Callable       #: (key, params, env_params) -> QRunnerState
    run_chunk: Callable  #: (carry, params, env_params) -> (carry, metrics of shape (T,))
    evaluate: Callable   #: (key, q, params, env_params) -> dict of scalars
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


def make_qlearning_runner(env: Any, state_fn: Callable, params: QRunnerParams,
                          env_params: Any = None) -> QLearningRunner:
    """Build the pure training functions of one learner for a gymnax-style ``env``.

    Args:
      env: ``reset(key, env_params) -> (obs, state)``, ``step(key, state, action,
        env_params) -> (obs, state, reward, terminated, truncated, info)`` with
        auto-reset and ``info["success"]``; optional ``num_actions``.
      state_fn: observation(s) (..., obs_dim) -> int32 discrete state in [0, S).
      params: validated here; its static fields (S, A, E, T, kinds) fix the shapes.
      env_params: used only to check that LEM can set ``start_difficulty``
        (default ``env.default_params``).

    Returns a :class:`QLearningRunner`. ``run_chunk`` runs ``params.chunk_steps``
    learner steps; its metrics (each of shape (T,)) are ``episodes`` (finished in
    that step), ``successes``, ``primitives`` and ``actions`` (summed lengths of the
    finished episodes), ``td_abs`` (mean |TD error| of the updated transitions),
    ``rate`` (epsilon or temperature), ``difficulty`` (LEM start difficulty) and
    ``lem_raises``. ``evaluate`` runs the greedy policy (random tie-breaking, no
    learning) for ``evaluate_steps`` (keyword of make: see below) and reports the
    success rate of each env's first finished episode.
    """
    validate(params)
    ap, mp, lp = params.agent, params.macro, params.lem
    n_envs, n_steps = params.num_envs, params.chunk_steps
    n_actions = getattr(env, "num_actions", None)
    if n_actions is not None and int(n_actions) != ap.num_actions:
        raise ParamError(f"agent.num_actions={ap.num_actions} but the env has {n_actions} "
                         "actions")
    if lp.enabled:
        ep = env.default_params if env_params is None else env_params
        if not hasattr(ep, "start_difficulty"):
            raise ParamError("lem.enabled=True needs env params with a 'start_difficulty' "
                             f"field; {type(ep).__name__} has none (set lem.enabled=False)")
    expl = ap.exploration
    tp = ap.trace
    sarsa = tp.enabled and tp.kind == "sarsa"
    async_macro = mp.enabled and mp.mode == "async"
    monte_carlo = ap.update == "monte_carlo"
    if monte_carlo and tp.enabled:
        raise ParamError("agent.update='monte_carlo' learns from whole trials; it does not "
                         "combine with agent.trace (set agent.trace.enabled=False)")
    if monte_carlo and ap.truncation == "bootstrap":
        raise ParamError("agent.update='monte_carlo' does not bootstrap; use "
                         "agent.truncation='skip' or 'terminal'")
    if async_macro and sarsa:
        raise ParamError("macro.mode='async' does not support agent.trace.kind='sarsa' (the "
                         "next action of an env is chosen only when its action ends); use "
                         "kind 'peng', 'watkins' or 'naive', or macro.mode='sync'")

    def env_params_at(env_params, difficulty):
        if lp.enabled:
            return env_params.replace(start_difficulty=difficulty)
        return env_params

    def states_of(obs):
        return jnp.asarray(jax.vmap(state_fn)(obs), jnp.int32)

    def init(key, params: QRunnerParams, env_params):
        k_reset, key = jax.random.split(key)
        q = init_q(params.agent)
        lem = lem_init(params.lem, q)
        ep = env_params_at(env_params, lem.difficulty)
        obs, env_state = jax.vmap(env.reset, in_axes=(0, None))(
            jax.random.split(k_reset, n_envs), ep)
        zeros = jnp.zeros((n_envs,), jnp.int32)
        return QRunnerState(key=key, q=q, env_state=env_state, obs=obs, s=states_of(obs),
                            steps=jnp.int32(0), episodes=jnp.int32(0), ep_primitives=zeros,
                            ep_actions=zeros, lem=lem,
                            trace=trace_init(n_envs, tp.length if tp.enabled else 1),
                            macro=macro_carry_init(n_envs),
                            mc=mc_init(n_envs, ap.mc_log if monte_carlo else 1))

    def env_transition(key, c: QRunnerState, action, params, env_params):
        """E env (macro) steps -> obs, env_state, reward, term, trunc, info, n, s_next."""
        ep = env_params_at(env_params, c.lem.difficulty)
        keys = jax.random.split(key, n_envs)
        if mp.enabled:
            out = jax.vmap(partial(macro_step, stop_on=mp.stop_on),
                           in_axes=(None, None, 0, 0, 0, 0, None, None, None, None))(
                env.step, state_fn, keys, c.env_state, c.s, action, ep,
                params.macro.max_repeats, params.agent.discount, params.macro.min_repeats)
            return (out.obs, out.env_state, out.reward, out.terminated, out.truncated,
                    out.info, out.num_primitives, out.next_state)
        obs, st, r, term, trunc, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
            keys, c.env_state, action, ep)
        return (obs, st, jnp.asarray(r, jnp.float32), jnp.asarray(term, bool),
                jnp.asarray(trunc, bool), info, jnp.ones((n_envs,), jnp.int32), states_of(obs))

    def one_step(c: QRunnerState, params: QRunnerParams, env_params, learn: bool,
                 eval_epsilon: Any = 0.0):
        key, k_act, k_env = jax.random.split(c.key, 3)
        count = c.steps if expl.count_unit == "steps" else c.episodes
        if learn:
            rate = schedule_value(params.agent.exploration.schedule, count)
            action = select_action(k_act, c.q[c.s], rate, expl.kind)
            if sarsa:  # the action chosen at the end of the previous step (none at first)
                action = jnp.where(c.trace.a_next >= 0, c.trace.a_next, action)
        else:
            rate = jnp.asarray(eval_epsilon, jnp.float32)
            action = select_action(k_act, c.q[c.s], rate, "epsilon_greedy")
        s_from, macro, upd = c.s, c.macro, None
        prims, acts = 1, 1  # primitives and decisions of each env in this step
        decided = jnp.ones((n_envs,), bool)  # envs that choose an action at this step
        if async_macro:  # one primitive per env; an env whose action runs on keeps it
            keys = jax.random.split(k_env, n_envs)
            ep = env_params_at(env_params, c.lem.difficulty)

            def step_out(a):
                out = jax.vmap(env.step, in_axes=(0, 0, 0, None))(keys, c.env_state, a, ep)
                return (*out, states_of(out[0]))

            out, upd, (s_from, action, r, n, decided), macro = async_macro_advance(
                c.macro, c.s, action, step_out, params.macro.max_repeats,
                params.agent.discount, params.macro.min_repeats, mp.stop_on)
            obs, st, _, term, trunc, info, s_next = out
            term, trunc = jnp.asarray(term, bool), jnp.asarray(trunc, bool)
            acts = decided.astype(jnp.int32)
        else:
            obs, st, r, term, trunc, info, n, s_next = env_transition(k_env, c, action, params,
                                                                      env_params)
            prims = n
        done = term | trunc
        q, lem, tr, mc = c.q, c.lem, c.trace, c.mc
        td_abs = jnp.float32(0.0)
        if learn and monte_carlo:
            # a deciding env's state and action (the one now in force); primitive index of
            # the decision / of the trial's last primitive (from 0)
            mc = mc_log(c.mc, decided, c.s, action, c.ep_primitives)
            scored = jnp.asarray(info["success"]).astype(bool) & done
            keep = None if ap.truncation == "terminal" else ~(trunc & ~term)
            q, mc, _ = mc_update(c.q, mc, done, scored, c.ep_primitives + prims - 1,
                                 params.agent.learning_rate, params.agent.discount, keep)
            # td_abs stays 0: no TD errors
        elif learn:
            terminal, weight, s_boot = term, None, s_next
            if ap.truncation == "skip":
                weight = ~(trunc & ~term)
            elif ap.truncation == "terminal":
                terminal = done
            else:  # bootstrap from the pre-reset observation
                if "final_obs" not in info:
                    raise ParamError("agent.truncation='bootstrap' needs info['final_obs'] "
                                     "from the env")
                s_boot = jnp.where(trunc & ~term, states_of(info["final_obs"]), s_next)
            if upd is not None:  # async: only the actions that ended at this primitive
                weight = upd if weight is None else upd & weight
            if not tp.enabled:
                q, delta = q_update(c.q, s_from, action, r, s_boot, terminal,
                                    params.agent.learning_rate, params.agent.discount,
                                    duplicates=ap.duplicates, weight=weight, num_primitives=n)
            else:
                a_boot = None
                if sarsa:  # pick the next action now (pre-update table, next count)
                    n_done = jnp.sum(done, dtype=jnp.int32)
                    count_next = c.steps + 1 if expl.count_unit == "steps" else c.episodes + n_done
                    rate_next = schedule_value(params.agent.exploration.schedule, count_next)
                    a_next = select_action(jax.random.fold_in(k_act, 1), c.q[s_next], rate_next,
                                           expl.kind)
                    a_boot = a_next
                    if ap.truncation == "bootstrap":  # final_obs: no next action, use V
                        a_boot = jnp.where(trunc & ~term, jnp.argmax(c.q[s_boot], axis=-1),
                                           a_next).astype(jnp.int32)
                q, delta, tr = trace_update(
                    c.q, c.trace, s_from, action, r, s_boot, terminal, done,
                    params.agent.learning_rate, params.agent.discount, params.agent.trace.lam,
                    kind=tp.kind, duplicates=ap.duplicates, weight=weight, num_primitives=n,
                    a_boot=a_boot, advance=upd)
                if sarsa:
                    tr = tr.replace(a_next=a_next)
            wsum = jnp.float32(n_envs) if weight is None else jnp.sum(weight.astype(jnp.float32))
            td_abs = jnp.sum(jnp.abs(delta)) / jnp.maximum(wsum, 1.0)
        success = jnp.asarray(info["success"]).astype(bool) & done
        if learn:
            lem = lem_update(c.lem, q, params.lem, jnp.sum(done), jnp.sum(success))
        ep_prim = c.ep_primitives + prims
        ep_act = c.ep_actions + acts
        metrics = dict(
            episodes=jnp.sum(done, dtype=jnp.int32),
            successes=jnp.sum(success, dtype=jnp.int32),
            primitives=jnp.sum(jnp.where(done, ep_prim, 0), dtype=jnp.int32),
            actions=jnp.sum(jnp.where(done, ep_act, 0), dtype=jnp.int32),
            td_abs=td_abs, rate=jnp.asarray(rate, jnp.float32),
            difficulty=c.lem.difficulty, lem_raises=lem.raises)
        new = QRunnerState(key=key, q=q, env_state=st, obs=obs, s=s_next, steps=c.steps + 1,
                           episodes=c.episodes + metrics["episodes"],
                           ep_primitives=jnp.where(done, 0, ep_prim),
                           ep_actions=jnp.where(done, 0, ep_act), lem=lem, trace=tr,
                           macro=macro, mc=mc)
        return new, metrics, done, success, ep_prim

    def run_chunk(carry: QRunnerState, params: QRunnerParams, env_params):
        def body(c, _):
            c, m, *_ = one_step(c, params, env_params, learn=True)
            return c, m

        return jax.lax.scan(body, carry, None, length=n_steps)

    def evaluate(key, q, params: QRunnerParams, env_params, num_steps: int = 200,
                 epsilon: Any = 0.0):
        """Greedy policy from fresh starts (``env_params`` as given: set the env's start
        difficulty yourself) for at most ``num_steps`` actions (static); each env's first
        finished episode counts. Stops as soon as every env has finished one episode
        (later steps could not change the result). ``epsilon`` > 0 (may be traced)
        evaluates the near-greedy policy instead: a uniform action with that probability
        (the standard remedy for a deterministic policy cycling between aliased states)."""
        if lp.enabled:  # start (and stay) at env_params' own difficulty: one reset only
            d = jnp.asarray(env_params.start_difficulty, jnp.float32)
            params = params.replace(lem=params.lem.replace(initial_difficulty=d))
        c = init(key, params, env_params).replace(q=jnp.asarray(q, jnp.float32))
        first = dict(finished=jnp.zeros((n_envs,), bool), success=jnp.zeros((n_envs,), bool),
                     primitives=jnp.zeros((n_envs,), jnp.int32))

        def body(carry):
            i, c, f = carry
            c, _, done, success, ep_prim = one_step(c, params, env_params, learn=False,
                                                    eval_epsilon=epsilon)
            new_first = done & ~f["finished"]
            f = dict(finished=f["finished"] | done,
                     success=jnp.where(new_first, success, f["success"]),
                     primitives=jnp.where(new_first, ep_prim, f["primitives"]))
            return i + 1, c, f

        def cond(carry):  # stop early once every env finished (later steps change nothing)
            i, _, f = carry
            return (i < num_steps) & ~jnp.all(f["finished"])

        _, _, f = jax.lax.while_loop(cond, body, (jnp.int32(0), c, first))
        fin = f["finished"].astype(jnp.float32)
        n_fin = jnp.sum(fin)
        return dict(success_rate=jnp.sum(f["success"].astype(jnp.float32)) / n_envs,
                    finished=n_fin / n_envs,
                    mean_primitives=jnp.sum(f["primitives"] * fin) / jnp.maximum(n_fin, 1.0))

    init_batch = jax.jit(jax.vmap(init, in_axes=(0, 0, 0)))
    run_chunk_batch = jax.jit(jax.vmap(run_chunk, in_axes=(0, 0, 0)))
    def evaluate_many(keys, q, params, env_params, num_steps: int = 200, epsilon: Any = 0.0):
        return jax.vmap(evaluate, in_axes=(0, 0, 0, 0, None, None))(
            keys, q, params, env_params, num_steps, epsilon)

    evaluate_batch = jax.jit(evaluate_many, static_argnums=(4,))
    return QLearningRunner(init=init, run_chunk=run_chunk, evaluate=evaluate,
                           init_batch=init_batch, run_chunk_batch=run_chunk_batch,
                           evaluate_batch=evaluate_batch, params=params)
