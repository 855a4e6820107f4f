"""One process over all devices against one process per device: the same training command,
the same metrics?

    python -m benchmarks.multiprocess [--devices 2] [--splits seeds,envs] [--deterministic]
        [--train-args "--total-timesteps 48000 ..."] [--out benchmarks/results/multiprocess.json]

For each split (``seeds``: ``--num-seeds D``, a seed per device; ``envs``: one seed whose envs
and batches are split, gradients summed across devices) it runs ``python -m jaxnav.train
--devices all`` three times: twice as one process that sees all ``D`` devices, and once as
``D`` processes of one device each (``jax.distributed`` on localhost, ``--coordinator``), as a
multi-host run would be launched. It then compares the ``metrics.csv`` files byte for byte.
On GPUs each process is given its own GPU with ``CUDA_VISIBLE_DEVICES``; on a CPU with
``XLA_FLAGS=--xla_force_host_platform_device_count``. ``--deterministic`` adds
``--xla_gpu_deterministic_ops=true`` to every process (XLA's GPU scatters and some reductions
otherwise use atomics, so two runs of one process differ already). Writes JSON and a markdown
table.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import socket
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from benchmarks.common import write_results

DEFAULT_TRAIN_ARGS = (
    "--total-timesteps 48000 --num-envs 64 --batch-size 256 --replay-ratio 4 --eval-episodes 100 "
    "--quiet"
)
SPLITS = ("seeds", "envs")
# run in a child: a GPU backend started here would hold the GPUs' memory the runs need
PROBE = (
    "import json; import jax; from benchmarks.common import machine_info; "
    "print(json.dumps(machine_info() | {'local_devices': jax.local_device_count()}))"
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def launch(
    train_args: Sequence[str], processes: int, env_of: Callable[[int], dict[str, str]]
) -> list[subprocess.Popen]:
    """``python -m jaxnav.train *train_args`` as one run of ``processes`` processes
    (``jax.distributed`` on localhost), process ``i`` with environment ``env_of(i)``."""
    coordinator = f"localhost:{_free_port()}"
    return [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "jaxnav.train",
                *train_args,
                "--coordinator",
                coordinator,
                "--num-processes",
                str(processes),
                "--process-id",
                str(i),
            ],
            env=env_of(i),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        for i in range(processes)
    ]


def _env(devices: int, visible: str | None, deterministic: bool, gpu: bool) -> dict[str, str]:
    env = {**os.environ, "JAXNAV_CACHE_DIR": ""}  # every run compiles its own program
    flags = env.get("XLA_FLAGS", "").split()
    flags = [f for f in flags if not f.startswith("--xla_force_host_platform_device_count")]
    if gpu:
        if visible is not None:
            env["CUDA_VISIBLE_DEVICES"] = visible
    else:
        flags.append(f"--xla_force_host_platform_device_count={devices}")
    if deterministic:
        flags.append("--xla_gpu_deterministic_ops=true")
    env["XLA_FLAGS"] = " ".join(flags)
    return env


def _train_args(args: list[str], out: Path) -> list[str]:
    return [*args, "--devices", "all", "--out", str(out)]


def run_split(
    split: str, devices: int, train_args: list[str], deterministic: bool, gpu: bool, tmp: Path
) -> dict[str, Any]:
    args = [*train_args, *(["--num-seeds", str(devices)] if split == "seeds" else [])]
    one = _env(devices, None, deterministic, gpu)
    outs = [tmp / f"{split}_one_{i}" for i in range(2)]
    for out in outs:
        command = [sys.executable, "-m", "jaxnav.train", *_train_args(args, out)]
        done = subprocess.run(command, env=one, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"one process exited {done.returncode}: {done.stderr[-2000:]}")
    multi = tmp / f"{split}_multi"
    procs = launch(_train_args(args, multi), devices, lambda i: _env(1, str(i), deterministic, gpu))
    results = [p.communicate() for p in procs]
    for p, (_, err) in zip(procs, results, strict=True):
        if p.returncode != 0:
            raise RuntimeError(f"process exited {p.returncode}: {err[-2000:]}")
    csv = [(o / "metrics.csv").read_bytes() for o in [*outs, multi]]
    return {
        "split": split,
        "one_process_twice_equal": csv[0] == csv[1],
        "one_vs_multi_process_equal": csv[0] == csv[2],
        "final_row_one_process": csv[0].decode().strip().splitlines()[-1],
        "final_row_multi_process": csv[2].decode().strip().splitlines()[-1],
    }


def table(rows: list[dict[str, Any]], devices: int, deterministic: bool) -> str:
    same = {True: "bitwise equal", False: "differ"}
    lines = [
        f"### metrics.csv, {devices} devices, XLA deterministic GPU ops "
        f"{'on' if deterministic else 'off'}",
        "",
        "| split | one process, run twice | one process vs one process per device |",
        "|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['split']} | {same[r['one_process_twice_equal']]} "
            f"| {same[r['one_vs_multi_process_equal']]} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--devices", type=int, default=2, help="devices, and processes of the run")
    p.add_argument("--splits", default="seeds,envs", help="comma-separated of seeds, envs")
    p.add_argument("--deterministic", action="store_true", help="XLA deterministic ops (GPUs)")
    p.add_argument("--train-args", default=DEFAULT_TRAIN_ARGS, help="jaxnav.train flags")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/multiprocess.json"))
    a = p.parse_args(argv)
    splits = a.splits.split(",")
    bad = [s for s in splits if s not in SPLITS]
    if bad or a.devices < 2:
        p.error(f"--splits {a.splits!r} / --devices {a.devices}: splits of {list(SPLITS)}, >= 2")
    probe = subprocess.run(
        [sys.executable, "-c", PROBE], env=_env(a.devices, None, False, False),
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    machine = json.loads(probe.stdout.strip().splitlines()[-1])
    gpu = machine["backend"] == "gpu"
    if machine["local_devices"] < a.devices:
        p.error(f"--devices {a.devices}: this machine has {machine['local_devices']} devices")
    with tempfile.TemporaryDirectory() as tmp:
        rows = [
            run_split(s, a.devices, shlex.split(a.train_args), a.deterministic, gpu, Path(tmp))
            for s in splits
        ]
    md = table(rows, a.devices, a.deterministic)
    print(md)
    result = {"machine": machine, "args": vars(a) | {"out": str(a.out)}, "rows": rows}
    write_results(a.out, result, md)
    return result


if __name__ == "__main__":
    main()
