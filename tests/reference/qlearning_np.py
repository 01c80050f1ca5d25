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


def trace_step_loop(q: np.ndarray, windows: list, s, a, r, s_boot, terminal, done,
                    lr: float, gamma: float, lam: float, length: int, kind: str = "peng",
                    rule: str = "mean", weight=None, num_primitives=None,
                    a_boot=None, advance=None) -> np.ndarray:
    """One synchronous step of truncated-trace Q(lambda) / Sarsa(lambda), env by env.

    ``windows[i]`` is env i's list of ``[state, action, eligibility]``, newest first, at
    most ``length`` long (updated in place). Every TD error uses the table from before the
    step. Per env: push the current pair with eligibility 1 (Watkins: first empty the
    window if the action is not greedy), TD error ``target - Q[s, a]`` for the current
    pair (Peng: ``target - max Q[s]`` for the older ones), target ``r + gamma**n * B`` with
    B = max Q[s'] (Sarsa: Q[s', a']). Contributions (eligibility, error) are grouped by
    (s, a); "mean": lr * sum(e d) / max(sum e, 1), "sum": lr * sum(e d). Afterwards every
    eligibility is multiplied by gamma**n * lam and the window is emptied at episode end.
    An env with ``advance[i]`` False is skipped altogether (its action runs on).
    """
    frozen = np.array(q, dtype=np.float64)
    out = np.array(q, dtype=np.float64)
    groups: dict[tuple[int, int], list[tuple[float, float]]] = defaultdict(list)
    for i in range(len(s)):
        if advance is not None and not advance[i]:
            continue
        si, ai = int(s[i]), int(a[i])
        n = 1 if num_primitives is None else int(num_primitives[i])
        g = gamma ** n
        if kind == "watkins" and frozen[si, ai] < frozen[si].max():
            windows[i].clear()
        windows[i].insert(0, [si, ai, 1.0])
        del windows[i][length:]
        if weight is None or weight[i]:
            if terminal[i]:
                boot = 0.0
            elif kind == "sarsa":
                boot = g * frozen[int(s_boot[i]), int(a_boot[i])]
            else:
                boot = g * frozen[int(s_boot[i])].max()
            target = r[i] + boot
            for k, (sk, ak, e) in enumerate(windows[i]):
                if k == 0:
                    d = target - frozen[si, ai]
                elif kind == "peng":
                    d = target - frozen[si].max()
                else:
                    d = target - frozen[si, ai]
                groups[(sk, ak)].append((e, d))
        if done[i]:
            windows[i].clear()
        else:
            for item in windows[i]:
                item[2] *= g * lam
    for (sk, ak), contrib in groups.items():
        total = sum(e * d for e, d in contrib)
        if rule == "mean":
            total /= max(sum(e for e, _ in contrib), 1.0)
        out[sk, ak] += lr * total
    return out
