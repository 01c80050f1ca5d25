"""The on-line segmentation's learner (paper Section 2.2): tabular values on the boxes of
:mod:`vbl.spaces.incremental`, learned while the boxes split and merge.

One robot, one environment (an experiment vmaps over seeds):

1. Every primitive the transition goes into the partition's ring buffer (truncated steps
   are not stored); every ``update_every`` primitives :func:`update_structure` refits
   the local models and splits or merges one box (:func:`vbl.spaces.incremental.structure_update`).
2. Boltzmann selection at ``temperature`` on the box's Q row; an *action* (option) holds
   its primitive until the box changes, the episode ends or ``max_repeat`` primitives pass.
3. Values (``update``):

   * ``"q_learning"``: when the action ends, one step of
     :func:`vbl.agents.qlearning.q_update` on the transition (box where the action began,
     primitive, reward of the action's last primitive, box after it, terminated):
     ``Q(s, a) += alpha (r + gamma max Q(s') - Q(s, a))``, target ``r`` when the episode
     terminated, no update on a time-limit truncation (weight 0). ``discount`` is per action
     (not per primitive: ``num_primitives`` is not passed); the reward of the action's
     earlier primitives is not added (the shooting task rewards only its terminal
     primitive). One transition per update, so q_update's duplicate rules coincide.
   * ``"monte_carlo"``: every decision of a trial moves towards ``mc_discount^(primitives to
     the goal)`` if the trial scored, else 0, when the trial ends
     (:func:`vbl.agents.monte_carlo.mc_update`, one env; the decision's box is read when
     the trial ends, so a box split meanwhile teaches its current box).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from vbl.agents.exploration import boltzmann_action
from vbl.agents.monte_carlo import MCLog, log_append, mc_update, mc_work_table
from vbl.agents.qlearning import q_update
from vbl.agents.steering import steer_action
from vbl.envs.rollout import rollout, stateless
from vbl.params import param
from vbl.spaces.incremental import (
    Buffer,
    Segmentation,
    SegmentationParams,
    init_buffer,
    init_segmentation,
    leaf_of,
    num_states,
    record,
    structure_update,
)

__all__ = [
    "VALUE_UPDATES",
    "IncrementalParams",
    "TrialLog",
    "Learner",
    "Option",
    "RunCarry",
    "init_learner",
    "init_option",
    "log_decision",
    "monte_carlo_update",
    "update_structure",
    "greedy_action",
    "learner_step",
    "held_boltzmann_policy",
    "evaluate_policies",
    "init_run",
    "run_updates",
    "per_trial",
]

F32 = jnp.float32
I32 = jnp.int32

VALUE_UPDATES = ("q_learning", "monte_carlo")


@struct.dataclass
class IncrementalParams(SegmentationParams):
    """The partition's thresholds (:class:`SegmentationParams`) and the learner on it."""

    learning_rate: float = param(0.25, doc="learning rate of the value update", gt=0.0, le=1.0)
    temperature: float = param(0.02, doc="Boltzmann temperature", unit="Q units", gt=0.0)
    max_repeat: int = param(50, doc="most primitives one action holds in an unchanged box",
                            unit="steps", ge=1)
    update: str = param("q_learning", doc="how Q learns: 'q_learning' (one-step target "
                              "r + gamma max Q(s') per action) or 'monte_carlo' (every "
                              "decision of a trial moves towards mc_discount^(primitives to the "
                              "goal) if the trial scored, else 0, when the trial ends; no "
                              "bootstrapping through aliased boxes)", static=True,
                              choices=VALUE_UPDATES)
    mc_discount: float = param(0.98, doc="monte_carlo: discount per primitive of a decision's "
                            "return", gt=0.0, le=1.0)
    mc_log: int = param(256, doc="monte_carlo: most decisions of one trial remembered (later "
                        "ones are not learned from)", static=True, ge=1)


@struct.dataclass
class TrialLog:
    """The decisions of the running trial (``update='monte_carlo'``): x (N, D)
    float32 features at the decision, a (N,) int32 primitive, clock (N,) int32 the
    learner's primitive count at the decision, n () int32 decisions logged. N = mc_log
    (1 with Q-learning, unused)."""

    x: jax.Array
    a: jax.Array
    clock: jax.Array
    n: jax.Array


