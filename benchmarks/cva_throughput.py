"""CVA identification throughput (full order sweep) vs SIPPY and the NumPy oracle loop.

Data: random stable systems (orders 1-6), N = 500 samples, q = 4 outputs, m = 2 inputs.
vbl: ``identify(u, y, CVAParams(lag=3))`` (k = 6, orders 1..12 swept, AIC argmin), timed after
a warm-up compile with ``block_until_ready``. Baselines in the same run: the float64 NumPy
oracle (tests/reference/cva_np.py) looped over data sets, and SIPPY's CVA with AIC order
selection (orders 1-10, f = 6), timed on a handful of data sets and extrapolated per
identification.

    python benchmarks/cva_throughput.py [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from reference.cva_np import cva_reference  # noqa: E402
from reference.sysid_systems import simulate_batch  # noqa: E402

import vbl  # noqa: E402,F401
from benchmarks.hardware import cpu_model  # noqa: E402
from vbl.sysid import CVAParams, identify  # noqa: E402

N, Q, M, LAG, SIPPY_F = 500, 4, 2, 3, 6


def time_vbl(u, y, params, repeats: int) -> float:
    jax.block_until_ready(identify(u, y, params).model.U)     # compile
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(identify(u, y, params).model.U)
        best = min(best, time.perf_counter() - t0)
    return best


def time_numpy(u, y, count: int) -> float:
    t0 = time.perf_counter()
    for i in range(count):
        cva_reference(u[i], y[i], LAG, 2 * LAG, n_max=None)
    return (time.perf_counter() - t0) / count


def time_sippy(u, y, count: int) -> float:
    from sippy_unipi import OLSims_methods as ols

    t0 = time.perf_counter()
    for i in range(count):
        with contextlib.redirect_stdout(io.StringIO()):
            ols.select_order_SIM(y[i].T.copy(), u[i].T.copy(), f=SIPPY_F, weights="CVA",
                                 method="AIC", orders=[1, 10], D_required=True)
    return (time.perf_counter() - t0) / count


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer sizes, about a minute")
    args = ap.parse_args()
    sizes = [1, 64, 1024] if args.quick else [1, 4, 16, 64, 256, 1024, 4096]
    n_base = 4 if args.quick else 16
    rng = np.random.default_rng(0)
    bmax = max(sizes)
    u, y, _ = simulate_batch(rng, rng.integers(1, 7, bmax), N, M, Q, noise=0.05,
                             min_separation=0.15)
    params = CVAParams(lag=LAG)
    t_np = time_numpy(u, y, n_base)
    t_sippy = time_sippy(u, y, max(2, n_base // 4))
    rows = []
    for b in sizes:
        t = time_vbl(u[:b], y[:b], params, repeats=2 if b >= 1024 else 3)
        rows.append(dict(datasets=b, seconds=t, ident_per_s=b / t,
                         speedup_vs_numpy=(b / t) * t_np, speedup_vs_sippy=(b / t) * t_sippy))
        print(f"B={b:5d}: {t:8.3f} s  {b / t:10.1f} ident/s  x{(b / t) * t_np:7.1f} numpy  "
              f"x{(b / t) * t_sippy:8.1f} sippy", flush=True)
    out = dict(
        benchmark="cva_throughput", quick=args.quick,
        hardware=dict(cpu=cpu_model(), cores=os.cpu_count(), jax=jax.__version__,
                      backend=jax.default_backend(), load_avg=os.getloadavg()),
        setting=dict(N=N, q=Q, m=M, lag=LAG, horizon=2 * LAG, orders_swept="1..12",
                     dtype="float64", sippy_f=SIPPY_F, sippy_orders="1..10"),
        baseline_seconds_per_identification=dict(numpy_oracle=t_np, sippy=t_sippy),
        rows=rows)
    res_dir = ROOT / "benchmarks" / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    (res_dir / "cva_throughput.json").write_text(json.dumps(out, indent=2))
    md = [f"CVA throughput (N={N}, q={Q}, m={M}, l={LAG}, k={2 * LAG}, full order sweep, "
          f"float64) on {out['hardware']['cpu']} ({os.cpu_count()} cores, shared), "
          f"jax {jax.__version__}. Baselines per identification: NumPy oracle "
          f"{t_np * 1e3:.1f} ms, SIPPY CVA {t_sippy * 1e3:.1f} ms.", "",
          "| data sets | time (s) | identifications/s | x NumPy loop | x SIPPY |",
          "|---|---|---|---|---|"]
    for r in rows:
        md.append(f"| {r['datasets']} | {r['seconds']:.3f} | {r['ident_per_s']:.0f} | "
                  f"{r['speedup_vs_numpy']:.1f} | {r['speedup_vs_sippy']:.0f} |")
    (res_dir / "cva_throughput.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
