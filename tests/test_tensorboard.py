"""Live curves in TensorBoard (``vbl run --tensorboard DIR``): the event files of a 2-point
run read back, with tensorboard's own ``EventAccumulator`` (the reader TensorBoard itself
uses, with nothing on top), as the mean and 95 % band of every chunk in ``metrics.jsonl``."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from tests.engine_helpers import TINY_SETS, toy_experiment
from vbl.engine.errors import EngineError
from vbl.engine.runner import run_experiment
from vbl.engine.tensorboard import point_run_name

pytest.importorskip("tensorboardX")
event_accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    yield from toy_experiment(tmp_path_factory.mktemp("exps"))


def _scalars(folder) -> dict[str, dict[int, float]]:
    acc = event_accumulator.EventAccumulator(str(folder), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: {e.step: e.value for e in acc.Scalars(tag)} for tag in acc.Tags()["scalars"]}


def test_event_files_hold_the_runs_means_and_bands(toy, tmp_path):
    """Per sweep point a TensorBoard run; per chunk and scalar metric its mean, lower and
    upper (mean -/+ ci95, a rate's clipped to [0, 1]) at step = chunks done; the final
    metrics under final/ at the last chunk: metrics.jsonl's values as 32-bit floats."""
    tb = tmp_path / "tb"
    res = run_experiment(toy, sets=dict(TINY_SETS, **{"train.num_chunks": 3}),
                         sweep={"agent.epsilon": [0.0, 0.3]}, seeds=3, out=tmp_path / "run",
                         quiet=True, plots=False, tensorboard=tb)
    rows = [json.loads(x) for x in (res.out_dir / "metrics.jsonl").read_text().splitlines()]
    runs = {p: point_run_name(p, v) for p, v in enumerate(res.points)}
    assert runs == {0: "p0_epsilon=0.0", 1: "p1_epsilon=0.3"}
    assert sorted(d.name for d in tb.iterdir()) == sorted(runs.values())
    got = {p: _scalars(tb / name) for p, name in runs.items()}
    n = 0
    for r in rows:
        final = r["chunk"] == "final"
        step = 3 if final else r["chunk"] + 1
        for k, st in r["metrics"].items():
            tag = f"final/{k}" if final else k
            m, h = st["mean"], st["ci95"]
            lo, hi = m - h, m + h
            if "rate" in k:
                lo, hi = max(lo, 0.0), min(hi, 1.0)
            for part, want in (("mean", m), ("lower", lo), ("upper", hi)):
                assert got[r["point"]][f"{tag}/{part}"][step] == np.float32(want), (tag, part)
                n += 1
    assert n == sum(len(d) for g in got.values() for d in g.values())  # nothing else


def test_the_cli_passes_tensorboard_on(toy, monkeypatch):
    """vbl run --tensorboard DIR reaches run_experiment(..., tensorboard=DIR)."""
    from vbl.cli import build_parser, main
    from vbl.engine import runner

    seen = {}

    def fake(experiment, **kw):
        seen.update(kw)
        raise EngineError("stop here")

    monkeypatch.setattr(runner, "run_experiment", fake)
    monkeypatch.setattr(runner, "describe_sweep", lambda *a: (1, 1, "one point"))
    assert build_parser().parse_args(["run", "x", "--tensorboard", "d"]).tensorboard == "d"
    assert main(["run", "toy_bandit", "--tensorboard", "tb-dir", "--quiet"]) == 1
    assert seen["tensorboard"] == "tb-dir"


def test_without_tensorboardx_a_run_stops_before_it_starts(toy, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # import fails
    with pytest.raises(EngineError, match=r"pip install 'vbl\[tensorboard\]'"):
        run_experiment(toy, sets=TINY_SETS, out=tmp_path / "run", quiet=True, tensorboard="x")
    assert not (tmp_path / "run").exists()


def test_a_points_run_name_joins_its_values_and_keeps_only_safe_characters():
    """The sub-folder of a sweep point: ``p<point>_`` and the swept values (last path
    part) joined by commas without spaces; characters other than letters, digits and
    ``_.,=+-`` become ``_`` (no folder separators or spaces in a run's name)."""
    assert point_run_name(1, {"agent.discount": 0.95, "env.initial_difficulty": 1.0}) == \
        "p1_discount=0.95,initial_difficulty=1.0"
    assert point_run_name(0, {}) == "p0_run"
    assert point_run_name(2, {"a.b": "x y/z", "c": (1, -2)}) == "p2_b=x_y_z,c=_1,-2_"


class _Log:
    """The MetricsLog part TensorBoardLog uses (rows kept in memory)."""

    path, enabled = None, True

    def __init__(self):
        self.rows = []

    def append(self, rows):
        self.rows += rows


def _row(chunk, mean):
    return {"point": 0, "chunk": chunk, "values": {}, "metrics": {"regret": {"mean": mean,
                                                                           "ci95": 1.0}}}


def test_a_resumed_run_hides_what_the_earlier_run_wrote_from_its_step_on(tmp_path):
    """Chunks 0-3 (steps 1-4) written, then a run resumed after chunk 1 writes chunk 2
    again: TensorBoard shows steps 1, 2 of the first run and step 3 of the second; the
    first run's steps 3 and 4 are gone."""
    from vbl.engine.tensorboard import TensorBoardLog

    first = TensorBoardLog(_Log(), tmp_path)
    first.append([_row(c, 10.0 + c) for c in range(4)])
    first.close()
    # the resumed run starts later: its event file sorts after (and does not replace) this
    for f in (tmp_path / "p0_run").iterdir():
        stamp, host = f.name.removeprefix("events.out.tfevents.").split(".", 1)
        f.rename(f.with_name(f"events.out.tfevents.{int(stamp) - 60}.{host}"))
    again = TensorBoardLog(_Log(), tmp_path)
    again.append([_row(2, 99.0)])
    again.close()
    got = _scalars(tmp_path / "p0_run")["regret/mean"]
    assert got == {1: 10.0, 2: 11.0, 3: 99.0}
