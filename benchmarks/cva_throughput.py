"""CVA identification throughput: identify's defaults and a fixed lag vs SIPPY and NumPy.

Data: random stable systems (orders 1-6), N = 500 samples, q = 4 outputs, m = 2 inputs.
vbl, timed after a warm-up compile with ``block_until_ready`` (wall and process CPU time,
best of a few repeats; the orders are read back, so every output is consumed):

* ``default``: ``identify(u, y)`` - lag and order selection included (the lags of
  ``CVAParams().lags()``, l = 6 and 3, k = 2l, in one program, all orders the pooled lags
  can identify swept);
* ``fixed l=3``: ``identify(u, y, CVAParams(lag=3))`` (k = 6).

Baselines in the same run, per identification: the float64 NumPy oracle
(tests/reference/cva_np.py) looped over data sets - at l = 3 for the fixed lag, summed over
the default's lags - and SIPPY's CVA with AIC order selection (orders 1-10, f = 6) in a
subprocess.

BLAS threads: ``--blas-threads`` (default 1) sets OMP/OPENBLAS/MKL_NUM_THREADS before NumPy
loads, for this process (vbl: jaxlib's CPU LAPACK kernels - Cholesky, triangular solves,
eigh, SVD - call SciPy's OpenBLAS; the NumPy oracle) and for the SIPPY subprocess alike.
With more threads, OpenBLAS's thread pool on these small matrices costs more CPU than it
saves, and its timing swings several-fold when the machine is shared.

    python benchmarks/cva_throughput.py [--quick] [--blas-threads N]
"""

from __future__ import annotations

import os
import sys


def _blas_threads(argv: list[str]) -> str:
    """Value of ``--blas-threads`` (read before NumPy loads; argparse checks it again)."""
    for i, a in enumerate(argv):
        if a.startswith("--blas-threads="):
            return a.split("=", 1)[1]
        if a == "--blas-threads" and i + 1 < len(argv):
            return argv[i + 1]
    return str(BLAS_THREADS)


