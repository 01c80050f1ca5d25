"""Throughput of batched tabular Q-learning: L learners x E = 64 environments.

Two measurements, each against NumPy in the same run:

* **Q-updates/s**: one synchronous batched update (``vbl.agents.q_update``, "mean"
  duplicate rule) of L tables (319 x 9) with 64 transitions each, vmapped over
  learners, vs (a) a vectorised NumPy implementation of the same rule (``np.bincount``
  over all learners at once) and (b) the plain per-transition loop of
  ``tests/reference/qlearning_np.py``.
* **training episodes/s**: full training steps (epsilon-greedy act, env step, update,
  episode bookkeeping) of ``vbl.agents.make_qlearning_runner`` on a synthetic 319-state,
  9-action stochastic MDP written in JAX below (reward 1 and episode end at the goal
  state, 50-step time limit), vs the same algorithm and MDP vectorised in NumPy.

Usage: ``python benchmarks/qlearning_throughput.py [--quick]``. Writes
``benchmarks/results/qlearning_throughput.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import vbl  # noqa: E402,F401  (x64 on, as in every vbl program)
from tests.reference.qlearning_np import (  # noqa: E402
    epsilon_greedy_np,
    q_update_batch_loop,
)
from vbl.agents import (  # noqa: E402
    ExplorationParams,
    QRunnerParams,
    learner_keys,
    make_qlearning_runner,
    q_update,
    stack_for_learners,
)
from vbl.agents.lem import LEMParams  # noqa: E402
from vbl.envs.macro import MacroActionParams  # noqa: E402

S, A, E = 319, 9, 64          # grid-sized table, 9 primitives, 64 envs per learner
GOAL, HORIZON, SLIP = 0, 50, 0.2  # goal state, time limit (steps), prob. of a random move
LR, GAMMA, EPS = 0.25, 0.8, 0.2


def mdp_table(seed: int = 0) -> np.ndarray:
    """Deterministic part of the synthetic MDP: next state (S, A) int32."""
    rng = np.random.default_rng(seed)
    return rng.integers(0, S, (S, A)).astype(np.int32)


@struct.dataclass
class MDPParams:
    next_state: jax.Array = struct.field(default_factory=lambda: jnp.asarray(mdp_table()))
    slip: float = SLIP
    horizon: int = HORIZON


@struct.dataclass
class MDPState:
    s: jax.Array
    t: jax.Array


class SyntheticMDP:
    """gymnax-style random MDP: obs = [s] float32; with prob. ``slip`` a uniform next state."""

    num_actions = A
    default_params = MDPParams()

    def reset(self, key, params):
        s = jax.random.randint(key, (), 1, S, jnp.int32)
        return jnp.array([s], jnp.float32), MDPState(s=s, t=jnp.int32(0))

    def step(self, key, state, action, params):
        u = jax.random.uniform(key, (3,), jnp.float32)  # slip?, random state, reset state
        rand = jnp.minimum((u[1] * S).astype(jnp.int32), S - 1)
        s2 = jnp.where(u[0] < params.slip, rand, params.next_state[state.s, action])
        s2 = s2.astype(jnp.int32)
        t = state.t + 1
        term = s2 == GOAL
        trunc = (t >= params.horizon) & ~term
        done = term | trunc
        start = 1 + jnp.minimum((u[2] * (S - 1)).astype(jnp.int32), S - 2)
        st = MDPState(s=jnp.where(done, start, s2), t=jnp.where(done, 0, t))
        obs = jnp.array([st.s], jnp.float32)
        return obs, st, term.astype(jnp.float32), term, trunc, {"success": term}


def state_fn(obs):
    return obs[..., 0].astype(jnp.int32)


# ----------------------------------------------------------------------------- NumPy


def np_update_vectorised(q, s, a, r, s2, term, lr, gamma):
    """q (L, S, A) float32; transitions (L, E). The "mean" duplicate rule, all learners."""
    n_l = q.shape[0]
    li = np.arange(n_l)[:, None]
    target = r + np.where(term, 0.0, gamma * q[li, s2].max(-1))
    delta = target - q[li, s, a]
    flat = ((li * S + s) * A + a).ravel()
    sums = np.bincount(flat, weights=delta.ravel(), minlength=n_l * S * A)
    counts = np.bincount(flat, minlength=n_l * S * A)
    q += (lr * sums / np.maximum(counts, 1)).reshape(q.shape).astype(np.float32)
    return q


class NumpyTrainer:
    """The runner's algorithm (epsilon-greedy, synthetic MDP, mean rule) vectorised in NumPy."""

    def __init__(self, n_learners: int, seed: int = 0):
        self.rng = np.random.default_rng(seed)
        self.table = mdp_table()
        self.q = np.zeros((n_learners, S, A), np.float32)
        self.s = self.rng.integers(1, S, (n_learners, E))
        self.t = np.zeros((n_learners, E), np.int64)
        self.episodes = 0

    def step(self):
        rng, q, s = self.rng, self.q, self.s
        n_l = q.shape[0]
        li = np.arange(n_l)[:, None]
        rows = q[li, s]                                         # (L, E, A)
        best = rows == rows.max(-1, keepdims=True)
        noise = rng.random(rows.shape) * best                  # random tie-break
        greedy = noise.argmax(-1)
        a = np.where(rng.random(s.shape) < EPS, rng.integers(0, A, s.shape), greedy)
        slip = rng.random(s.shape) < SLIP
        s2 = np.where(slip, rng.integers(0, S, s.shape), self.table[s, a])
        self.t += 1
        term = s2 == GOAL
        trunc = (self.t >= HORIZON) & ~term
        r = term.astype(np.float32)
        np_update_vectorised(q, s, a, r, s2, term, LR, GAMMA)
        done = term | trunc
        self.episodes += int(done.sum())
        self.s = np.where(done, rng.integers(1, S, s.shape), s2)
        self.t = np.where(done, 0, self.t)


