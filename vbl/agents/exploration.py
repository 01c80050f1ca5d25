"""Exploration for tabular learners: epsilon-greedy and Boltzmann action selection.

The exploration rate (epsilon) or temperature follows a schedule of the optax
family (``optax.constant_schedule``, ``optax.linear_schedule``,
``optax.exponential_decay``, ``optax.cosine_decay_schedule``): :class:`ExplorationParams`
is a :class:`ScheduleParams` with the selection rule added. The schedule's formula
(``schedule``) is static (it picks the formula); its *numbers* are traced pytree leaves,
so a sweep can ``vmap`` over e.g. the final epsilon. optax's constructors run
Python checks on their numbers (``if transition_steps <= 0``), which a traced
value cannot pass, so :func:`schedule_value` evaluates the same formulas with
``jnp``; :func:`to_optax` builds the optax schedule for concrete numbers and the
tests check that both agree.

Greedy choices break ties uniformly at random with an explicit key.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import ParamError, param

if TYPE_CHECKING:  # optax loads with to_optax, not with the module (vbl's start-up)
    import optax

__all__ = [
    "SCHEDULE_KINDS",
    "EXPLORATION_POLICIES",
    "ScheduleParams",
    "ExplorationParams",
    "schedule_value",
    "to_optax",
    "greedy_action",
    "epsilon_greedy_action",
    "boltzmann_action",
    "boltzmann_probs",
    "select_action",
]

#: Schedule formulas (static choice); each equals the optax schedule of that name.
SCHEDULE_KINDS = ("constant", "linear", "exponential", "cosine")
#: Action-selection rules (static choice).
EXPLORATION_POLICIES = ("epsilon_greedy", "boltzmann")


@struct.dataclass
class ScheduleParams:
    """A scalar schedule v(count) of the optax family (count = schedule steps, see
    :attr:`ExplorationParams.count_unit`).

    * ``constant``: v = init_value.
    * ``linear`` (``optax.linear_schedule``): init_value until ``transition_begin``, then a
      straight line to end_value over ``transition_steps``, then end_value.
    * ``exponential`` (``optax.exponential_decay``): init_value * decay_rate ** (c / T)
      with c = count - transition_begin (c <= 0: init_value), floored to c // T when
      ``staircase``, never below end_value.
    * ``cosine`` (``optax.cosine_decay_schedule`` with alpha = end/init): end_value +
      (init_value - end_value) * (1 + cos(pi * min(count, T) / T)) / 2.
    """

    schedule: str = param("linear", doc="schedule formula", static=True,
                          choices=SCHEDULE_KINDS)
    init_value: float = param(1.0, doc="value at count 0", ge=0.0)
    end_value: float = param(0.1, doc="final value (exponential: lower bound)", ge=0.0)
    transition_steps: float = param(2000.0, doc="length T of the transition, in counts",
                                    unit="count", gt=0.0)
    transition_begin: float = param(0.0, doc="counts held at init_value before the "
                                    "transition (linear, exponential)", unit="count", ge=0.0)
    decay_rate: float = param(0.5, doc="exponential: factor per transition_steps",
                              gt=0.0, le=1.0)
    staircase: bool = param(False, doc="exponential: decay in discrete steps of T counts",
                            static=True)


@struct.dataclass
class ExplorationParams(ScheduleParams):
    """How a learner picks actions from its Q-table row: ``policy`` at the rate (epsilon or
    temperature) of the schedule this class extends."""

    policy: str = param("epsilon_greedy", doc="epsilon-greedy (rate = epsilon) or Boltzmann "
                        "(rate = temperature, in Q units)", static=True,
                        choices=EXPLORATION_POLICIES)
    count_unit: str = param("steps", doc="what the schedule counts: learner steps (one step "
                            "= one action in each of the E environments) or finished "
                            "episodes (trials) of the learner", static=True,
                            choices=("steps", "episodes"))

    def check(self) -> None:
        for name in ("init_value", "end_value"):
            v = getattr(self, name)
            arr = np.asarray(v)
            if self.policy == "epsilon_greedy" and bool(np.any((arr < 0) | (arr > 1))):
                raise ParamError(f"exploration.{name}={v!r}: epsilon must be in [0, 1]")
            if self.policy == "boltzmann" and bool(np.any(arr <= 0)):
                raise ParamError(f"exploration.{name}={v!r}: a Boltzmann temperature "
                                 "must be > 0 (use epsilon_greedy with epsilon 0 for greedy)")


def schedule_value(p: ScheduleParams, count: Any) -> jax.Array:
    """The schedule at ``count`` (any shape, int or float), as float32; traced numbers allowed."""
    c = jnp.asarray(count, jnp.float32)
    init = jnp.asarray(p.init_value, jnp.float32)
    end = jnp.asarray(p.end_value, jnp.float32)
    steps = jnp.asarray(p.transition_steps, jnp.float32)
    begin = jnp.asarray(p.transition_begin, jnp.float32)
    if p.schedule == "constant":
        return jnp.broadcast_to(init, c.shape)
    if p.schedule == "linear":
        frac = 1.0 - jnp.clip(c - begin, 0.0, steps) / steps
        return (init - end) * frac + end
    if p.schedule == "exponential":
        d = c - begin
        e = d / steps
        if p.staircase:
            e = jnp.floor(e)
        rate = jnp.asarray(p.decay_rate, jnp.float32)
        v = jnp.where(d <= 0, init, init * jnp.power(rate, e))
        return jnp.maximum(v, end)
    if p.schedule == "cosine":
        cos = 0.5 * (1.0 + jnp.cos(jnp.pi * jnp.minimum(c, steps) / steps))
        return (init - end) * cos + end
    raise ParamError(f"schedule {p.schedule!r} unknown; choose one of {list(SCHEDULE_KINDS)}")


def to_optax(p: ScheduleParams) -> optax.Schedule:
    """The equivalent optax schedule (needs concrete Python numbers, not traced ones)."""
    import optax

    init, end = float(p.init_value), float(p.end_value)
    steps, begin = float(p.transition_steps), float(p.transition_begin)
    if p.schedule == "constant":
        return optax.constant_schedule(init)
    if p.schedule == "linear":
        return optax.linear_schedule(init, end, steps, begin)
    if p.schedule == "exponential":
        return optax.exponential_decay(init, steps, float(p.decay_rate), begin, p.staircase, end)
    if p.schedule == "cosine":
        return optax.cosine_decay_schedule(init, steps, alpha=end / init if init else 0.0)
    raise ParamError(f"schedule {p.schedule!r} unknown; choose one of {list(SCHEDULE_KINDS)}")


def _greedy_from_uniform(u: jax.Array, q_rows: jax.Array) -> jax.Array:
    """argmax of q_rows (..., A); among k tied maxima pick number floor(u * k), u in [0, 1)."""
    is_max = q_rows >= jnp.max(q_rows, axis=-1, keepdims=True)
    count = jnp.sum(is_max, axis=-1, dtype=jnp.int32)
    k = jnp.minimum((u * count).astype(jnp.int32), count - 1)
    rank = jnp.cumsum(is_max, axis=-1, dtype=jnp.int32) - 1
    return jnp.argmax(is_max & (rank == k[..., None]), axis=-1).astype(jnp.int32)


def greedy_action(key: jax.Array, q_rows: jax.Array) -> jax.Array:
    """argmax over the last axis of ``q_rows`` (..., A), ties broken uniformly at random.

    Returns int32 (...)."""
    u = jax.random.uniform(key, q_rows.shape[:-1], jnp.float32)
    return _greedy_from_uniform(u, q_rows)


def epsilon_greedy_action(key: jax.Array, q_rows: jax.Array, epsilon: Any) -> jax.Array:
    """With probability ``epsilon`` a uniform action (any of the A), else greedy. int32 (...).

    Draws three uniforms per row in one call (explore?, random action, tie-break)."""
    shape, n_act = q_rows.shape[:-1], q_rows.shape[-1]
    u = jax.random.uniform(key, (3, *shape), jnp.float32)
    explore = u[0] < jnp.asarray(epsilon, jnp.float32)
    rand = jnp.minimum((u[1] * n_act).astype(jnp.int32), n_act - 1)
    return jnp.where(explore, rand, _greedy_from_uniform(u[2], q_rows))


def boltzmann_probs(q_rows: jax.Array, temperature: Any) -> jax.Array:
    """softmax(q / T) over the last axis, float32 (..., A); stable for small T."""
    t = jnp.asarray(temperature, jnp.float32)
    return jax.nn.softmax(q_rows.astype(jnp.float32) / t, axis=-1)


def boltzmann_action(key: jax.Array, q_rows: jax.Array, temperature: Any) -> jax.Array:
    """Sample a ~ softmax(q / T) over the last axis (T > 0, Q units). int32 (...)."""
    t = jnp.asarray(temperature, jnp.float32)
    logits = q_rows.astype(jnp.float32) / t
    return jax.random.categorical(key, logits, axis=-1).astype(jnp.int32)


def select_action(key: jax.Array, q_rows: jax.Array, rate: Any, policy: str) -> jax.Array:
    """Pick actions for Q rows (..., A) with ``policy`` (static) at ``rate`` (epsilon or T)."""
    if policy == "epsilon_greedy":
        return epsilon_greedy_action(key, q_rows, rate)
    if policy == "boltzmann":
        return boltzmann_action(key, q_rows, rate)
    raise ParamError(f"exploration policy {policy!r} unknown; choose one of "
                     f"{list(EXPLORATION_POLICIES)}")
