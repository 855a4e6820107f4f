"""The command lines as a user runs them: outputs on disk, and bad input refused cleanly."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SMALL_GRID_FLAGS  # pytest puts tests/ on sys.path

from jaxnav import host, run_dir
from jaxnav.evaluate.__main__ import main as evaluate_main
from jaxnav.train.__main__ import main as train_main

TINY = SMALL_GRID_FLAGS


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "tiny"
    assert train_main([*TINY, "--out", str(out), "--quiet"]) == 0
    return out


def test_train_writes_a_complete_run(tiny_run):
    assert sorted(p.name for p in tiny_run.iterdir()) == [
        "config.json", "metrics.csv", "params", "summary.json", "timing.csv",
    ]  # fmt: skip
    config = json.loads((tiny_run / "config.json").read_text())
    assert config["config"]["env_kwargs"] == {"size": 7}
    assert config["network"]["hidden_sizes"] == [32, 32]
    assert config["environment"]["packages"]["jax"]
    assert config["environment"]["cpu"] == host.cpu_info()  # where its times were measured
    rows = list(csv.DictReader((tiny_run / "metrics.csv").open()))
    assert len(rows) == 2 * 4  # seeds x logging intervals
    assert {"env_steps", "mean_return", "success_rate", "loss", "epsilon"} <= set(rows[0])
    assert [int(r["env_steps"]) for r in rows[:4]] == [1000, 2000, 3000, 4000]
    assert {r["seed"] for r in rows} == {"0", "1"}
    assert [r["loss"] for r in rows[:4]] != [r["loss"] for r in rows[4:]]  # seeds differ
    # wall-clock rates apart, so that metrics.csv is bitwise reproducible
    timing = list(csv.DictReader((tiny_run / "timing.csv").open()))
    assert [r["env_steps"] for r in timing] == [r["env_steps"] for r in rows]
    assert all(float(r["sps"]) > 0 for r in timing)
    summary = json.loads((tiny_run / "summary.json").read_text())
    for policy in ("trained", "random_policy"):
        assert 0.0 <= summary[policy]["success_rate"] <= 1.0
        assert summary[policy]["episodes"] == 50
    assert len(summary["trained_per_seed"]) == 2


def test_evaluate_reads_the_run_and_generalizes(tiny_run, tmp_path, capsys):
    assert evaluate_main([str(tiny_run), "--episodes", "40"]) == 0
    result = json.loads((tiny_run / "eval.json").read_text())
    assert result["episodes"] == 40 and len(result["per_seed"]) == 2
    assert result["success_rate"] + result["collision_rate"] + result["timeout_rate"] == (
        pytest.approx(1.0)
    )
    out = tmp_path / "other.json"
    args = [str(tiny_run), "--policy", "random", "--env-arg", "layout_seed=5", "--out", str(out)]
    assert evaluate_main(args) == 0
    other = json.loads(out.read_text())
    assert other["policy"] == "random" and other["env_kwargs"] == {"size": 7, "layout_seed": 5}
    assert "success_rate" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, named",
    [
        (["--env", "Nope-v0"], "Nope-v0"),
        (["--bogus", "1"], "--bogus"),
        (["--bogus", "a\nb"], "--bogus a\\nb"),  # a line break in the value stays on one line
        (["--resume", "a\nb"], "--resume a\\nb: no unfinished run"),  # ... also in a path
        (["--num-envs", "0"], "num_envs=0"),
        (["--total-timesteps", "-5"], "total_timesteps=-5"),
        (["--env-arg", "size=0"], "size=0"),
        (["--env-arg", "obstacle_density=0.999"], "obstacle_density=0.999"),
        (["--env-arg", "colour=3"], "colour"),
        (["--env", "RobotSimple-v0", "--env-arg", "trail_cell=-1"], "trail_cell=-1: must be"),
        (["--batch-size", "5000", "--buffer-size", "4000"], "batch_size=5000"),
        (["--learning-starts", "10000000"], "learning_starts=10000000"),
        (["--gamma", "1.5"], "gamma=1.5"),
        (["--replay-ratio", "abc"], "--replay-ratio: invalid float value: 'abc'"),
        (["--replay-ratio", "-1"], "replay_ratio=-1.0"),
        (["--replay-ratio", "nan"], "replay_ratio=nan"),
        (["--replay-ratio", "0"], "replay_ratio=0.0: must be positive"),
        # 3 * 16 / 128 = 0.375 gradient steps an iteration: a batch of 48 would take one
        (["--replay-ratio", "3"], "replay_ratio=3.0 with num_envs=16 and batch_size=128"),
        (["--num-envs", "1000"], "e.g. batch_size=125 (64 per iteration)"),
        (["--dueling", "maybe"], "maybe"),
        # sizes that would exhaust memory are refused before anything is allocated
        (["--buffer-size", "1000000000", "--num-seeds", "64"], "buffer_size=1000000000"),
        (["--hidden-sizes", "65536,65536,65536", "--num-seeds", "64"], "hidden_sizes=65536"),
        (["--env-arg", "size=255"], "size=255"),
        (["--checkpoint-every", "0"], "--checkpoint-every 0"),
        (["--keep-checkpoints", "0"], "--keep-checkpoints 0"),
    ],
)
def test_bad_input_is_one_line_exit_2_nothing_written(args, named, tmp_path, capsys):
    out = tmp_path / "run"
    assert train_main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and named in err and "Traceback" not in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_unwritable_or_used_out_dir_is_refused(tiny_run, tmp_path, capsys):
    assert train_main(["--out", str(tiny_run)]) == 2  # never overwrite a run
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert train_main(["--out", str(blocker / "run")]) == 2
    err = capsys.readouterr().err
    assert str(tiny_run) in err and str(blocker) in err


@pytest.mark.slow  # two processes of the CLI
def test_cli_process_exit_code_and_help():
    bad = subprocess.run(
        [sys.executable, "-m", "jaxnav.train", "--num-envs", "-3"], capture_output=True, text=True
    )
    assert bad.returncode == 2
    assert (
        bad.stderr.strip()
        == "jaxnav.train: error: num_envs=-3: must be an integer in [1, 16777216]"
    )
    helped = subprocess.run(
        [sys.executable, "-m", "jaxnav.train", "--help"], capture_output=True, text=True
    )
    assert helped.returncode == 0
    flags = ("--env", "--algo", "--num-seeds", "--total-timesteps", "--gamma", "--env-arg", "--out")
    for flag in flags:
        assert flag in helped.stdout
    assert "default: 240000" in helped.stdout
    missing = subprocess.run(
        [sys.executable, "-m", "jaxnav.evaluate", "/nonexistent/run"],
        capture_output=True,
        text=True,
    )
    assert missing.returncode == 2 and "no config.json" in missing.stderr


def test_evaluate_refuses_an_env_whose_observations_do_not_fit(tiny_run, capsys):
    argv = [str(tiny_run), "--env", "RobotSimple-v0", "--env-arg", "backend=kinematic"]
    assert evaluate_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxnav.evaluate: error: --env RobotSimple-v0: observations (")
    assert err.endswith("do not fit the run's network (10,) one-hot encoded to 34")
    # the same observation shape, but a grid of another size: other one-hot widths
    assert evaluate_main([str(tiny_run), "--env-arg", "size=6"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(
        "observations (10,) one-hot encoded to 30 do not fit the run's network (10,) one-hot "
        "encoded to 34"
    )


def test_a_run_saved_with_updates_per_iteration_loads_as_its_replay_ratio(tiny_run, capsys):
    """The config.json of a run trained before ``replay_ratio`` has ``updates_per_iteration``
    u in its place: the run loads (evaluate, render, export, --resume) with replay_ratio =
    u * batch_size / num_envs, the same training."""
    old = tiny_run.parent / "old"
    shutil.copytree(tiny_run, old)
    now = run_dir.load_config(tiny_run)
    assert (now.replay_ratio, now.num_envs, now.batch_size) == (4.0, 8, 32)
    document = json.loads((old / "config.json").read_text())
    document["config"] = {
        ("updates_per_iteration" if k == "replay_ratio" else k): (1 if k == "replay_ratio" else v)
        for k, v in document["config"].items()
    }
    (old / "config.json").write_text(json.dumps(document))
    assert run_dir.load_config(old) == now and now.updates_per_iteration == 1
    assert evaluate_main([str(old), "--episodes", "10"]) == 0
    capsys.readouterr()
    # 4 gradient steps of 128 per step of 64 envs: 8 sampled transitions per env step
    four = {**run_dir.config_to_json(now), "num_envs": 64, "batch_size": 128}
    del four["replay_ratio"]
    config = run_dir.config_from_json({**four, "updates_per_iteration": 4})
    assert config.replay_ratio == 8.0 and config.updates_per_iteration == 4


# An editable install (pip install -e .) as setuptools writes one: a finder after Python's path
# finder maps the package to its source folder. Python's path finder takes a folder named
# jaxnav in the working directory (as in the folder holding a clone named jaxnav) for a
# namespace package first, so the package's __init__ never runs; its modules are found
# beneath it by the install's finder. ``sys.argv[1:]``: the module to run and its flags.
EDITABLE_INSTALL = """
import runpy, sys
from importlib.machinery import PathFinder

