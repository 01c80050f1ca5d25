"""Checkpoints (vbl/engine/checkpoint.py): how many are kept, arrays that changed on disk,
what a refused checkpoint tells the user to do, and carries that cannot be stored."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from vbl.engine.checkpoint import CheckpointError, Checkpoints
from vbl.engine.errors import EngineError

TREE = {"q": np.arange(6, dtype=np.float32).reshape(3, 2), "k": np.ones((3, 2), np.uint32)}


LIKE = {k: np.zeros_like(v) for k, v in TREE.items()}  # shapes and dtypes, as a resume has


def _saved(path, steps, keep=2):
    ck = Checkpoints(path, fingerprint="aaaa", max_to_keep=keep)
    for s in steps:
        ck.save(s, TREE, {"group": 0})
    ck.close()
    return Checkpoints(path, "aaaa", max_to_keep=keep)


def _change_checksum(path, step):
    """Make the arrays of ``step`` differ from the checksums saved with them."""
    f = path / str(step) / "meta" / "metadata"
    meta = json.loads(f.read_text())
    meta["sha256"]["leaf_0000"] = "0" * 64
    f.write_text(json.dumps(meta))


def test_the_last_two_checkpoints_are_kept(tmp_path):
    ck = _saved(tmp_path / "ck", [1, 2, 3])
    assert ck.latest_step() == 3
    assert sorted(int(p.name) for p in (tmp_path / "ck").iterdir() if p.name.isdigit()) \
        == [2, 3]
    back, meta = ck.restore(2, LIKE)
    assert meta["step"] == 2 and meta["group"] == 0
    for k in TREE:
        np.testing.assert_array_equal(back[k], TREE[k])


def test_changed_arrays_are_refused_naming_the_checkpoint_to_fall_back_on(tmp_path):
    ck = _saved(tmp_path / "ck", [1, 2, 4], keep=3)
    _change_checksum(tmp_path / "ck", 4)
    with pytest.raises(CheckpointError, match="does not match the checksum") as e:
        ck.restore(4, LIKE)
    assert "continue from the checkpoint at step 2" in str(e.value)  # the latest intact
    ck.restore(2, LIKE)
    _change_checksum(tmp_path / "ck", 1)
    with pytest.raises(CheckpointError, match="no earlier checkpoint is kept"):
        ck.restore(1, LIKE)


def test_a_leaf_of_another_dtype_is_refused_naming_both_dtypes(tmp_path):
    """Never cast silently (the checkpoint library would cast), and say so: not as a
    corrupt file."""
    ck = _saved(tmp_path / "ck", [1])
    with pytest.raises(CheckpointError, match="leaf_0001 was saved as float32, this run "
                       "expects int32"):
        ck.restore(1, {"q": LIKE["q"].astype(np.int32), "k": LIKE["k"]})


def test_a_typed_prng_key_in_the_carry_is_refused(tmp_path):
    ck = Checkpoints(tmp_path / "ck", fingerprint="aaaa")
    with pytest.raises(EngineError, match="typed PRNG key"):
        ck.save(1, {"key": jax.random.key(0)}, {})
    ck.close()
