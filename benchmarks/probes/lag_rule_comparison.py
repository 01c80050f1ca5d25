"""Order recovery of `identify`'s lag and order rules on the recovery draw sets of
docs/sysid.md ("Measured order recovery"): one row per rule, one column per draw set.

Each rule is a `CVAParams` setting (the pooled predictor rule with other lags or penalties,
fixed lags); each draw set is the test generator's random stable systems (orders 1-6,
m = q = 2, N = 1000, poles at least 0.15 apart; `tests/reference/sysid_systems.py`) at a
seed, a number of draws and a measurement-noise level. Prints a Markdown table of the
fraction of draws whose identified order n* equals the true order.

Usage::

    python benchmarks/probes/lag_rule_comparison.py            # every row (a few minutes)
    python benchmarks/probes/lag_rule_comparison.py --quick    # two rules, small sets
    python benchmarks/probes/lag_rule_comparison.py --tiny     # smoke test: one rule, 8 draws
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from reference.sysid_systems import simulate_batch  # noqa: E402

from vbl.sysid import CVAParams, identify  # noqa: E402

N, SEPARATION = 1000, 0.15  #: samples per data set; least distance between two poles
DRAW_SETS = {  # column: (draws, seed, noise std as a fraction of each output's std)
    "seed 7, 100": (100, 7, 0.05),
    "seed 0, 200": (200, 0, 0.05),
    "seed 1, 300": (300, 1, 0.05),
    "seed 1, 1000": (1000, 1, 0.05),
    "seed 5, 8 (2 %)": (8, 5, 0.02),
    "15 %: seed 0, 300": (300, 0, 0.15),
    "15 %: seed 1, 300": (300, 1, 0.15),
}
RULES = {  # row: identify's parameters
    "pooled AIC3 over l = 6, 3 (default)": CVAParams(),
    "pooled AIC3 over l = 2..6": CVAParams(lag_step=1),
    "pooled AIC3 over l = 2, 4, 6": CVAParams(lag_step=2),
    "pooled AIC3 over l = 2, 3, 4": CVAParams(lag_max=4, lag_step=1),
    "pooled, penalty 2 (Eq. 6) over l = 2..6": CVAParams(lag_step=1, order_penalty=2.0),
    "pooled, penalty 2.5 over l = 2..6": CVAParams(lag_step=1, order_penalty=2.5),
    "pooled, penalty 3.5 over l = 2..6": CVAParams(lag_step=1, order_penalty=3.5),
    "fixed l = 3": CVAParams(lag=3),
    "fixed l = 4": CVAParams(lag=4),
    "fixed l = 6": CVAParams(lag=6),
}


def recovery(params: CVAParams, draws: int, seed: int, noise: float) -> float:
    """Fraction of ``draws`` random systems whose n* equals the true order."""
    rng = np.random.default_rng(seed)
    orders = rng.integers(1, 7, draws)
    u, y, _ = simulate_batch(rng, orders, N, 2, 2, noise=noise, min_separation=SEPARATION)
    return float(np.mean(np.asarray(identify(u, y, params).n) == orders))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two rules on the two small sets")
    ap.add_argument("--tiny", action="store_true",
                    help="smoke test: the default rule on the 8-draw set")
    args = ap.parse_args(argv)
    n_rules, max_draws = (1, 8) if args.tiny else (2, 100) if args.quick else (None, None)
    rules = dict(list(RULES.items())[:n_rules])
    sets = {k: v for k, v in DRAW_SETS.items() if max_draws is None or v[0] <= max_draws}
    print("| rule | " + " | ".join(sets) + " |")
    print("|---|" + "---|" * len(sets))
    for name, params in rules.items():
        cells = [f"{recovery(params, *spec):.1%}" for spec in sets.values()]
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