@struct.dataclass
class Learner:
    """seg, buf (the partition), q (L, A) float32, splits/merges () int32 counters
    (value_splits: the splits made by the value criterion, included in splits), clock ()
    int32 primitives taken, log the running trial's decisions (Monte Carlo updates)."""

    seg: Segmentation
    buf: Buffer
    q: jax.Array
    splits: jax.Array
    merges: jax.Array
    clock: jax.Array
    value_splits: jax.Array
    log: TrialLog


def init_learner(p: IncrementalParams, dim: int, num_actions: int) -> Learner:
    """One box covering [0, 1]^dim, an empty buffer, Q = q_init."""
    z = jnp.zeros((), I32)
    n_log = p.mc_log if p.update == "monte_carlo" else 1
    log = TrialLog(x=jnp.zeros((n_log, dim), F32), a=jnp.zeros((n_log,), I32),
                   clock=jnp.zeros((n_log,), I32), n=z)
    return Learner(seg=init_segmentation(p, dim), buf=init_buffer(p, dim),
                   q=jnp.full((p.max_states, num_actions), p.q_init, F32), splits=z,
                   merges=z, clock=z, value_splits=z, log=log)


def update_structure(lr: Learner, p: SegmentationParams
                     ) -> tuple[Learner, jax.Array, jax.Array]:
    """:func:`vbl.spaces.incremental.structure_update` on the learner's boxes, buffer and Q,
    counting splits and merges. Returns (learner, split () bool, merge () bool)."""
    seg, q, split, merge, vsplit = structure_update(lr.seg, lr.buf, lr.q, p)
    return lr.replace(seg=seg, q=q, splits=lr.splits + split.astype(I32),
                      merges=lr.merges + merge.astype(I32),
                      value_splits=lr.value_splits + vsplit.astype(I32)), split, merge


def log_decision(log: TrialLog, decide: jax.Array, x: jax.Array, a: jax.Array,
                 clock: jax.Array) -> TrialLog:
    """Append a decision (features x (D,), primitive a, clock) when ``decide``; a full log
    drops it."""
    one = lambda v: jnp.asarray(v)[None]  # noqa: E731  (a batch of one env)
    (xs, a_s, clocks), n = log_append((log.x[None], log.a[None], log.clock[None]),
                                      log.n[None], one(decide), (one(x), one(a), one(clock)))
    return TrialLog(x=xs[0], a=a_s[0], clock=clocks[0], n=n[0])


def monte_carlo_update(q: jax.Array, seg: Segmentation, log: TrialLog, ended: jax.Array,
                       scored: jax.Array, clock: jax.Array, alpha: Any,
                       gamma: Any) -> tuple[jax.Array, TrialLog]:
    """When the trial ``ended`` (a time-limit end counts as a failure): every logged decision
    (its box *now*, its primitive) gets the return ``gamma^(clock - its clock)`` if the
    trial ``scored`` (``clock`` = the scoring primitive's), else 0; a (box, primitive) with
    c decisions moves towards their mean return by ``1 - (1 - alpha)^c``
    (:func:`vbl.agents.monte_carlo.mc_update` with one env); the log empties.
    Returns (q (L, A), log)."""
    one = MCLog(s=leaf_of(seg, log.x)[None], a=log.a[None], clock=log.clock[None],
                n=log.n[None], sums=mc_work_table(q.size))
    q, _, _ = mc_update(q, one, jnp.asarray(ended)[None], jnp.asarray(scored)[None],
                        jnp.asarray(clock, I32)[None], alpha, gamma)
    return q, log.replace(n=jnp.where(ended, 0, log.n).astype(I32))


def greedy_action(lr: Learner, x: jax.Array, key: jax.Array | None = None) -> jax.Array:
    """argmax_a Q(box(x), a), int32. Ties (e.g. a box never updated, all ``q_init``) go to
    the first action without ``key``, to a uniformly drawn tied action with it."""
    q = lr.q[leaf_of(lr.seg, x)]
    if key is None:
        return jnp.argmax(q, axis=-1).astype(I32)
    tied = q >= jnp.max(q, axis=-1, keepdims=True)
    return jax.random.categorical(key, jnp.where(tied, 0.0, -jnp.inf), axis=-1).astype(I32)


