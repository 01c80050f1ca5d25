"""Probe: a hand-written policy table on the 319-state grid, from fully random starts.

What it measures: whether the hand-designed grid of ``grid_shooting`` can represent a good
shooting policy at the experiment's task (start difficulty 1, 100 s limit, macro actions of
at least 3 primitives). The table: ball seen left / right in the image -> FL / FR; ball
centred -> F, or FL / FR when the goal is left / right (seen or lost to that side); ball
lost left / right -> TL / TR. The uniformly random policy (all-zero table: every action
tied) on the same starts is the reference. Greedy evaluation through the runner of
``grid_shooting`` (``make_qlearning_runner(...).evaluate``), first episode of each start.

Not an experiment (``vbl reproduce`` does not run it) and not a benchmark (``vbl bench``
reads ``benchmarks/*.py`` only). Run from the repository root:

    python benchmarks/probes/grid_hand_table.py [--starts 256] [--seed 0] [--max-steps 300]
        [--out runs/grid_hand_table] [--tiny]

Writes ``benchmarks/results/grid_hand_table.json``: per invocation (key: the episode limit
in primitives, then the options that differ from their defaults, e.g. ``max_steps=1000``,
``max_steps=300``) each table's success and the run's CPU seconds, keeping the entries of
other invocations. ``--tiny`` (a smoke test: 64 starts, episodes of at most 30 primitives)
checks that the probe runs and writes into ``--out`` only; its numbers mean little.

Cost: about a minute of CPU, mostly compilation. Cited by docs/findings/grid_shooting.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from benchmarks.hardware import write_entry  # noqa: E402

RESULT = ROOT / "benchmarks" / "results" / "grid_hand_table.json"


SYNC_EVAL_STEPS = 400
"""Cap on synchronous macro actions per evaluation episode: above the time limit over the
shortest action (1,000 / 3 primitives), so the time limit ends an unfinished episode."""


def hand_table(labels: tuple[str, ...]) -> np.ndarray:
    """(319, 9) table with 1 at the rule's action of every grid state, 0 elsewhere."""
    from vbl.spaces.grid import NUM_GRID_STATES, decode_state

    act = {name: labels.index(name) for name in ("F", "FL", "FR", "TL", "TR")}
    q = np.zeros((NUM_GRID_STATES, len(labels)), np.float32)
    for s in range(NUM_GRID_STATES):
        b, g = decode_state(s)
        if b == 9:
            a = "TL"
        elif b == 10:
            a = "TR"
        elif b // 3 == 0:
            a = "FL"
        elif b // 3 == 2:
            a = "FR"
        else:  # ball centred: steer towards the goal
            goal_side = 0 if g == 27 else 2 if g == 28 else g // 9
            a = ("FL", "F", "FR")[goal_side]
        q[s, act[a]] = 1.0
    return q


def invocation_key(max_steps: int, starts: int, seed: int) -> str:
    """The results file's key of an invocation: the episode limit, then the options that
    differ from their defaults."""
    extra = [f"{k}={v}" for k, v, d in (("starts", starts, 256), ("seed", seed, 0)) if v != d]
    return ", ".join([f"max_steps={max_steps}", *extra])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=256, help="fresh starts (multiple of 64)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-steps", type=int, default=None,
                    help="episode time limit in primitives (default: the experiment's, 1000)")
    ap.add_argument("--out", default="runs/grid_hand_table",
                    help="--tiny: the folder of the results file")
    ap.add_argument("--tiny", action="store_true",
                    help="smoke-test size: 64 starts, 30-primitive episodes")
    args = ap.parse_args(argv)
    t0 = time.process_time()
    if args.tiny:
        args.starts, args.max_steps = 64, 30

    from vbl.agents.qlearning import make_qlearning_runner
    from vbl.envs.shooting import ShootingEnv
    from vbl.programs.baselines import TASK_DIFFICULTY, grid_agent, grid_env, grid_space
    from vbl.spaces.grid import NUM_GRID_STATES, grid_state
    from vbl.world.robots import TWO_MOTOR_LABELS

    grid = grid_space()
    agent = grid_agent().replace(num_states=NUM_GRID_STATES)
    agent = agent.replace(macro=agent.macro.replace(mode="sync"))  # as the findings' figures
    env_params = grid_env().replace(start_difficulty=float(TASK_DIFFICULTY))
    if args.max_steps is not None:
        env_params = env_params.replace(max_steps=args.max_steps)
    runner = make_qlearning_runner(ShootingEnv(), lambda o: grid_state(o, grid), agent)
    n_envs = agent.num_envs
    if args.starts % n_envs:
        print(f"--starts must be a multiple of {n_envs}", file=sys.stderr)
        return 2
    ev = jax.jit(runner.evaluate, static_argnums=(4,))
    tables = {"hand-written table": jnp.asarray(hand_table(TWO_MOTOR_LABELS)),
              "random policy (all-zero table)": jnp.zeros((NUM_GRID_STATES, 9), jnp.float32)}
    print(f"grid_shooting task: start difficulty {float(TASK_DIFFICULTY)}, "
          f"{int(env_params.max_steps)} primitives, {args.starts} fresh starts, seed {args.seed}")
    success = {}
    for name, q in tables.items():
        keys = jax.random.split(jax.random.PRNGKey(args.seed), args.starts // n_envs)
        s = [float(ev(k, q, agent, env_params, SYNC_EVAL_STEPS)["success_rate"])
             for k in keys]
        success[name] = float(np.mean(s))
        print(f"{name}: success {np.mean(s):.3f} ({args.starts} starts)")
    max_steps = int(env_params.max_steps)
    dest = Path(args.out) / RESULT.name if args.tiny else RESULT
    write_entry(dest, invocation_key(max_steps, args.starts, args.seed), {
        "max_steps": max_steps, "starts": args.starts, "seed": args.seed,
        "start_difficulty": float(TASK_DIFFICULTY), "success": success,
        "cpu_seconds": round(time.process_time() - t0, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
