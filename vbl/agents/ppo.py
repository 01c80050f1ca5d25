"""A categorical action distribution and a network factory for brax's PPO.

brax's PPO (``brax.training.agents.ppo``) ships only Gaussian action distributions; vbl's
tasks have discrete action primitives. :class:`CategoricalDistribution` plugs into brax's
``ParametricDistribution`` protocol (the policy network outputs one logit per primitive;
actions are int32 indices), and :func:`make_categorical_ppo_networks` is a
``network_factory`` for ``brax.training.agents.ppo.train``::

    from brax.training.agents.ppo import train as ppo
    env = BraxAdapter(ShootingEnv())
    make_policy, params, metrics = ppo.train(
        env, num_timesteps=1_000_000, episode_length=env.episode_length,
        network_factory=make_categorical_ppo_networks, ...)

:class:`vbl.agents.ppo_params.PPONetParams` holds the network sizes as named parameters;
``functools.partial(make_categorical_ppo_networks, **net.kwargs())`` passes them.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
from flax import linen

from vbl.agents.ppo_params import PPONetParams
from vbl.envs.brax_adapter import quiet_import

with quiet_import():
    from brax.training import distribution, networks, types
    from brax.training.agents.ppo import networks as ppo_networks

__all__ = ["CategoricalDistribution", "make_categorical_ppo_networks", "network_size"]


class _Categorical:
    """Categorical distribution over the last axis of ``logits`` (..., K)."""

    def __init__(self, logits: jax.Array):
        self.logits = jnp.asarray(logits)

    @property
    def loc(self) -> jax.Array:
        """The logits (brax's PPO loss logs loc/scale statistics of every distribution)."""
        return self.logits

    @property
    def scale(self) -> jax.Array:
        """The probabilities (logged by brax's PPO loss as the distribution's 'std')."""
        return jnp.exp(self._logp())

    def _logp(self) -> jax.Array:
        return jax.nn.log_softmax(self.logits, axis=-1)

    def sample(self, seed: jax.Array) -> jax.Array:
        return jax.random.categorical(seed, self.logits, axis=-1).astype(jnp.int32)

    def mode(self) -> jax.Array:
        return jnp.argmax(self.logits, axis=-1).astype(jnp.int32)

    def log_prob(self, x: jax.Array) -> jax.Array:
        idx = jnp.asarray(x).astype(jnp.int32)[..., None]
        return jnp.take_along_axis(self._logp(), idx, axis=-1)[..., 0]

    def entropy(self) -> jax.Array:
        logp = self._logp()
        return -jnp.sum(jnp.exp(logp) * logp, axis=-1)

    def kl_divergence(self, old_dist: _Categorical) -> jax.Array:
        """KL(old_dist || self), per batch element (brax's convention)."""
        old = old_dist._logp()
        return jnp.sum(jnp.exp(old) * (old - self._logp()), axis=-1)


class _Identity:
    """No postprocessing of the sampled index (zero log-det Jacobian)."""

    def forward(self, x):
        return x

    def inverse(self, x):
        return x

    def forward_log_det_jacobian(self, x):
        return jnp.zeros(jnp.shape(x), jnp.float32)


class CategoricalDistribution(distribution.ParametricDistribution):
    """brax ``ParametricDistribution`` over ``num_actions`` primitives: parameters are the
    logits (..., num_actions); samples and modes are int32 indices (...)."""

    def __init__(self, num_actions: int):
        if int(num_actions) < 1:
            raise ValueError(f"num_actions must be >= 1, got {num_actions}")
        super().__init__(param_size=int(num_actions), postprocessor=_Identity(),
                         event_ndims=0, reparametrizable=False)

    def create_dist(self, parameters):
        return _Categorical(parameters)


def make_categorical_ppo_networks(
        observation_size: types.ObservationSize, action_size: int,
        preprocess_observations_fn: types.PreprocessObservationFn = (
            types.identity_observation_preprocessor),
        policy_hidden_layer_sizes: Sequence[int] = (64, 64),
        value_hidden_layer_sizes: Sequence[int] = (64, 64),
        activation: networks.ActivationFn = linen.swish) -> ppo_networks.PPONetworks:
    """brax ``PPONetworks`` with a categorical policy over ``action_size`` primitives (the
    ``network_factory`` argument of ``brax.training.agents.ppo.train``)."""
    dist = CategoricalDistribution(action_size)
    # brax's 'tanh_normal' policy network is a plain MLP with param_size outputs: the logits
    policy = networks.make_policy_network(
        dist.param_size, observation_size, preprocess_observations_fn=preprocess_observations_fn,
        hidden_layer_sizes=policy_hidden_layer_sizes, activation=activation,
        distribution_type="tanh_normal")
    value = networks.make_value_network(
        observation_size, preprocess_observations_fn=preprocess_observations_fn,
        hidden_layer_sizes=value_hidden_layer_sizes, activation=activation)
    return ppo_networks.PPONetworks(policy_network=policy, value_network=value,
                                    parametric_action_distribution=dist)


def network_size(obs_size: int, num_actions: int, net: PPONetParams) -> dict[str, int]:
    """Parameter counts ``{"policy": ..., "value": ...}`` of the two MLPs (weights + biases)."""
    def count(sizes):
        return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:], strict=True))
    return {"policy": count([obs_size, *net.policy_hidden, num_actions]),
            "value": count([obs_size, *net.value_hidden, 1])}
