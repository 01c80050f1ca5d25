"""Probe: where Figure 5's cell map succeeds and fails, by the kind of start.

Collects the experience and builds the cell map exactly as ``fig5_action_based`` does
(its default config: 1,000 episodes per primitive, horizon 100, start difficulty
U[0, 0.3]; quantile cells per lost-side pattern), with this probe's own key (so the map
is one like the run's, not the run's own), and optionally refines it (``--refine``: the
closed-loop refinement, ~2 M primitives). The map's policy then
plays ``--starts`` fresh starts at the task's start difficulty (0.1, 300-primitive
limit); success is split by what the robot sees at the start: the ball seen left of,
within or right of a +-20 px band around the image centre, or lost to the left / right.

Not an experiment (``vbl reproduce`` does not run it) and not a benchmark (``vbl bench``
reads ``benchmarks/*.py`` only). Run from the repository root:

    python benchmarks/probes/fig5_by_start.py [--seed 0] [--starts 512] [--refine]
        [--episodes N] [--tiny]

``--tiny`` (a smoke test: 16 episodes of 50 primitives per primitive, 32 starts, 1
refinement iteration of 16 episodes with ``--refine``) checks that the probe runs; its
numbers mean little.

Cost: about 1 CPU-minute, under 2 with ``--refine`` (mostly compilation). Cited by
docs/findings/fig5_action_based.md.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

BAND_PX = 20.0


def start_kind(obs: np.ndarray) -> np.ndarray:
    """0 ball left, 1 centred, 2 right (seen; +-BAND_PX), 3 lost left, 4 lost right."""
    from vbl.vision.section2 import SEC2_BALL_LOST_SIDE, SEC2_BALL_POS, SEC2_BALL_VISIBLE

    x2 = obs[:, SEC2_BALL_POS]
    seen = obs[:, SEC2_BALL_VISIBLE] > 0.5
    kind = np.where(x2 < -BAND_PX, 0, np.where(x2 > BAND_PX, 2, 1))
    lost = np.where(obs[:, SEC2_BALL_LOST_SIDE] > 0, 4, 3)
    return np.where(seen, kind, lost)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--starts", type=int, default=512)
    ap.add_argument("--refine", action="store_true", help="also refine the map (slow)")
    ap.add_argument("--episodes", type=int, default=None, help="experience episodes per "
                    "primitive (default: the experiment's)")
    ap.add_argument("--tiny", action="store_true", help="smoke-test size: 16 episodes of 50 "
                    "primitives per primitive, 32 starts, 1 small refinement iteration")
    args = ap.parse_args(argv)

    from vbl.engine.jax_setup import engine_precision
    from vbl.engine.registry import get
    from vbl.envs.rollout import fresh_starts, rollout, stateless
    from vbl.programs.action_map_program import ENV as env
    from vbl.spaces.action_based import collect_experience, sec2_features
    from vbl.spaces.action_cells import build_cell_map, cell_policy_action, num_cell_states
    from vbl.spaces.cell_refine import refine_cell_map, refined_policy_action

    c = get("fig5_action_based").default_config
    if args.episodes is not None:
        c = c.replace(collect=c.collect.replace(episodes_per_action=args.episodes))
    if args.tiny:
        args.starts = 32
        c = c.replace(collect=c.collect.replace(episodes_per_action=16, horizon=50),
                      refine=c.refine.replace(iterations=1, episodes=16, horizon=50))
    ep = c.env.replace(start_difficulty=float(c.baseline.train.eval_difficulty))
    feat = lambda o: sec2_features(o, c.features)  # noqa: E731
    k_col, k_build, k_eval = jax.random.split(jax.random.PRNGKey(args.seed), 3)

    with engine_precision():
        @jax.jit
        def build(k_col, k_ref):
            exp = collect_experience(env, c.env, k_col, feat, env.num_actions, c.collect)
            cm = build_cell_map(exp, c.cells)
            rm = refine_cell_map(env, c.env, k_ref, feat, cm, c.refine) if args.refine \
                else None
            return cm, rm

        cm, rm = build(k_col, jax.random.fold_in(k_build, 1))
        policies = {"cell map (construction)": lambda o, _: cell_policy_action(cm, feat(o))}
        if args.refine:
            policies["same map, refined"] = (
                lambda o, _: refined_policy_action(cm, rm, feat(o)))

        obs0 = np.asarray(jax.jit(lambda k: fresh_starts(env, ep, k, args.starts)[0])(k_eval))
        kind = start_kind(obs0)
        names = ("ball left", "ball centred", "ball right", "ball lost left",
                 "ball lost right")
        print(f"Figure 5 cell map, seed {args.seed}: {int(num_cell_states(cm))} states; "
              f"{args.starts} fresh starts at start difficulty {float(ep.start_difficulty)}, "
              f"{int(c.env.max_steps)} primitives")
        print("| policy | all | " + " | ".join(names) + " |")
        print("|---|---|" + "---|" * len(names))
        counts = " | ".join(str(int((kind == i).sum())) for i in range(len(names)))
        print(f"| starts | {args.starts} | {counts} |")
        for name, pol in policies.items():
            ok, _ = jax.jit(lambda k, pol=pol: rollout(
                env, ep, k, stateless(pol), args.starts, int(c.env.max_steps)))(k_eval)
            ok = np.asarray(ok, float)
            cols = " | ".join(f"{ok[kind == i].mean():.2f}" if (kind == i).any() else "-"
                              for i in range(len(names)))
            print(f"| {name} | {ok.mean():.3f} | {cols} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
