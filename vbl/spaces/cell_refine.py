"""Closed-loop refinement of an off-line cell map (an extension of paper Section 2.1).

The construction of :mod:`vbl.spaces.action_cells` judges a primitive in a cell open-loop
(it reaches a labelled cell, whatever that cell's primitive then does). The refinement
keeps the construction's partition and re-chooses each unit's primitive (a unit is a
labelled cell or a pattern's remainder, or every cell) by what the map's policy achieves,
with on-policy Monte Carlo control (every-visit, epsilon-greedy, macro actions): a
decision scores ``discount**k`` when its episode scores k primitives later, and a unit
with ``min_visits`` decisions takes the primitive of highest mean score. The refined
map's states are the units with the same primitive and the same number of transitions to
the goal. Deterministic for a key; jit- and vmap-able.

See docs/state_spaces.md, "Closed-loop refinement" (units, episodes, the estimates).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from vbl.params import ParamError, param, validate
from vbl.spaces.action_based import reset_at_random_difficulty
from vbl.spaces.action_cells import CellMap, cell_index

__all__ = [
    "RefineParams",
    "RefinedMap",
    "decision_statistics",
    "initial_units",
    "refine_cell_map",
    "refined_policy_action",
    "num_refined_states",
    "num_refined_units",
]

F32 = jnp.float32
I32 = jnp.int32
UNITS = ("labelled", "cells")


@struct.dataclass
class RefineParams:
    """Closed-loop refinement of a cell map (module docstring; defaults: Figure 5's,
    measured in docs/findings/fig5_action_based.md)."""

    iterations: int = param(50, doc="policy-improvement iterations (0: no refinement)",
                            static=True, ge=0)
    episodes: int = param(512, doc="episodes per iteration (in parallel)", static=True, ge=1)
    horizon: int = param(150, doc="primitives per episode (an episode that has not scored "
                         "by then counts as a failure)", unit="steps", static=True, ge=1)
    epsilon: float = param(0.2, doc="probability that a decision takes a uniformly random "
                           "primitive instead of the unit's", ge=0.0, le=1.0)
    max_hold: int = param(20, doc="most primitives a decision is held while the unit does "
                          "not change", unit="steps", ge=1)
    discount: float = param(0.98, doc="per-primitive discount of a decision's score",
                            gt=0.0, le=1.0)
    min_visits: float = param(10.0, doc="fewest decisions of a primitive in a unit before "
                              "its mean score is trusted", ge=1.0)
    difficulty_lo: float = param(0.0, doc="least start difficulty of the episodes (envs with "
                                 "a start_difficulty parameter)", ge=0.0, le=1.0)
    difficulty_hi: float = param(0.3, doc="largest start difficulty of the episodes",
                                 ge=0.0, le=1.0)
    units: str = param("labelled", doc="rows of the policy table: 'labelled' (the map's "
                       "labelled cells + one remainder per categorical pattern) or 'cells' "
                       "(every cell)", static=True, choices=UNITS)
    max_transitions: int = param(12, doc="cap on a unit's transitions to the goal (states "
                                 "are (transitions, primitive) pairs)", static=True, ge=1)

    def check(self) -> None:
        if self.difficulty_lo > self.difficulty_hi:
            raise ParamError(f"refine.difficulty_lo={self.difficulty_lo} must be <= "
                             f"refine.difficulty_hi={self.difficulty_hi}")


@struct.dataclass
class RefinedMap:
    """A refined policy over the units of a cell map.

    unit_of (C,) int32 unit of each cell; policy (U,) int32 primitive per unit; score (U, A)
    float32 mean decision score (-1 where never tried); visits (U, A) float32 decisions;
    transitions (U,) int32 state transitions to the goal (0 = never reached it); state (U,)
    int32 = transitions x A + primitive, -1 for units that never reached the goal;
    train_success (iterations,) float32 fraction of each iteration's episodes that scored;
    primitives () float32 primitives the refinement used. U = C (units "cells") or C + P."""

    unit_of: jax.Array
    policy: jax.Array
    score: jax.Array
    visits: jax.Array
    transitions: jax.Array
    state: jax.Array
    train_success: jax.Array
    primitives: jax.Array


def initial_units(cm: CellMap, units: str) -> tuple[jax.Array, jax.Array]:
    """(unit_of (C,) int32, policy (U,) int32): the units of :class:`RefineParams` and the
    map's primitive in each (labelled cell: its state's; remainder: its pattern's)."""
    n_cells = cm.cell_state.shape[0]
    n_pat = cm.fallback.shape[0]
    cells = jnp.arange(n_cells, dtype=I32)
    labelled = cm.cell_state >= 0
    map_act = jnp.where(labelled, cm.action[jnp.maximum(cm.cell_state, 0)],
                        cm.fallback[cells % n_pat]).astype(I32)
    if units == "cells":
        return cells, map_act
    if units != "labelled":
        raise ParamError(f"refine.units={units!r}; allowed: {list(UNITS)}")
    unit_of = jnp.where(labelled, cells, n_cells + cells % n_pat).astype(I32)
    return unit_of, jnp.concatenate([map_act, cm.fallback.astype(I32)])


