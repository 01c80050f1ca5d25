"""brax's PPO as pure functions of one learner, so the engine can ``vmap`` it over seeds.

``brax.training.agents.ppo.train`` is a host-side loop (``pmap``, timing, callbacks); this
module assembles the same training step from brax's own parts (``acting.generate_unroll``,
``ppo.losses.compute_ppo_loss`` with its GAE and truncation bootstrap,
``acme.running_statistics``, the training wrappers) and optax's Adam, without the host
loop: :func:`make_ppo_learner` returns ``init`` / ``train`` / ``train_chunk`` /
``evaluate``, all jit- and vmap-able. The env is built per learner by
``make_env(env_params, difficulty)`` (e.g. a :class:`vbl.envs.brax_adapter.BraxAdapter`
whose params hold a learner's CVA models), so per-learner data stays in the carry.

Curriculum (Learning from Easy Missions for PPO, :class:`CurriculumParams`): the start
difficulty lives in the carry; after every chunk the deterministic policy is evaluated at
the current difficulty and the difficulty rises by ``step`` when its success reaches
``success_level``. Off, every episode starts at ``task_difficulty``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from vbl.agents.ppo import make_categorical_ppo_networks
from vbl.agents.ppo_params import CurriculumParams, PPOParams
from vbl.envs.brax_adapter import quiet_import, set_difficulty

with quiet_import():
    from brax.envs.wrappers import training as wrappers
    from brax.training import acting
    from brax.training.acme import running_statistics, specs
    from brax.training.agents.ppo import losses as ppo_losses
    from brax.training.agents.ppo import networks as ppo_networks

__all__ = ["curriculum_update", "PPOCarry", "PPOLearner", "make_ppo_learner"]

F32 = jnp.float32
EXTRA_FIELDS = ("truncation", "episode_metrics", "episode_done")


@struct.dataclass
class PPOCarry:
    """One learner: network params, Adam state, normaliser, the batched env state, the
    per-learner env params, the start difficulty () float32, key, env steps () float32."""

    params: ppo_losses.PPONetworkParams
    opt_state: Any
    normalizer: running_statistics.RunningStatisticsState
    env_state: Any
    env_params: Any
    difficulty: jax.Array
    key: jax.Array
    env_steps: jax.Array


class PPOLearner(struct.PyTreeNode):
    """Pure functions of one learner, from :func:`make_ppo_learner`."""

    init: Callable = struct.field(pytree_node=False)
    train: Callable = struct.field(pytree_node=False)
    train_chunk: Callable = struct.field(pytree_node=False)
    evaluate: Callable = struct.field(pytree_node=False)
    networks: Any = struct.field(pytree_node=False)


def curriculum_update(cur: CurriculumParams, difficulty: jax.Array, level_success: jax.Array,
                      task_difficulty: jax.Array) -> jax.Array:
    """The next start difficulty () float32: ``difficulty + cur.step`` (at most
    ``task_difficulty``) when the curriculum is on and ``level_success`` (evaluation at
    ``difficulty``) reaches ``cur.success_level``; else unchanged."""
    up = jnp.asarray(cur.enabled, bool) & (level_success >= cur.success_level)
    raised = jnp.minimum(difficulty + cur.step, task_difficulty)
    return jnp.where(up, raised, difficulty).astype(F32)


def _x32(fn: Callable) -> Callable:
    """Trace ``fn`` with 32-bit defaults: brax's wrappers create their counters with the
    default float type, which must match the adapter's float32 (``jax_enable_x64`` on)."""
    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with jax.enable_x64(False):
            return fn(*args, **kwargs)
    return wrapped


@contextlib.contextmanager
def _brax_asks_float64():
    """Silence JAX's float64-truncation warning where brax asks float64 of a 32-bit
    program (its networks' dummy inputs, the running statistics' ``std_eps``): float32 is
    what the learner computes in, so the warning tells a user nothing."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Explicitly requested dtype float64")
        yield


def _optimizer(p: PPOParams) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(p.max_grad_norm),
                       optax.adam(learning_rate=p.learning_rate))


@dataclasses.dataclass(frozen=True)
class _Parts:
    """What one learner's functions share: the env factory, the observation size, the
    PPOParams ``p`` whose static fields they fix, the networks and their inference
    function, unrolls per training step and the task's difficulty () float32."""

    make_env: Callable
    obs_size: int
    p: PPOParams
    nets: Any
    make_policy: Callable
    unrolls: int
    task_d: jax.Array


def _train_env(parts: _Parts, env_params, difficulty):
    """The wrapped training env (brax's ``wrappers.wrap``) and the bare one."""
    env = parts.make_env(env_params, difficulty)
    return wrappers.wrap(env, episode_length=env.episode_length), env


