"""Fault injection, round two: hostile values that used to pass validation and fail later (NaN
observations, silent float32 overflow, shape tracebacks, memory errors after ``.partial``,
flax tracebacks, starts inside walls, a wrong exit code, a cache that runs code). Each ends in
one line naming the value (exit 2 for the commands). Tiny configs."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from pathlib import Path

import pytest
from conftest import TINY_FLAGS, TINY_TRAIN  # pytest puts tests/ on sys.path

import jaxnav
from jaxnav import registration
from jaxnav.envs.robot import mazes
from jaxnav.train.__main__ import main as train_main

ROBOT = [a for a in TINY_FLAGS if a not in ("--env-arg", "size=5")]  # robot envs have no size


def one_line_error(capsys, code: int, got: int) -> str:
    assert got == code
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


# ------------------------------------------------------------------ 1. physical sizes
@pytest.mark.parametrize("cell_size", ["1e20", "1e-9"])
def test_maze_file_cell_size_out_of_range_is_one_line(cell_size, tmp_path, capsys):
    maze = tmp_path / "maze.txt"
    maze.write_text(f"cell_size: {cell_size}\nS...\n.##.\n...G\n")
    out = tmp_path / "r"
    argv = [*ROBOT, "--env", "RobotMaze-v0", "--maze-file", str(maze), "--out", str(out)]
    err = one_line_error(capsys, 2, train_main(argv))
    assert f"cell_size {cell_size!r}" in err and "metres" in err, err
    assert not out.exists() and not (tmp_path / ".r.partial").exists()


@pytest.mark.parametrize("cell_size", [1e20, 1e-9])
def test_maze_and_bank_cell_size_out_of_range_is_refused(cell_size):
    grid = [[False, False], [False, False]]
    want = re.escape(f"cell_size={cell_size!r}: must be in [0.01, 100] metres")
    with pytest.raises(ValueError, match=want):
        mazes.Maze(grid, cell_size)
    with pytest.raises(ValueError, match=re.escape(f"cell_size={cell_size!r}")):
        mazes.random_maze_bank(1, rows=4, cols=4, cell_size=cell_size)


def open_maze_file(path: Path, side: int) -> Path:
    """A ``side`` x ``side`` maze file without walls, S and G in opposite corners."""
    rows = ["." * side for _ in range(side)]
    rows[0], rows[-1] = "S" + rows[0][1:], rows[-1][:-1] + "G"
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_maze_file_too_large_for_its_geodesic_table_is_refused_before_it_is_built(
    tmp_path, capsys
):
    """200 x 200 cells, a table from every cell: 3 GiB (the env built for minutes before).
    152 x 152 is the largest square under the 1 GiB limit; num_goal_cells lifts it."""
    big = open_maze_file(tmp_path / "big.txt", 200)
    with pytest.raises(ValueError, match=r"200 x 200 cells .* 3,052 MiB \(at most 1,024\)"):
        registration.env_config("RobotMaze-v0", maze_file=str(big))
    with pytest.raises(ValueError, match="num_goal_cells=32"):
        jaxnav.make("RobotMaze-v0", maze_file=str(big))
    registration.env_config("RobotMaze-v0", maze_file=str(big), num_goal_cells=32)
    with pytest.raises(ValueError, match="153 x 153 cells"):
        registration.env_config("RobotMaze-v0", maze_file=str(open_maze_file(big, 153)))
    registration.env_config("RobotMaze-v0", maze_file=str(open_maze_file(big, 152)))
    out = tmp_path / "r"
    argv = [*ROBOT, "--maze-file", str(open_maze_file(big, 200)), "--out", str(out)]
    err = one_line_error(capsys, 2, train_main(argv))
    assert f"maze_file={str(big)!r}" in err and "num_goal_cells" in err, err
    assert not out.exists() and not (tmp_path / ".r.partial").exists()


@pytest.mark.parametrize(
    "argv, want",
    [
        (["--env", ""], "--env '': empty"),
        (["--env", "  "], "--env '  ': empty"),
        (["--env-arg", "size="], "--env-arg size given twice (5, then '')"),
        (["--env-arg", "obs_mode=paper", "--env-arg", "obs_mode=full"], "obs_mode given twice"),
        (["--maze-file", ""], "--maze-file: empty path ''"),
        (["--maze-file", "m.txt", "--env-arg", "maze_file=n.txt"], "both given"),
    ],
)
def test_empty_env_repeated_env_arg_and_empty_maze_file_are_refused(argv, want, tmp_path, capsys):
    """Each was a silent choice: the default env, the last value, the current directory."""
    out = tmp_path / "r"
    err = one_line_error(capsys, 2, train_main([*TINY_FLAGS, *argv, "--out", str(out)]))
    assert want in err, err
    assert not list(tmp_path.iterdir())  # nothing written


def test_empty_env_is_refused_by_evaluate_and_render_too(capsys):
    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.render import main as render_main

    for main in (evaluate_main, render_main):
        err = one_line_error(capsys, 2, main(["--pretrained", "gridmaze-dqn", "--env", ""]))
        assert "--env '': empty" in err, err


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_a_maze_file_with_a_utf8_bom_reads_as_without(newline, tmp_path):
    text = newline.join(["cell_size: 1.5", "S..", ".#.", "..G", ""])
    plain, bom = tmp_path / "plain.txt", tmp_path / "bom.txt"
    plain.write_bytes(text.encode())
    bom.write_bytes(b"\xef\xbb\xbf" + text.encode())  # what Notepad writes
    a, b = mazes.load_maze(plain), mazes.load_maze(bom)
    assert (a.grid == b.grid).all() and (a.start, a.goal, a.cell_size) == (b.start, b.goal, 1.5)
    grid_only = tmp_path / "grid.txt"
    grid_only.write_bytes(b"\xef\xbb\xbfS.\n.G\n")  # the BOM before a grid row, not a header
    assert mazes.load_maze(grid_only).grid.shape == (2, 2)


# ------------------------------------------------------------------ 2, 3. every float, every bool
def typed_fields(kind: str) -> list[tuple[str, str]]:
    """(env id, field) for every field of the grid and robot configs annotated ``kind``."""
    return [
        (env_id, f.name)
        for env_id in ("GridMaze-v0", "RobotSimple-v0")
        for f in dataclasses.fields(registration.env_config(env_id))
        if f.type == kind
    ]


FLOAT_FIELDS = typed_fields("float") + [("RobotSimple-v0", "speed_range")]


@pytest.mark.parametrize("env_id,name", FLOAT_FIELDS)
@pytest.mark.parametrize("value", [1e39, -1e39, 1e7])
def test_every_float_field_beyond_float32_or_a_sane_bound_is_refused(env_id, name, value):
    config = registration.env_config(env_id)
    bad = (1.0, value) if name.endswith("_range") else value
    with pytest.raises(ValueError) as info:
        dataclasses.replace(config, **{name: bad}).validate()
    # the field's own check or check_fields; a derived size's (speed_range: the top speed)
    # names it in its own format
    shown = {f"{name}={bad!r}", f"{name}={bad}", f"{name.removesuffix('_range')}={value:g}"}
    assert any(s in str(info.value) for s in shown) and "\n" not in str(info.value), info.value


@pytest.mark.parametrize("env_id,name", typed_fields("bool"))
@pytest.mark.parametrize("value", [2, 1, 0, "False", None])
def test_every_bool_field_refuses_what_is_not_a_bool(env_id, name, value):
    config = registration.env_config(env_id)  # built directly: config.json, Python callers
    with pytest.raises(ValueError, match=re.escape(f"{name}={value!r}: must be true or false")):
        dataclasses.replace(config, **{name: value}).validate()


@pytest.mark.parametrize(
    "arg", ["turn_speed=1e39", "goal_reward=1e39", "obs_proximity=2", "laser_range=1e30"]
)
def test_float32_overflow_and_int_bools_on_the_command_line_are_one_line(arg, tmp_path, capsys):
    out = tmp_path / "r"
    argv = [*ROBOT, "--env", "RobotSimple-v0", "--env-arg", arg, "--out", str(out)]
    err = one_line_error(capsys, 2, train_main(argv))
    name, value = arg.split("=")
    assert f"{name}={float(value) if 'e' in value else int(value)!r}" in err, err
    assert not out.exists() and not (tmp_path / ".r.partial").exists()
    assert len(FLOAT_FIELDS) > 20 and jaxnav.make("RobotSimple-v0", goal_reward=1e6)  # the bound


# ------------------------------------------------------------------ 4. memory
def test_per_interval_metrics_too_large_for_memory_are_refused_before_the_run_dir(tmp_path, capsys):
    out = tmp_path / "r"
    big = ["--num-seeds", "4096", "--log-interval", "1", "--num-envs", "1", "--replay-ratio", "8"]
    argv = [*TINY_FLAGS, *big, "--total-timesteps", "2000000000", "--out", str(out)]
    err = one_line_error(capsys, 2, train_main(argv))
    assert "log_interval=1" in err and "metrics need about" in err and "GiB" in err, err
    assert not list(tmp_path.iterdir())  # neither the run nor its .partial


def test_replay_too_large_for_a_gpu_is_refused_per_device(monkeypatch):
    """On an accelerator the replay buffer and networks are checked against one device's
    memory (split over --devices), not the host's: a 2.3 GiB replay is refused on a 2 GiB
    device and accepted on a 4 GiB one (``device_memory_limit`` reads the device's limit,
    which this CPU has none of)."""
    import jaxnav.train as train

    monkeypatch.setattr(train, "device_memory_limit", lambda: 2 * 2**30)
    # 8192 envs x 8192 rows of GridMaze-v0's 10-byte observations (two copies) and 4
    # four-byte fields: about 2.3 GiB
    big = dataclasses.replace(
        TINY_TRAIN, num_envs=8192, buffer_size=8192**2, batch_size=8192 * 2, learning_starts=8192,
        total_timesteps=8192 * 4, log_interval=8192,
    )  # fmt: skip
    with pytest.raises(ValueError, match=r"buffer_size=67108864.*on each of 1 device.*2\.0 GiB"):
        train.Trainer(big)
    monkeypatch.setattr(train, "device_memory_limit", lambda: 4 * 2**30)
    assert train.Trainer(big).config.buffer_rows == 8192


def test_layout_bank_too_large_to_build_is_refused():
    # without the waypoint's offsets the distance fields alone (1.9 GiB) pass the size check
    kw = dict(num_layouts=1_000_000, size=32, goals_per_layout=1, waypoint_cells=0)
    with pytest.raises(ValueError, match=r"num_layouts=1000000.*building the layout bank"):
        registration.env_config("GridMaze-Random-v0", **kw)
    registration.env_config("GridMaze-Random-v0", num_layouts=100_000)  # 15 x 15: 1.8 GiB


# ------------------------------------------------------------------ 5. edited config.json
@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("trained") / "run"
    argv = [*TINY_FLAGS, "--total-timesteps", "32", "--eval-episodes", "2", "--out", str(out)]
    assert train_main(argv) == 0
    return out


EDITS = [{"hidden_sizes": [32]}, {"hidden_sizes": [16, 16]}, {"dueling": False}, {"num_seeds": 2}]


@pytest.mark.parametrize("edit", EDITS)
def test_evaluate_on_a_run_whose_config_was_edited_is_one_line(edit, trained, tmp_path, capsys):
    from jaxnav.evaluate.__main__ import main as evaluate_main

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    saved = json.loads((run / "config.json").read_text())
    saved["config"].update(edit)  # the training config; "network" describes it for humans
    (run / "config.json").write_text(json.dumps(saved))
    err = one_line_error(capsys, 2, evaluate_main([str(run), "--episodes", "1"]))
    assert f"{run}" in err and "parameters" in err and "config.json" in err, err
    assert not (run / "eval.json").exists()


# ------------------------------------------------------------------ 6. reset_to's cells
def test_grid_reset_to_refuses_blocked_or_off_map_cells_and_suites_check_first():
    import jax
    import numpy as np

    from jaxnav import experiments

    env, params = jaxnav.make("GridMaze-v0", size=7, obstacle_density=0.3)
    walls = np.asarray(params.bank.obstacles[0])
    wall = [int(v) for v in np.argwhere(walls)[0]]
    free = [[int(r), int(c)] for r, c in np.argwhere(~walls)[:2]]
    key = jax.random.key(0)
    for start, goal, layout, why in (
        (wall, free[1], 0, f"reset_to start={wall}: a blocked cell"),
        (free[0], wall, 0, f"reset_to goal={wall}: a blocked cell"),
        ([-1, 0], free[1], 0, "reset_to start=[-1, 0]: off the 7x7 grid"),
        (free[0], [0, 7], 0, "reset_to goal=[0, 7]: off the 7x7 grid"),
        (free[0], free[1], 1, "layout 1 is not in the bank's 1"),
    ):
        with pytest.raises(ValueError, match=re.escape(why)):
            env.reset_to(key, params, np.array(start), np.array(goal), layout)
    env.reset_to(key, params, np.array(free[0]), np.array(free[1]))  # free cells: fine
    suite = {"start": np.array([free[0], wall]), "goal": np.array(free[1::-1]), "layout": [0, 0]}
    with pytest.raises(ValueError, match=re.escape(f"reset_to start={wall}")):
        experiments.start_suite(env, params, suite)  # vmapped: checked before


def test_robot_reset_to_refuses_a_pose_in_a_wall_or_off_the_arena():
    import jax
    import numpy as np

    env, params = jaxnav.make("RobotSimple-v0", backend="kinematic")
    bank = params.bank
    rows = bank.grid.shape[1]
    r, c = (int(v) for v in np.argwhere(np.asarray(bank.grid[0]))[0])
    cs = float(bank.cell_size[0])
    inside = [(c + 0.5) * cs, (rows - 1 - r + 0.5) * cs]
    free_xy = np.asarray(bank.free_xy[0, :2], np.float64)
    width, height = bank.size_m
    key = jax.random.key(0)
    for pose, goal, why in (
        ([*inside, 0.0], free_xy[1], f"reset_to pose={[*inside, 0.0]}: a blocked cell"),
        ([-0.5, 1.0, 0.0], free_xy[1], "reset_to pose=[-0.5, 1.0, 0.0]: off the"),
        ([float("nan"), 1.0, 0.0], free_xy[1], "reset_to pose=[nan, 1.0, 0.0]: off the"),
        ([*free_xy[0], 0.0], [width + 1, 1.0], f"reset_to goal=[{width + 1}, 1.0]: off the"),
    ):
        with pytest.raises(ValueError, match=re.escape(why)):
            env.reset_to(key, params, np.array(pose), np.array(goal))
    env.reset_to(key, params, np.array([*free_xy[0], 0.0]), free_xy[1])  # free: fine


# ------------------------------------------------------------------ 7. signal while finishing
@pytest.mark.slow
def test_sigterm_during_the_final_evaluation_exits_143_and_resume_completes(
    tmp_path, capsys, monkeypatch
):
    import os
    import signal

    from jaxnav import runner

    tiny = [*TINY_FLAGS, "--total-timesteps", "64", "--eval-episodes", "2"]
    ref = tmp_path / "ref"
    assert train_main([*tiny, "--out", str(ref)]) == 0
    evaluate = runner.evaluate_seeds

    sent = []

    def evaluate_then_sigterm(*args, **kwargs):
        result = evaluate(*args, **kwargs)
        if not sent:  # once: a second signal ends the process at once, by design
            sent.append(os.kill(os.getpid(), signal.SIGTERM))  # train's handler records it
        return result

    monkeypatch.setattr(runner, "evaluate_seeds", evaluate_then_sigterm)
    out = tmp_path / "run"
    capsys.readouterr()
    assert train_main([*tiny, "--out", str(out)]) == 128 + signal.SIGTERM
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "stopped by SIGTERM" in err and "--resume" in err, err
    assert not out.exists() and (tmp_path / ".run.partial").is_dir()
    monkeypatch.setattr(runner, "evaluate_seeds", evaluate)
    assert train_main(["--resume", str(out)]) == 0
    assert (out / "metrics.csv").read_text() == (ref / "metrics.csv").read_text()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["trained"] == json.loads((ref / "summary.json").read_text())["trained"]


# ------------------------------------------------------------------ 7b. Ctrl-C while starting
def test_ctrl_c_while_the_command_imports_is_one_line_exit_130(tmp_path):
    """JAX takes seconds to import: a SIGINT then was a KeyboardInterrupt traceback."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    argv = [*TINY_FLAGS, "--total-timesteps", "64", "--out", str(out)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "jaxnav.train", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    time.sleep(0.5)  # jaxnav is imported, JAX is loading
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.count("\n") == 1 and err.startswith("jaxnav.train: stopped by SIGINT"), err
    assert not list(tmp_path.iterdir())  # nothing written


