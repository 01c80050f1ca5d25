"""Figure 9's program: one robot per learner shoots on the on-line segmentation
(:mod:`vbl.agents.segmentation_learner`) while the ball changes size
(:mod:`vbl.envs.schedules`); its final policy is evaluated beside random primitives, the
hand-written steering policy and, optionally, the grid baseline trained from scratch on the
final ball (:func:`vbl.engine.nested.run_program`).

The config of :func:`make_segmentation_program` has the sections ``env``
(:class:`~vbl.envs.shooting.ShootingParams`), ``features``
(:class:`~vbl.spaces.action_based.FeatureParams`), ``learner``
(:class:`~vbl.agents.segmentation_learner.IncrementalParams`), ``change``
(:class:`~vbl.envs.schedules.BallChangeParams`), ``train`` (``num_trials``, ``num_chunks``,
``updates_per_chunk``, ``eval_episodes``, ``grid_baseline``, ``steer_reference``,
``steer_band``) and ``baseline`` (``grid``, ``agent``, ``train`` of the grid baseline).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from vbl.agents import segmentation_learner as sl
from vbl.engine.experiment import Program
from vbl.engine.nested import run_program
from vbl.envs.schedules import ball_radius_params
from vbl.envs.shooting import ShootingEnv
from vbl.programs.baselines import grid_program
from vbl.spaces.action_based import sec2_features

__all__ = ["make_segmentation_program"]

F32, ENV = jnp.float32, ShootingEnv()


def make_segmentation_program(cfg) -> Program:
    """Per chunk ``updates_per_chunk`` structure updates of one learner; ``final``: its
    evaluation and per-trial records (read by :mod:`vbl.programs.segmentation_figures`)."""
    n_tr, dim, tr = cfg.train.num_trials, cfg.features.dim, cfg.train
    feat = lambda c: lambda o: sec2_features(o, c.features)  # noqa: E731
    env_at = lambda c, t: ball_radius_params(c.env, t, c.change)  # noqa: E731
    grid_cfg = lambda c, ep: c.baseline.replace(  # noqa: E731
        train=c.baseline.train.replace(eval_curve=False)).on(ep)
    gprog = grid_program(grid_cfg(cfg, cfg.env)) if tr.grid_baseline else None

    def init(key, c):
        zero = jnp.zeros((n_tr,), F32)
        return sl.init_run(key, ENV, env_at(c, jnp.zeros((), jnp.int32)), c.learner, dim,
                           ENV.num_actions), zero, zero

    def step(carry, c):
        run, ts, st = carry
        t0 = run.trials
        run, out = sl.run_updates(run, ENV, lambda t: env_at(c, t), c.learner, feat(c),
                                  tr.updates_per_chunk)
        ts, st = sl.per_trial(out, ts, st)
        n_ep = (run.trials - t0).astype(F32)
        return (run, ts, st), {k: jnp.asarray(v, F32) for k, v in dict(
            episodes=n_ep,
            train_success=jnp.sum(out["success"].astype(F32)) / jnp.maximum(n_ep, 1.0),
            states=out["states"][-1], trials=run.trials, splits=run.lr.splits,
            merges=run.lr.merges, value_splits=run.lr.value_splits).items()}

    def final(carry, c, key):
        (run, ts, st), lr = carry, carry[0].lr
        ep = env_at(c, run.trials).replace(start_difficulty=jnp.asarray(
            c.baseline.train.eval_difficulty, F32))
        k_eval, k_grid, k_gfin = jax.random.split(key, 3)
        ok = sl.evaluate_policies(k_eval, lr, ENV, ep, c.learner, feat(c), tr.eval_episodes,
                                  cfg.env.max_steps, c.train.steer_band if tr.steer_reference
                                  else None)
        out = {f"{k}_success": jnp.mean(v.astype(F32)) for k, v in ok.items()}
        out.update({k: jnp.asarray(v, F32) for k, v in dict(
            states=jnp.sum(lr.seg.active), splits=lr.splits, value_splits=lr.value_splits,
            trials_done=run.trials, primitives_done=lr.clock, trial_success=ts,
            trial_states=st, box_lo=lr.seg.lo, box_hi=lr.seg.hi, box_active=lr.seg.active,
            box_action=jnp.argmax(lr.q, axis=-1)).items()})
        if gprog is not None:        # the grid learner from scratch on the final ball
            gfin, tot = run_program(gprog, grid_cfg(c, ep), k_grid, k_gfin, lambda m: {
                "grid_trials": m["episodes"],
                "grid_primitives": m["episodes"] * m["mean_primitives"]})
            out.update(tot, grid_success=gfin["greedy_success"])
        return out

    return Program(init=init, step=step, num_chunks=tr.num_chunks, final=final,
                   progress_metric="train_success")
