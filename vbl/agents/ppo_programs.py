"""Engine programs of brax PPO on vbl's tasks, and the pieces of their report.

* :func:`make_shooting_program`: the shooting task of Section 2 (9 features, 9 primitives)
  through :class:`vbl.envs.brax_adapter.BraxAdapter`, with or without the curriculum
  (``ppo.curriculum.enabled``, traced).
* :func:`make_shoot_pass_program`: the two-robot task (``ShootPassEnv("select")``: the
  traced ``env.task_pass`` picks shooter or passer) through
  :class:`vbl.agents.ppo_inputs.InputEnv` (kind "select": the traced ``inputs.index`` picks
  current features, a frame stack or the CVA state; one compilation for all six rows),
  with or without the curriculum on ``ShootPassParams.start_difficulty``.

Per chunk (per learner): ``env_steps`` (training env steps at the end of the chunk),
``success_rate`` (deterministic policy, ``ppo.eval_envs`` fresh starts at the task's start
distribution, first episode each), ``level_success_rate`` (same at the curriculum's
difficulty), ``difficulty``, ``episodes``, ``train_success_rate``, ``loss``, ``entropy``.
``final``: ``greedy_success_rate`` on ``run.final_eval_envs`` fresh starts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import struct

from vbl.agents.ppo_inputs import INPUTS, InputEnv, InputParams, prepare_models
from vbl.agents.ppo_train import make_ppo_learner
from vbl.envs.brax_adapter import BraxAdapter, with_difficulty
from vbl.envs.shoot_pass import ShootPassEnv
from vbl.envs.shooting import ShootingEnv
from vbl.params import param

__all__ = ["PPORunParams", "InputChoice", "make_shooting_program", "make_shoot_pass_program",
           "ci95", "welch_ci", "plot_success_vs_steps", "plot_two_robot_curves", "input_label"]


@struct.dataclass
class PPORunParams:
    """Run length and the final evaluation."""

    num_chunks: int = param(50, doc="engine chunks per run (each ppo.env_steps_per_chunk "
                            "env steps per learner)", static=True, ge=1)
    final_eval_envs: int = param(256, doc="fresh starts of the final deterministic-policy "
                                 "evaluation (first episode each)", static=True, ge=1)


@struct.dataclass
class InputChoice:
    """What the two-robot PPO learner sees."""

    index: int = param(0, doc="input: 0 current features (26,), 1 the last `frames` "
                       "observations stacked, 2 the tabular learner's CVA state vector "
                       "(traced; all three zero-padded to one length)", ge=0, le=2)
    frames: int = param(3, doc="observations stacked for input 1 (3 = the CVA filter's "
                        "longest history, cva.cva.lag_max)", static=True, ge=1)


def _program(lrn, init_env, num_chunks: int, final_envs: int):
    from vbl.engine import Program  # lazy: keep vbl.agents importable without the engine

    def init(key, c):
        k_env, k_lrn = jax.random.split(key)
        return lrn.init(k_lrn, init_env(k_env, c), c.ppo)

    def step(carry, c):
        return lrn.train_chunk(carry, c.ppo)

    def final(carry, c, key):
        return {"greedy_success_rate": lrn.evaluate(carry, key, 1.0, final_envs)}

    return Program(init=init, step=step, num_chunks=num_chunks, final=final)


def make_shooting_program(cfg: Any):
    """Program for a config with sections ``env`` (ShootingParams), ``ppo`` (PPOParams),
    ``run`` (PPORunParams); evaluation at start difficulty 1 (fully random starts)."""
    env = ShootingEnv()

    def make_env(env_params, difficulty):
        return BraxAdapter(env, env_params.replace(start_difficulty=difficulty))

    lrn = make_ppo_learner(make_env, env.observation_shape[0], env.num_actions, cfg.ppo)
    return _program(lrn, lambda key, c: c.env, cfg.run.num_chunks, cfg.run.final_eval_envs)


def make_shoot_pass_program(cfg: Any):
    """Program for a config with sections ``env`` (ShootPassParams), ``inputs``
    (InputChoice), ``cva`` (CVAStateParams of the tabular learner), ``ppo``, ``run``."""
    base = ShootPassEnv("select")
    ienv = InputEnv(base, "select", cfg.inputs.frames, cfg.cva, m=2)

    def make_env(env_params, difficulty):
        return BraxAdapter(ienv, with_difficulty(env_params, difficulty))

    def init_env(key, c):
        models = prepare_models(base, key, c.cva, c.env)
        return InputParams(c.env, models, c.inputs.index)

    lrn = make_ppo_learner(make_env, ienv.observation_shape[0], ienv.num_actions, cfg.ppo)
    return _program(lrn, init_env, cfg.run.num_chunks, cfg.run.final_eval_envs)


def input_label(index: int) -> str:
    return INPUTS[int(index)]


def ci95(x: Any) -> tuple[float, float]:
    """(mean, Student-t 95 % half-width) over the last axis (seeds); half-width nan for 1."""
    from scipy import stats

    x = np.asarray(x, float)
    if x.size < 2:
        return float(x.mean()), float("nan")
    return float(x.mean()), float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1)
                                  / np.sqrt(x.size))


def welch_ci(a: Any, b: Any) -> tuple[float, float]:
    """(mean(a) - mean(b), Welch 95 % half-width) of two samples (e.g. seeds of two arms)."""
    from scipy import stats

    a, b = np.asarray(a, float), np.asarray(b, float)
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    if va + vb == 0:  # both samples constant: the difference is exact
        return float(a.mean() - b.mean()), 0.0
    dof = (va + vb) ** 2 / (va ** 2 / (a.size - 1) + vb ** 2 / (b.size - 1) + 1e-30)
    return float(a.mean() - b.mean()), float(stats.t.ppf(0.975, dof) * np.sqrt(va + vb))


def plot_success_vs_steps(curves: dict, labels: list[str], path: Path, title: str) -> Path:
    """``success_rate`` (mean over seeds, 95 % band) against training env steps, one line
    per sweep point; ``curves[metric]`` is (points, chunks, seeds)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    steps, sr = np.asarray(curves["env_steps"]), np.asarray(curves["success_rate"])
    for i, label in enumerate(labels):
        x = steps[i].mean(axis=1)  # env steps at the end of each chunk
        m = sr[i].mean(axis=1)
        (line,) = ax.plot(x, m, label=label)
        if sr.shape[2] > 1:
            h = np.array([ci95(r)[1] for r in sr[i]])
            ax.fill_between(x, m - h, m + h, color=line.get_color(), alpha=0.2, lw=0)
    ax.set(xlabel="training env steps (primitives) per learner", ylabel="success rate",
           ylim=(0, 1), title=f"{title} ({sr.shape[2]} seeds, 95% band)")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_two_robot_curves(curves: dict, rows: list[tuple[str, str, bool]], path: Path,
                          title: str) -> Path:
    """The two-robot comparison's ``success_rate`` against training env steps: one panel per
    task, a colour per input, dashed with the curriculum; mean over seeds with its 95 %
    band. ``rows[i]`` = (task, input, curriculum) of sweep point i; ``curves[metric]`` is
    (points, chunks, seeds)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    steps, sr = np.asarray(curves["env_steps"]), np.asarray(curves["success_rate"])
    tasks = [t for t in ("shoot", "pass") if any(r[0] == t for r in rows)]
    colours = {"current": "C0", "stack": "C1", "cva": "C2"}
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.2 * len(tasks), 4.0), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        for i, (t, inp, cur) in enumerate(rows):
            if t != task:
                continue
            x, m = steps[i].mean(axis=1), sr[i].mean(axis=1)
            ax.plot(x, m, color=colours.get(inp, "C3"), ls="--" if cur else "-",
                    label=f"{inp}{', curriculum' if cur else ''}")
            if sr.shape[2] > 1:
                h = np.array([ci95(r)[1] for r in sr[i]])
                ax.fill_between(x, m - h, m + h, color=colours.get(inp, "C3"), alpha=0.12,
                                lw=0)
        ax.set(xlabel="training env steps (primitives) per learner", ylabel="success rate",
               ylim=(0, 1), title=f"{task}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    fig.suptitle(f"{title} ({sr.shape[2]} seeds, mean and 95% band; evaluation at start "
                 "difficulty 1)", fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