@pytest.mark.parametrize("moment", ["building the env", "the run directory written"])
@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_ctrl_c_or_sigterm_before_training_began_is_one_line_128_plus_it_and_resumable(
    moment, signame, tmp_path, capsys, monkeypatch
):
    """SIGTERM then killed the process without a word (Ctrl-C was answered)."""
    import os
    import signal

    from jaxnav import runner
    from jaxnav.train import __main__ as train_cli

    signum = getattr(signal, signame)

    def then_ctrl_c(real):
        def call(*args, **kwargs):
            result = real(*args, **kwargs)
            os.kill(os.getpid(), signum)  # as the terminal or a scheduler sends it
            return result

        return call

    if moment == "building the env":
        monkeypatch.setattr(train_cli, "Trainer", then_ctrl_c(train_cli.Trainer))
    else:
        monkeypatch.setattr(runner, "open_run", then_ctrl_c(runner.open_run))
    out = tmp_path / "run"
    argv = [*TINY_FLAGS, "--total-timesteps", "64", "--eval-episodes", "0", "--out", str(out)]
    err = one_line_error(capsys, 128 + signum, train_main(argv))
    assert err.startswith(f"jaxnav.train: stopped by {signame} before training began; ")
    monkeypatch.undo()
    if moment == "building the env":
        assert err.endswith("nothing was trained or written") and not list(tmp_path.iterdir())
        assert train_main(argv) == 0  # nothing in the way of the same command
    else:
        assert err.endswith(f"continue with: python -m jaxnav.train --resume {out}")
        assert train_main(["--resume", str(out)]) == 0
    assert (out / "summary.json").is_file()