#: Default BLAS threads for every timed computation (see the module docstring).
BLAS_THREADS = 1
BLAS_ENV = {k: _blas_threads(sys.argv[1:]) for k in
            ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
os.environ.update(BLAS_ENV)

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from reference.cva_np import cva_reference  # noqa: E402
from reference.sysid_systems import simulate_batch  # noqa: E402

from benchmarks.hardware import cpu_model  # noqa: E402
from vbl.sysid import CVAParams, identify  # noqa: E402
from vbl.sysid.lag import n_cap_for  # noqa: E402
from vbl.sysid.sweep import CHUNK  # noqa: E402

N, Q, M, LAG, SIPPY_F = 500, 4, 2, 3, 6
DEFAULT_LAGS = CVAParams().lags()
CONFIGS = {"default": None, "fixed l=3": CVAParams(lag=LAG)}

SIPPY_SCRIPT = """
import contextlib, io, sys, time
import numpy as np
from sippy_unipi import OLSims_methods as ols
d = np.load(sys.argv[1]); u, y = d["u"], d["y"]
t0, c0 = time.perf_counter(), time.process_time()
for i in range(len(u)):
    with contextlib.redirect_stdout(io.StringIO()):
        ols.select_order_SIM(y[i].T.copy(), u[i].T.copy(), f=SIPPY_F, weights="CVA",
                             method="AIC", orders=[1, 10], D_required=True)
print((time.perf_counter() - t0) / len(u), (time.process_time() - c0) / len(u))
""".replace("SIPPY_F", str(SIPPY_F))


def _run(u, y, params):
    res = identify(u, y) if params is None else identify(u, y, params)
    jax.block_until_ready(res.model.U)
    if not (np.asarray(res.n) >= 1).all():           # consume the result
        raise RuntimeError("identification returned an order below 1")
    return res


def time_vbl(u, y, params, repeats: int) -> tuple[float, float]:
    """Best wall and CPU seconds of one batched identification (after a warm-up)."""
    _run(u, y, params)
    best, cpu = np.inf, np.inf
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        _run(u, y, params)
        best = min(best, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return best, cpu


def time_numpy(u, y, count: int, lags) -> float:
    """CPU seconds per identification of the NumPy oracle, summed over ``lags``."""
    c0 = time.process_time()
    for i in range(count):
        for lag in lags:
            cva_reference(u[i], y[i], lag, 2 * lag, n_max=None)
    return (time.process_time() - c0) / count


def time_sippy(u, y, count: int, tmp: Path) -> tuple[float, float]:
    """SIPPY wall and CPU seconds per identification in a subprocess (``BLAS_ENV``)."""
    np.savez(tmp, u=u[:count], y=y[:count])
    env = {**os.environ, **BLAS_ENV}
    out = subprocess.run([sys.executable, "-c", SIPPY_SCRIPT, str(tmp)], capture_output=True,
                         text=True, env=env, check=True)
    wall, cpu = map(float, out.stdout.split()[-2:])
    return wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer sizes, about a minute")
    ap.add_argument("--blas-threads", type=int, default=BLAS_THREADS,
                    help="BLAS threads for vbl's LAPACK calls, the NumPy oracle and SIPPY")
    args = ap.parse_args()
    sizes = [1, 64, 1024] if args.quick else [1, 4, 16, 64, 256, 1024, 4096]
    n_base = 4 if args.quick else 16
    rng = np.random.default_rng(0)
    bmax = max(sizes)
    u, y, _ = simulate_batch(rng, rng.integers(1, 7, bmax), N, M, Q, noise=0.05,
                             min_separation=0.15)
    res_dir = ROOT / "benchmarks" / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()
    base = {"default": time_numpy(u, y, n_base, DEFAULT_LAGS),
            "fixed l=3": time_numpy(u, y, n_base, [LAG])}
    sippy_wall, sippy_cpu = time_sippy(u, y, max(2, n_base // 2), res_dir / "_sippy_data.npz")
    (res_dir / "_sippy_data.npz").unlink()
    rows = []
    for name, params in CONFIGS.items():
        for b in sizes:
            t, c = time_vbl(u[:b], y[:b], params, repeats=2 if b >= 1024 else 3)
            r = dict(config=name, datasets=b, seconds=t, cpu_seconds=c, ident_per_s=b / t,
                     cpu_ms_per_ident=1e3 * c / b, x_numpy_cpu=base[name] * b / c,
                     x_sippy_cpu=sippy_cpu * b / c, x_sippy_wall=sippy_wall * b / t)
            rows.append(r)
            print(f"{name:10s} B={b:5d}: {t:8.3f} s wall, {c:8.3f} s CPU, "
                  f"x{r['x_numpy_cpu']:7.1f} numpy (CPU), x{r['x_sippy_cpu']:8.1f} sippy (CPU)",
                  flush=True)
    out = dict(
        benchmark="cva_throughput", quick=args.quick,
        hardware=dict(cpu=cpu_model(), cores=os.cpu_count(), jax=jax.__version__,
                      backend=jax.default_backend(), load_avg_start=load0,
                      load_avg_end=os.getloadavg()),
        setting=dict(N=N, q=Q, m=M,
                     default=f"lag_rule=predictor, l={DEFAULT_LAGS}, k=2l, orders "
                             f"1..{n_cap_for(CVAParams(), M, Q)}, chunks of {CHUNK}",
                     fixed=f"l={LAG}, k={2 * LAG}, orders "
                           f"1..{n_cap_for(CVAParams(lag=LAG), M, Q)}",
                     dtype="float64", sippy_f=SIPPY_F, sippy_orders="1..10",
                     blas_threads=args.blas_threads, blas_env=BLAS_ENV),
        baseline_cpu_seconds_per_identification=dict(
            numpy_oracle_all_lags=base["default"], numpy_oracle_l3=base["fixed l=3"],
            sippy=sippy_cpu),
        sippy_wall_seconds_per_identification=sippy_wall, rows=rows)
    (res_dir / "cva_throughput.json").write_text(json.dumps(out, indent=2))
    md = [f"CVA throughput (N={N}, q={Q}, m={M}, float64) on {out['hardware']['cpu']} "
          f"({os.cpu_count()} cores shared with other jobs: load average {load0[0]:.1f} at the "
          f"start, {out['hardware']['load_avg_end'][0]:.1f} at the end), jax {jax.__version__}. "
          f"BLAS threads {args.blas_threads} for vbl, the NumPy oracle and SIPPY. "
          "Ratios use process CPU time of the same run. Baselines, CPU per identification: "
          f"NumPy oracle {base['fixed l=3'] * 1e3:.1f} ms at l=3, "
          f"{base['default'] * 1e3:.1f} ms for l={DEFAULT_LAGS}; SIPPY CVA "
          f"{sippy_cpu * 1e3:.1f} ms ({sippy_wall * 1e3:.1f} ms wall).", "",
          "| config | data sets | wall (s) | CPU (s) | CPU ms / ident | x NumPy (CPU) | "
          "x SIPPY (CPU) | x SIPPY (wall) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        md.append(f"| {r['config']} | {r['datasets']} | {r['seconds']:.3f} | "
                  f"{r['cpu_seconds']:.3f} | {r['cpu_ms_per_ident']:.2f} | "
                  f"{r['x_numpy_cpu']:.1f} | {r['x_sippy_cpu']:.0f} | {r['x_sippy_wall']:.0f} |")
    (res_dir / "cva_throughput.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
