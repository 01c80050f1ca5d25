"""Off-line, action-based state-space construction (paper Section 2.1).

A *state* is a set of input vectors from which repeating **one kind** of action
primitive reaches the goal, or a state built before, whatever the number of
repetitions; that primitive is the state's action. States are grown backwards from
the goal until no new one appears.

Algorithm (all fixed-shape, jit- and vmap-able):

1. :func:`collect_experience`: ``episodes_per_action`` episodes per primitive in
   parallel environments, each holding its primitive for ``horizon`` steps (or until
   the episode ends); start situations are the env's random starts, optionally with
   a per-episode start difficulty drawn uniformly in ``[difficulty_lo,
   difficulty_hi]`` (spreads the data over the feature space). Features are
   normalised to ``[0, 1]`` (:class:`FeatureParams`).
2. :func:`build_state_map`, iteration ``i = 0, 1, ...``: a point ``x_t`` of an
   episode with primitive ``a`` (one of its first ``start_window`` points, not yet
   inside a built state) *reaches* when a later step of the same episode hits the
   goal or lands inside a built state. Per primitive and *categorical pattern* (the
   values of the last ``categorical_dims`` features, e.g. the objects' lost sides:
   "seen", "lost left", "lost right"), the reaching points are clustered (k-means,
   ``clusters_per_action``) and each cluster becomes a hyper-ellipsoid
   (:mod:`vbl.spaces.ellipsoids`, ``coverage`` quantile of its members) that only holds
   points of its pattern. A cluster is kept when it has ``min_points`` members and at
   least ``min_reliability`` of *all* of ``a``'s start points inside it reach. The kept
   ellipsoids of primitive ``a`` at iteration ``i`` form one state with action ``a``,
   ``1 +`` the transitions of the state its points reach, and division order ``i``.
   Stop when an iteration adds nothing (or after ``max_iterations``).

Each ellipsoid also gets a *value*: the mean over its start points of
``discount^(primitives to the target)`` x the target's value (goal 1, not reached 0),
and an expected *time*: the mean over its reaching start points of the primitives to
the target plus the target's time (goal 0).
The result is a :class:`StateMap`; :func:`classify` maps ``x`` to the containing
state with the fewest transitions (ties: smallest Mahalanobis distance; or, with
``rank = "value"``, the containing ellipsoid of highest value; with ``rank = "time"``
the one of fewest expected primitives), ``-1`` in the *remainder* (no state contains
``x``: situations never seen reaching the goal); :func:`policy_action` uses the nearest
ellipsoid of the same pattern there.

Options (all off by default): ``start_max_speed`` keeps as start points only those
whose recorded world speed (:attr:`Experience.speed`, e.g. the ball's) is below it;
``chain_reliability`` counts a point that reaches a built state with that ellipsoid's
reliability instead of 1 (so reliability is the chance of scoring through the chain);
``max_reach_steps`` counts a point as reaching only within that many primitives.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import ParamError, param, validate
from vbl.spaces.ellipsoids import (
    best_inside,
    fit_ellipsoids,
    kmeans,
    mahalanobis2,
    mahalanobis2_chunked,
)

__all__ = [
    "FeatureParams",
    "CollectParams",
    "ActionBasedParams",
    "Experience",
    "StateMap",
    "sec2_features",
    "pattern_of",
    "collect_experience",
    "reset_at_random_difficulty",
    "build_state_map",
    "check_build",
    "classify",
    "policy_action",
    "num_states",
    "rollout_success",
]

F32 = jnp.float32
TIME_TIE = 1e-3
"""With ``rank = "time"``: weight of the Mahalanobis distance (<= 1 inside) that breaks
ties between containing ellipsoids of equal expected time (well below one primitive)."""


@struct.dataclass
class FeatureParams:
    """Normalisation of the Section-2 observation to the unit cube (paper ranges)."""

    ball_size_max: float = param(270.0, doc="x1 ball diameter range [0, max]", unit="px",
                                 source="P", gt=0.0)
    ball_pos_max: float = param(270.0, doc="x2 ball position range [-max, max]", unit="px",
                                source="P", gt=0.0)
    goal_size_max: float = param(480.0, doc="x3 goal size range [0, max]", unit="px",
                                 source="P", gt=0.0)
    goal_pos_max: float = param(256.0, doc="x4 goal position range [-max, max]", unit="px",
                                source="P", gt=0.0)
    lost_sides: bool = param(True, doc="append the ball/goal lost side ((side + 1) / 2) as "
                             "features 6 and 7 (else 5 features)", static=True)

    @property
    def dim(self) -> int:
        return 7 if self.lost_sides else 5


def sec2_features(obs: jax.Array, p: FeatureParams | None = None) -> jax.Array:
    """Section-2 observation (..., 9) -> normalised features (..., p.dim) float32 in [0, 1].

    x1 / max, (x2 + max) / 2max, x3 / max, (x4 + max) / 2max, (x5 + 1) / 2, and when
    ``lost_sides``: (ball_lost_side + 1) / 2, (goal_lost_side + 1) / 2; clipped to [0, 1].
    """
    p = FeatureParams() if p is None else p
    o = jnp.asarray(obs, F32)
    f = [o[..., 0] / p.ball_size_max, (o[..., 1] + p.ball_pos_max) / (2 * p.ball_pos_max),
         o[..., 2] / p.goal_size_max, (o[..., 3] + p.goal_pos_max) / (2 * p.goal_pos_max),
         (o[..., 4] + 1.0) / 2.0]
    if p.lost_sides:
        f += [(o[..., 7] + 1.0) / 2.0, (o[..., 8] + 1.0) / 2.0]
    return jnp.clip(jnp.stack(f, axis=-1), 0.0, 1.0).astype(F32)


@struct.dataclass
class CollectParams:
    """Experience collection: episodes holding one primitive."""

    episodes_per_action: int = param(1000, doc="episodes per action primitive (all run in "
                                     "parallel)", static=True, ge=1)
    horizon: int = param(100, doc="primitives held per episode (fewer when it ends)",
                         unit="steps", static=True, ge=1)
    difficulty_lo: float = param(0.0, doc="per-episode start difficulty drawn uniformly in "
                                 "[lo, hi] (envs with params.start_difficulty)", ge=0.0, le=1.0)
    difficulty_hi: float = param(1.0, doc="upper end of the start difficulty range",
                                 ge=0.0, le=1.0)

    def check(self) -> None:
        if np.any(np.asarray(self.difficulty_lo) > np.asarray(self.difficulty_hi)):
            raise ParamError(f"collect.difficulty_lo={self.difficulty_lo} must be <= "
                             f"collect.difficulty_hi={self.difficulty_hi}")


@struct.dataclass
class ActionBasedParams:
    """Thresholds of the backward construction (normalised feature units)."""

    max_iterations: int = param(12, doc="most construction iterations (transitions to goal)",
                                static=True, ge=1)
    clusters_per_action: int = param(6, doc="k-means clusters per primitive, iteration and "
                                     "categorical pattern", static=True, ge=1)
    kmeans_iters: int = param(10, doc="Lloyd iterations of the k-means", static=True, ge=1)
    start_window: int = param(50, doc="first points of each episode used as start points "
                              "(the rest only serve as look-ahead)", unit="steps",
                              static=True, ge=1)
    coverage: float = param(0.95, doc="fraction of a cluster's members inside its ellipsoid",
                            gt=0.0, le=1.0)
    min_points: float = param(20.0, doc="fewest members of a kept cluster", ge=1.0)
    min_reliability: float = param(0.6, doc="least fraction of the primitive's start points "
                                   "inside the ellipsoid that reach the goal/built states "
                                   "(with chain_reliability: their mean chance of scoring)",
                                   gt=0.0, le=1.0)
    ridge: float = param(1e-4, doc="added to cluster covariances", unit="(norm. units)^2",
                         gt=0.0)
    categorical_dims: int = param(0, doc="the last this many features are categorical (e.g. "
                                  "the objects' lost sides): points are clustered per "
                                  "pattern of their values and an ellipsoid only holds "
                                  "points of its own pattern (0: all features continuous)",
                                  static=True, ge=0)
    categorical_levels: int = param(3, doc="values of each categorical feature, equally "
                                    "spaced in [0, 1] (3: 0, 0.5, 1 = lost left, seen, lost "
                                    "right)", static=True, ge=2)

    discount: float = param(0.98, doc="discount per primitive of an ellipsoid's value (mean "
                            "over its start points of discount^(primitives to the target) x "
                            "the target's value, 1 for the goal, 0 when not reached)",
                            gt=0.0, le=1.0)
    rank: str = param("transitions", doc="which containing state classifies a point: 'value' "
                      "(the ellipsoid of highest value: reached most reliably and soonest), "
                      "'transitions' (fewest transitions to the goal, then smallest "
                      "Mahalanobis distance) or 'time' (the ellipsoid with the fewest "
                      "expected primitives to the goal, ell_time)", static=True,
                      choices=("value", "transitions", "time"))

    supersede: bool = param(False, doc="with rank 'value': a later state may also claim "
                            "points inside built states of another action when its value "
                            "there is higher (else only points in no state are candidates)",
                            static=True)
    start_max_speed: float = param(0.0, doc="only points whose world speed "
                                   "(Experience.speed, e.g. the ball's) is below this are "
                                   "start points (look-ahead points unchanged); 0: no filter",
                                   unit="m/s", ge=0.0)
    chain_reliability: bool = param(False, doc="reliability = mean over the start points "
                                    "inside of the chance of scoring through the chain: 1 "
                                    "for a point that scores, the reliability of the "
                                    "ellipsoid it reaches for a point that reaches a built "
                                    "state, 0 otherwise (else 1 for reaching anything)",
                                    static=True)
    max_reach_steps: int = param(0, doc="a point reaches only when the goal or built state "
                                 "is hit within this many primitives (0: no cap, the "
                                 "paper's 'regardless of its length')", unit="steps", ge=0)

    def check(self) -> None:
        if self.supersede and self.rank != "value":
            raise ParamError("build.supersede=True needs build.rank='value' (a state "
                             "supersedes another by value)")

    @property
    def num_patterns(self) -> int:
        return self.categorical_levels ** self.categorical_dims


@struct.dataclass
class Experience:
    """x (A, N, T+1, D) float32 features before each step; valid (A, N, T+1) bool (inside
    the episode); goal (A, N, T) bool (step t scored); speed (A, N, T+1) float32 a world
    speed at each point (``speed_fn`` of :func:`collect_experience`, e.g. the ball's; 0
    without one). Episode group a held primitive a."""

    x: jax.Array
    valid: jax.Array
    goal: jax.Array
    speed: jax.Array


@struct.dataclass
class StateMap:
    """Built states (capacity S = max_iterations * A) made of ellipsoids (E = S * K * P,
    K = clusters_per_action, P = categorical patterns).

    centre (E, D), shape (E, D, D) float32 (zero for inactive ellipsoids); ell_active (E,)
    bool; ell_state (E,) int32 the state an ellipsoid belongs to; ell_pattern (E,) int32 the
    categorical pattern of its points (:func:`pattern_of`); ell_reliability (E,) float32
    the fraction of its primitive's start points inside it that reached; ell_value (E,)
    float32 the mean over those start points of discount^(primitives to the target) x the
    target's value (goal 1, unreached 0); ell_time (E,) float32 the expected primitives to
    the goal: mean over its reaching start points of (primitives to the target + the
    target's ell_time, 0 for the goal); per state (S,):
    action int32 (state s = i * A + a, made at iteration i, has action a), transitions int32
    (state transitions to the goal: 1 + those of the state its points reach), order int32
    (division order i), active bool; iterations () int32 run. An ellipsoid whose points,
    repeating a, reach a state that already has action a joins that state (F then F is
    still F). Static: categorical_dims, categorical_levels, rank (as in
    :class:`ActionBasedParams`).
    """

    centre: jax.Array
    shape: jax.Array
    ell_active: jax.Array
    ell_state: jax.Array
    ell_pattern: jax.Array
    ell_reliability: jax.Array
    ell_value: jax.Array
    ell_time: jax.Array
    action: jax.Array
    transitions: jax.Array
    order: jax.Array
    active: jax.Array
    iterations: jax.Array
    categorical_dims: int = struct.field(pytree_node=False, default=0)
    categorical_levels: int = struct.field(pytree_node=False, default=3)
    rank: str = struct.field(pytree_node=False, default="transitions")


def pattern_of(x: jax.Array, categorical_dims: int, levels: int) -> jax.Array:
    """Categorical pattern (int32 (...)) of features x (..., D): the last
    ``categorical_dims`` features, each rounded to one of ``levels`` equally spaced values
    in [0, 1], read as digits base ``levels`` (0 when ``categorical_dims`` is 0)."""
    if categorical_dims == 0:
        return jnp.zeros(x.shape[:-1], jnp.int32)
    digits = jnp.clip(jnp.round(x[..., -categorical_dims:] * (levels - 1)), 0, levels - 1)
    base = (levels ** jnp.arange(categorical_dims, dtype=jnp.int32)).astype(F32)
    return jnp.sum(digits * base, axis=-1).astype(jnp.int32)


def reset_at_random_difficulty(env: Any, env_params: Any, k_d: jax.Array, k_reset: jax.Array,
                               lo: Any, hi: Any) -> tuple[jax.Array, Any, Any]:
    """``env.reset(k_reset, ...)`` with the start difficulty drawn uniformly in [lo, hi] from
    ``k_d`` when the env's params have ``start_difficulty`` (else the params as given).
    Returns (obs, state, the episode's env params)."""
    ep = env_params
    if hasattr(env_params, "start_difficulty"):
        ep = env_params.replace(start_difficulty=jax.random.uniform(k_d, (), F32, lo, hi))
    obs, st = env.reset(k_reset, ep)
    return obs, st, ep


def collect_experience(env: Any, env_params: Any, key: jax.Array,
                       feature_fn: Callable[[jax.Array], jax.Array], num_actions: int,
                       p: CollectParams | None = None,
                       speed_fn: Callable[[Any], jax.Array] | None = None) -> Experience:
    """Run ``episodes_per_action`` episodes per primitive, each holding it (jit-able).

    ``feature_fn(obs) -> (D,) float32`` normalises an observation; ``p`` defaults to
    ``CollectParams()``; ``speed_fn(env_state) -> ()`` (optional) records a world speed
    at each point (e.g. the ball's, for ``ActionBasedParams.start_max_speed``; zeros
    without it). Returns :class:`Experience` with A = ``num_actions`` groups."""
    spd = (lambda st: jnp.zeros((), F32)) if speed_fn is None else (  # noqa: E731
        lambda st: jnp.asarray(speed_fn(st), F32))
    p = CollectParams() if p is None else p
    n, t_len = p.episodes_per_action, p.horizon

    def episode(k, a):
        k_d, k_reset, k_run = jax.random.split(k, 3)
        obs, st, ep = reset_at_random_difficulty(env, env_params, k_d, k_reset,
                                                 p.difficulty_lo, p.difficulty_hi)

        def body(carry, kt):
            obs, st, alive = carry
            obs2, st2, _, term, trunc, info = env.step(kt, st, a, ep)
            out = (feature_fn(obs), alive, alive & info["success"], spd(st))
            return (obs2, st2, alive & ~(term | trunc)), out

        (obs_t, st_t, alive_t), (xs, valid, goal, sp) = jax.lax.scan(
            body, (obs, st, jnp.ones((), bool)), jax.random.split(k_run, t_len))
        x = jnp.concatenate([xs, feature_fn(obs_t)[None]], axis=0)
        valid = jnp.concatenate([valid, alive_t[None]], axis=0)
        sp = jnp.concatenate([sp, spd(st_t)[None]], axis=0)
        return x.astype(F32), valid, goal, sp

    keys = jax.random.split(key, num_actions * n).reshape(num_actions, n, -1)
    acts = jnp.broadcast_to(jnp.arange(num_actions, dtype=jnp.int32)[:, None], (num_actions, n))
    x, valid, goal, speed = jax.vmap(jax.vmap(episode))(keys, acts)
    return Experience(x=x, valid=valid, goal=goal, speed=speed)


def check_build(p: ActionBasedParams, num_features: int, horizon: int) -> None:
    """Raise ParamError unless ``p`` fits experience of ``num_features`` features and
    episodes of ``horizon`` primitives (callable before any data exists)."""
    validate(p)
    if p.start_window > horizon:
        raise ParamError(f"start_window={p.start_window} must be <= the collection horizon "
                         f"{horizon} (the episodes' length)")
    if p.categorical_dims >= num_features:
        raise ParamError(f"categorical_dims={p.categorical_dims} must be < the number of "
                         f"features {num_features} (some must be continuous)")


def _check_build(exp: Experience, p: ActionBasedParams) -> None:
    if exp.x.ndim != 4:
        raise ValueError(f"experience.x must be (A, N, T+1, D), got shape {exp.x.shape}")
    check_build(p, exp.x.shape[-1], exp.x.shape[2] - 1)


def _rank_terms(rank: str, value: jax.Array, time: jax.Array,
                transitions: jax.Array) -> tuple[jax.Array, float]:
    """Ranking of containing ellipsoids (lowest wins): ``base + coef * d2`` with d2 the
    squared Mahalanobis distance; per ellipsoid value, expected time and its state's
    transitions (E,) -> (base (E,), coef). "value": -value; "time": time, ties by
    ``TIME_TIE * d2``; "transitions": 4 x transitions + d2 (d2 <= 1 inside)."""
    if rank == "value":
        return -value, 0.0
    if rank == "time":
        return time, TIME_TIE
    return transitions.astype(F32) * 4.0, 1.0


def build_state_map(exp: Experience, p: ActionBasedParams, key: jax.Array) -> StateMap:
    """Grow the states backwards from the goal (see the module docstring).

    Jit-able with ``p`` static-closed (traced thresholds may be vmapped); use
    :func:`make_builder` for a checked, jitted version.
    """
    n_act, n_ep, t1, dim = exp.x.shape
    w, n_it, n_pat = p.start_window, p.max_iterations, p.num_patterns
    k = p.clusters_per_action * n_pat                # ellipsoids per primitive and iteration
    s_cap = n_it * n_act
    e_cap = s_cap * k
    goal_lab = s_cap                       # target label of "scored"
    big = jnp.int32(10 ** 6)
    pts = exp.x[:, :, :w, :].reshape(n_act, n_ep * w, dim)
    pat_of = lambda x: pattern_of(x, p.categorical_dims, p.categorical_levels)  # noqa: E731
    pts_pat = pat_of(pts)                                                       # (A, P)
    x_pat = pat_of(exp.x)                                                       # (A, N, T1)
    cl_pat = jnp.repeat(jnp.arange(n_pat, dtype=jnp.int32), p.clusters_per_action)  # (k,)
    i32 = jnp.int32
    thr = jnp.asarray(p.start_max_speed, F32)
    at_rest = (thr <= 0.0) | (exp.speed[:, :, :w] < thr)     # start points: speed filter
    starts_valid = exp.valid[:, :, :w] & at_rest
    cap = jnp.asarray(p.max_reach_steps, i32)

    smap = StateMap(
        centre=jnp.zeros((e_cap, dim), F32), shape=jnp.zeros((e_cap, dim, dim), F32),
        ell_active=jnp.zeros((e_cap,), bool), ell_state=jnp.zeros((e_cap,), i32),
        ell_pattern=jnp.tile(cl_pat, s_cap), ell_reliability=jnp.zeros((e_cap,), F32),
        ell_value=jnp.zeros((e_cap,), F32), ell_time=jnp.zeros((e_cap,), F32),
        action=jnp.tile(jnp.arange(n_act, dtype=i32), n_it),
        transitions=jnp.full((s_cap,), big, i32),
        order=jnp.repeat(jnp.arange(n_it, dtype=i32), n_act),
        active=jnp.zeros((s_cap,), bool), iterations=jnp.zeros((), i32),
        categorical_dims=p.categorical_dims, categorical_levels=p.categorical_levels,
        rank=p.rank)
    gamma = jnp.asarray(p.discount, F32)

    def cluster(kk, pa, ppat, cand, starts, reach, tgt, val, cur_v, chain, tm):
        _, assign = kmeans(kk, pa, cand, p.clusters_per_action, p.kmeans_iters, ppat, n_pat)
        c, m, cnt = fit_ellipsoids(pa, cand, assign, k, p.coverage, p.ridge)
        inside = ((mahalanobis2_chunked(pa, c, m) <= 1.0) & (ppat[:, None] == cl_pat[None])
                  & starts[:, None])                                            # (P, k)
        n_in = jnp.sum(inside, axis=0).astype(F32)
        in_ok = inside & reach[:, None]
        n_ok = jnp.sum(in_ok, axis=0).astype(F32)
        if p.chain_reliability:   # chance of scoring through the chain
            rel = (jnp.sum(jnp.where(in_ok, chain[:, None], 0.0), axis=0)
                   / jnp.maximum(n_in, 1.0))
        else:
            rel = n_ok / jnp.maximum(n_in, 1.0)
        e_time = jnp.sum(jnp.where(in_ok, tm[:, None], 0.0), axis=0) / jnp.maximum(n_ok, 1.0)
        value = jnp.sum(jnp.where(inside, val[:, None], 0.0), axis=0) / jnp.maximum(n_in, 1.0)
        ok = (cnt >= p.min_points) & (rel >= p.min_reliability)
        if p.supersede:           # better than the states the ellipsoid's points are in now
            now = jnp.sum(jnp.where(inside, cur_v[:, None], 0.0), axis=0) / jnp.maximum(n_in, 1.0)
            ok = ok & (value > now)
        member = jax.nn.one_hot(assign, k, dtype=F32) * cand.astype(F32)[:, None]  # (P, k)
        hist = member.T @ jax.nn.one_hot(jnp.maximum(tgt, 0), s_cap + 1, dtype=F32)
        c = jnp.where(ok[:, None], c, 0.0)
        m = jnp.where(ok[:, None, None], m, 0.0)
        return (c, m, ok, rel, value, e_time,
                jnp.argmax(hist, axis=-1).astype(i32))                          # mode target

    def first_target(lab, lab_v, lab_c, lab_t):
        """Per point (A, N, T): label of the first goal/built state hit after it (-1 none),
        its value discount^(steps to it) x the target's value (goal 1, none 0), its chain
        value (the target's reliability, goal 1), its time (steps to the target + the
        target's time) and the steps to the target."""
        def back(nxt, inp):
            g, l_next, v_next, c_next, t_next = inp
            n_lab, n_val, n_ch, n_tm, n_st = nxt
            hit = l_next >= 0
            cur = jnp.where(g, goal_lab, jnp.where(hit, l_next, n_lab))
            val = jnp.where(g, 1.0, gamma * jnp.where(hit, v_next, n_val))
            ch = jnp.where(g, 1.0, jnp.where(hit, c_next, n_ch))
            tm = 1.0 + jnp.where(g, 0.0, jnp.where(hit, t_next, n_tm))
            st = 1 + jnp.where(g | hit, 0, n_st)
            out = (cur, val, ch, tm, st)
            return out, out
        mv = lambda a: jnp.moveaxis(a, 2, 0)  # noqa: E731
        xs = (mv(exp.goal), mv(lab[..., 1:]), mv(lab_v[..., 1:]), mv(lab_c[..., 1:]),
              mv(lab_t[..., 1:]))
        zf = jnp.zeros(exp.goal.shape[:2], F32)
        init = (jnp.full(exp.goal.shape[:2], -1, i32), zf, zf, zf,
                jnp.zeros(exp.goal.shape[:2], i32))
        _, outs = jax.lax.scan(back, init, xs, reverse=True)
        return tuple(jnp.moveaxis(o, 0, 2) for o in outs)

    def body(carry):
        it, key, sm, lab, lab_v, lab_c, lab_t, _ = carry
        key, kc = jax.random.split(key)
        tgt, val, chain, tm, steps = first_target(lab, lab_v, lab_c, lab_t)
        reach = (tgt >= 0) & ((cap <= 0) | (steps <= cap))
        free = lab[..., :w] < 0
        if p.supersede:
            starts = starts_valid
            own = jnp.arange(n_act, dtype=i32)[:, None, None]
            other = sm.action[jnp.maximum(lab[..., :w], 0)] != own
            free = free | (other & (val[..., :w] > lab_v[..., :w]))
        else:
            starts = starts_valid & free
        cand = starts_valid & free & reach[..., :w]
        flat = (lambda a: a.reshape(n_act, -1))
        c, m, ok, rel, value, e_time, mode = jax.vmap(cluster)(
            jax.random.split(kc, n_act), pts, pts_pat, flat(cand), flat(starts),
            flat(reach[..., :w]), flat(tgt[..., :w]), flat(val[..., :w]),
            flat(lab_v[..., :w]), flat(chain[..., :w]), flat(tm[..., :w]))      # (A, k, ...)
        acts = jnp.arange(n_act, dtype=i32)[:, None]
        fresh = (it * n_act + acts) * jnp.ones((1, k), i32)                       # (A, k)
        mode_state = jnp.minimum(mode, s_cap - 1)
        same = (mode < goal_lab) & (sm.action[mode_state] == acts)
        ell_state = jnp.where(same, mode, fresh)                                  # (A, k)
        trans_mode = jnp.where(mode == goal_lab, 0, sm.transitions[mode_state])
        new_trans = jnp.where(ok & ~same, trans_mode + 1, big)
        fresh_trans = jnp.min(new_trans, axis=1)                                  # (A,)
        base = (it * n_act * k).astype(i32)
        z = jnp.zeros((), i32)
        s_idx = (it * n_act).astype(i32)
        upd = jax.lax.dynamic_update_slice
        transitions = upd(sm.transitions, fresh_trans, (s_idx,))
        active = upd(sm.active, jnp.any(ok & ~same, axis=1), (s_idx,))
        sm = sm.replace(
            centre=upd(sm.centre, c.reshape(-1, dim), (base, z)),
            shape=upd(sm.shape, m.reshape(-1, dim, dim), (base, z, z)),
            ell_active=upd(sm.ell_active, ok.reshape(-1), (base,)),
            ell_state=upd(sm.ell_state, ell_state.reshape(-1), (base,)),
            ell_reliability=upd(sm.ell_reliability, jnp.where(ok, rel, 0.0).reshape(-1),
                                (base,)),
            ell_value=upd(sm.ell_value, jnp.where(ok, value, 0.0).reshape(-1), (base,)),
            ell_time=upd(sm.ell_time, jnp.where(ok, e_time, 0.0).reshape(-1), (base,)),
            transitions=transitions, active=active, iterations=it + 1)
        # label the points that fall inside the new ellipsoids (the rank of classify)
        e_st = ell_state.reshape(-1)
        e_val = value.reshape(-1)
        e_rel = rel.reshape(-1)
        e_tm = e_time.reshape(-1)
        base, coef = _rank_terms(p.rank, e_val, e_tm, transitions[e_st])
        best, inside = best_inside(exp.x, x_pat, c.reshape(-1, dim), m.reshape(-1, dim, dim),
                                   jnp.tile(cl_pat, n_act), ok.reshape(-1), base,
                                   coef)                                         # (A, N, T1)
        new_v = e_val[best]
        hit = inside & exp.valid
        hit = hit & ((lab < 0) | (new_v > lab_v)) if p.supersede else hit & (lab < 0)
        lab = jnp.where(hit, e_st[best], lab)
        lab_v = jnp.where(hit, new_v, lab_v)
        lab_c = jnp.where(hit, e_rel[best], lab_c)
        lab_t = jnp.where(hit, e_tm[best], lab_t)
        return it + 1, key, sm, lab, lab_v, lab_c, lab_t, jnp.any(ok)

    def cond(carry):
        it, *_, added = carry
        return (it < n_it) & added

    zf = jnp.zeros(exp.valid.shape, F32)
    init = (jnp.zeros((), i32), key, smap, jnp.full(exp.valid.shape, -1, i32),
            zf, zf, zf, jnp.ones((), bool))
    smap = jax.lax.while_loop(cond, body, init)[2]
    return smap


def make_builder(p: ActionBasedParams) -> Callable[[Experience, jax.Array], StateMap]:
    """Validated, jitted ``build(exp, key) -> StateMap`` for the thresholds ``p``."""
    validate(p)

    @jax.jit
    def _build(exp, key):
        return build_state_map(exp, p, key)

    def build(exp: Experience, key: jax.Array) -> StateMap:
        _check_build(exp, p)
        return _build(exp, key)

    return build


def _scores(sm: StateMap, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Squared Mahalanobis distance to every ellipsoid (inf for inactive ones and for those
    of another categorical pattern) and the ellipsoids' states."""
    d2 = mahalanobis2(x, sm.centre, sm.shape)                                    # (..., E)
    pat = pattern_of(x, sm.categorical_dims, sm.categorical_levels)
    d2 = jnp.where(sm.ell_active & (pat[..., None] == sm.ell_pattern), d2, jnp.inf)
    return d2, sm.ell_state


def classify(sm: StateMap, x: jax.Array) -> jax.Array:
    """State index (int32, (...)) of features x (..., D); -1 when no state contains x.

    Among the containing ellipsoids (same categorical pattern, inside), ``rank =
    "transitions"``: the state with the fewest transitions to the goal, ties by the
    smallest Mahalanobis distance; ``"value"``: the ellipsoid of highest value."""
    d2, st = _scores(sm, x)
    inside = d2 <= 1.0
    base, coef = _rank_terms(sm.rank, sm.ell_value, sm.ell_time, sm.transitions[st])
    rank = base + coef * d2
    key = jnp.where(inside, rank, jnp.inf)
    best = jnp.argmin(key, axis=-1)
    return jnp.where(jnp.any(inside, axis=-1), st[best], -1).astype(jnp.int32)


def nearest_state(sm: StateMap, x: jax.Array) -> jax.Array:
    """State of the ellipsoid with the smallest Mahalanobis distance among those of x's
    categorical pattern, or among all ellipsoids when the pattern has none (int32 (...))."""
    d2, st = _scores(sm, x)
    d_all = jnp.where(sm.ell_active, mahalanobis2(x, sm.centre, sm.shape), jnp.inf)
    d2 = jnp.where(jnp.any(jnp.isfinite(d2), axis=-1, keepdims=True), d2, d_all)
    return st[jnp.argmin(d2, axis=-1)].astype(jnp.int32)


def policy_action(sm: StateMap, x: jax.Array) -> jax.Array:
    """The map's action for features x (..., D): the containing state's action, else the
    nearest ellipsoid's (int32 (...))."""
    s = classify(sm, x)
    s = jnp.where(s >= 0, s, nearest_state(sm, x))
    return sm.action[s]


def num_states(sm: StateMap) -> jax.Array:
    """Number of built states (the goal not counted), int32."""
    return jnp.sum(sm.active).astype(jnp.int32)


def rollout_success(env: Any, env_params: Any, key: jax.Array,
                    policy: Callable[[jax.Array, jax.Array], jax.Array], num_episodes: int,
                    max_steps: int) -> tuple[jax.Array, jax.Array]:
    """Run ``num_episodes`` fresh episodes (parallel) with ``policy(obs, key) -> action``.

    Returns (success (num_episodes,) bool: the first episode scored within max_steps,
    length (num_episodes,) int32 steps taken).
    """
    def one(k):
        k0, k1 = jax.random.split(k)
        obs, st = env.reset(k0, env_params)

        def body(carry, kt):
            obs, st, alive, ok, n = carry
            ka, ks = jax.random.split(kt)
            a = policy(obs, ka)
            obs2, st2, _, term, trunc, info = env.step(ks, st, a, env_params)
            ok = ok | (alive & info["success"])
            n = n + alive.astype(jnp.int32)
            return (obs2, st2, alive & ~(term | trunc), ok, n), None

        init = (obs, st, jnp.ones((), bool), jnp.zeros((), bool), jnp.zeros((), jnp.int32))
        (_, _, _, ok, n), _ = jax.lax.scan(body, init, jax.random.split(k1, max_steps))
        return ok, n

    return jax.vmap(one)(jax.random.split(key, num_episodes))
