"""vbl: a JAX-vectorised batch experiment engine for vision-based robot learning."""

import os

# XLA's C++ logger prints a warning for every program loaded from the compilation cache
# below ("Assume version compatibility"); keep errors only unless the user chose a level.
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import jax  # noqa: E402

# Identification runs in float64 by default; hot paths (world, vision, envs, agents)
# create float32 arrays explicitly (docs/architecture.md).
jax.config.update("jax_enable_x64", True)

# Compilation dominates short runs on CPU: keep compiled programs on disk so the second
# run of an experiment, a test or a benchmark starts at once. VBL_JAX_CACHE=0 turns it
# off; VBL_JAX_CACHE=/some/dir moves it (default ~/.cache/vbl/jax).
_cache = os.environ.get("VBL_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "vbl",
                                                      "jax"))
if _cache not in ("0", "", "off") and not jax.config.jax_compilation_cache_dir:
    jax.config.update("jax_compilation_cache_dir", _cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

__version__ = "0.1.0"
