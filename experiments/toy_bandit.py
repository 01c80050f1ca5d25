"""Toy experiment: epsilon-greedy learners on the 10-armed Gaussian bandit testbed.

A tiny but real learning problem used by the engine's tests and docs (not a paper result).
Each learner draws its own arm means ``mu ~ N(0, arm_spread^2)`` at ``init``, then pulls
arms epsilon-greedily and updates action values with a constant step size.
Run it: ``vbl run toy_bandit --quick`` or ``python experiments/toy_bandit.py --quick``.
"""

import jax
import jax.numpy as jnp
from flax import struct

from vbl.engine import Experiment, Program, register
from vbl.params import param, section


@struct.dataclass
class BanditEnv:
    num_arms: int = param(10, doc="number of arms", static=True, ge=2)
    arm_spread: float = param(1.0, doc="std of the arm means drawn per learner", gt=0.0)
    reward_noise: float = param(1.0, doc="std of the reward around the arm mean", ge=0.0)


@struct.dataclass
class BanditAgent:
    learning_rate: float = param(0.1, doc="constant step size of the value update", gt=0.0,
                                 le=1.0)
    epsilon: float = param(0.1, doc="probability of a uniformly random arm", ge=0.0, le=1.0)
    initial_value: float = param(0.0, doc="initial action value (optimism)")


@struct.dataclass
class BanditTrain:
    num_chunks: int = param(20, doc="chunks (progress/checkpoint units) per run", static=True,
                            ge=1)
    pulls_per_chunk: int = param(50, doc="arm pulls per chunk", static=True, ge=1)


@struct.dataclass
class BanditConfig:
    env: BanditEnv = section(BanditEnv, doc="the bandit")
    agent: BanditAgent = section(BanditAgent, doc="the learner")
    train: BanditTrain = section(BanditTrain, doc="run length")


@struct.dataclass
class Carry:
    key: jax.Array  # uint32[2]
    mu: jax.Array  # float32[arms], true arm means
    q: jax.Array  # float32[arms], value estimates


def make_program(cfg: BanditConfig) -> Program:
    arms, pulls = cfg.env.num_arms, cfg.train.pulls_per_chunk

    def init(key, c):
        k_mu, k_run = jax.random.split(key)
        mu = c.env.arm_spread * jax.random.normal(k_mu, (arms,), jnp.float32)
        return Carry(k_run, mu, jnp.full((arms,), c.agent.initial_value, jnp.float32))

    def pull(c, carry, _):
        key, k_explore, k_arm, k_noise = jax.random.split(carry.key, 4)
        explore = jax.random.uniform(k_explore) < c.agent.epsilon
        arm = jnp.where(explore, jax.random.randint(k_arm, (), 0, arms), jnp.argmax(carry.q))
        reward = carry.mu[arm] + c.env.reward_noise * jax.random.normal(k_noise, (), jnp.float32)
        q = carry.q.at[arm].add(c.agent.learning_rate * (reward - carry.q[arm]))
        best = arm == jnp.argmax(carry.mu)
        return Carry(key, carry.mu, q), (best, reward, jnp.max(carry.mu) - carry.mu[arm])

    def step(carry, c):
        carry, (best, reward, regret) = jax.lax.scan(lambda s, x: pull(c, s, x), carry, None,
                                                     length=pulls)
        return carry, {"episodes": jnp.float32(pulls),
                       "success_rate": jnp.mean(best.astype(jnp.float32)),
                       "mean_reward": jnp.mean(reward), "regret": jnp.sum(regret)}

    def final(carry, c, key):
        return {"greedy_is_best": (jnp.argmax(carry.q) == jnp.argmax(carry.mu)).astype(
                    jnp.float32),
                "value_error": jnp.mean(jnp.abs(carry.q - carry.mu))}

    return Program(init=init, step=step, num_chunks=cfg.train.num_chunks, final=final,
                   progress_metric="success_rate")


EXPERIMENT = register(Experiment(
    name="toy_bandit",
    description="epsilon-greedy learners on the 10-armed Gaussian bandit (engine test toy)",
    default_config=BanditConfig(),
    make_program=make_program,
    quick={"train.num_chunks": 5},
    seeds=16,
    quick_seeds=4,
    presets={"greedy": {"agent.epsilon": 0.0}},
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