@struct.dataclass
class Option:
    """The action being held: state s0, primitive a, steps n, active (False: choose anew)."""

    s0: jax.Array
    a: jax.Array
    n: jax.Array
    active: jax.Array


def init_option() -> Option:
    return Option(jnp.zeros((), I32), jnp.zeros((), I32), jnp.zeros((), I32),
                  jnp.zeros((), bool))


def learner_step(key: jax.Array, lr: Learner, opt: Option, env: Any, env_state: Any,
                 obs: jax.Array, env_params: Any, p: IncrementalParams,
                 feature_fn: Callable[[jax.Array], jax.Array]):
    """One primitive of the on-line learner (value update + buffer; no structure change).

    Returns (learner, option, env_state, obs, info) with info from the env plus
    ``reward``, ``terminated``, ``truncated``.
    """
    k_act, k_env = jax.random.split(key)
    x = feature_fn(obs)
    s = leaf_of(lr.seg, x)
    a_new = boltzmann_action(k_act, lr.q[s], p.temperature)
    a = jnp.where(opt.active, opt.a, a_new)
    s0 = jnp.where(opt.active, opt.s0, s)
    n = jnp.where(opt.active, opt.n, 0) + 1
    obs2, env_state2, r, term, trunc, info = env.step(k_env, env_state, a, env_params)
    done = term | trunc
    x2 = feature_fn(obs2)
    s2 = leaf_of(lr.seg, x2)
    dx = jnp.where(term, 0.0, x2 - x)
    y = jnp.concatenate([dx, info["success"].astype(F32)[None]])
    learn = ~(trunc & ~term)                     # a time-limit truncation teaches nothing
    buf = record(lr.buf, x, a, y, learn, lr.clock, term)
    end = done | (s2 != s0) | (n >= p.max_repeat)
    if p.update == "monte_carlo":
        log = log_decision(lr.log, ~opt.active, x, a, lr.clock)
        q, log = monte_carlo_update(lr.q, lr.seg, log, done, info["success"], lr.clock,
                                    p.learning_rate, p.mc_discount)
        lr = lr.replace(log=log)
    else:
        one = lambda v: jnp.asarray(v)[None]  # noqa: E731  (one transition)
        q, _ = q_update(lr.q, one(s0), one(a), one(r), one(s2), one(term), p.learning_rate,
                        p.discount, weight=one(end & learn))
    lr = lr.replace(buf=buf, q=q.astype(F32), clock=lr.clock + 1)
    opt = Option(s0=s0.astype(I32), a=a.astype(I32), n=n.astype(I32), active=~end)
    info = dict(info, reward=r, terminated=term, truncated=trunc)
    return lr, opt, env_state2, obs2, info


def held_boltzmann_policy(lr: Learner, p: IncrementalParams,
                          feature_fn: Callable[[jax.Array], jax.Array], temperature: Any
                          ) -> tuple[Callable, tuple[jax.Array, jax.Array, jax.Array]]:
    """The learner's own behaviour, frozen (no learning, no structure change), as a
    :func:`vbl.envs.rollout.rollout` policy: Boltzmann selection at ``temperature`` whenever
    the box changes, an episode starts or ``max_repeat`` primitives pass, the primitive held
    in between (as in training). Returns (policy, its initial state (box -1, primitive 0,
    held 0), each () int32)."""
    def policy(obs, held, key):
        s0, a, n = held
        s = leaf_of(lr.seg, feature_fn(obs))
        decide = (s != s0) | (n >= p.max_repeat)
        a = jnp.where(decide, boltzmann_action(key, lr.q[s], temperature), a).astype(I32)
        n = jnp.where(decide, 1, n + 1).astype(I32)
        return a, (s, a, n)

    return policy, (jnp.full((), -1, I32), jnp.zeros((), I32), jnp.zeros((), I32))


