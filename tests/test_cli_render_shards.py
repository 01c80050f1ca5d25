"""``vbl render`` of a sharded run: a shard's folder renders the learners it holds (its
own checkpoints; ``--point`` and ``--seed`` are the whole run's), one that does not hold
them names the part that does, and a merged run (no checkpoints) says to render a shard.

The folders are made without training, as tests/test_video.py makes them: ``config.json``
from the engine's own ``resolve`` / ``shard_spec`` and a final checkpoint per shard whose
Q table marks each learner with its global index."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.engine_helpers import one_error_line, zero_carry
from vbl.engine.checkpoint import Checkpoints
from vbl.engine.registry import get
from vbl.engine.runner import resolve, shard_spec, whole_spec
from vbl.engine.sweep import Shard, make_plan
from vbl.programs.video import load_policy

SEEDS = 2  # x the 2 points of grid_shooting's default sweep: 4 learners, 2 per shard


def _shard_folder(folder, exp, config, spec, shard: Shard) -> None:
    folder.mkdir(parents=True)
    sspec = shard_spec(spec, shard)
    (folder / "config.json").write_text(json.dumps(sspec))
    (folder / "summary.json").write_text(json.dumps({"experiment": exp.name,
                                                     "shard": sspec["shard"]}))
    plan = make_plan(exp, config, spec["sweep"], SEEDS, 0, shard)
    g = plan.groups[0]
    carry = zero_carry(g)
    q = np.zeros(carry.learner.q.shape, np.float32)
    lo, _ = shard.learner_range(2 * SEEDS)  # of the whole run's learners
    for k in range(g.num_learners):
        q[k] = lo + k + 1  # the learner's global index + 1
    carry = carry.replace(learner=carry.learner.replace(q=q))
    ck = Checkpoints(folder / "checkpoints", sspec["fingerprint"])
    ck.save(g.step_offset + g.num_chunks, carry, {"group": 0})
    ck.close()


@pytest.fixture(scope="module")
def sharded(tmp_path_factory):
    """Two shard folders of a grid_shooting run and their merge (config and summary as
    ``vbl merge`` writes them, no checkpoints)."""
    tmp = tmp_path_factory.mktemp("render-shards")
    exp = get("grid_shooting")
    config, _, _, spec = resolve(exp, {}, None, SEEDS, 0, True, None)
    for i in (1, 2):
        _shard_folder(tmp / f"shard-{i}", exp, config, spec, Shard(i, 2))
    merged = tmp / "merged"
    merged.mkdir()
    (merged / "config.json").write_text(json.dumps(whole_spec(shard_spec(spec, Shard(1, 2)))))
    (merged / "summary.json").write_text(json.dumps({
        "experiment": exp.name, "points": [],
        "shards": [{"shard": f"{i}/2", "folder": f"shard-{i}", "learners": 2}
                   for i in (1, 2)]}))
    return tmp


@pytest.mark.parametrize("point,seed", [(0, 0), (0, 1), (1, 0), (1, 1)])
def test_a_shard_renders_its_own_learners(sharded, point, seed):
    part = 1 + (point * SEEDS + seed) // 2
    pol = load_policy(sharded / f"shard-{part}", "learned", point, seed)
    assert np.all(np.asarray(pol.q) == point * SEEDS + seed + 1)


def _render(folder, tmp_path, capsys, *extra: str) -> tuple[int, str]:
    from vbl.cli import main

    capsys.readouterr()
    code = main(["render", str(folder), "--out", str(tmp_path / "x.gif"), *extra])
    return code, one_error_line(capsys.readouterr().err)


def test_a_shard_without_the_learner_names_the_part_that_has_it(sharded, tmp_path, capsys):
    code, line = _render(sharded / "shard-2", tmp_path, capsys, "--point", "0", "--seed", "1")
    assert code == 2
    assert "part 2/2 of a sharded run (learners 2-3" in line
    assert "point 0 seed 1 is in part 1/2" in line


def test_a_merged_run_says_which_shard_to_render(sharded, tmp_path, capsys):
    code, line = _render(sharded / "merged", tmp_path, capsys, "--point", "1")
    assert code == 2
    assert "is a merged run (vbl merge), which keeps no checkpoints/" in line
    assert "render part 2/2 (its folder: shard-2), which holds point 1 seed 0" in line
    assert "--policy random" in line
