"""What every benchmark records: the machine it ran on, and JSON plus a markdown table."""

from __future__ import annotations

import datetime
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

from jaxnav.config import TrainConfig
from jaxnav.host import host_info, package_version


def machine_info() -> dict[str, Any]:
    return {
        **host_info(),
        "jax_version": jax.__version__,
        "backend": jax.default_backend(),
        "device_kind": jax.devices()[0].device_kind,  # e.g. "NVIDIA H100 80GB HBM3"
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "loadavg_1m_at_start": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "gymnax_version": package_version("gymnax"),
    }


def machine_text(machine: dict[str, Any]) -> str:
    """``machine_info``'s backend, cores and CPU in a few words, for a table's or plot's head:
    "cpu (2 cores; AMD EPYC, family 25 model 1, AVX2, no AVX-512)". Results recorded before
    the CPU was recorded give the cores alone."""
    cpu, details = machine.get("cpu") or {}, []
    if cpu.get("model"):
        details.append(cpu["model"])
    if cpu.get("family") is not None and cpu.get("model_number") is not None:
        details.append(f"family {cpu['family']} model {cpu['model_number']}")
    features = cpu.get("features")
    if features is not None:
        details += [name.upper() for name, present in features.items() if present]
        if not features["avx512f"]:
            details.append("no AVX-512")
    cores = f"{machine['cpu_count']} cores" + (f"; {', '.join(details)}" if details else "")
    kind = machine.get("device_kind")
    backend = f"{machine['backend']} {kind}" if kind and machine["backend"] != "cpu" else ""
    return f"{backend or machine['backend']} ({cores})"


def write_results(out: Path, result: dict[str, Any], markdown: str) -> None:
    """``out`` (JSON) and the same name with ``.md`` (the printed table)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    write_whole(out, json.dumps(result, indent=2) + "\n")
    write_whole(out.with_suffix(".md"), markdown + "\n")


def write_whole(path: Path, text: str) -> None:
    """``path`` holds ``text`` whole or is left as it was: a temporary file renamed over it."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


class TimedProgram:
    """A compiled program. Calling it runs it once, on the arguments it was compiled for or on
    others of the same shapes, and returns the seconds it took."""

    def __init__(self, compiled: jax.stages.Compiled, args: tuple[Any, ...]) -> None:
        self.compiled, self.args = compiled, args

    def __call__(self, *args: Any) -> float:
        t0 = time.perf_counter()
        jax.block_until_ready(self.compiled(*(args or self.args)))
        return time.perf_counter() - t0

    @property
    def peak_bytes(self) -> int | None:
        """XLA's peak memory of the program (arguments, outputs and temporaries), or None
        where the backend does not report it."""
        stats = self.compiled.memory_analysis()
        if stats is None:
            return None
        peak = getattr(stats, "peak_memory_in_bytes", 0)
        return int(peak) or int(
            stats.argument_size_in_bytes
            + stats.output_size_in_bytes
            + stats.temp_size_in_bytes
            - stats.alias_size_in_bytes
        )


def compile_timed(fn: Callable[..., Any], *args: Any) -> tuple[TimedProgram, float]:
    """Compile ``jit(fn)`` for ``args``; return (the program, timing one call per call, the
    compile time). One warm-up call is made, so the first timed call is a steady-state one."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    run = TimedProgram(compiled, args)
    run()
    return run, compile_s


def time_in_turn(rows: list[dict[str, Any]], rounds: int) -> None:
    """Call each row's ``run`` ``rounds`` times in turn (A, B, C, A, B, C, ...), so a change of
    machine load hits all rows alike and ratios between them stay meaningful. Stores the times
    as ``run_s`` and drops ``run`` (a function cannot go into JSON).

    Each timed call follows an untimed one of the same row: the first call after another
    program can pay for the switch (on the 2-core CPU, GridMaze-v0's 40 ms run took 120 ms
    right after jaxmarl JaxNav's), which is not the row's own cost."""
    for _ in range(rounds):
        for row in rows:
            row["run"]()
            row.setdefault("run_s", []).append(row["run"]())
    for row in rows:
        del row["run"]


def train_config(overrides: str, **defaults: Any) -> TrainConfig:
    """The training CLI's config for ``overrides``, a JSON object of ``TrainConfig`` fields
    over ``defaults``: the preset of its env (default GridMaze-v0, the paper's grid experiment)
    and algorithm, then the other fields."""
    values = json.loads(overrides)
    if not isinstance(values, dict):
        raise ValueError("must be a JSON object of TrainConfig fields")
    values = defaults | values
    if "hidden_sizes" in values:
        values["hidden_sizes"] = tuple(values["hidden_sizes"])
    # the env's preset for the algorithm first, as the training CLI applies it
    config = TrainConfig.for_env(values.pop("env", "GridMaze-v0"), **values)
    config.validate()
    return config
