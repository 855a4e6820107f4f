"""Checkpoint and resume, signals and the divergence guard, as a user meets them: real
processes killed at an arbitrary moment, resumed runs compared bitwise with uninterrupted ones."""

from __future__ import annotations

import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_FLAGS  # pytest puts tests/ on sys.path

from jaxnav import run_dir
from jaxnav.train import DIVERGENCE_QUANTITIES, Trainer
from jaxnav.train.__main__ import main as train_main

# 25 logging intervals of 32 env steps, a checkpoint after every other: seconds of training
TINY = [
    *TINY_FLAGS,
    "--total-timesteps", "800",
    "--eval-episodes", "5",
    "--checkpoint-every", "64",
]  # fmt: skip


# the algorithms' own flags on top of TINY: PQN steps each of the 4 envs twice per iteration
# and takes 2 minibatches of 4 transitions (2 epochs, its preset) from every rollout; with a
# GRU of 8 units ("-memory") the minibatches are 2 envs' sequences, for PPO too
PQN_FLAGS = ["--algo", "pqn", "--rollout-length", "2", "--num-minibatches", "2"]
PPO_MEMORY = ["--algo", "ppo", "--rollout-length", "2", "--num-minibatches", "2", "--memory", "8"]
ALGO_FLAGS = {
    "dqn": [],
    "pqn": PQN_FLAGS,
    "pqn-memory": [*PQN_FLAGS, "--memory", "8"],
    "ppo-memory": PPO_MEMORY,
}


@pytest.fixture(scope="module")
def cache_env(tmp_path_factory) -> dict[str, str]:
    """Subprocess environment sharing one compilation cache, so only the first run compiles."""
    return {**os.environ, "JAXNAV_CACHE_DIR": str(tmp_path_factory.mktemp("xla"))}


def train_process(args: list[str], env: dict[str, str]) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "jaxnav.train", *args]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def checkpoint_steps(out: Path) -> list[int]:
    """Complete checkpoints of the unfinished run for ``out`` (orbax's temporary ones excluded)."""
    directory = run_dir.partial_dir(out) / "checkpoints"
    names = [p.name for p in directory.iterdir()] if directory.is_dir() else []
    return sorted(int(n) for n in names if n.isdigit())


def wait_for_checkpoint(out: Path, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not checkpoint_steps(out):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no checkpoint appeared"
        time.sleep(0.02)


def final_params(run: Path):
    trainer = Trainer(run_dir.load_config(run))
    return jax.device_get(run_dir.load_trained_params(run, trainer))


@pytest.fixture(scope="module", params=sorted(ALGO_FLAGS))
def algo(request) -> str:
    return request.param


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory, cache_env, algo) -> Path:
    out = tmp_path_factory.mktemp("ref") / "run"
    proc = train_process([*TINY, *ALGO_FLAGS[algo], "--out", str(out)], cache_env)
    assert proc.wait() == 0, proc.communicate()
    return out


@pytest.mark.slow
def test_kill_9_at_an_arbitrary_moment_then_resume_is_bitwise_identical(
    algo, uninterrupted, cache_env, tmp_path
):
    out = tmp_path / "run"
    proc = train_process([*TINY, *ALGO_FLAGS[algo], "--out", str(out)], cache_env)
    wait_for_checkpoint(out, proc)
    delay = random.uniform(0.0, 0.6)  # anywhere in training: mid-interval, mid-save, ...
    time.sleep(delay)
    proc.kill()
    assert proc.wait() == -signal.SIGKILL, f"the run ended before the kill at +{delay:.2f}s"
    assert not out.exists() and checkpoint_steps(out), "an unfinished run with checkpoints"

    resumed = train_process(["--resume", str(out)], cache_env)
    stdout, stderr = resumed.communicate()
    assert resumed.returncode == 0, stderr
    assert "resumed from the checkpoint at env step" in stdout
    assert (out / "metrics.csv").read_bytes() == (uninterrupted / "metrics.csv").read_bytes()
    mine, ref = final_params(out), final_params(uninterrupted)
    assert jax.tree.structure(mine) == jax.tree.structure(ref)
    for a, b in zip(jax.tree.leaves(mine), jax.tree.leaves(ref), strict=True):
        np.testing.assert_array_equal(a, b)
    assert sorted(p.name for p in out.iterdir()) == [
        "config.json", "metrics.csv", "params", "summary.json", "timing.csv",
    ]  # fmt: skip
    assert not run_dir.partial_dir(out).exists()
    # what reproducing it needs is saved with it
    doc = json.loads((out / "config.json").read_text())
    assert doc["config"]["algo"] == algo.split("-")[0]
    assert doc["config"]["memory"] == (8 if algo.endswith("memory") else 0)
    assert doc["environment"]["jax_backend"] == jax.default_backend()
    assert doc["environment"]["packages"]["jax"] == jax.__version__
    assert doc["checkpointing"] == {"checkpoint_every": 64, "keep_checkpoints": 2}


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signal_saves_a_checkpoint_and_says_how_to_resume(signum, cache_env, tmp_path):
    out = tmp_path / "run"
    proc = train_process([*TINY, "--out", str(out)], cache_env)
    wait_for_checkpoint(out, proc)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, stderr
    last = stderr.strip().splitlines()[-1]
    name = signal.Signals(signum).name
    assert last.startswith(f"jaxnav.train: stopped by {name} at env step ")
    assert last.endswith(f"continue with: python -m jaxnav.train --resume {out}")
    steps = int(re.search(r"at env step ([\d,]+) \(", last).group(1).replace(",", ""))
    assert checkpoint_steps(out)[-1] * 32 == steps  # saved where it stopped
    rows = (run_dir.partial_dir(out) / "metrics.csv").read_text().splitlines()
    assert len(rows) == 1 + steps // 32 and rows[-1].split(",")[1] == str(steps)
    assert "Traceback" not in stderr and not out.exists()