def loop_steps_per_s(n_steps: int = 10, seed: int = 0) -> float:
    """The plain textbook loop (one learner, its 64 envs one at a time, per-transition update
    with targets from the table before the step, as ``q_update_batch_loop``): env steps/s.
    Its cost is linear in the learner count, so one learner measures the rate."""
    rng = np.random.default_rng(seed)
    table, q = mdp_table(), np.zeros((S, A), np.float32)
    s, t = rng.integers(1, S, E), np.zeros(E, int)
    t0 = time.perf_counter()
    for _ in range(n_steps):
        a, s2, r, term = np.zeros(E, int), np.zeros(E, int), np.zeros(E), np.zeros(E, bool)
        for i in range(E):
            a[i] = epsilon_greedy_np(rng, q[s[i]], EPS)
            s2[i] = rng.integers(0, S) if rng.random() < SLIP else table[s[i], a[i]]
            term[i], r[i] = s2[i] == GOAL, float(s2[i] == GOAL)
        q = q_update_batch_loop(q, s, a, r, s2, term, LR, GAMMA, "mean").astype(np.float32)
        for i in range(E):
            t[i] += 1
            if term[i] or t[i] >= HORIZON:
                s2[i], t[i] = rng.integers(1, S), 0
        s = s2
    return n_steps * E / (time.perf_counter() - t0)


# ---------------------------------------------------------------------------- timing


