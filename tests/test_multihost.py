"""A run over two processes (``jax.distributed`` on localhost, one CPU device each) computes
what one process with two devices does, writes one run directory, and resumes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest
from conftest import TINY_FLAGS

ROOT = str(Path(__file__).resolve().parents[1])  # `benchmarks` is not installed; plain `pytest`
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from benchmarks import multiprocess  # noqa: E402
from jaxnav import run_dir  # noqa: E402
from jaxnav.train.__main__ import main as train_main  # noqa: E402

FLAGS = [*TINY_FLAGS, "--eval-episodes", "4", "--devices", "all"]
pytestmark = pytest.mark.xdist_group("multihost")  # two processes of their own


def _launch(flags: list[str]) -> list[subprocess.Popen]:
    """The same command in two processes, one CPU device each."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=1"}
    env["JAXNAV_CACHE_DIR"] = ""
    return multiprocess.launch(flags, 2, lambda i: env)


def _wait(procs: list[subprocess.Popen]) -> list[tuple[int, str, str]]:
    return [(p.wait(timeout=300), *p.communicate()) for p in procs]


def _same_run(a: Path, b: Path) -> None:
    assert (a / "metrics.csv").read_text() == (b / "metrics.csv").read_text()
    with ocp.StandardCheckpointer() as ckpt:
        pa, pb = ckpt.restore(a.absolute() / "params"), ckpt.restore(b.absolute() / "params")
    jax.tree.map(np.testing.assert_array_equal, pa, pb)


def test_two_processes_stop_together_resume_and_train_as_one_process_with_two_devices(tmp_path):
    """Stopped on one host, both stop; resumed, process 0 alone reports and writes one run
    directory, the same as one process with two devices (bitwise). A run that is never
    stopped is ``benchmarks.multiprocess``'s (its smoke test)."""
    steps = ["--total-timesteps", "1920", "--checkpoint-every", "320"]
    assert train_main([*FLAGS, *steps, "--out", str(tmp_path / "one")]) == 0
    out = tmp_path / "two"
    procs = _launch([*FLAGS, *steps, "--out", str(out)])
    checkpoints = run_dir.partial_dir(out) / "checkpoints"
    deadline = time.monotonic() + 240
    while not (checkpoints.exists() and any(c.name.isdigit() for c in checkpoints.iterdir())):
        assert time.monotonic() < deadline and procs[0].poll() is None, _wait(procs)
        time.sleep(0.05)
    procs[1].send_signal(signal.SIGTERM)  # one host is told: both stop after one interval
    results = _wait(procs)
    assert [code for code, _, _ in results] == [143, 143], results
    assert f"--resume {out}" in results[0][2]
    results = _wait(_launch(["--quiet", *FLAGS[-2:], "--resume", str(out)]))
    assert [code for code, _, _ in results] == [0, 0], results
    (_, out0, _), (_, out1, _) = results
    assert "resumed from the checkpoint" in out0 and "run saved to" in out0
    assert "resumed" not in out1 and "saved" not in out1, out1  # process 0 reports, alone
    assert "training GridMaze" not in out1, out1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one", "two"]  # one run directory
    _same_run(tmp_path / "one", out)
