"""Q-learning on CVA-estimated state vectors (the architecture of Figure 11, Section 3).

One learner (``vmap``-ed over learners): **collect** ``u(t)``, ``y(t)`` with random actions
(:func:`collect`); **identify** one CVA model per observed object (ball, goal, other
robot) with the AIC order and the lag rule of Sec. 3.1.2 (:func:`identify_object`);
**filter** each object's history into its canonical state ``mu`` inside the env loop and
concatenate the first ``n_used`` components of each, ``[mu_ball, mu_goal, mu_other]``;
**quantise** that vector into a Q-table index (:mod:`vbl.spaces.quantize`); **learn** with
the one tabular learner (:mod:`vbl.programs.tabular`). :func:`filtered_env` builds the
wrapper stack, whose observation is ``{"index": int32 (), "perceived": int32 (), "state":
float32 (d,)}``, and :func:`filtered_params` its per-learner params. ``state="current"``
(Table 2's baseline) takes the current features ``y(t)`` as the state vector instead.

See docs/cva_learning.md, "Pipeline" (decision-time state, episode starts, "perceived").
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.envs.wrappers import (
    KINDS,
    HistoryFilterWrapper,
    HistoryParams,
    LinearFilter,
    QuantizeParams,
    QuantizeWrapper,
)
from vbl.params import ParamError, param, section, validate
from vbl.spaces.quantize import (
    Quantizer,
    QuantizerParams,
    fit_quantizer,
    make_quantizer,
    num_states,
    quantize,
)
from vbl.sysid.cva import fit_lags
from vbl.sysid.lag import lag_caps_for, select_fit
from vbl.sysid.linalg import x64_scope
from vbl.sysid.params import CVAParams

__all__ = [
    "STATE_KINDS",
    "CVAStateParams",
    "ObjectModel",
    "collect",
    "identify_object",
    "history_wrapper",
    "filtered_env",
    "filtered_params",
    "state_dim",
    "command_dim",
    "check_collection",
    "prepare_state",
    "state_count",
]

#: What the Q-learner sees (static choice). "select": both state vectors are built (zero-padded
#: to one length) and the traced ``use_cva`` picks one per learner, so one compilation serves
#: both rows of Table 2.
STATE_KINDS = KINDS


@struct.dataclass
class CVAStateParams:
    """The state of the Figure 11 pipeline for one learner: data collection, CVA per object,
    the history filter and the quantiser (the Q-learner's params are a
    :class:`~vbl.agents.qlearning.QRunnerParams` of their own)."""

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
    ident: CVAParams = section(lambda: CVAParams(lag_rule="paper"), doc="CVA identification "
                               "(order by AIC; with lag 0 the lag by the paper's log det rule, "
                               "Section 3.1.2)")
    quantizer: QuantizerParams = section(QuantizerParams, doc="state vector -> Q-table index")

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
        if self.ident.lag == 0 and self.ident.lag_max < 1:
            raise ParamError("ident.lag_max must be >= 1")
        if self.ident.lag == 0 and self.ident.lag_rule != "paper":
            raise ParamError(f"ident.lag_rule={self.ident.lag_rule!r}: the learner selects the "
                             "lag by the paper's rule (ident.lag_rule='paper'), or give a "
                             "fixed ident.lag >= 1")
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
class ObjectModel(LinearFilter):
    """A fitted CVA filter of one object, padded to ``lag_max`` (normalised units).

    A :class:`vbl.envs.wrappers.LinearFilter` (``Uu`` (n_used, lag_max, m), ``Uy``
    (n_used, lag_max, q), means, scales): ``mu = sum_j Uu[:, j] @ u_n(t-j) + Uy[:, j] @
    y_n(t-j)`` over j = 0 .. lag_max-1 (the decision-time state; ``u_n(t) = 0``), where
    ``x_n = (x - mean) / scale``; plus the identification's figures at the chosen lag.
    """

    lag: jax.Array      # () int32 selected l
    n: jax.Array        # () int32 AIC order n* at that l
    logdet: jax.Array   # () log det R(n*) at that l
    aic: jax.Array      # () AIC(n*) at that l
    cancor: jax.Array   # (n_used,) canonical correlations of the used components at that l


def collect(env: Any, key: jax.Array, env_params: Any, num_steps: int) -> dict[str, jax.Array]:
    """Run uniformly random actions (i.i.d., one per primitive: the paper's random
    exploration) for ``num_steps`` (auto-reset included).

    Returns ``obs`` (N, obs_dim) float32 = y(t), ``u`` (N, m) float32 = the command taken
    after observing y(t), ``start`` (N,) bool = y(t) is the first of an episode. ``env``
    has ``reset_state`` / ``step_state`` / ``get_obs`` (the dynamics apart from the
    observation, :class:`vbl.envs.shoot_pass.ShootPassEnv`): each step observes its state
    inside the loop body, so the compiled program holds the env's camera once.
    """
    k_reset, k_run = jax.random.split(key)

    def body(c, k):
        st, eps, start = c
        k_a, k_s = jax.random.split(k)
        a = jax.random.randint(k_a, (), 0, env.num_actions, jnp.int32)
        st2, eps2, _, term, trunc, info = env.step_state(k_s, st, a, env_params)
        out = (env.get_obs(st, env_params, eps), jnp.asarray(info["u"], jnp.float32), start)
        return (st2, eps2, term | trunc), out

    init = (*env.reset_state(k_reset, env_params), jnp.bool_(True))
    _, (obs, u, start) = jax.lax.scan(body, init, jax.random.split(k_run, num_steps))
    return {"obs": obs.astype(jnp.float32), "u": u, "start": start}


def identify_object(u: jax.Array, y: jax.Array, cva: CVAParams, n_used: int,
                    keep_beyond_order: Any = False) -> ObjectModel:
    """CVA + AIC order + lag rule on one data set ``u (N, m)``, ``y (N, q)`` (jit/vmap-able).

    The filter holds the first ``n_used`` canonical components; those beyond the AIC order
    n* are 0 unless ``keep_beyond_order`` (bool, may be traced).

    Lag rule (Sec. 3.1.2, :func:`vbl.sysid.lag.select_fit`): from ``l = 1``, stop at
    the first l whose ``log det R(n*) < cva.logdet_stop`` (keep l); otherwise keep growing l
    while ``AIC(n*)`` decreases (keep the last l that lowered it); at most ``cva.lag_max``
    (a fixed ``cva.lag > 0`` skips the rule). Every lag is fitted in one computation
    (:func:`vbl.sysid.cva.fit_lags`), each with its own order cap ``min(l(m+q), kq)`` (and
    ``cva.n_max``), as a fit of that lag alone.
    """
    m, q = u.shape[1], y.shape[1]
    lags = cva.lags()
    horizons = tuple(cva.horizon_for(lag) for lag in lags)
    caps = lag_caps_for(cva, m, q)
    h = max(lags)  # the state map's columns: [u(t-1..t-h); y(t-1..t-h)], zero beyond l
    fits = fit_lags(u, y, cva, lags=lags, horizons=horizons, n_cap=max(caps), lag_caps=caps)
    # the rule in the caller's precision (its index arithmetic must match the enclosing
    # program's integer width); float64 in the engine, which runs with 64-bit types on
    f, j, logdet, aic = select_fit(fits, cva.logdet_stop)
    with x64_scope():  # the float64 fits stay float64 until the model is cast
        rows = f.U[:n_used]
        if rows.shape[0] < n_used:
            rows = jnp.concatenate([rows, jnp.zeros((n_used - rows.shape[0], rows.shape[1]),
                                                    rows.dtype)])
        keep = (jnp.arange(n_used) < f.n) | jnp.asarray(keep_beyond_order, bool)
        rows = rows * keep[:, None]  # components beyond n* are 0 unless kept
        cc = jnp.pad(f.cancor[:n_used], (0, max(0, n_used - f.cancor.shape[0])))
        fields = dict(Uu=rows[:, :h * m].reshape(n_used, h, m),
                      Uy=rows[:, h * m:].reshape(n_used, h, q), u_mean=f.u_mean,
                      u_scale=f.u_scale, y_mean=f.y_mean, y_scale=f.y_scale,
                      logdet=logdet[j], aic=aic[j], cancor=cc * keep)
        return ObjectModel(lag=jnp.asarray(lags, jnp.int32)[j], n=f.n.astype(jnp.int32),
                           **{k: v.astype(jnp.float32) for k, v in fields.items()})


# ---------------------------------------------------------------------------- the env stack


def history_wrapper(env: Any, p: CVAStateParams, m: int,
                    world: bool = False) -> HistoryFilterWrapper:
    """The history filter of ``p``: objects, lag ``max(p.ident.lags())``, ``n_used`` per
    object, state kind and extra slices (its filters are the :class:`ObjectModel` s);
    ``world``: also the state vector without command terms."""
    return HistoryFilterWrapper(env, tuple(p.objects), max(p.ident.lags()), m,
                                p.n_used_per_object(), p.state, tuple(p.extra), world=world)


def filtered_env(env: Any, p: CVAStateParams, m: int) -> QuantizeWrapper:
    """The env the Q-learner sees: ``QuantizeWrapper(history_wrapper(world=True))``
    (quantised by :func:`vbl.spaces.quantize.quantize`); its observation is
    ``{"index", "perceived", "state"}``: the state's index, the index of the state without
    its command terms, and the state vector."""
    return QuantizeWrapper(history_wrapper(env, p, m, world=True), quantize)


def filtered_params(env_params: Any, models: tuple, quantizer: Quantizer,
                    use_cva: Any) -> QuantizeParams:
    """Params of :func:`filtered_env` for one learner: the inner env's, the CVA models (one
    per object; () for 'current'), the quantiser and the traced ``use_cva`` ('select')."""
    return QuantizeParams(HistoryParams(env_params, tuple(models), use_cva), quantizer)


def state_dim(env: Any, p: CVAStateParams) -> int:
    """Dimension d of the state vector that is quantised."""
    return int(sum(history_wrapper(env, p, 1).block_dims()))


def command_dim(env: Any) -> int:
    """Length m of ``info["u"]`` (the motor command) of ``env``: its ``command_dim``."""
    m = getattr(env, "command_dim", None)
    if not isinstance(m, int | np.integer) or m < 1:
        raise ParamError(f"CVA needs the motor command info['u'] of the env; "
                         f"{type(env).__name__} declares no command_dim (a positive int)")
    return int(m)


def check_collection(env: Any, p: CVAStateParams, m: int) -> None:
    """ParamError when ``p.collect_steps`` is too few for CVA up to the largest lag."""
    hist = history_wrapper(env, p, m)
    lags = p.ident.lags()
    q_max = max(sl.stop - sl.start for sl in hist.slices)
    need = p.ident.min_samples_factor * 2 * max(lags) * (m + q_max) + 2 * max(lags)
    if p.state != "current" and p.collect_steps < need:
        raise ParamError(f"collect_steps={p.collect_steps} is too few for CVA up to lag "
                         f"{max(lags)}; use >= {int(need)}")


def prepare_state(env: Any, p: CVAStateParams, m: int, key: jax.Array, pp: CVAStateParams,
                  env_params: Any) -> tuple[tuple, Quantizer, jax.Array]:
    """Collect (random actions), identify one model per object and fit the quantiser to the
    collected state vectors: ``(models, quantizer, use_cva)`` of one learner. ``p`` gives
    the static fields, ``pp`` the learner's (traced) ones."""
    hist = history_wrapper(env, p, m)
    groups = hist.block_dims()
    k_col, k_q = jax.random.split(key)
    data = collect(env, k_col, env_params, p.collect_steps)
    models = ()
    if p.state != "current":
        models = tuple(identify_object(data["u"], data["obs"][:, sl], pp.ident, k,
                                       pp.keep_beyond_order)
                       for sl, k in zip(hist.slices, p.n_used_per_object(), strict=True))
    use_cva = jnp.asarray(pp.use_cva, bool)
    xs = hist.replay(data["obs"], data["u"], data["start"],
                     HistoryParams(env_params, models, use_cva))
    return models, fit_quantizer(k_q, xs, pp.quantizer, groups=groups), use_cva


def state_count(env: Any, p: CVAStateParams) -> int:
    """Number of discrete states of ``p``'s quantiser on ``env`` (validates ``p``)."""
    validate(p)
    hist = history_wrapper(env, p, 1)
    groups = hist.block_dims()
    d = int(sum(groups))
    make_quantizer(p.quantizer, d, groups)
    return int(num_states(p.quantizer, d))
