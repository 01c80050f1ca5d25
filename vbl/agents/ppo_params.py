"""brax PPO's hyperparameters as named vbl parameters, in a module that does not import
brax, so that experiment configs (and ``vbl list``, ``vbl params``) load without it.
:mod:`vbl.agents.ppo` and :mod:`vbl.agents.ppo_train` use them."""

from __future__ import annotations

from flax import struct

from vbl.params import ParamError, param, section

__all__ = ["PPONetParams", "CurriculumParams", "PPOParams"]


@struct.dataclass
class PPONetParams:
    """Sizes of the policy and value networks (multi-layer perceptrons, swish units)."""

    policy_hidden: tuple = param((64, 64), doc="hidden layer widths of the policy network "
                                 "(brax's default (32,)*4)", static=True)
    value_hidden: tuple = param((64, 64), doc="hidden layer widths of the value network "
                                "(brax's default (256,)*5 limits PPO to ~20 k env steps/s "
                                "on 2 CPU cores, benchmarks/ppo_throughput.py)", static=True)

    def check(self) -> None:
        from vbl.params import ParamError

        for name in ("policy_hidden", "value_hidden"):
            v = getattr(self, name)
            if not v or not all(isinstance(k, int) and k >= 1 for k in v):
                raise ParamError(f"{name}={v!r}: one or more layer widths, integers >= 1")

    def kwargs(self) -> dict:
        return {"policy_hidden_layer_sizes": tuple(self.policy_hidden),
                "value_hidden_layer_sizes": tuple(self.value_hidden)}



@struct.dataclass
class CurriculumParams:
    """LEM for PPO: raise the start difficulty as the evaluation success passes a level."""

    enabled: bool = param(False, doc="curriculum on (traced: both arms share a compilation)")
    initial_difficulty: float = param(0.0, doc="start difficulty of the first chunk", ge=0.0,
                                      le=1.0)
    step: float = param(0.1, doc="difficulty added after a chunk whose evaluation at the "
                        "current difficulty succeeds at >= success_level", gt=0.0, le=1.0)
    success_level: float = param(0.8, doc="deterministic-policy success at the current "
                                 "difficulty that raises it", gt=0.0, le=1.0)


@struct.dataclass
class PPOParams:
    """brax PPO hyperparameters (names as in ``brax.training.agents.ppo.train``)."""

    net: PPONetParams = section(PPONetParams, doc="network sizes")
    num_envs: int = param(64, doc="parallel envs per learner", static=True, ge=1)
    unroll_length: int = param(20, doc="env steps per trajectory of the PPO loss", unit="step",
                               static=True, ge=1)
    batch_size: int = param(32, doc="trajectories per minibatch", static=True, ge=1)
    num_minibatches: int = param(4, doc="minibatches per pass over a batch", static=True,
                                 ge=1)
    num_updates_per_batch: int = param(4, doc="SGD passes over each batch", static=True, ge=1)
    steps_per_chunk: int = param(20, doc="training steps (batches) per engine chunk",
                                 static=True, ge=1)
    normalize_observations: bool = param(True, doc="running mean/std normalisation of the "
                                         "observations (brax's running_statistics)",
                                         static=True)
    learning_rate: float = param(3e-4, doc="Adam step size", gt=0.0)
    entropy_cost: float = param(1e-2, doc="weight of the entropy bonus", ge=0.0)
    discounting: float = param(0.99, doc="discount per primitive (0.1 s)", gt=0.0, le=1.0)
    gae_lambda: float = param(0.95, doc="GAE lambda", ge=0.0, le=1.0)
    clipping_epsilon: float = param(0.2, doc="PPO ratio clipping", gt=0.0)
    reward_scaling: float = param(1.0, doc="factor on rewards", gt=0.0)
    max_grad_norm: float = param(0.5, doc="global gradient-norm clip", gt=0.0)
    eval_envs: int = param(32, doc="fresh starts per evaluation after each chunk "
                           "(deterministic policy, first episode of each)", static=True, ge=1)
    curriculum: CurriculumParams = section(CurriculumParams, doc="LEM for PPO")

    def check(self) -> None:
        n = self.batch_size * self.num_minibatches
        if n % self.num_envs:
            raise ParamError(f"batch_size x num_minibatches = {n} must be a multiple of "
                             f"num_envs = {self.num_envs} (each env unrolls whole "
                             "trajectories)")

    @property
    def env_steps_per_training_step(self) -> int:
        return self.batch_size * self.num_minibatches * self.unroll_length

    @property
    def env_steps_per_chunk(self) -> int:
        return self.env_steps_per_training_step * self.steps_per_chunk
