"""PPO throughput: env steps/s and compile time of vbl's PPO learner on both tasks.

For each task (``shooting``: ``ShootingEnv`` through the brax adapter, Section 2 features;
``shoot_pass``: ``ShootPassEnv("select")`` through ``InputEnv("current")``), network size
(``64x64``: the comparator's policy and value MLPs; ``brax``: brax's defaults, policy
(32,)*4, value (256,)*5) and number of learners vmapped together, one training call
(:meth:`vbl.agents.ppo_train.make_ppo_learner` ``train``: ``ppo.steps_per_chunk`` PPO
training steps of ``ppo.num_envs`` envs, no evaluation) is compiled (time reported), warmed
up and timed with ``block_until_ready`` (best of ``--reps``). Env steps/s counts training
primitives of all learners. The table states each network's parameter count.

Usage::

    python benchmarks/ppo_throughput.py           # both tasks, both nets, 1 and 4 learners
    python benchmarks/ppo_throughput.py --quick   # shooting, 64x64, 1 learner
Writes benchmarks/results/ppo_throughput.{json,md} (``--out`` elsewhere).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402

import vbl  # noqa: E402,F401
from benchmarks.hardware import hardware_info, write_results  # noqa: E402
from vbl.agents.ppo import network_size  # noqa: E402
from vbl.agents.ppo_inputs import InputEnv, InputParams  # noqa: E402
from vbl.agents.ppo_params import PPONetParams, PPOParams  # noqa: E402
from vbl.agents.ppo_train import make_ppo_learner  # noqa: E402
from vbl.envs.brax_adapter import BraxAdapter, with_difficulty  # noqa: E402
from vbl.envs.shoot_pass import ShootPassEnv  # noqa: E402
from vbl.envs.shooting import ShootingEnv  # noqa: E402

NETS = {"64x64": PPONetParams(),
        "brax": PPONetParams(policy_hidden=(32,) * 4, value_hidden=(256,) * 5)}


def make_task(name: str):
    """(make_env, env_params, obs_size, num_actions) of a task."""
    if name == "shooting":
        env = ShootingEnv()
        return (lambda ep, d: BraxAdapter(env, ep.replace(start_difficulty=d)),
                env.default_params, 9, env.num_actions)
    ienv = InputEnv(ShootPassEnv("select"), "current")
    return (lambda ep, d: BraxAdapter(ienv, with_difficulty(ep, d)),
            InputParams(ienv.env.default_params), ienv.observation_shape[0], ienv.num_actions)


def time_train(task: str, net: str, learners: int, p: PPOParams, reps: int) -> dict:
    make_env, env_params, obs, acts = make_task(task)
    p = p.replace(net=NETS[net])
    lrn = make_ppo_learner(make_env, obs, acts, p)
    keys = jax.random.split(jax.random.PRNGKey(0), learners)
    carry = jax.jit(jax.vmap(lambda k: lrn.init(k, env_params, p)))(keys)
    train = jax.jit(jax.vmap(lambda c: lrn.train(c, p)[0]))
    t0 = time.perf_counter()
    compiled = train.lower(carry).compile()
    compile_s = time.perf_counter() - t0
    carry = jax.block_until_ready(compiled(carry))  # warm-up
    best, cpu = float("inf"), 0.0
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        carry = jax.block_until_ready(compiled(carry))
        dt = time.perf_counter() - t0
        if dt < best:
            best, cpu = dt, time.process_time() - c0
    steps = learners * p.env_steps_per_chunk
    sizes = network_size(obs, acts, NETS[net])
    return dict(task=task, net=net, learners=learners, env_steps=steps, seconds=best,
                cpu_seconds=cpu, steps_per_s=steps / best, compile_s=compile_s,
                policy_params=sizes["policy"], value_params=sizes["value"],
                obs_size=int(obs), num_envs=p.num_envs)


def markdown(result: dict, cmd: str) -> str:
    hw = result["hardware"]
    lines = [f"# PPO throughput\n\n`{cmd}`; {hw['cpu']}, {hw['cores']} cores, jax "
             f"{hw['jax']}, load average {hw['load_average']:.1f} at the start (shared machine)."
             f"\n\nOne training call = {result['ppo']['steps_per_chunk']} PPO training steps "
             f"x {result['ppo']['env_steps_per_training_step']:,} env steps per learner "
             f"({result['ppo']['num_envs']} envs x unroll {result['ppo']['unroll_length']}, "
             f"{result['ppo']['num_minibatches']} minibatches x "
             f"{result['ppo']['num_updates_per_batch']} epochs), best of {result['reps']}.\n",
             "| task | networks | policy / value params | learners | env steps/s | "
             "CPU s per 1 M steps | compile s |", "|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['task']} | {r['net']} | {r['policy_params']:,} / "
                     f"{r['value_params']:,} | {r['learners']} | {r['steps_per_s']:,.0f} | "
                     f"{1e6 * r['cpu_seconds'] / r['env_steps']:.1f} | {r['compile_s']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shooting, 64x64, one learner")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "ppo_throughput"))
    args = ap.parse_args(argv)
    p = PPOParams(steps_per_chunk=5)
    grid = ([("shooting", "64x64", 1)] if args.quick else
            [(t, n, k) for t in ("shooting", "shoot_pass") for n in NETS for k in (1, 4)])
    result = dict(benchmark="ppo_throughput", quick=args.quick, hardware=hardware_info(),
                  reps=args.reps, rows=[],
                  ppo=dict(num_envs=p.num_envs, unroll_length=p.unroll_length,
                           num_minibatches=p.num_minibatches,
                           num_updates_per_batch=p.num_updates_per_batch,
                           steps_per_chunk=p.steps_per_chunk,
                           env_steps_per_training_step=p.env_steps_per_training_step))
    for task, net, k in grid:
        row = time_train(task, net, k, p, args.reps)
        print(f"{task:10s} {net:6s} (policy / value {row['policy_params']:,} / "
              f"{row['value_params']:,} params) learners={k}: {row['steps_per_s']:,.0f} env "
              f"steps/s, compile {row['compile_s']:.1f} s", flush=True)
        result["rows"].append(row)
    out = pathlib.Path(args.out)
    cmd = "python benchmarks/ppo_throughput.py" + (" --quick" if args.quick else "")
    write_results(out, result, markdown(result, cmd))
    print(f"wrote {out}.json / .md")


if __name__ == "__main__":
    main()