def test_sigint_or_sigterm_while_evaluate_runs_is_one_line_and_writes_nothing(trained, tmp_path):
    """Commands without training's handler: a SIGTERM killed them without a word, a Ctrl-C
    gave a KeyboardInterrupt traceback; now they unwind (nothing half written), then one
    line and 128 + the signal."""
    import os
    import signal
    import subprocess
    import sys
    import time

    for signum in (signal.SIGINT, signal.SIGTERM):
        out = tmp_path / f"eval-{signum}.json"
        argv = [str(trained), "--episodes", "10000000", "--out", str(out)]
        proc = subprocess.Popen(
            [sys.executable, "-m", "jaxnav.evaluate", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        time.sleep(4)  # importing, compiling or evaluating: each answered alike
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=120)
        name = signal.Signals(signum).name
        assert proc.returncode == 128 + signum, err
        assert err.count("\n") == 1 and err.startswith(f"jaxnav.evaluate: stopped by {name}"), err
        assert not out.exists() and not list(tmp_path.glob(".*partial*"))


def test_a_signal_raised_inside_a_gc_callback_is_sent_again_not_lost(monkeypatch):
    """A SIGTERM whose exception landed in XLA's gc callback was printed as "Exception
    ignored" and lost: the command ran to its end, exit 0. The command's unraisable hook sends
    the signal again, so it lands in the command's own code."""
    import signal
    import time

    import jaxnav

    class Collected:
        def __del__(self):
            jaxnav.raise_stopped(signal.SIGTERM, None)  # as the handler, inside a __del__

    monkeypatch.setattr("sys.unraisablehook", jaxnav._stopped_unraisable)
    previous = signal.signal(signal.SIGTERM, jaxnav.raise_stopped)
    try:
        with pytest.raises(jaxnav.Stopped) as e:
            Collected()  # collected at once: its exception goes to the unraisable hook
            time.sleep(5)  # the signal sent again ends the wait
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert e.value.signum == signal.SIGTERM


@pytest.mark.parametrize(
    "argv",
    [
        ["evaluate", "--seed", "1" * 30],
        ["render", "--seed", str(2**31)],
        ["experiments", "generalization", "RUN", "--seed", "1" * 30],
        ["experiments", "generalization", "RUN", "--family", "NoSuchEnv-v0 size=5"],
    ],
)
def test_seeds_beyond_32_bits_and_unknown_family_envs_are_one_line(argv, trained, tmp_path, capsys):
    """A seed too large for jax.random.key was an OverflowError traceback; a family of an
    unknown env id was skipped with exit 0."""
    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.experiments import main as experiments_main
    from jaxnav.render import main as render_main

    main = {"evaluate": evaluate_main, "render": render_main, "experiments": experiments_main}
    command, *rest = argv
    rest = [str(trained) if a == "RUN" else a for a in rest]
    if command != "experiments":
        rest = [str(trained), *rest]
    out = tmp_path / ("out.png" if command == "render" else "out")
    err = one_line_error(capsys, 2, main[command]([*rest, "--out", str(out)]))
    assert ("must be in [0, 2147483647]" in err) or ("unknown env id 'NoSuchEnv-v0'" in err), err
    assert not out.exists()


@pytest.mark.parametrize(
    "case", ["render missing run", "render empty pretrained", "export run a file",
             "evaluate config not UTF-8", "pretrained add a FIFO"],
)  # fmt: skip
def test_errors_name_the_input_at_fault_not_a_path_made_from_it(case, trained, tmp_path, capsys):
    """The red team's misattributed lines: a missing run blamed on render's default --out,
    --pretrained '' on --out '.gif', a file as RUN called "no such directory", a config.json
    that is not UTF-8 without its path, a FIFO given to pretrained add "no such file"."""
    import os

    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.export import main as export_main
    from jaxnav.pretrained.__main__ import main as pretrained_main
    from jaxnav.render import main as render_main

    missing, afile, fifo = tmp_path / "missing", tmp_path / "afile", tmp_path / "p.npz"
    afile.write_text("x")
    os.mkfifo(fifo)
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    (run / "config.json").write_bytes(b"\x00\xffgarbage")
    command, argv, want = {
        "render missing run": (render_main, [str(missing)], f"{missing}: not a run directory"),
        "render empty pretrained": (
            render_main, ["--pretrained", ""], "--pretrained '': empty; give a shipped"
        ),
        "export run a file": (export_main, [str(afile)], f"{afile}: not a run directory (not a"),
        "evaluate config not UTF-8": (
            evaluate_main, [str(run)], f"{run / 'config.json'}: unreadable run config"
        ),
        "pretrained add a FIFO": (
            pretrained_main, ["add", "x", str(fifo), "--command", "c"],
            f"{fifo}: not a regular file",
        ),
    }[case]  # fmt: skip
    err = one_line_error(capsys, 2, command(argv))
    assert want in err, err


# ------------------------------------------------------------------ 8. the programs cache
class Planted:
    """A pickle that, when loaded, creates a file: what a hostile cache entry could do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.mark.slow
def test_a_cache_directory_others_can_write_is_not_used_and_nothing_is_unpickled(
    tmp_path, capsys, monkeypatch
):
    import os
    import pickle

    flags = [*TINY_FLAGS, "--total-timesteps", "64", "--eval-episodes", "2"]
    root = tmp_path / "cache"
    monkeypatch.setenv("JAXNAV_CACHE_DIR", str(root))
    assert train_main([*flags, "--out", str(tmp_path / "a")]) == 0
    (entry,) = list((root / "programs").iterdir())
    marker = tmp_path / "code-ran"
    (entry / "programs.pkl").write_bytes(pickle.dumps(Planted(marker)))
    os.chmod(root, 0o777)  # e.g. a shared directory: anyone could have planted that entry
    capsys.readouterr()
    assert train_main([*flags, "--out", str(tmp_path / "b")]) == 0
    out, err = capsys.readouterr()
    assert not marker.exists()
    assert "from the cache" not in out
    (warning,) = [line for line in err.splitlines() if "JAXNAV_CACHE_DIR" in line]
    assert f"{root} is writable by other users (mode 777)" in warning, warning
    assert "not used" in warning


# ------------------------------------------------------------------ 8. the deployment layer
@pytest.fixture(scope="module")
def laser_policy_metadata() -> dict:
    from jaxnav import export
    from jaxnav.config import TrainConfig
    from jaxnav.train import Trainer

    config = TrainConfig(
        env="RobotSimple-v0", env_kwargs={"backend": "kinematic"}, hidden_sizes=(8,)
    )
    return export.policy_metadata(Trainer(config))


def test_scan_values_that_used_to_crash_or_pass_are_refused_in_one_line(laser_policy_metadata):
    """A range_max given as text crashed inside numpy; 2-D ranges, a negative beam width and
    a pose or goal beyond float32 (a frame or unit mix-up) gave observations of inf."""
    from jaxnav.deploy.sensors import LaserScan, ScanObservation

    scan = dict(
        angle_min=-3.14159, angle_increment=2 * 3.14159 / 360, range_min=0.1, range_max=10.0
    )
    ranges = [1.0] * 360
    build = ScanObservation(laser_policy_metadata)
    at, goal = (1.0, 1.0, 0.0), (2.0, 2.0)
    cases = {
        "range_max='10'": (LaserScan(**{**scan, "range_max": "x"}, ranges=ranges), at, goal),
        "ranges of shape (1, 360)": (LaserScan(**scan, ranges=[ranges]), at, goal),
        "robot_x=1e+300": (LaserScan(**scan, ranges=ranges), (1e300, 1.0, 0.0), goal),
        "goal_x=-1e+40": (LaserScan(**scan, ranges=ranges), at, (-1e40, 2.0)),
    }
    for name, args in cases.items():
        want = name.split("=")[0] if name.startswith("range_max") else name
        with pytest.raises(ValueError, match=re.escape(want)) as e:
            build(*args)
        assert "\n" not in str(e.value)
    narrow = ScanObservation(laser_policy_metadata, beam_width=-0.1)
    with pytest.raises(ValueError, match=r"beam_width=-0.1: must be a width >= 0"):
        narrow(LaserScan(**scan, ranges=ranges), at, goal)
    # range_max=inf stays allowed, as documented
    obs = build(LaserScan(**{**scan, "range_max": float("inf")}, ranges=ranges), at, goal)
    assert obs.dtype.name == "float32" and bool((abs(obs) < 1e6).all())


def test_policy_refuses_observations_beyond_float32_or_not_real():
    """1e39 is finite in float64 and inf in the float32 the network computes in: its action
    came from inf Q-values; complex numbers lost their imaginary part with a warning."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxnav import export
    from jaxnav.config import TrainConfig
    from jaxnav.deploy.policy import Policy
    from jaxnav.train import Trainer

    trainer = Trainer(TrainConfig(env="GridMaze-v0", env_kwargs={"size": 5}, hidden_sizes=(8,)))
    params = trainer.network.init(jax.random.key(0), jnp.zeros((1, trainer.obs_size)))
    policy = Policy(export.policy_arrays(trainer.network, params), export.policy_metadata(trainer))
    n = policy.obs_size
    with pytest.raises(ValueError, match=r"observation\[3\]=1e\+39: beyond float32"):
        policy.act(np.r_[np.zeros(3), 1e39, np.zeros(n - 4)])
    for bad in (np.zeros(n, complex), np.array(["1"] * n), [None] * n):
        with pytest.raises(ValueError, match="observation: must be real numbers"):
            policy.act(bad)
    assert policy.act(np.zeros(n, np.int64)) in range(4)  # integers and bools are numbers