def decision_statistics(unit: jax.Array, action: jax.Array, decided: jax.Array,
                        success: jax.Array, greedy: jax.Array, discount: float | jax.Array,
                        num_units: int, num_actions: int):
    """Per (unit, primitive) decision statistics of episodes (E, T).

    unit, action (E, T) int32 the unit and the primitive in force at each step; decided
    (E, T) bool a decision was taken at the step; success (E, T) bool the episode scored at
    the step (at most once per row; steps after an episode's end must be neither decided
    nor success); greedy (E, T) bool the decision took the unit's primitive.
    Returns (score_sum (U, A), visits (U, A), trans_sum (U,), trans_count (U,)) float32:
    every decision scores discount**k when the episode scores k primitives after it
    (counting the decision's own step as 0), else 0; trans_* sum, over greedy decisions of
    scoring episodes, the decisions from this one to the scoring step inclusive."""

    def back(carry, inp):
        g, n = carry
        dec, succ = inp
        g = jnp.where(succ, 1.0, discount * g)
        n = jnp.where(succ, dec.astype(F32), n + dec.astype(F32))
        return (g, n), (g, n)

    init = (jnp.zeros(unit.shape[:1], F32), jnp.zeros(unit.shape[:1], F32))
    _, (ret, rem) = jax.lax.scan(back, init, (decided.T, success.T), reverse=True)
    ret, rem = ret.T, rem.T
    size = num_units * num_actions
    idx = jnp.where(decided, unit * num_actions + action, size).reshape(-1)

    def seg(w, ids, n):
        return jax.ops.segment_sum(w.reshape(-1), ids, num_segments=n + 1)[:n]

    score_sum = seg(jnp.where(decided, ret, 0.0), idx, size).reshape(num_units, num_actions)
    visits = seg(decided.astype(F32), idx, size).reshape(num_units, num_actions)
    reached = decided & greedy & (ret > 0)
    uidx = jnp.where(reached, unit, num_units).reshape(-1)
    return (score_sum, visits, seg(jnp.where(reached, rem, 0.0), uidx, num_units),
            seg(reached.astype(F32), uidx, num_units))