def _init(parts: _Parts, key, env_params, pp: PPOParams) -> PPOCarry:
    """A learner's first carry: fresh networks, optimiser and statistics, its envs reset
    at the curriculum's first difficulty (the task's without a curriculum)."""
    p, nets = parts.p, parts.nets
    k_pol, k_val, k_env, k_run = jax.random.split(key, 4)
    cur = pp.curriculum
    d0 = jnp.where(jnp.asarray(cur.enabled, bool), jnp.asarray(cur.initial_difficulty, F32),
                   parts.task_d)
    env, _ = _train_env(parts, env_params, d0)
    env_state = env.reset(jax.random.split(k_env, p.num_envs))
    with _brax_asks_float64():
        params = ppo_losses.PPONetworkParams(policy=nets.policy_network.init(k_pol),
                                             value=nets.value_network.init(k_val))
        normalizer = running_statistics.init_state(specs.Array((parts.obs_size,),
                                                               jnp.dtype(F32)))
    return PPOCarry(params, _optimizer(pp).init(params), normalizer, env_state, env_params,
                    d0, k_run, jnp.zeros((), F32))


def _rollout(parts: _Parts, env, env_state, policy, key):
    """``unrolls`` unrolls of ``unroll_length`` steps of every env: (env_state, data
    (unrolls * envs, T, ...))."""
    p = parts.p

    def unroll(c, _):
        st, k = c
        k, k_u = jax.random.split(k)
        st, data = acting.generate_unroll(env, st, policy, k_u, p.unroll_length,
                                          extra_fields=EXTRA_FIELDS)
        return (st, k), data

    (env_state, _), data = jax.lax.scan(unroll, (env_state, key), (), length=parts.unrolls)
    # (unrolls, T, envs, ...) -> (unrolls * envs, T, ...)
    data = jax.tree.map(lambda x: jnp.swapaxes(x, 1, 2), data)
    return env_state, jax.tree.map(lambda x: jnp.reshape(x, (-1,) + x.shape[2:]), data)


def _sgd(parts: _Parts, pp: PPOParams, params, opt_state, normalizer, data, key):
    """``num_updates_per_batch`` epochs of minibatch SGD on ``data``: (opt_state, params,
    per-minibatch loss metrics)."""
    p = parts.p
    loss = functools.partial(
        ppo_losses.compute_ppo_loss, ppo_network=parts.nets, entropy_cost=pp.entropy_cost,
        discounting=pp.discounting, reward_scaling=pp.reward_scaling,
        gae_lambda=pp.gae_lambda, clipping_epsilon=pp.clipping_epsilon,
        normalize_advantage=True)
    grad_fn = jax.value_and_grad(loss, has_aux=True)
    opt = _optimizer(pp)

    def minibatch(c, mb):
        o_state, prm, k = c
        k, k_loss = jax.random.split(k)
        (_, metrics), grads = grad_fn(prm, normalizer, mb, k_loss)
        updates, o_state = opt.update(grads, o_state, prm)
        return (o_state, optax.apply_updates(prm, updates), k), metrics

    def epoch(c, _):
        o_state, prm, k = c
        k, k_perm, k_mb = jax.random.split(k, 3)
        shuffled = jax.tree.map(lambda x: jnp.reshape(
            jax.random.permutation(k_perm, x), (p.num_minibatches, -1) + x.shape[1:]), data)
        (o_state, prm, _), metrics = jax.lax.scan(minibatch, (o_state, prm, k_mb), shuffled)
        return (o_state, prm, k), metrics

    (opt_state, params, _), metrics = jax.lax.scan(
        epoch, (opt_state, params, key), (), length=p.num_updates_per_batch)
    return opt_state, params, metrics


def _training_step(parts: _Parts, pp: PPOParams, env, carry, _):
    """One PPO training step (rollout, statistics, SGD) as a ``lax.scan`` body."""
    params, opt_state, normalizer, env_state, key = carry
    k_sgd, k_unroll, k_next = jax.random.split(key, 3)
    policy = parts.make_policy((normalizer, params.policy, params.value))
    env_state, data = _rollout(parts, env, env_state, policy, k_unroll)
    with _brax_asks_float64():
        normalizer = running_statistics.update(normalizer, data.observation)
    opt_state, params, metrics = _sgd(parts, pp, params, opt_state, normalizer, data, k_sgd)
    ex = data.extras["state_extras"]
    done = ex["episode_done"]
    stats = {"episodes": jnp.sum(done),
             "successes": jnp.sum(done * ex["episode_metrics"]["success"]),
             "loss": jnp.mean(metrics["total_loss"]),
             "entropy": -jnp.mean(metrics["entropy_loss"]) / jnp.maximum(
                 pp.entropy_cost, 1e-12)}
    return (params, opt_state, normalizer, env_state, k_next), stats


