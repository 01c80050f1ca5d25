"""Plain NumPy reference for tabular Q-learning (independent of vbl.agents).

* :func:`value_iteration`: Q* of a finite deterministic MDP given as tables.
* :func:`q_update_one`: the textbook single Q-learning update, in place.
* :func:`q_update_batch_loop`: one synchronous batch of transitions as a Python loop
  of single updates whose TD errors all use the table from before the batch, with
  the duplicate rule applied per (s, a) group ("mean" or "sum").
* :func:`epsilon_greedy_np`: per-row epsilon-greedy choice with random tie-breaking.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np


def value_iteration(next_state: np.ndarray, reward: np.ndarray, terminal: np.ndarray,
                    gamma: float, tol: float = 1e-12, max_iter: int = 100_000) -> np.ndarray:
    """Q*(s, a) = R(s, a) + gamma * (1 - T(s, a)) * max_b Q*(s'(s, a), b), float64 (S, A)."""
    n_s, n_a = reward.shape
    q = np.zeros((n_s, n_a))
    for _ in range(max_iter):
        new = np.empty_like(q)
        for s in range(n_s):
            for a in range(n_a):
                cont = 0.0 if terminal[s, a] else gamma * max(q[next_state[s, a]])
                new[s, a] = reward[s, a] + cont
        if np.max(np.abs(new - q)) < tol:
            return new
        q = new
    raise RuntimeError("value iteration did not converge")


def q_update_one(q: np.ndarray, s: int, a: int, r: float, s2: int, terminal: bool,
                 lr: float, gamma: float) -> float:
    """Q[s, a] += lr * (r + gamma * max Q[s2] - Q[s, a]) in place; returns the TD error."""
    target = r if terminal else r + gamma * float(np.max(q[s2]))
    delta = target - q[s, a]
    q[s, a] += lr * delta
    return delta


def q_update_batch_loop(q: np.ndarray, s, a, r, s2, terminal, lr: float, gamma: float,
                        rule: str = "mean", weight=None, num_primitives=None) -> np.ndarray:
    """A batch of transitions, one at a time, with targets from the pre-batch table."""
    frozen = np.array(q, dtype=np.float64)
    out = np.array(q, dtype=np.float64)
    groups: dict[tuple[int, int], list[float]] = defaultdict(list)
    for i in range(len(s)):
        if weight is not None and not weight[i]:
            continue
        g = gamma if num_primitives is None else gamma ** int(num_primitives[i])
        target = r[i] if terminal[i] else r[i] + g * max(frozen[s2[i]])
        groups[(int(s[i]), int(a[i]))].append(target - frozen[s[i], a[i]])
    for (si, ai), deltas in groups.items():
        step = sum(deltas) / len(deltas) if rule == "mean" else sum(deltas)
        out[si, ai] += lr * step
    return out


def epsilon_greedy_np(rng: np.random.Generator, q_row: np.ndarray, epsilon: float) -> int:
    """Uniform action with probability epsilon, else a uniformly chosen argmax."""
    if rng.random() < epsilon:
        return int(rng.integers(len(q_row)))
    best = np.flatnonzero(q_row == q_row.max())
    return int(rng.choice(best))