SOURCE = {source!r}


class EditableFinder:
    @classmethod
    def find_spec(cls, fullname, path=None, target=None):
        if fullname == "jaxnav":
            return PathFinder.find_spec(fullname, [SOURCE])
        if fullname.rpartition(".")[0] == "jaxnav":
            return PathFinder.find_spec(fullname, [SOURCE + "/jaxnav"])
        return None


sys.meta_path.insert(sys.meta_path.index(PathFinder) + 1, EditableFinder)
if sys.argv[1] == "--shadowed":
    import jaxnav

    print(getattr(jaxnav, "__file__", None))
else:
    sys.argv = sys.argv[1:]
    runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
"""


def test_commands_run_from_the_folder_holding_a_clone_named_jaxnav(tmp_path):
    """Every command failed there: "cannot import name '__version__' from 'jaxnav'"."""
    (tmp_path / "jaxnav").mkdir()  # the clone: a README, the package one level down
    (tmp_path / "jaxnav" / "README.md").write_text("jaxnav\n")
    source = str(Path(__file__).resolve().parents[1])
    code = EDITABLE_INSTALL.format(source=source)

    def run(*args: str) -> subprocess.CompletedProcess:
        argv = [sys.executable, "-c", code, *args]
        return subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=300)

    shadowed = run("--shadowed")
    assert shadowed.stdout.strip() == "None", shadowed  # the namespace package, as a user has
    for command in ("jaxnav.export", "jaxnav.evaluate", "jaxnav.render"):
        done = run(command, "--help")
        assert done.returncode == 0 and f"usage: python -m {command}" in done.stdout, done.stderr