def timeit(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` (already warmed up), seconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def bench_updates(n_l: int, repeats: int) -> dict:
    rng = np.random.default_rng(n_l)
    q0 = rng.normal(size=(n_l, S, A)).astype(np.float32)
    s, a = rng.integers(0, S, (n_l, E)), rng.integers(0, A, (n_l, E))
    r = rng.random((n_l, E)).astype(np.float32)
    s2, term = rng.integers(0, S, (n_l, E)), rng.random((n_l, E)) < 0.1
    upd = jax.jit(jax.vmap(lambda q, *x: q_update(q, *x, LR, GAMMA)[0]))
    args = [jnp.asarray(x) for x in (q0, s, a, r, s2, term)]
    upd(*args).block_until_ready()
    t_jax = timeit(lambda: upd(*args).block_until_ready(), repeats)
    qn = q0.copy()
    np_update_vectorised(qn, s, a, r, s2, term, LR, GAMMA)
    t_np = timeit(lambda: np_update_vectorised(qn, s, a, r, s2, term, LR, GAMMA), repeats)
    n_loop = min(n_l, 16)  # the per-transition loop is slow: time a subset of learners
    t0 = time.perf_counter()
    for i in range(n_loop):
        q_update_batch_loop(q0[i], s[i], a[i], r[i], s2[i], term[i], LR, GAMMA, "mean")
    t_loop = (time.perf_counter() - t0) / n_loop * n_l
    n_up = n_l * E
    return dict(learners=n_l, updates=n_up, jax_per_s=n_up / t_jax, numpy_per_s=n_up / t_np,
                loop_per_s=n_up / t_loop, ratio_numpy=t_np / t_jax, ratio_loop=t_loop / t_jax)


def bench_episodes(n_l: int, chunk: int, repeats: int, np_steps: int) -> dict:
    params = QRunnerParams(
        num_states=S, num_actions=A, learning_rate=LR, discount=GAMMA,
        exploration=ExplorationParams(schedule="constant", init_value=EPS),
        macro=MacroActionParams(enabled=False), lem=LEMParams(enabled=False),
        num_envs=E, chunk_steps=chunk)
    env = SyntheticMDP()
    runner = make_qlearning_runner(env, state_fn, params)
    bp, ep = stack_for_learners(params, n_l), stack_for_learners(env.default_params, n_l)
    carry = runner.init_batch(learner_keys(0, n_l), bp, ep)
    carry, _ = runner.run_chunk_batch(carry, bp, ep)
    jax.block_until_ready(carry)
    state = {"carry": carry, "episodes": 0}

    def run():
        c, m = runner.run_chunk_batch(state["carry"], bp, ep)
        state["carry"] = jax.block_until_ready(c)
        state["episodes"] += int(m["episodes"].sum())

    t_jax = timeit(run, repeats)
    eps_jax = state["episodes"] / repeats / t_jax
    trainer = NumpyTrainer(n_l)
    for _ in range(HORIZON):  # reach the steady state of episode ends first
        trainer.step()
    trainer.episodes = 0
    t0 = time.perf_counter()
    for _ in range(np_steps):
        trainer.step()
    t_np = (time.perf_counter() - t0) / np_steps
    eps_np = trainer.episodes / np_steps / t_np
    loop = loop_steps_per_s()
    jax_steps = n_l * E * chunk / t_jax
    return dict(learners=n_l, envs=E, jax_steps_per_s=jax_steps,
                numpy_steps_per_s=n_l * E / t_np, loop_steps_per_s=loop,
                jax_episodes_per_s=eps_jax, numpy_episodes_per_s=eps_np,
                ratio=jax_steps / (n_l * E / t_np), ratio_loop=jax_steps / loop)


def hardware() -> dict:
    from benchmarks.hardware import cpu_model

    return dict(cpu=cpu_model(), cores=os.cpu_count(), jax=jax.__version__, numpy=np.__version__,
                backend=jax.default_backend(), python=platform.python_version())


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer sizes, about a minute")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    sizes = [1, 256] if args.quick else [1, 4, 16, 64, 256, 1024]
    chunk = 50 if args.quick else 100
    rep = 3 if args.quick else 5
    upd, epi = [], []
    for n_l in sizes:
        upd.append(bench_updates(n_l, repeats=10 if args.quick else 30))
        print("updates ", {k: round(v, 1) for k, v in upd[-1].items()}, flush=True)
        epi.append(bench_episodes(n_l, chunk, rep, np_steps=5 if n_l >= 256 else 20))
        print("episodes", {k: round(v, 1) for k, v in epi[-1].items()}, flush=True)
    res = dict(benchmark="qlearning_throughput", quick=args.quick, hardware=hardware(),
               config=dict(states=S, actions=A, envs_per_learner=E, chunk_steps=chunk,
                           lr=LR, discount=GAMMA, epsilon=EPS, duplicates="mean"),
               q_updates=upd, training=epi)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "qlearning_throughput.json").write_text(json.dumps(res, indent=2))
    (out / "qlearning_throughput.md").write_text(markdown(res))
    print(markdown(res))
    return res


def markdown(res: dict) -> str:
    h = res["hardware"]
    lines = [f"Q-learning throughput ({h['cpu']}, {h['cores']} cores, jax {h['jax']}, "
             f"{'quick' if res['quick'] else 'full'} run; 319 states x 9 actions, 64 envs "
             "per learner; the machine is shared, ratios matter more than absolute rates)", "",
             "| learners | Q-updates/s vbl | NumPy vectorised | NumPy loop | x vectorised | "
             "x loop |", "|---|---|---|---|---|---|"]
    for r in res["q_updates"]:
        lines.append(f"| {r['learners']} | {r['jax_per_s']:.3g} | {r['numpy_per_s']:.3g} | "
                     f"{r['loop_per_s']:.3g} | {r['ratio_numpy']:.1f} | {r['ratio_loop']:.0f} |")
    lines += ["", "| learners | training env steps/s vbl | NumPy vectorised | NumPy loop | "
              "episodes/s vbl | NumPy vectorised | x vectorised | x loop |",
              "|---|---|---|---|---|---|---|---|"]
    for r in res["training"]:
        lines.append(f"| {r['learners']} | {r['jax_steps_per_s']:.3g} | "
                     f"{r['numpy_steps_per_s']:.3g} | {r['loop_steps_per_s']:.3g} | "
                     f"{r['jax_episodes_per_s']:.3g} | {r['numpy_episodes_per_s']:.3g} | "
                     f"{r['ratio']:.1f} | {r['ratio_loop']:.0f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
