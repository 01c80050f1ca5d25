"""What runs and benchmarks record about the machine they ran on (the machines are shared:
read every time or rate with the load beside it)."""

from __future__ import annotations

import os
import platform

__all__ = ["cpu_model", "load_average", "machine_description"]


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (or the platform's processor string)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_average() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    try:
        return os.getloadavg()[0]
    except OSError:
        return None


def machine_description() -> str:
    """CPU model and core count, e.g. "Intel Xeon ... (2 cores)"."""
    return f"{cpu_model()} ({os.cpu_count()} cores)"
