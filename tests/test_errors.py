"""The one-line error messages (vbl/engine/errors.py) for the OS errors a run meets when it
writes, and the VBL_DEBUG switch. Truths: the errno a kernel gives for each case."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time

import pytest

from vbl.engine.errors import STOP_GRACE_S, _hint_tail, debug_requested, one_line, stop_hint


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


# The watchdog's forced exit: a main thread that swallows the interrupt (as a compiled
# program or a library's callback can) still ends, with the line the command would print.
_SWALLOWER = """
import time
from vbl.engine.errors import install_stop_handlers, stop_hint
install_stop_handlers()
stop_hint(lambda: "continue with: outer --resume")
stop_hint(lambda: "continue with: inner --resume")
said = False
while True:  # only the first signal raises: the inner or the outer handler swallows it
    try:
        if not said:
            said = True
            print("ready", flush=True)
        while True:
            try:
                time.sleep(0.05)
            except BaseException:
                pass
    except BaseException:
        pass
"""


@pytest.mark.parametrize("sig,code,name", [(signal.SIGTERM, 143, "terminated (SIGTERM)"),
                                           (signal.SIGINT, 130, "interrupted")])
def test_forced_exit_line_says_how_to_go_on(sig, code, name):
    p = subprocess.Popen([sys.executable, "-c", _SWALLOWER], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "ready"
        t0 = time.monotonic()
        p.send_signal(sig)
        _, err = p.communicate(timeout=30)
        took = time.monotonic() - t0
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == code, err
    # the grace period, not the 60 s loop nor an instant exit, ended it
    assert STOP_GRACE_S - 0.5 < took < STOP_GRACE_S + 10, took
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines == [f"vbl: error: {name} (stopped after {STOP_GRACE_S:g} s); "
                     "continue with: outer --resume"], err


def test_a_failing_or_removed_hint_leaves_the_plain_line():
    forget = stop_hint(lambda: 1 / 0)
    try:
        assert _hint_tail() == ""
    finally:
        forget()
    forget = stop_hint(lambda: "go on")
    assert _hint_tail() == "; go on"
    forget()
    assert _hint_tail() == ""
