"""benchmarks/sweep_scaling.py: the scaling model against analytic cases, and the benchmark
itself at a tiny size (its output's shape, every prediction finite and positive)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import sweep_scaling as ss  # noqa: E402

A, B = 0.012, 0.3  # s per learner-chunk per device, s per chunk


def _row(per_device: int, seconds: float) -> dict:
    return dict(learners=per_device, padded=per_device, learners_per_device=per_device,
                s_per_chunk=seconds, compile_s=7.0, metric_bytes=8.0 * per_device,
                carry_bytes=1000.0 * per_device, checkpoint_every=10)


def test_fit_recovers_the_constants_of_synthetic_rows():
    rows = [_row(n, A * n + B) for n in (8, 16, 64, 256, 1024)]
    m = ss.fit(rows)
    assert m.learner_chunk_s == pytest.approx(A, rel=1e-9)
    assert m.chunk_s == pytest.approx(B, rel=1e-9)
    assert (m.metric_bytes, m.carry_bytes, m.compile_s) == (8.0, 1000.0, 7.0)


def test_fit_with_noise_stays_close_and_never_negative():
    rng = np.random.default_rng(0)
    sizes = np.repeat([16, 64, 256, 1024, 4096], 4)
    rows = [_row(int(n), (A * n + B) * (1 + 0.01 * rng.standard_normal())) for n in sizes]
    m = ss.fit(rows)
    assert m.learner_chunk_s == pytest.approx(A, rel=0.02)
    # a fixed cost that the noise would make negative is 0, the slope through the origin
    m0 = ss.fit([_row(16, 16 * A * 0.9), _row(1024, 1024 * A)])
    assert m0.chunk_s == 0.0 and m0.learner_chunk_s > 0


def test_chunk_and_run_seconds_match_hand_computed_values():
    m = ss.Model(learner_chunk_s=A, chunk_s=B, compile_s=5.0)  # no bytes: compute only
    assert ss.chunk_seconds(m, 100, hosts=2, devices=4) == pytest.approx(A * 13 + B)
    # 2 groups x (401 chunks x (4 x 1024 learners / 8 devices) + one compile each)
    want = 2 * (401 * (A * 4096 / 8 + B) + 5.0)
    assert ss.run_seconds(m, 2, 4, seeds=1024, points=4, groups=2, chunks=401) == (
        pytest.approx(want))
    # more learners than one compiled call holds: batches of the engine's layout
    assert ss.run_seconds(m, 1, 1, seeds=3000, points=4, groups=1, chunks=1) == (
        pytest.approx(3 * (A * 4000 + B) + 5.0))
    # twice the speed halves the compute term only
    assert ss.chunk_seconds(m, 64, 1, 1, speed=2.0) == pytest.approx(A * 32 + B)


def test_transfers_count_the_other_hosts_share_and_the_checkpoint_write():
    m = ss.Model(learner_chunk_s=0.0, chunk_s=0.0, metric_bytes=100.0, carry_bytes=1e4,
                 checkpoint_every=10)
    ckpt = 1e4 * 1000 / 10  # bytes per chunk
    one = ckpt / ss.DISK_BYTES_PER_S
    assert ss.chunk_seconds(m, 1000, 1, 8) == pytest.approx(one)
    four = (100.0 * 1000 + ckpt) * 3 / 4 / ss.HOST_LINK_BYTES_PER_S + one
    assert ss.chunk_seconds(m, 1000, 4, 8) == pytest.approx(four)
    # a benchmark row writes no checkpoint: the metrics' gather only
    assert ss.chunk_seconds(m, 1000, 4, 8, checkpoints=False) == pytest.approx(
        100.0 * 1000 * 3 / 4 / ss.HOST_LINK_BYTES_PER_S)
    assert ss.chunk_seconds(m, 1000, 1, 8, checkpoints=False) == 0.0


def test_model_check_gives_each_configurations_median_and_worst_error():
    def row(p, d, pred, meas):
        return dict(processes=p, devices=p * d, predicted_s_per_chunk=pred, s_per_chunk=meas)

    rows = [row(1, 1, 1.0, 1.0), row(1, 1, 1.1, 1.0), row(1, 2, 0.5, 1.0),
            row(1, 2, 1.0, 0.8), row(1, 2, 1.0, 1.0), row(2, 1, 3.0, 2.0)]
    check = ss.model_check(rows)
    assert check["1 x 1"] == pytest.approx(dict(median=0.05, worst=0.1, rows=2))
    assert check["1 x 2"] == pytest.approx(dict(median=0.0, worst=-0.5, rows=3))
    assert check["2 x 1"] == pytest.approx(dict(median=0.5, worst=0.5, rows=1))


def test_layout_is_the_engines():
    from vbl.engine.sharding import batch_layout

    for n, d, cap in [(4096, 8, 4096), (8192, 3, 4096), (5, 2, 4096), (100, 4, 10)]:
        assert ss._layout(n, d, cap) == batch_layout(n, d, cap)


@pytest.mark.slow
@pytest.mark.timeout(1800)  # about 11 min at load 10 on 2 cores: compilations
def test_tiny_benchmark_writes_rows_scaling_and_finite_predictions(tmp_path):
    """Both learners, 1 and 2 learners, 1 x 1, 1 x 2 and 2 x 1 (processes x devices)."""
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "sweep_scaling.py"),
                        "--tiny", "--out", str(tmp_path)], capture_output=True, text=True,
                       timeout=1200, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads((tmp_path / "sweep_scaling.json").read_text())
    rows = res["rows"]
    got = sorted((x["experiment"], x["processes"], x["devices"], x["learners"]) for x in rows)
    want = sorted((e, p, p * d, n) for e in ss.EXPERIMENTS for p, d in ss.CONFIGS
                  for n in ((1, 2) if p * d == 1 else (2,)))
    assert got == want
    for x in rows:
        assert x["s_per_chunk"] > 0 and x["cpu_s"] > 0 and math.isfinite(x["metrics_sum"])
        assert math.isfinite(x["predicted_s_per_chunk"]) and x["predicted_s_per_chunk"] > 0
        assert x["carry_bytes"] > 0 and x["metric_bytes"] > 0
        if x["devices"] == 2:
            assert x["strong_efficiency"] == pytest.approx(x["speedup"] / 2)
            assert x["weak_efficiency"] > 0
    run = res["model"][ss.PREDICTED]
    assert run["run"]["groups"] == 2 and run["run"]["points_per_group"] == 4
    for key in ("cpu_hours", "gpu_hours"):
        hours = list(run[key].values())
        assert len(hours) == len(ss.GRID) ** 2
        assert all(math.isfinite(h) and h > 0 for h in hours)
    md = (tmp_path / "sweep_scaling.md").read_text()
    assert "predicted s" in md and "Tiny run" in md and "a prediction, not a measurement" in md
    assert md.count("| hosts \\ devices per host |") == 2
    assert "Model check" in md
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "sweep_scaling.py"),
                        "--rebuild", "--out", str(tmp_path)], capture_output=True, text=True,
                       timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    assert (tmp_path / "sweep_scaling.md").read_text() == md  # the same rows, the same text
