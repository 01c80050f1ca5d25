"""Progress over chunks: a tqdm bar (episodes per second, the current success rate) and a
small status file in the run folder that ``vbl reproduce`` reads for its progress lines."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
import time
from typing import Any

import numpy as np
from tqdm.auto import tqdm

__all__ = ["auto_quiet", "Progress", "bar_width", "STATUS_FILE",
           "read_status", "eta_text"]

STATUS_FILE = ".vbl-progress"
"""JSON ``{"phase", "done", "total", "eta_s"}`` in a run folder while it runs (removed
when the chunks end, or the run stops): phase
"compiling" until the first chunk ends (it includes tracing and compilation), then
"training" with chunks done and an ETA from the chunks after the first; "finishing" once
the last chunk is done (final metrics, summary, plots)."""

BAR_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]"
"""tqdm's bar without its own rate and remaining time (they would count compilation)."""

DEFAULT_COLUMNS = 100  #: bar width when the terminal reports no usable width
MIN_COLUMNS = 40  #: narrower reported widths are taken as unusable (e.g. 0 in some IDEs)


def bar_width() -> int | None:
    """None (follow the terminal) when it reports a usable width, else DEFAULT_COLUMNS."""
    cols = shutil.get_terminal_size((0, 0)).columns
    return None if cols >= MIN_COLUMNS else DEFAULT_COLUMNS


def auto_quiet() -> bool:
    """True when ``CI`` is set to true, or stderr is not a terminal and the process is
    no Jupyter (IPython) kernel, whose cells show the bar (``tqdm.auto``)."""
    ci = os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")
    return ci or not (sys.stderr.isatty() or _in_kernel())


def _in_kernel() -> bool:
    """Whether this process is an IPython kernel (a Jupyter notebook's)."""
    ipython = sys.modules.get("IPython")
    try:
        shell = ipython.get_ipython() if ipython is not None else None
    except Exception:  # noqa: BLE001 - a broken IPython is no kernel
        return False
    return shell is not None and "IPKernelApp" in getattr(shell, "config", {})


class Progress:
    """``update(metrics, seconds)`` after every chunk; ``metrics`` are host arrays with the
    learner axis first."""

    def __init__(self, total: int, initial: int = 0, desc: str = "", quiet: bool = False,
                 status_dir: str | os.PathLike | None = None):
        self._bar = None
        self._status = None if status_dir is None else os.path.join(status_dir, STATUS_FILE)
        self._total, self._done, self._first = total, initial, initial
        self._t0: float | None = None  # end of the first chunk of this process
        self._write_status("compiling")
        if not quiet:
            width = bar_width()
            # the first chunk includes compilation: the bar shows vbl's own ETA (from the
            # chunks after it, as the status file) instead of tqdm's
            self._bar = tqdm(total=total, initial=initial, desc=f"{desc} (compiling)",
                             unit="chunk", dynamic_ncols=width is None, ncols=width,
                             file=sys.stderr, bar_format=BAR_FORMAT)
        self._desc = desc
        self._t = time.perf_counter()

    def update(self, metrics: dict[str, Any], seconds: float | None = None,
               shown: str | None = None) -> None:
        """One chunk done: ``metrics`` (learner axis first), its ``seconds``, and ``shown``,
        the metric the bar shows (its mean over learners; the program's
        ``progress_metric``)."""
        now = time.perf_counter()
        dt = seconds if seconds is not None else now - self._t
        self._t = now
        self._done += 1
        if self._t0 is None:
            self._t0, self._first = now, self._done
        self._write_status("training" if self._done < self._total else "finishing")
        if self._bar is None:
            return
        self._bar.set_description_str(self._desc, refresh=False)
        post = {}
        eta = self.eta()
        if eta is not None:
            post["ETA"] = eta_text(eta)
        if "episodes" in metrics and dt > 0:
            post["episodes/s"] = f"{float(np.sum(metrics['episodes'])) / dt:,.0f}"
        if shown is not None and shown in metrics:
            post[shown] = f"{float(np.mean(metrics[shown])):.3f}"
        self._bar.set_postfix(post, refresh=False)
        self._bar.update(1)

    def compiling(self) -> None:
        """A new program starts (the next sweep group): its first chunk includes tracing
        and compilation, so the phase is "compiling" and the ETA restarts after it."""
        self._t0, self._first = None, self._done
        self._write_status("compiling")
        if self._bar is not None:
            self._bar.set_description_str(f"{self._desc} (compiling)")

    def eta(self) -> float | None:
        """Seconds left at the mean time per chunk after the first chunk of this process
        (which includes compilation); None before a second chunk."""
        if self._t0 is None or self._done <= self._first:
            return None
        per_chunk = (time.perf_counter() - self._t0) / (self._done - self._first)
        return round(per_chunk * (self._total - self._done), 1)

    def _write_status(self, phase: str) -> None:
        if self._status is None:
            return
        eta = self.eta()
        tmp = self._status + ".tmp"
        try:
            with open(tmp, "w") as f:
                json.dump({"phase": phase, "done": self._done, "total": self._total,
                           "eta_s": eta}, f)
            os.replace(tmp, self._status)
        except OSError:
            pass  # progress is best effort; the run's results do not depend on it
        finally:  # left only when interrupted (a signal) before the replace
            with contextlib.suppress(OSError):
                os.remove(tmp)

    def close(self) -> None:
        """Close the bar and remove the status file (the run is no longer running)."""
        if self._bar is not None:
            self._bar.close()
        if self._status is not None:
            for path in (self._status, self._status + ".tmp"):
                with contextlib.suppress(OSError):
                    os.remove(path)


def eta_text(seconds: float) -> str:
    """A remaining time as the bar and the progress lines show it: "42 s", "3 min"."""
    return f"{seconds / 60:.0f} min" if seconds >= 90 else f"{seconds:.0f} s"


def read_status(run_dir: str | os.PathLike) -> str:
    """The status file of a running run folder as short text, e.g. "training 12/400 chunks,
    ETA 3 min"; "" when there is none (not started, or not a chunked program)."""
    try:
        with open(os.path.join(run_dir, STATUS_FILE)) as f:
            st = json.load(f)
    except (OSError, ValueError):
        return ""
    text = f"{st.get('phase')} {st.get('done')}/{st.get('total')} chunks"
    eta = st.get("eta_s")
    if isinstance(eta, int | float):
        text += f", ETA {eta_text(eta)}"
    return text
