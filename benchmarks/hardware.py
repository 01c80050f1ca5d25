"""What the benchmarks report about the machine they ran on."""

import os
import platform

import jax


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
    """The 1-minute load average (the machines are shared: read numbers with it)."""
    try:
        return os.getloadavg()[0]
    except OSError:
        return None


def hardware_info() -> dict:
    """CPU model, core count, jax version, device list and load average."""
    return dict(cpu=cpu_model(), cores=os.cpu_count(), jax=jax.__version__,
                devices=[str(d) for d in jax.devices()], load_average=load_average())
