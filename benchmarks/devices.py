"""Host devices of a benchmark process: set before JAX is imported."""

import os
import sys


def force_host_devices(argv: list[str] | None = None) -> int:
    """Expose N CPU host devices to JAX (``--xla_force_host_platform_device_count``): N from
    ``--devices N`` in ``argv`` (default ``sys.argv``), else every usable core, as the
    ``vbl`` command. Call before JAX is imported; returns N."""
    argv = sys.argv if argv is None else argv
    n = (int(argv[argv.index("--devices") + 1]) if "--devices" in argv
         else len(os.sched_getaffinity(0)))
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + f" --xla_force_host_platform_device_count={n}")
    return n
