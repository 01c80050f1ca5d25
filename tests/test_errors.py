"""The one-line error messages (vbl/engine/errors.py) for the OS errors a run meets when it
writes, and the VBL_DEBUG switch. Truths: the errno a kernel gives for each case."""

from __future__ import annotations

import errno
import os

import pytest

from vbl.engine.errors import debug_requested, one_line


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EDQUOT, errno.EFBIG])
def test_a_full_disk_a_quota_or_a_file_size_limit_says_free_space_and_resume(code):
    """EFBIG is what a write past ``ulimit -f`` gives: the same advice as a full disk."""
    line = one_line(OSError(code, os.strerror(code), "/runs/x/metrics.jsonl"))
    assert line.startswith("cannot write /runs/x/metrics.jsonl: ")
    assert "free some space" in line and "--resume" in line


@pytest.mark.parametrize("code", [errno.EACCES, errno.EPERM, errno.EROFS])
def test_a_folder_that_cannot_be_written_says_make_it_writable(code):
    """EROFS is a read-only file system (a mounted image, a read-only bind mount)."""
    line = one_line(PermissionError(code, os.strerror(code), "/runs/x")
                    if code != errno.EROFS else OSError(code, os.strerror(code), "/runs/x"))
    assert line.startswith("cannot write /runs/x: ")
    assert "make the folder writable or pick another --out" in line


@pytest.mark.parametrize(("value", "on"), [("", False), ("0", False), ("false", False),
                                           ("No", False), (" FALSE ", False), ("1", True),
                                           ("yes", True), ("true", True)])
def test_vbl_debug_is_off_for_empty_zero_false_and_no(monkeypatch, value, on):
    monkeypatch.setenv("VBL_DEBUG", value)
    assert debug_requested() is on
