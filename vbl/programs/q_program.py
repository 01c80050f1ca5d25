"""Engine programs from the Q-learning runner: train tabular Q-learners on any env + state map.

:func:`make_q_program` turns :func:`vbl.agents.qlearning.make_qlearning_runner` into a
:class:`vbl.engine.Program` (one learner's run, chunked; the engine vmaps it over seeds x
sweep values). The experiment's config is a ``flax.struct`` dataclass with at least the
sections

* ``env``: the env's params (e.g. :class:`vbl.envs.shooting.ShootingParams`),
* ``agent``: :class:`vbl.agents.QRunnerParams` (Q-learning, macro actions, LEM, E envs,
  learner steps per chunk),
* ``train``: :class:`QTrainParams` (chunks, evaluation),

plus whatever the state function reads (e.g. a ``grid`` section for
:func:`vbl.spaces.grid.grid_state`). ``state_fn(obs, config) -> int32`` gets one
learner's config, so its parameters are traced and sweepable.

Per engine chunk (``train.eval_every`` training chunks; metrics per learner, scalars):

* ``episodes``: training episodes (trials) finished in the engine chunk; ``successes``:
  of those, how many scored; ``train_success``: successes / episodes (0 when none
  finished) of the training episodes, i.e. with exploration and under the start
  distribution in effect (with LEM: the curriculum's); per finished episode, hence biased
  towards short (successful) episodes.
* ``eval_success`` (only with ``train.eval_curve`` on): the greedy policy (no learning; a
  uniform action with probability ``train.curve_epsilon``, default 0) after the engine
  chunk on ``train.eval_envs`` fresh starts at ``train.eval_difficulty``: fraction whose
  first episode scores.
* ``mean_primitives``: mean primitives per finished training episode (0 when none).
* ``difficulty``: start difficulty of the training episodes at the end of the chunk (LEM's;
  with LEM off the env's own ``start_difficulty``); ``lem_raises``: raises so
  far; ``epsilon``: exploration rate (epsilon or temperature) at the end of the chunk;
  ``td_abs``: mean absolute TD error (mean over the training chunks); ``learning_rate``:
  the step size of the last training chunk (``agent.learning_rate`` times
  ``train.lr_scale`` at the training chunks done).

``final`` (once, independent key): ``greedy_success``, ``near_greedy_success`` and
``random_success`` (the greedy policy of the learned table, the same with a uniform action
with probability ``train.eval_epsilon``, and the uniformly random policy, i.e. an all-zero
table with random tie-breaking, in the same action space: macro actions if on) on
``train.final_eval_rounds x train.eval_envs`` fresh starts at ``train.eval_difficulty``,
``greedy_primitives`` (mean episode length of the greedy policy, primitives),
``num_states`` (S) and ``states_with_value`` (states whose Q row moved from ``q_init``).

The evaluation key of chunk k is ``fold_in(carry.key, EVAL_STREAM)``: it does not advance
the training stream, so switching the evaluation curve on or off leaves training
unchanged.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from vbl.agents.exploration import ScheduleParams, schedule_value
from vbl.agents.qlearning import QRunnerState, make_qlearning_runner
from vbl.engine.experiment import Program
from vbl.params import ParamError, param, section, validate

__all__ = ["QTrainParams", "make_q_program", "curve_metric", "EVAL_STREAM"]

F32 = jnp.float32
EVAL_STREAM = 0x5EED  #: fold_in tag of the evaluation keys (kept off the training stream)

def curve_metric(curves: dict) -> str:
    """The learning curve a run has: ``eval_success`` (``train.eval_curve`` on), else
    ``train_success``."""
    return "eval_success" if "eval_success" in curves else "train_success"


@struct.dataclass
class QTrainParams:
    """Run length and evaluation of a Q-learning program (one chunk = ``agent.chunk_steps``
    learner steps of ``agent.num_envs`` environments)."""

    num_chunks: int = param(40, doc="training chunks per run (a curve point and metrics "
                            "line every eval_every of them)", static=True, ge=1)
    eval_curve: bool = param(True, doc="evaluate the policy on fresh starts for the "
                             "eval_success curve (every eval_every chunks); off: no "
                             "eval_success curve (train_success is always recorded)",
                             static=True)
    eval_every: int = param(1, doc="training chunks per curve point: one engine chunk (a "
                            "metrics line, the checkpoint unit) trains this many chunks, then "
                            "evaluates once; num_chunks must be a multiple of it",
                            static=True, ge=1)
    eval_envs: int = param(32, doc="fresh starts per greedy evaluation (one episode each)",
                           static=True, ge=1)
    eval_steps: int = param(300, doc="cap on learner steps per evaluation episode (macro "
                            "actions with synchronous macros, else primitives; an episode not "
                            "finished by then counts as a failure)", unit="step",
                            static=True, ge=1)
    eval_difficulty: float = param(1.0, doc="start difficulty of evaluation episodes (1: fully "
                                   "random starts)", ge=0.0, le=1.0)
    eval_epsilon: float = param(0.05, doc="final evaluation: epsilon of the near-greedy "
                                "policy (greedy, but a uniform action with this probability: "
                                "breaks cycles between aliased states)", ge=0.0, le=1.0)
    curve_epsilon: float = param(0.0, doc="epsilon of the policy the eval_success curve "
                                 "evaluates (0: greedy; e.g. eval_epsilon: near-greedy)",
                                 ge=0.0, le=1.0)
    final_eval_rounds: int = param(4, doc="final evaluation: rounds of eval_envs fresh starts "
                                   "for the greedy and for the random policy", static=True,
                                   ge=1)
    lr_scale: ScheduleParams = section(
        lambda: ScheduleParams(schedule="constant", init_value=1.0),
        doc="factor on agent.learning_rate in each training chunk, count = chunks done "
        "(default constant 1: the agent's step size throughout)")

    def check(self) -> None:
        if self.num_chunks % self.eval_every:
            raise ParamError(f"train.num_chunks={self.num_chunks} must be a multiple of "
                             f"train.eval_every={self.eval_every}")


def _require(cfg: Any, names: tuple[str, ...]) -> None:
    missing = [n for n in names if not hasattr(cfg, n)]
    if missing:
        raise ParamError(f"a Q-learning program config needs sections {list(names)}; "
                         f"{type(cfg).__name__} lacks {missing}")


# shape: a program factory in the purejaxrl mould: init, step and final are short closures
# over the static config, and the factory's length is theirs.
def make_q_program(env: Any, state_fn: Callable[[jax.Array, Any], jax.Array], cfg: Any,
                   *, num_states: int | None = None):
    """An engine :class:`~vbl.engine.Program` training one Q-learner on ``env``.

    Args:
      env: gymnax-style env (``reset``/``step`` with auto-reset and ``info["success"]``;
        with LEM its params need ``start_difficulty``; the evaluation sets it too).
      state_fn: ``(obs (obs_dim,), config) -> int32`` discrete state in [0, S) of one
        observation, reading one learner's (traced) config.
      cfg: the experiment's resolved config (sections ``env``, ``agent``, ``train``); only
        its static fields shape the program.
      num_states: if given, must equal ``cfg.agent.num_states`` (a clear error
        otherwise).

    Returns ``Program(init, step, num_chunks=cfg.train.num_chunks, final)``; metrics in the
    module docstring. Raises ParamError for a bad config.
    """
    _require(cfg, ("env", "agent", "train"))
    validate(cfg.agent)
    train = validate(cfg.train, "train.")
    if num_states is not None and int(num_states) != cfg.agent.num_states:
        raise ParamError(f"agent.num_states={cfg.agent.num_states} but the state "
                         f"function has {num_states} states")
    if not hasattr(cfg.env, "start_difficulty"):
        raise ParamError(f"the evaluation sets env.start_difficulty; {type(cfg.env).__name__} "
                         "has no such field")
    eval_params = cfg.agent.replace(num_envs=train.eval_envs)

    def runners(c):
        """Training and evaluation runners whose state map reads the learner's config ``c``."""
        fn = lambda o: state_fn(o, c)  # noqa: E731
        return (make_qlearning_runner(env, fn, cfg.agent, cfg.env),
                make_qlearning_runner(env, fn, eval_params, cfg.env))

    def eval_env(c):
        return c.env.replace(start_difficulty=jnp.asarray(c.train.eval_difficulty, F32))

    def init(key, c) -> QRunnerState:
        return runners(c)[0].init(key, c.agent, c.env)

    def train_chunk(carry: QRunnerState, c):
        """One training chunk: (carry, totals of the chunk)."""
        run, _ = runners(c)
        chunk = carry.steps // cfg.agent.chunk_steps
        lr = c.agent.learning_rate * schedule_value(c.train.lr_scale, chunk)
        agent = c.agent.replace(learning_rate=lr)
        carry, m = run.run_chunk(carry, agent, c.env)
        return carry, dict(episodes=jnp.sum(m["episodes"]).astype(F32),
                           successes=jnp.sum(m["successes"]).astype(F32),
                           primitives=jnp.sum(m["primitives"]).astype(F32),
                           epsilon=m["rate"][-1].astype(F32),
                           td_abs=jnp.mean(m["td_abs"]).astype(F32),
                           learning_rate=jnp.asarray(lr, F32))

    def step(carry: QRunnerState, c):
        if train.eval_every == 1:
            carry, t = train_chunk(carry, c)
        else:  # eval_every chunks, totals summed (rates: the last chunk's; td_abs: mean)
            carry, ts = jax.lax.scan(lambda cr, _: train_chunk(cr, c), carry, None,
                                     length=train.eval_every)
            t = {k: (jnp.sum(v) if k in ("episodes", "successes", "primitives") else
                     jnp.mean(v) if k == "td_abs" else v[-1]) for k, v in ts.items()}
        n = jnp.maximum(t["episodes"], 1.0)
        train_rate = t["successes"] / n
        out = dict(episodes=t["episodes"], successes=t["successes"],
                   train_success=train_rate, mean_primitives=t["primitives"] / n,
                   difficulty=(carry.lem.difficulty if cfg.agent.lem.enabled else
                               jnp.asarray(c.env.start_difficulty)).astype(F32),
                   lem_raises=carry.lem.raises.astype(F32), epsilon=t["epsilon"],
                   td_abs=t["td_abs"], learning_rate=t["learning_rate"])
        if train.eval_curve:
            _, ev = runners(c)
            res = ev.evaluate(jax.random.fold_in(carry.key, EVAL_STREAM), carry.q,
                              c.agent, eval_env(c), train.eval_steps, c.train.curve_epsilon)
            out["eval_success"] = res["success_rate"].astype(F32)
        return carry, out

    def final(carry: QRunnerState, c, key):
        _, ev = runners(c)
        rounds = train.final_eval_rounds
        keys = jax.random.split(key, 3 * rounds)
        # one traced evaluation for three policies: tables (3 * rounds, S, A) and epsilons:
        # learned greedy, learned near-greedy (eval_epsilon), zero table (uniformly random)
        learned = jnp.broadcast_to(carry.q, (2 * rounds, *carry.q.shape))
        qs = jnp.concatenate([learned, jnp.zeros((rounds, *carry.q.shape), F32)])
        eps = jnp.concatenate([jnp.zeros((rounds,), F32),
                               jnp.full((rounds,), c.train.eval_epsilon, F32),
                               jnp.zeros((rounds,), F32)])
        res = jax.vmap(lambda k, q, e: ev.evaluate(k, q, c.agent, eval_env(c), train.eval_steps,
                                                   e))(keys, qs, eps)
        moved = jnp.any(carry.q != jnp.asarray(c.agent.q_init, F32), axis=1)
        return dict(greedy_success=jnp.mean(res["success_rate"][:rounds]).astype(F32),
                    near_greedy_success=jnp.mean(
                        res["success_rate"][rounds:2 * rounds]).astype(F32),
                    random_success=jnp.mean(res["success_rate"][2 * rounds:]).astype(F32),
                    greedy_primitives=jnp.mean(res["mean_primitives"][:rounds]).astype(F32),
                    num_states=jnp.asarray(cfg.agent.num_states, F32),
                    states_with_value=jnp.sum(moved).astype(F32))

    return Program(init=init, step=step, num_chunks=train.num_chunks // train.eval_every,
                   final=final)