def evaluate_policies(key: jax.Array, lr: Learner, env: Any, env_params: Any,
                      p: IncrementalParams, feature_fn: Callable[[jax.Array], jax.Array],
                      num_episodes: int, max_steps: int,
                      steer_band: Any = None) -> dict[str, jax.Array]:
    """Success (num_episodes,) bool of the frozen learner's policies on the same fresh
    starts (one ``key``): ``greedy`` (ties broken at random), ``boltzmann``
    (:func:`held_boltzmann_policy` at ``p.temperature``), ``random`` (uniform primitives)
    and, with ``steer_band`` (px), ``steer`` (:func:`vbl.agents.steering.steer_action`); the
    first episode of each start counts (:func:`vbl.envs.rollout.rollout`)."""
    n_act = lr.q.shape[1]

    def run(k, which):           # 0 greedy, 1 uniform random, 2 steering
        def pol(o, ka):
            kr, kg = jax.random.split(ka)
            r = jax.random.randint(kr, (), 0, n_act, I32)
            g = greedy_action(lr, feature_fn(o), kg)
            steer = (r if steer_band is None
                     else steer_action(o, steer_band, env.action_labels))
            return jnp.select([which == 0, which == 1], [g, r], steer)
        return rollout(env, env_params, k, stateless(pol), num_episodes, max_steps)[0]

    ok = jax.vmap(run, in_axes=(None, 0))(key, jnp.arange(2 if steer_band is None else 3))
    held, held0 = held_boltzmann_policy(lr, p, feature_fn, p.temperature)
    out = dict(greedy=ok[0],
               boltzmann=rollout(env, env_params, key, held, num_episodes, max_steps,
                                 held0)[0],
               random=ok[1])
    if steer_band is not None:
        out["steer"] = ok[2]
    return out


@struct.dataclass
class RunCarry:
    """Everything one on-line learner carries between chunks."""

    key: jax.Array
    lr: Learner
    opt: Option
    env_state: Any
    obs: jax.Array
    trials: jax.Array      # () int32 finished episodes


def init_run(key: jax.Array, env: Any, env_params: Any, p: IncrementalParams, dim: int,
             num_actions: int) -> RunCarry:
    """Fresh learner (one box) and a fresh episode."""
    k_env, k_run = jax.random.split(key)
    obs, st = env.reset(k_env, env_params)
    return RunCarry(key=k_run, lr=init_learner(p, dim, num_actions), opt=init_option(),
                    env_state=st, obs=obs, trials=jnp.zeros((), I32))


def run_updates(carry: RunCarry, env: Any, params_fn: Callable[[jax.Array], Any],
                p: IncrementalParams, feature_fn: Callable[[jax.Array], jax.Array],
                num_updates: int):
    """``num_updates`` x (``update_every`` primitives, then :func:`update_structure`).

    ``params_fn(trials) -> env params`` lets the environment change with the number of
    finished trials (e.g. :mod:`vbl.envs.schedules`). Returns (carry, per-step dict with
    ``success``, ``done`` (U * K,) bool and ``trial`` (U * K,) int32 index of the trial
    the step belonged to, ``states`` (U * K,) int32 number of boxes during the step).
    """
    def prim(c, _):
        key, k = jax.random.split(c.key)
        ep = params_fn(c.trials)
        lr, opt, st, obs, info = learner_step(k, c.lr, c.opt, env, c.env_state, c.obs, ep, p,
                                              feature_fn)
        done = info["terminated"] | info["truncated"]
        out = dict(success=info["success"] & done, done=done, trial=c.trials,
                   states=num_states(lr.seg))
        opt = opt.replace(active=opt.active & ~done)
        return RunCarry(key, lr, opt, st, obs, c.trials + done.astype(I32)), out

    def block(c, _):
        c, out = jax.lax.scan(prim, c, None, length=p.update_every)
        lr, _, _ = update_structure(c.lr, p)
        return c.replace(lr=lr), out

    carry, out = jax.lax.scan(block, carry, None, length=num_updates)
    return carry, jax.tree_util.tree_map(lambda a: a.reshape((-1,) + a.shape[2:]), out)


def per_trial(out: dict, success: jax.Array, states: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Write the per-step output of :func:`run_updates` into per-trial records ``success``,
    ``states`` (T,) float32 at the index of each finished trial (trials past T dropped):
    whether it scored, and the number of boxes at its last step."""
    n = success.shape[0]
    idx = jnp.where(out["done"] & (out["trial"] < n), out["trial"], n)
    return (success.at[idx].set(out["success"].astype(F32), mode="drop"),
            states.at[idx].set(out["states"].astype(F32), mode="drop"))
