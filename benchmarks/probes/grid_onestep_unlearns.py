"""Probe: one-step Q-learning started from a good hand-written table on the 319-state grid.

``grid_shooting``'s task (fully random starts, 100 s, macro actions of at least 3
primitives), its 64 robots per learner and the hand-written table of
``grid_hand_table.py`` as the initial Q (1 at the rule's action, 0 elsewhere). Then
``--chunks`` x 100 learner steps of Q-learning (learning rate 0.05, epsilon 0.1 constant,
no curriculum: every episode at difficulty 1), with one-step targets (the paper's
learner) or with the experiment's multi-step returns (Peng's Q(lambda), lambda 0.9,
window 32 actions). After every chunk the greedy policy plays ``--starts`` fresh starts.
Question: does one-step learning keep a policy that the grid can represent?

Not an experiment (``vbl reproduce`` does not run it) and not a benchmark (``vbl bench``
reads ``benchmarks/*.py`` only). Run from the repository root:

    python benchmarks/probes/grid_onestep_unlearns.py [--chunks 4] [--starts 128] [--seed 0]
        [--chunk-steps 100] [--max-steps N] [--out runs/grid_onestep_unlearns] [--tiny]

Writes ``benchmarks/results/grid_onestep_unlearns.json``: per invocation (key: the episode
limit in primitives, then the options that differ from their defaults, e.g.
``max_steps=1000``) each learner's greedy success before and after every chunk, the greedy
actions it changed and the run's CPU seconds, keeping the entries of other invocations.
``--tiny`` (a smoke test: one chunk of 10 learner steps, 64 starts, episodes of at most 30
primitives) checks that the probe runs and writes into ``--out`` only; its numbers mean
little.

Cost: about two minutes of CPU, mostly compilation. Cited by
docs/findings/grid_shooting.md.
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

RESULT = ROOT / "benchmarks" / "results" / "grid_onestep_unlearns.json"
DEFAULTS = {"chunks": 4, "starts": 128, "seed": 0, "chunk_steps": 100}


def invocation_key(max_steps: int, **options: int) -> str:
    """The results file's key of an invocation: the episode limit, then the options that
    differ from their defaults (``DEFAULTS``)."""
    extra = [f"{k}={v}" for k, v in options.items() if v != DEFAULTS[k]]
    return ", ".join([f"max_steps={max_steps}", *extra])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chunks", type=int, default=4, help="chunks of 100 learner steps")
    ap.add_argument("--starts", type=int, default=128, help="fresh starts (multiple of 64)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--chunk-steps", type=int, default=100, help="learner steps per chunk")
    ap.add_argument("--max-steps", type=int, default=None,
                    help="episode time limit in primitives (default: the experiment's, 1000)")
    ap.add_argument("--out", default="runs/grid_onestep_unlearns",
                    help="--tiny: the folder of the results file")
    ap.add_argument("--tiny", action="store_true", help="smoke-test size: 1 chunk of 10 "
                    "learner steps, 64 starts, 30-primitive episodes")
    args = ap.parse_args(argv)
    t0 = time.process_time()
    if args.tiny:
        args.chunks, args.starts, args.chunk_steps, args.max_steps = 1, 64, 10, 30

    from vbl.agents.qlearning import make_qlearning_runner
    from vbl.engine.jax_setup import engine_precision
    from vbl.engine.registry import load_script
    from vbl.envs.shooting import ShootingEnv
    from vbl.programs.baselines import TASK_DIFFICULTY, grid_agent, grid_env, grid_space
    from vbl.spaces.grid import NUM_GRID_STATES, grid_state
    from vbl.world.robots import TWO_MOTOR_LABELS

    hand = load_script(Path(__file__).with_name("grid_hand_table.py"))
    grid = grid_space()
    d = float(TASK_DIFFICULTY)
    env_params = grid_env().replace(start_difficulty=d)
    if args.max_steps is not None:
        env_params = env_params.replace(max_steps=args.max_steps)
    q0 = jnp.asarray(hand.hand_table(TWO_MOTOR_LABELS))
    a = grid_agent()
    base = a.replace(  # synchronous macro actions, 100 actions per chunk: the findings' setting
        num_states=NUM_GRID_STATES, learning_rate=0.05, chunk_steps=args.chunk_steps,
        macro=a.macro.replace(mode="sync"),
        exploration=a.exploration.replace(schedule="constant", init_value=0.1),
        lem=a.lem.replace(initial_difficulty=d, max_difficulty=d))
    variants = {"one-step Q-learning": "q_learning",
                "Peng's Q(lambda 0.9), 32 actions": base.update}
    n_envs = base.num_envs
    rounds = max(1, args.starts // n_envs)
    print(f"grid_shooting task from the hand-written table: difficulty {d}, "
          f"{int(env_params.max_steps)} primitives, lr 0.05, epsilon 0.1, {n_envs} robots; "
          f"greedy success on {rounds * n_envs} fresh starts after each chunk of "
          f"{base.chunk_steps} learner steps")
    k_train, k_eval = jax.random.split(jax.random.PRNGKey(args.seed))
    with engine_precision():
        # the greedy evaluation does not depend on the update rule: one program for both
        ev = jax.jit(make_qlearning_runner(ShootingEnv(), lambda o: grid_state(o, grid),
                                           base).evaluate, static_argnums=(4,))

        def greedy(q):
            return np.mean([float(ev(k, q, base, env_params, hand.SYNC_EVAL_STEPS)[
                "success_rate"]) for k in jax.random.split(k_eval, rounds)])

        learners = {}
        for name, update in variants.items():
            p = base.replace(update=update)
            runner = make_qlearning_runner(ShootingEnv(), lambda o: grid_state(o, grid), p)
            run = jax.jit(runner.run_chunk)
            carry = jax.jit(runner.init)(k_train, p, env_params).replace(q=q0)
            row = [greedy(carry.q)]
            for _ in range(args.chunks):
                carry, _ = run(carry, p, env_params)
                row.append(greedy(carry.q))
            changed = int(np.sum(np.argmax(np.asarray(carry.q), 1) != np.argmax(q0, 1)))
            learners[name] = {"greedy_success": [float(v) for v in row],
                              "greedy_actions_changed": changed}
            print(f"{name}: greedy success per chunk " + ", ".join(f"{v:.3f}" for v in row)
                  + f"; greedy actions changed in {changed} of {NUM_GRID_STATES} states")
    max_steps = int(env_params.max_steps)
    options = {k: getattr(args, k) for k in DEFAULTS}
    dest = Path(args.out) / RESULT.name if args.tiny else RESULT
    write_entry(dest, invocation_key(max_steps, **options), {
        "max_steps": max_steps, **options, "robots": n_envs, "evaluation_starts": rounds * n_envs,
        "num_states": NUM_GRID_STATES, "learners": learners,
        "cpu_seconds": round(time.process_time() - t0, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
