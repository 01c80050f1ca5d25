"""What the benchmarks report about the machine they ran on."""

import json
import os
import pathlib
import resource

import jax

from vbl.engine.machine import cpu_model, load_average

__all__ = ["cpu_model", "load_average", "hardware_info", "write_results", "write_entry",
           "children_cpu_s"]


def write_results(out: pathlib.Path, result: dict, text: str) -> None:
    """``out``.json (the result) and ``out``.md (its Markdown ``text``), the folder made."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2))
    out.with_suffix(".md").write_text(text)


def write_entry(dest: pathlib.Path, key: str, entry: dict) -> None:
    """Write ``entry`` under ``key`` into the JSON file ``dest`` (keys sorted), keeping the
    other keys' entries: a probe's results file, one key per invocation."""
    data = json.loads(dest.read_text()) if dest.exists() else {}
    data[key] = entry
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(dict(sorted(data.items())), indent=1) + "\n")


def hardware_info() -> dict:
    """CPU model, core count, jax version, device list and load average."""
    return dict(cpu=cpu_model(), cores=os.cpu_count(), jax=jax.__version__,
                devices=[str(d) for d in jax.devices()], load_average=load_average())


def children_cpu_s() -> float:
    """CPU seconds (user + system, all threads) of this process's finished child processes."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime
