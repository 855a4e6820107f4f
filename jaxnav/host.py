"""The machine and packages a run or benchmark runs on, as run directories and results record
them: the CPU (``cpu_info``), installed versions (``package_version``) and the host
(``host_info``)."""

from __future__ import annotations

import os
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

import jax

# vector instruction sets XLA compiles CPU programs for when the host has them: a run's speed
# (and possibly the rounding of its sums) differs between CPUs with and without them
CPU_FEATURES = ("avx2", "avx512f", "avx512_bf16", "amx_tile")


def cpu_info(cpuinfo: str | None = None) -> dict[str, Any]:
    """The host CPU as ``cpuinfo`` (default: /proc/cpuinfo) describes its first processor: model
    name, family and model numbers, and whether it has each of ``CPU_FEATURES``; None for what
    it does not say (all of it off Linux; an ARM CPU's have other fields)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            cpuinfo = ""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        key, colon, value = line.partition(":")
        if not colon:
            if fields:
                break  # a blank line ends the first processor's block
            continue
        fields.setdefault(key.strip(), value.strip())
    family, model, flags = (fields.get(k) for k in ("cpu family", "model", "flags"))
    return {
        "model": fields.get("model name"),
        "family": int(family) if family and family.isdigit() else None,
        "model_number": int(model) if model and model.isdigit() else None,
        "features": None if flags is None else {f: f in flags.split() for f in CPU_FEATURES},
    }


def package_version(dist: str) -> str | None:
    """The installed version of distribution ``dist``, or None where it is not installed."""
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def host_info() -> dict[str, Any]:
    """The machine a run or benchmark ran on: OS, Python, cores, CPU and JAX's devices."""
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "cpu": cpu_info(),
        "devices": [str(d) for d in jax.devices()],
    }