# ------------------------------------------------------------------ resume refusals
def unfinished_run(tmp_path: Path, extra: list[str] = ()) -> Path:
    """An unfinished run killed before its first checkpoint: only its config.json exists."""
    out = tmp_path / "run"
    from jaxnav.train.__main__ import config_from_args
    from jaxnav.train.__main__ import parser as train_parser

    args = train_parser().parse_args([*TINY, *extra])
    config = config_from_args(args)
    partial = run_dir.partial_dir(out)
    partial.mkdir()
    doc = run_dir.config_document(config, Trainer(config))
    doc["checkpointing"] = {"checkpoint_every": 64, "keep_checkpoints": 2}
    run_dir.write_json(partial / "config.json", doc)
    return out


def test_resume_refuses_other_flags_and_runs_it_cannot_continue(tmp_path, capsys):
    out = unfinished_run(tmp_path)

    def refused(argv: list[str]) -> str:
        before = sorted(tmp_path.rglob("*"))
        assert train_main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err
        assert sorted(tmp_path.rglob("*")) == before  # nothing written
        return err

    err = refused(["--resume", str(out), "--lr", "0.5", "--num-envs", "8", "--env-arg", "size=6"])
    assert "started with env_kwargs={'size': 5}, num_envs=4, lr=0.001, not " in err
    assert "not env_kwargs={'size': 6}, num_envs=8, lr=0.5; leave these flags out" in err
    assert "--out" in refused(["--resume", str(out), "--out", str(tmp_path / "x")])
    assert "no unfinished run" in refused(["--resume", str(tmp_path / "nowhere")])
    assert "unfinished run is in" in refused([*TINY, "--out", str(out)])  # never overwritten
    complete = tmp_path / "done"
    complete.mkdir()
    (complete / "summary.json").write_text("{}")
    assert "is complete" in refused(["--resume", str(complete)])


def test_checkpoint_of_another_state_layout_is_refused_naming_the_array(tmp_path):
    """A checkpoint whose arrays have other shapes (another jaxnav version's observation, say)
    is refused with the array's name, not restored as saved and fed to the compiled run."""
    from jaxnav.checkpoints import Checkpoints

    metrics = {"loss": np.zeros((1, 4), np.float32)}
    state = {"buffer": {"obs": np.zeros((1, 16, 4, 26), np.int8)}, "step": np.int32(3)}
    saving = Checkpoints(tmp_path / "checkpoints", keep=1)
    saving.save(1, state, metrics, {"seconds": {}})
    saving.close()
    like = {
        "buffer": {"obs": jax.ShapeDtypeStruct((1, 16, 4, 10), jnp.int8)},
        "step": state["step"],
    }
    restoring = Checkpoints(tmp_path / "checkpoints", keep=1)
    with pytest.raises(
        ValueError,
        match=r"\['state'\]\['buffer'\]\['obs'\] was saved as "
        r"int8\[1, 16, 4, 26\], this run expects int8\[1, 16, 4, 10\]",
    ):
        restoring.restore(like, metrics)
    step, restored, _, _ = restoring.restore(state, metrics)  # the matching layout restores
    assert step == 1 and restored["buffer"]["obs"].shape == (1, 16, 4, 26)
    restoring.close()