def refine_cell_map(env: Any, env_params: Any, key: jax.Array,
                    feature_fn: Callable[[jax.Array], jax.Array], cm: CellMap,
                    p: RefineParams) -> RefinedMap:
    """Refine the map's policy by closed-loop Monte Carlo control (module docstring).

    ``env`` follows the ``ShootingEnv`` API (``reset``, auto-resetting ``step`` with
    ``info["success"]``, ``num_actions``); ``feature_fn(obs) -> (D,)`` gives the features
    the map reads. Jit-able with ``p`` static."""
    n_act = env.num_actions
    unit_of, pol0 = initial_units(cm, p.units)
    n_units = pol0.shape[0]
    gamma = jnp.asarray(p.discount, F32)

    def episode(k, pol):
        k_d, k_reset, k_run = jax.random.split(k, 3)
        obs, st, ep = reset_at_random_difficulty(env, env_params, k_d, k_reset,
                                                 p.difficulty_lo, p.difficulty_hi)

        def body(carry, kt):
            obs, st, alive, prev, a, held = carry
            k_e, k_r, k_s = jax.random.split(kt, 3)
            u = unit_of[cell_index(cm, feature_fn(obs))]
            decide = (u != prev) | (held >= p.max_hold)
            explore = jax.random.uniform(k_e) < p.epsilon
            rnd = jax.random.randint(k_r, (), 0, n_act, dtype=I32)
            a = jnp.where(decide, jnp.where(explore, rnd, pol[u]), a).astype(I32)
            held = jnp.where(decide, 1, held + 1).astype(I32)
            obs2, st2, _, term, trunc, info = env.step(k_s, st, a, ep)
            rec = (u, a, decide & alive, alive & info["success"], ~explore, alive)
            return (obs2, st2, alive & ~(term | trunc), u, a, held), rec

        init = (obs, st, jnp.ones((), bool), jnp.full((), -1, I32), jnp.zeros((), I32),
                jnp.zeros((), I32))
        _, rec = jax.lax.scan(body, init, jax.random.split(k_run, p.horizon))
        return rec

    last = p.iterations - max(p.iterations // 4, 1)   # transitions: the last quarter

    def improve(carry, xs):
        k, i = xs
        pol, s_sum, n_sum, t_sum, t_cnt = carry
        u, a, dec, succ, greedy, alive = jax.vmap(episode, in_axes=(0, None))(
            jax.random.split(k, p.episodes), pol)
        ds, dn, dt, dc = decision_statistics(u, a, dec, succ, greedy, gamma, n_units, n_act)
        s_sum, n_sum = s_sum + ds, n_sum + dn
        trusted = n_sum >= p.min_visits
        mean = jnp.where(trusted, s_sum / jnp.maximum(n_sum, 1.0), -1.0)
        cur_ok = jnp.take_along_axis(trusted, pol[:, None], axis=1)[:, 0]
        pol = jnp.where(cur_ok, jnp.argmax(mean, axis=1), pol).astype(I32)
        late = (i >= last).astype(F32)
        stats = (jnp.mean(jnp.any(succ, axis=1).astype(F32)), jnp.sum(alive).astype(F32))
        return (pol, s_sum, n_sum, t_sum + late * dt, t_cnt + late * dc), stats

    zeros = jnp.zeros((n_units, n_act), F32)
    init = (pol0, zeros, zeros, jnp.zeros((n_units,), F32), jnp.zeros((n_units,), F32))
    (pol, s_sum, n_sum, t_sum, t_cnt), (succ, prims) = jax.lax.scan(
        improve, init, (jax.random.split(key, p.iterations), jnp.arange(p.iterations)))
    trans = jnp.where(t_cnt > 0, jnp.clip(jnp.round(t_sum / jnp.maximum(t_cnt, 1.0)), 1,
                                          p.max_transitions), 0).astype(I32)
    return RefinedMap(unit_of=unit_of, policy=pol,
                      score=jnp.where(n_sum > 0, s_sum / jnp.maximum(n_sum, 1.0), -1.0),
                      visits=n_sum, transitions=trans,
                      state=jnp.where(trans > 0, trans * n_act + pol, -1).astype(I32),
                      train_success=succ, primitives=jnp.sum(prims))


def make_refiner(env: Any, feature_fn: Callable[[jax.Array], jax.Array], p: RefineParams):
    """Validated, jitted ``refine(env_params, key, cm) -> RefinedMap``."""
    validate(p)
    return jax.jit(lambda env_params, key, cm: refine_cell_map(env, env_params, key,
                                                               feature_fn, cm, p))


def refined_policy_action(cm: CellMap, rm: RefinedMap, x: jax.Array) -> jax.Array:
    """The refined map's primitive for features x (..., D), int32 (...)."""
    return rm.policy[rm.unit_of[cell_index(cm, x)]]


def num_refined_states(rm: RefinedMap, num_actions: int, max_transitions: int) -> jax.Array:
    """Distinct (transitions, primitive) states among the units that reached the goal,
    int32 (the goal not counted)."""
    size = (max_transitions + 1) * num_actions
    idx = jnp.where(rm.state >= 0, rm.state, size)
    used = jax.ops.segment_sum(jnp.ones_like(idx, dtype=I32), idx, num_segments=size + 1)
    return jnp.sum(used[:size] > 0).astype(I32)


def num_refined_units(rm: RefinedMap) -> jax.Array:
    """Rows of the policy table in use: units some cell maps to and the refinement tried,
    int32."""
    used = jnp.zeros(rm.policy.shape, bool).at[rm.unit_of].set(True)
    return jnp.sum(used & (jnp.sum(rm.visits, -1) > 0)).astype(I32)