def _evaluate(parts: _Parts, carry: PPOCarry, key, difficulty, num: int) -> jax.Array:
    """Success rate () of the deterministic policy over ``num`` fresh starts."""
    # brax's EvalWrapper loop with the observation inside the loop body (the env's
    # camera held once): an env counts while its first episode runs (until termination
    # or the time limit), and succeeds if any of those steps succeeds
    base = parts.make_env(carry.env_params, jnp.asarray(difficulty, F32))
    k_reset, k_run = jax.random.split(key)
    st, eps = jax.vmap(base.reset_state)(jax.random.split(k_reset, num))
    policy = parts.make_policy((carry.normalizer, carry.params.policy, carry.params.value),
                               deterministic=True)
    ones = jnp.ones((num,), bool)

    def cond(c):
        *_, t, active, _ = c
        return (t < base.episode_length) & jnp.any(active)

    def body(c):
        s, e, k, t, active, success = c
        k, k_a = jax.random.split(k)
        s = jax.vmap(base.observe)(s, e)
        action, _ = policy(s.obs, k_a)
        s, e = jax.vmap(base.step_state)(s, action)
        success = success | (active & (s.metrics["success"] > 0))
        ended = (s.done > 0) | (t + 1 >= base.episode_length)
        return s, e, k, t + 1, active & ~ended, success

    *_, success = jax.lax.while_loop(
        cond, body, (st, eps, k_run, jnp.zeros((), jnp.int32), ones, ~ones))
    return jnp.mean(success.astype(F32))


def _train(parts: _Parts, carry: PPOCarry, pp: PPOParams):
    """``steps_per_chunk`` training steps: (carry, stats per step)."""
    p = parts.p
    env, _ = _train_env(parts, carry.env_params, carry.difficulty)
    c0 = (carry.params, carry.opt_state, carry.normalizer, carry.env_state, carry.key)
    (params, opt_state, normalizer, env_state, key), stats = jax.lax.scan(
        functools.partial(_training_step, parts, pp, env), c0, (), length=p.steps_per_chunk)
    return carry.replace(params=params, opt_state=opt_state, normalizer=normalizer,
                         env_state=env_state, key=key,
                         env_steps=carry.env_steps + p.env_steps_per_chunk), stats


def _train_chunk(parts: _Parts, carry: PPOCarry, pp: PPOParams):
    """:func:`_train`, the evaluations at the task's and the curriculum's difficulty and
    the curriculum update: (carry, metrics)."""
    task_d = parts.task_d
    carry, stats = _train(parts, carry, pp)
    k_task, k_level, key = jax.random.split(carry.key, 3)
    carry = carry.replace(key=key)
    # one traced evaluation for both difficulties (the task's, the curriculum's)
    task_sr, level_sr = jax.vmap(functools.partial(_evaluate, parts),
                                 in_axes=(None, 0, 0, None))(
        carry, jnp.stack([k_task, k_level]), jnp.stack([task_d, carry.difficulty]),
        parts.p.eval_envs)
    new_d = curriculum_update(pp.curriculum, carry.difficulty, level_sr, task_d)
    # the envs' next starts are drawn at the new difficulty
    env_state = carry.env_state
    if "difficulty" in env_state.info:
        env_state = set_difficulty(env_state, new_d)
    eps = jnp.sum(stats["episodes"])
    metrics = {"env_steps": carry.env_steps, "success_rate": task_sr,
               "level_success_rate": level_sr, "difficulty": carry.difficulty,
               "episodes": eps,
               "train_success_rate": jnp.sum(stats["successes"]) / jnp.maximum(eps, 1.0),
               "loss": jnp.mean(stats["loss"]), "entropy": jnp.mean(stats["entropy"])}
    return carry.replace(difficulty=new_d, env_state=env_state), metrics


def make_ppo_learner(make_env: Callable[[Any, jax.Array], Any], obs_size: int,
                     num_actions: int, p: PPOParams, task_difficulty: float = 1.0
                     ) -> PPOLearner:
    """Build one learner's pure functions (static fields of ``p`` fixed here).

    make_env(env_params, difficulty): a brax Env of one env (unbatched; e.g. a
      ``BraxAdapter``) whose resets draw starts at ``difficulty`` (() float32; ignored by
      tasks without one); its ``episode_length`` is the time limit.
    Functions (``p`` there may be traced; its static fields must match):
      init(key, env_params, p) -> PPOCarry
      train(carry, p) -> (carry, stats): ``steps_per_chunk`` PPO training steps (no
        evaluation; stats per training step: episodes, successes, loss, entropy).
      train_chunk(carry, p) -> (carry, metrics): ``train``,
        the evaluations at the task and the current difficulty, the curriculum update.
      evaluate(carry, key, difficulty, num) -> () success rate of the deterministic policy
        over ``num`` fresh starts (first episode of each).
    """
    norm = running_statistics.normalize if p.normalize_observations else (lambda x, y: x)
    nets = make_categorical_ppo_networks(obs_size, num_actions, preprocess_observations_fn=norm,
                                         **p.net.kwargs())
    parts = _Parts(make_env=make_env, obs_size=obs_size, p=p, nets=nets,
                   make_policy=ppo_networks.make_inference_fn(nets),
                   unrolls=p.batch_size * p.num_minibatches // p.num_envs,
                   task_d=jnp.asarray(task_difficulty, F32))
    return PPOLearner(**{name: _x32(functools.partial(fn, parts)) for name, fn in (
        ("init", _init), ("train", _train), ("train_chunk", _train_chunk),
        ("evaluate", _evaluate))}, networks=nets)