def test_resume_before_any_checkpoint_starts_over_with_the_saved_settings(tmp_path, capsys):
    out = unfinished_run(tmp_path, ["--total-timesteps", "128"])
    # the same flags may be repeated; the partial directory's name works as well as --out
    assert train_main(["--resume", str(run_dir.partial_dir(out)), "--num-envs", "4"]) == 0
    assert "a checkpoint every 64 in" in capsys.readouterr().out  # saved, not default
    rows = (out / "metrics.csv").read_text().splitlines()
    assert [r.split(",")[1] for r in rows[1:]] == ["32", "64", "96", "128"]
    assert not (out / "checkpoints").exists()


# ------------------------------------------------------------------ divergence guard
UNSTABLE = [
    *(a for a in TINY if a != "--quiet"),  # progress lines show where it stopped
    "--hidden-sizes", "64,64",
    "--total-timesteps", "320",
    "--checkpoint-every", "32",
    "--learning-starts", "64",  # two good checkpoints first
    "--replay-ratio", "8",  # 4 gradient steps of 8 per step of the 4 envs
    "--optimizer", "sgd",
    "--lr", "10",
    "--lr-end", "10",
    "--max-grad-norm", "1e9",  # no clipping
    "--gamma", "1.0",
    "--loss", "mse",
    "--eval-episodes", "5",
]  # fmt: skip


def test_divergence_stops_within_an_interval_and_keeps_the_last_good_checkpoint(tmp_path, capsys):
    out = tmp_path / "run"
    assert train_main([*UNSTABLE, "--out", str(out)]) == 3
    stdout, err = capsys.readouterr()
    err = err.strip()
    assert err.count("\n") == 0 and err.startswith("jaxnav.train: diverged: seed 0: ")
    quantity = err.split("seed 0: ")[1].split(" became")[0]
    assert quantity in DIVERGENCE_QUANTITIES
    bad_step = int(err.split("at env step ")[1].split(";")[0].replace(",", ""))
    good_step = int(err.split("checkpoint (env step ")[1].split(")")[0].replace(",", ""))
    assert good_step < bad_step <= good_step + 32  # the checkpoint before the bad interval
    assert checkpoint_steps(out)[-1] * 32 == good_step
    last_progress = re.findall(r"steps +([\d,]+)/", stdout)[-1]
    assert int(last_progress.replace(",", "")) == good_step + 32  # stopped after that interval
    rows = (run_dir.partial_dir(out) / "metrics.csv").read_text().splitlines()
    assert rows[-1].split(",")[1] == str(good_step)
    assert not out.exists()
    print(f"divergence demo: {err}")


@pytest.mark.parametrize("quantity", DIVERGENCE_QUANTITIES)
def test_divergence_flag_names_the_first_bad_quantity_and_step(
    quantity, stepwise_trainer, stepwise_run_one
):
    trainer = stepwise_trainer
    c = trainer.config
    ts = jax.jit(trainer.init)(jax.random.key(0))
    first_learning = c.first_learning_iteration
    for it in range(first_learning):  # warm-up fills the replay buffer
        ts, _ = stepwise_run_one(ts, it)
    assert int(ts.diverged) == 0
    nan = lambda tree: jax.tree.map(lambda x: jnp.full_like(x, jnp.nan), tree)  # noqa: E731
    if quantity == "q_values":  # the acting step's Q-values are the first to see them
        ts = ts.replace(params=nan(ts.params))
    elif quantity == "loss":  # rewards in the replay buffer: only the TD loss sees them
        buffer = ts.algo_state.buffer.replace(reward=nan(ts.algo_state.buffer.reward))
        ts = ts.replace(algo_state=ts.algo_state.replace(buffer=buffer))
    else:  # an infinite step size: loss and Q-values finite, the updated parameters not
        ts = ts.replace(hparams=ts.hparams.replace(lr=jnp.float32(jnp.inf)))
    ts, _ = stepwise_run_one(ts, first_learning)  # a learning iteration
    assert DIVERGENCE_QUANTITIES[int(ts.diverged) - 1] == quantity
    assert int(ts.diverged_at) == (first_learning + 1) * c.num_envs
    later, _ = stepwise_run_one(ts, first_learning + 1)
    assert int(later.diverged) == int(ts.diverged)  # the first one stays
    assert int(later.diverged_at) == int(ts.diverged_at)
