"""Q-learning on CVA-estimated state vectors (the architecture of Figure 11, Section 3).

One learner (all functions are written for one learner and ``vmap``-ed over learners):

1. **collect** ``u(t)``, ``y(t)`` with uniformly random actions (:func:`collect`);
2. **identify** one CVA model per observed object (``ball``, ``goal``, ``other``) with the
   AIC order and the lag rule of Sec. 3.1.2 (:func:`identify_object`, built on
   :func:`vbl.sysid.cva.fit_one`);
3. **filter**: inside the env loop, each object's model turns the running history of its
   outputs and the learner's inputs into the canonical state ``mu`` (:func:`filter_state`);
   the first ``n_used`` components of every object (``n_used_objects``: one count per
   object; CVA orders them by canonical correlation, i.e. importance) are concatenated
   into the state vector ``[mu_ball, mu_goal, mu_other]``;
4. **quantise** the state vector into a Q-table index with a quantiser fitted to the states
   of the collected data (:mod:`vbl.spaces.quantize`);
5. **Q-learning** with the batched runner of :mod:`vbl.agents.qlearning`.

The baseline of Table 2 (``state="current"``) is the same pipeline with the current
features ``y(t)`` of the same objects as the state vector (no history, no CVA).

The memory (the filter history) lives in the env-loop carry: :class:`FilteredEnv` wraps a
gymnax-style env; its state holds the inner env state and the history; its observation is
``{"index": int32 (), "state": float32 (d,)}``, so the generic Q-learning runner uses
``state_fn = lambda o: o["index"]``. Its params hold the fitted models and the quantiser,
which are per-learner pytrees.

Decision-time state: at time ``t`` (after observing ``y(t)``, before choosing ``u(t)``) the
state is ``mu(t+1) = [I_n 0] U p(t+1)`` with the not-yet-chosen ``u(t)`` at its data mean
(0 in normalised units), i.e. built from ``y(t) .. y(t-l+1)`` and ``u(t-1) .. u(t-l+1)``.
At an episode start the history is filled with the first observation and the stop command
``u = 0`` (the robot at rest).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.agents.exploration import ExplorationParams, ScheduleParams
from vbl.agents.lem import LEMParams
from vbl.agents.qlearning import QLearningParams, QRunnerParams, make_qlearning_runner
from vbl.params import ParamError, param, section, validate
from vbl.spaces.macro_action import MacroActionParams
from vbl.spaces.quantize import (
    Quantizer,
    QuantizerParams,
    fit_quantizer,
    make_quantizer,
    num_states,
    quantize,
)
from vbl.sysid.cva import fit_one, n_identifiable
from vbl.sysid.params import CVAParams

__all__ = [
    "STATE_KINDS",
    "CVAStateParams",
    "ObjectModel",
    "FilteredParams",
    "FilteredState",
    "FilteredEnv",
    "collect",
    "identify_object",
    "filter_state",
    "state_dim",
    "make_cva_learner",
    "greedy_params",
    "first_episode_stats",
]

#: What the Q-learner sees (static choice). "select": both state vectors are built (zero-padded
#: to one length) and the traced ``use_cva`` picks one per learner, so one compilation serves
#: both rows of Table 2.
STATE_KINDS = ("cva", "current", "select")


def default_runner() -> QRunnerParams:
    """Runner defaults of this pipeline: primitive actions (no macro actions), no LEM,
    epsilon-greedy with epsilon 1.0 -> 0.05 over 2000 learner steps (agent.num_states is
    set from the quantiser)."""
    return QRunnerParams(
        agent=QLearningParams(num_states=1, num_actions=7, exploration=ExplorationParams(
            schedule=ScheduleParams(kind="linear", init_value=1.0, end_value=0.05,
                                    transition_steps=2000.0))),
        macro=MacroActionParams(enabled=False), lem=LEMParams(enabled=False),
        num_envs=64, chunk_steps=100)


@struct.dataclass
class CVAStateParams:
    """The Figure 11 pipeline of one learner (data collection, CVA, quantiser, Q-learning)."""

    state: str = param("cva", doc="'cva': CVA state vectors [mu_obj...]; 'current': the "
                       "current features y(t) of the same objects (Table 2 baseline); "
                       "'select': both, zero-padded to one length, use_cva picks one per "
                       "learner (one compilation for both; needs quantizer.method "
                       "'vq' or 'product_vq')",
                       static=True, choices=STATE_KINDS)
    use_cva: bool = param(True, doc="state='select' only: True = CVA state vector, False = "
                          "current features (traced, so a sweep over it is one compilation)")
    objects: tuple = param(("ball", "goal", "other"), doc="observed objects (keys of the "
                           "env's obs_slices), one CVA model each", static=True)
    n_used: int = param(2, doc="canonical states used per object (the first n_used, ordered "
                        "by canonical correlation); components beyond the AIC order n* are 0",
                        static=True, ge=1)
    n_used_objects: tuple = param((), doc="per-object override of n_used, one int per entry "
                                  "of objects (e.g. (4, 2): ball 4 components (position and "
                                  "velocity), goal 2); () = n_used for every object",
                                  static=True)
    keep_beyond_order: bool = param(False, doc="keep the canonical components beyond the "
                                    "AIC order n* among the n_used (False: they are 0, the "
                                    "paper's state); e.g. the ball's image velocity, which "
                                    "its AIC order 4 drops (docs/cva_learning.md)")
    extra: tuple = param((), doc="extra obs_slices appended unfiltered to the state vector "
                         "(e.g. 'lost_side')", static=True)
    collect_steps: int = param(2000, doc="random-action steps collected per learner for the "
                               "identification and the quantiser fit", unit="step",
                               static=True, ge=10)
    cva: CVAParams = section(lambda: CVAParams(lag_rule="paper"), doc="CVA identification "
                             "(order by AIC; with lag 0 the lag by the paper's log det rule, "
                             "Section 3.1.2)")
    quantizer: QuantizerParams = section(QuantizerParams, doc="state vector -> Q-table index")
    runner: QRunnerParams = section(default_runner, doc="batched Q-learning runner "
                                    "(agent.num_states is overridden by the quantiser's size)")

    def check(self) -> None:
        if not self.objects:
            raise ParamError("objects must name at least one observed object")
        if self.n_used_objects:
            if len(self.n_used_objects) != len(self.objects):
                raise ParamError(f"n_used_objects={self.n_used_objects!r} must have one entry "
                                 f"per object of objects={self.objects!r}, or be ()")
            if not all(isinstance(k, int | np.integer) and not isinstance(k, bool) and k >= 1
                       for k in self.n_used_objects):
                raise ParamError(f"n_used_objects={self.n_used_objects!r} must hold integers "
                                 ">= 1")
        if self.cva.lag == 0 and self.cva.lag_max < 1:
            raise ParamError("cva.lag_max must be >= 1")
        if self.cva.lag == 0 and self.cva.lag_rule != "paper":
            raise ParamError(f"cva.lag_rule={self.cva.lag_rule!r}: the learner selects the "
                             "lag by the paper's rule (cva.lag_rule='paper'), or give a "
                             "fixed cva.lag >= 1")
        if self.state == "select" and self.quantizer.method == "bins":
            raise ParamError("state='select' zero-pads the shorter state vector; it needs "
                             "quantizer.method 'vq' or 'product_vq', got 'bins'")
        groups = len(self.objects) + len(self.extra)
        if self.quantizer.method == "product_vq" and len(self.quantizer.group_codes) != groups:
            raise ParamError(f"quantizer.group_codes={self.quantizer.group_codes!r} needs one "
                             f"codebook size per object of objects={self.objects!r} and per "
                             f"extra slice of extra={self.extra!r} ({groups} entries)")

    def n_used_per_object(self) -> tuple[int, ...]:
        """Canonical components used for each object (``n_used_objects`` or ``n_used``)."""
        if self.n_used_objects:
            return tuple(int(k) for k in self.n_used_objects)
        return (int(self.n_used),) * len(self.objects)


@struct.dataclass
class ObjectModel:
    """A fitted CVA filter of one object, padded to ``lag_max`` (normalised units).

    ``mu = sum_j Uu[:, j] @ u_n(t-j) + Uy[:, j] @ y_n(t-j)`` over j = 0 .. lag_max-1 (the
    decision-time state; ``u_n(t) = 0``), where ``x_n = (x - mean) / scale``.
    """

    Uu: jax.Array       # (n_used, lag_max, m)
    Uy: jax.Array       # (n_used, lag_max, q)
    u_mean: jax.Array   # (m,)
    u_scale: jax.Array  # (m,)
    y_mean: jax.Array   # (q,)
    y_scale: jax.Array  # (q,)
    lag: jax.Array      # () int32 selected l
    n: jax.Array        # () int32 AIC order n* at that l
    logdet: jax.Array   # () log det R(n*) at that l
    aic: jax.Array      # () AIC(n*) at that l
    cancor: jax.Array   # (n_used,) canonical correlations of the used components at that l


def collect(env: Any, key: jax.Array, env_params: Any, num_steps: int) -> dict[str, jax.Array]:
    """Run uniformly random actions for ``num_steps`` (auto-reset included).

    Returns ``obs`` (N, obs_dim) float32 = y(t), ``u`` (N, m) float32 = the command taken
    after observing y(t), ``start`` (N,) bool = y(t) is the first of an episode.
    """
    k_reset, k_run = jax.random.split(key)
    obs0, st0 = env.reset(k_reset, env_params)

    def body(c, k):
        obs, st, start = c
        k_a, k_s = jax.random.split(k)
        a = jax.random.randint(k_a, (), 0, env.num_actions, jnp.int32)
        obs2, st2, _, term, trunc, info = env.step(k_s, st, a, env_params)
        out = (obs, jnp.asarray(info["u"], jnp.float32), start)
        return (obs2, st2, term | trunc), out

    _, (obs, u, start) = jax.lax.scan(body, (obs0, st0, jnp.bool_(True)),
                                      jax.random.split(k_run, num_steps))
    return {"obs": obs.astype(jnp.float32), "u": u, "start": start}


def identify_object(u: jax.Array, y: jax.Array, cva: CVAParams, n_used: int,
                    keep_beyond_order: Any = False) -> ObjectModel:
    """CVA + AIC order + lag rule on one data set ``u (N, m)``, ``y (N, q)`` (jit/vmap-able).

    The filter holds the first ``n_used`` canonical components; those beyond the AIC order
    n* are 0 unless ``keep_beyond_order`` (bool, may be traced).

    Lag rule (Sec. 3.1.2): from ``l = 1``, stop at the first l whose ``log det R(n*) <
    cva.logdet_stop``; otherwise keep growing l while ``AIC(n*)`` decreases; at most
    ``cva.lag_max`` (a fixed ``cva.lag > 0`` skips the rule).
    """
    m, q = u.shape[1], y.shape[1]
    lags = cva.lags()
    lag_max = max(lags)
    fits = []
    for lag in lags:
        k = cva.horizon_for(lag)
        cap = n_identifiable(lag, k, m, q) if not cva.n_max else min(
            cva.n_max, n_identifiable(lag, k, m, q))
        f = fit_one(u, y, cva, lag=lag, horizon=k, n_cap=cap)
        rows = f.U[:n_used]
        if rows.shape[0] < n_used:
            rows = jnp.concatenate([rows, jnp.zeros((n_used - rows.shape[0], rows.shape[1]),
                                                    rows.dtype)])
        keep = (jnp.arange(n_used) < f.n) | jnp.asarray(keep_beyond_order, bool)
        rows = rows * keep[:, None]  # components beyond n* are 0 unless kept
        cc = jnp.pad(f.cancor[:n_used], (0, max(0, n_used - f.cancor.shape[0])))
        uu = rows[:, :lag * m].reshape(n_used, lag, m)
        uy = rows[:, lag * m:].reshape(n_used, lag, q)
        pad = lag_max - lag
        uu = jnp.pad(uu, ((0, 0), (0, pad), (0, 0)))
        uy = jnp.pad(uy, ((0, 0), (0, pad), (0, 0)))
        fits.append(ObjectModel(Uu=uu.astype(jnp.float32), Uy=uy.astype(jnp.float32),
                                u_mean=f.u_mean.astype(jnp.float32),
                                u_scale=f.u_scale.astype(jnp.float32),
                                y_mean=f.y_mean.astype(jnp.float32),
                                y_scale=f.y_scale.astype(jnp.float32),
                                lag=jnp.int32(lag), n=f.n.astype(jnp.int32),
                                logdet=f.logdet[f.n].astype(jnp.float32),
                                aic=f.aic[f.n].astype(jnp.float32),
                                cancor=(cc * keep).astype(jnp.float32)))
    # lag rule as a static sweep with a "stopped" flag
    chosen = fits[0]
    stopped = fits[0].logdet < cva.logdet_stop
    for f in fits[1:]:
        take = (~stopped) & (f.aic < chosen.aic)
        stopped = stopped | (~take) | (f.logdet < cva.logdet_stop)
        chosen = jax.tree.map(lambda a, b, t=take: jnp.where(t, a, b), f, chosen)
    return chosen


def filter_state(model: ObjectModel, hist_u: jax.Array, hist_y: jax.Array) -> jax.Array:
    """Decision-time canonical state (n_used,) float32 from raw histories.

    ``hist_u`` (lag_max, m): row j = u(t-j) (row 0 is ignored: u(t) is not chosen yet);
    ``hist_y`` (lag_max, q): row j = y(t-j).
    """
    un = (hist_u - model.u_mean) / model.u_scale
    un = un.at[0].set(0.0)
    yn = (hist_y - model.y_mean) / model.y_scale
    return (jnp.einsum("njm,jm->n", model.Uu, un)
            + jnp.einsum("njq,jq->n", model.Uy, yn)).astype(jnp.float32)


# ---------------------------------------------------------------------------- the env wrapper


@struct.dataclass
class FilteredParams:
    """Per-learner params of :class:`FilteredEnv` (a pytree; vmapped over learners)."""

    inner: Any                      # the wrapped env's params
    models: tuple                   # one ObjectModel per object (empty for 'current')
    quantizer: Quantizer
    use_cva: jax.Array              # () bool, state 'select' only


@struct.dataclass
class FilteredState:
    """inner: the wrapped env's state; hist_u/hist_y: per object (lag_max, m) / (lag_max, q)
    raw histories, row 0 = newest; episodes () int32: episodes finished since this state was
    reset; first_success () bool: the first of them succeeded (a first-episode evaluation
    reads these two after a greedy run from fresh resets)."""

    inner: Any
    hist_u: tuple
    hist_y: tuple
    episodes: jax.Array
    first_success: jax.Array


class FilteredEnv:
    """A gymnax-style env whose observation is the quantised (CVA or current) state."""

    def __init__(self, env: Any, p: CVAStateParams, m: int):
        self.env, self.p, self.m = env, p, int(m)
        self.num_actions = env.num_actions
        slices = env.obs_slices
        for name in tuple(p.objects) + tuple(p.extra):
            if name not in slices:
                raise ParamError(f"object {name!r} is not in the env's obs_slices; valid: "
                                 f"{sorted(slices)}")
        self.slices = [slices[o] for o in p.objects]
        self.extra = [slices[o] for o in p.extra]
        self.lag_max = max(p.cva.lags())

    def block_dims(self) -> tuple[int, ...]:
        """Sizes of the state vector's blocks: one per object (CVA: its ``n_used``; current:
        its features; 'select': the larger of the two), then one per ``extra`` slice."""
        n_cva = self.p.n_used_per_object()
        n_cur = [s.stop - s.start for s in self.slices]
        per = {"cva": n_cva, "current": n_cur,
               "select": [max(a, b) for a, b in zip(n_cva, n_cur, strict=True)]}[self.p.state]
        return tuple(int(k) for k in per) + tuple(s.stop - s.start for s in self.extra)

    def state_vector(self, hist_u, hist_y, obs, models, use_cva=True) -> jax.Array:
        """(d,) float32: the object blocks then the extra slices; state 'select': both
        vectors with every object block zero-padded to :meth:`block_dims`, ``use_cva`` picks
        (object g occupies the same components in both, so a per-object quantiser applies)."""
        extra = [obs[s].astype(jnp.float32) for s in self.extra]
        cur = [obs[s].astype(jnp.float32) for s in self.slices]
        if self.p.state == "current":
            return jnp.concatenate(cur + extra)
        cva = [filter_state(mod, hu, hy).astype(jnp.float32) for mod, hu, hy in
               zip(models, hist_u, hist_y, strict=True)]
        if self.p.state == "cva":
            return jnp.concatenate(cva + extra)
        dims = self.block_dims()
        pad = lambda v, k: jnp.pad(v, (0, k - v.shape[0]))  # noqa: E731
        cva = jnp.concatenate([pad(v, k) for v, k in zip(cva, dims, strict=False)] + extra)
        cur = jnp.concatenate([pad(v, k) for v, k in zip(cur, dims, strict=False)] + extra)
        return jnp.where(jnp.asarray(use_cva, bool), cva, cur)

    def _fresh_hist(self, obs):
        hu = tuple(jnp.zeros((self.lag_max, self.m), jnp.float32) for _ in self.slices)
        hy = tuple(jnp.broadcast_to(obs[s], (self.lag_max, s.stop - s.start)).astype(
            jnp.float32) for s in self.slices)
        return hu, hy

    def _out(self, obs, hu, hy, params: FilteredParams):
        x = self.state_vector(hu, hy, obs, params.models, params.use_cva)
        return {"index": quantize(params.quantizer, x), "state": x}

    def reset(self, key, params: FilteredParams):
        obs, st = self.env.reset(key, params.inner)
        hu, hy = self._fresh_hist(obs)
        return self._out(obs, hu, hy, params), FilteredState(st, hu, hy, jnp.int32(0),
                                                             jnp.bool_(False))

    def step(self, key, state: FilteredState, action, params: FilteredParams):
        obs, st, r, term, trunc, info = self.env.step(key, state.inner, action, params.inner)
        u = jnp.asarray(info["u"], jnp.float32)
        done = term | trunc
        hu_new, hy_new = [], []
        for hu, hy, s in zip(state.hist_u, state.hist_y, self.slices, strict=True):
            hu = jnp.roll(hu, 1, axis=0).at[1].set(u).at[0].set(0.0)
            hy = jnp.roll(hy, 1, axis=0).at[0].set(obs[s])
            hu_new.append(hu)
            hy_new.append(hy)
        fu, fy = self._fresh_hist(obs)
        hu = tuple(jnp.where(done, a, b) for a, b in zip(fu, hu_new, strict=True))
        hy = tuple(jnp.where(done, a, b) for a, b in zip(fy, hy_new, strict=True))
        success = jnp.asarray(info["success"], bool) & done
        first = jnp.where(done & (state.episodes == 0), success, state.first_success)
        new = FilteredState(st, hu, hy, state.episodes + done.astype(jnp.int32), first)
        return self._out(obs, hu, hy, params), new, r, term, trunc, info


def state_dim(env: Any, p: CVAStateParams) -> int:
    """Dimension d of the state vector that is quantised."""
    sl = env.obs_slices
    n_cva = p.n_used_per_object()
    n_cur = [sl[o].stop - sl[o].start for o in p.objects]
    per = {"cva": n_cva, "current": n_cur,
           "select": [max(a, b) for a, b in zip(n_cva, n_cur, strict=True)]}[p.state]
    return int(sum(per) + sum(sl[o].stop - sl[o].start for o in p.extra))


def _history_states(fenv: FilteredEnv, data, models, use_cva=True) -> jax.Array:
    """State vectors (N, d) of the collected data, with the same history rule as the env loop."""
    obs, u, start = data["obs"], data["u"], data["start"]

    def body(c, x):
        hu, hy = c
        o, u_prev, st = x
        rolled_u = tuple(jnp.roll(h, 1, axis=0).at[1].set(u_prev).at[0].set(0.0) for h in hu)
        rolled_y = tuple(jnp.roll(h, 1, axis=0).at[0].set(o[s])
                         for h, s in zip(hy, fenv.slices, strict=True))
        fu, fy = fenv._fresh_hist(o)
        hu = tuple(jnp.where(st, a, b) for a, b in zip(fu, rolled_u, strict=True))
        hy = tuple(jnp.where(st, a, b) for a, b in zip(fy, rolled_y, strict=True))
        return (hu, hy), fenv.state_vector(hu, hy, o, models, use_cva)

    u_prev = jnp.concatenate([jnp.zeros_like(u[:1]), u[:-1]])
    init = fenv._fresh_hist(obs[0])
    _, xs = jax.lax.scan(body, init, (obs, u_prev, start))
    return xs


class CVALearner(struct.PyTreeNode):
    """Pure functions of one learner (vmap over learners); built by :func:`make_cva_learner`."""

    prepare: Any = struct.field(pytree_node=False)  # (key, p, env_params) -> FilteredParams
    runner: Any = struct.field(pytree_node=False)   # QLearningRunner on the FilteredEnv
    env: Any = struct.field(pytree_node=False)      # the FilteredEnv
    num_states: int = struct.field(pytree_node=False)
    runner_params: Any = struct.field(pytree_node=False)  # p -> QRunnerParams with S set


def make_cva_learner(env: Any, p: CVAStateParams, m: int | None = None) -> CVALearner:
    """Validate ``p`` and build the learner's pure functions for ``env``.

    ``env`` needs ``num_actions``, ``obs_slices``, ``reset``/``step`` (gymnax style, auto-reset,
    ``info["u"]`` the motor command (m,), ``info["success"]``). ``m`` is the input dimension
    (default: the length of ``info["u"]``, found by one abstract step).

    ``prepare(key, p, env_params)``: collect, identify, fit the quantiser; returns the
    :class:`FilteredParams` for the runner. The runner's ``agent.num_states`` must equal
    the quantiser's number of states: use ``learner.runner_params(p)`` (sets it).
    """
    validate(p)
    if m is None:
        key = jax.random.PRNGKey(0)
        ep = env.default_params
        _, st = jax.eval_shape(env.reset, key, ep)
        out = jax.eval_shape(lambda s: env.step(key, s, jnp.int32(0), ep), st)
        m = int(np.prod(out[5]["u"].shape))
    fenv = FilteredEnv(env, p, m)
    d = state_dim(env, p)
    groups = fenv.block_dims()
    make_quantizer(p.quantizer, d, groups)
    s = num_states(p.quantizer, d)
    lags = p.cva.lags()
    q_max = max(sl.stop - sl.start for sl in fenv.slices)
    need = p.cva.min_samples_factor * 2 * max(lags) * (m + q_max) + 2 * max(lags)
    if p.state != "current" and p.collect_steps < need:
        raise ParamError(f"collect_steps={p.collect_steps} is too few for CVA up to lag "
                         f"{max(lags)}; use >= {int(need)}")
    runner = make_qlearning_runner(fenv, lambda o: o["index"], runner_params(p, s))

    def prepare(key, pp: CVAStateParams, env_params) -> FilteredParams:
        k_col, k_q = jax.random.split(key)
        data = collect(env, k_col, env_params, p.collect_steps)
        models = ()
        if p.state != "current":
            models = tuple(identify_object(data["u"], data["obs"][:, sl], pp.cva, k,
                                           pp.keep_beyond_order)
                           for sl, k in zip(fenv.slices, p.n_used_per_object(), strict=True))
        use_cva = jnp.asarray(pp.use_cva, bool)
        xs = _history_states(fenv, data, models, use_cva)
        qz = fit_quantizer(k_q, xs, pp.quantizer, groups=groups)
        return FilteredParams(inner=env_params, models=models, quantizer=qz, use_cva=use_cva)

    return CVALearner(prepare=prepare, runner=runner, env=fenv, num_states=s,
                      runner_params=lambda pp: runner_params(pp, s))


def runner_params(p: CVAStateParams, s: int) -> QRunnerParams:
    """``p.runner`` with ``agent.num_states = s`` (the quantiser's number of states)."""
    return p.runner.replace(agent=p.runner.agent.replace(num_states=int(s)))


def greedy_params(rp: QRunnerParams, greedy: jax.Array) -> QRunnerParams:
    """``rp`` with learning switched off (learning_rate 0) and exploration rate 0 where the
    traced bool ``greedy`` is set: a greedy evaluation runs through the same compiled
    ``run_chunk`` as training (no separate compilation of the env loop)."""
    g = jnp.asarray(greedy, bool)
    sch = rp.agent.exploration.schedule
    sch = sch.replace(init_value=jnp.where(g, 0.0, sch.init_value).astype(jnp.float32),
                      end_value=jnp.where(g, 0.0, sch.end_value).astype(jnp.float32))
    agent = rp.agent.replace(
        learning_rate=jnp.where(g, 0.0, rp.agent.learning_rate).astype(jnp.float32),
        exploration=rp.agent.exploration.replace(schedule=sch))
    return rp.replace(agent=agent)


def first_episode_stats(env_state: FilteredState) -> dict[str, jax.Array]:
    """First-episode evaluation from the counters of a batch (E,) of :class:`FilteredState`
    (reset at the start of the evaluation): ``success_rate`` = fraction of the E envs whose
    first episode succeeded, ``finished`` = fraction that finished one."""
    fin = (env_state.episodes > 0).astype(jnp.float32)
    ok = (env_state.first_success & (env_state.episodes > 0)).astype(jnp.float32)
    return {"success_rate": jnp.mean(ok), "finished": jnp.mean(fin)}
