"""A new user's first hour (issue 19): each documented command does what it says."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from matplotlib.figure import Figure

from jaxnav import render
from jaxnav.cli import Parser, UsageError, add_env_args
from jaxnav.evaluate.__main__ import main as evaluate_main
from jaxnav.evaluate.__main__ import parser as evaluate_parser
from jaxnav.train.__main__ import main as train_main
from tests.conftest import TINY_FLAGS

README = Path(__file__).resolve().parents[1] / "README.md"
STEPS = ["--total-timesteps", "64", "--eval-episodes", "4"]
MAZE = "cell_size: 1.0\n#####\n#S..#\n#...#\n#..G#\n#####\n"
OTHER_MAZE = "cell_size: 1.0\n########\n#......#\n#.####.#\n#......#\n########\n"
ROBOT = [
    "--hidden-sizes", "16", "--num-envs", "4", "--batch-size", "8", "--replay-ratio", "2",
    "--buffer-size", "64",
    "--learning-starts", "8", "--log-interval", "32", "--n-step", "1",
    "--env-arg", "backend=kinematic", "--quiet", *STEPS,
]  # fmt: skip


@pytest.fixture(scope="module")
def grid_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "grid"
    assert train_main([*TINY_FLAGS, *STEPS, "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def robot_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("robot")
    (root / "maze.txt").write_text(MAZE)
    (root / "other.txt").write_text(OTHER_MAZE)
    out = root / "run"
    assert train_main([*ROBOT, "--maze-file", str(root / "maze.txt"), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def generalist_run(tmp_path_factory):
    """A tiny RobotNav-v0 run (32 lasers all around, no absolute positions, a waypoint)."""
    root = tmp_path_factory.mktemp("generalist")
    (root / "maze.txt").write_text(OTHER_MAZE)
    out = root / "run"
    flags = [*ROBOT, "--env", "RobotNav-v0", "--env-arg", "num_layouts=2", "--out", str(out)]
    assert train_main(flags) == 0
    return out


def test_a_run_takes_its_sensors_to_another_maze(generalist_run, monkeypatch, capsys):
    maze = generalist_run.parent / "maze.txt"
    out = generalist_run.parent / "on-maze.json"
    argv = [str(generalist_run), "--maze-file", str(maze), "--episodes", "2"]
    assert evaluate_main([*argv, "--out", str(out)]) == 0
    kwargs = json.loads(out.read_text())["env_kwargs"]
    assert kwargs["maze_file"] == str(maze) and kwargs["num_lasers"] == 32
    assert kwargs["laser_fov"] == 360.0 and kwargs["obs_absolute"] is False
    drawn = []
    monkeypatch.setattr(
        render, "trajectories_figure", lambda eps, title: drawn.append(eps) or empty_figure()
    )
    png = generalist_run.parent / "t.png"
    assert render.main([*argv[:3], "--episodes", "1", "--out", str(png)]) == 0
    assert [float(v) for v in drawn[0][0]["arena"]] == [8.0, 5.0]  # the maze file's
    # a sensor the user changes explicitly is refused, naming it
    capsys.readouterr()
    for command in (evaluate_main, render.main):
        assert command([*argv[:3], "--env-arg", "num_lasers=8", "--out", str(png)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--env-arg num_lasers=8" in err
        assert "num_lasers=32" in err


@pytest.mark.slow
def test_render_draws_the_maze_file_it_is_given(robot_run, monkeypatch, tmp_path):
    drawn = []
    monkeypatch.setattr(
        render, "trajectories_figure", lambda eps, title: drawn.append(eps) or empty_figure()
    )
    other = robot_run.parent / "other.txt"
    png = tmp_path / "t.png"
    assert render.main([str(robot_run), "--episodes", "1", "--maze-file", str(other),
                        "--out", str(png)]) == 0  # fmt: skip
    # OTHER_MAZE is 8 x 5 cells of 1 m; the training maze 5 x 5
    assert [float(v) for v in drawn[0][0]["arena"]] == [8.0, 5.0]


def empty_figure() -> Figure:
    """An empty real figure for a stubbed drawing: render saves and closes it as its own."""
    return Figure()


def test_readme_does_not_promise_fixed_start_and_goal_cells():
    text = " ".join(README.read_text().split())
    assert "(start and goal cells)" not in text
    assert "they do not fix the start or the goal" in text


def test_evaluations_of_other_policies_and_envs_keep_their_own_files(grid_run, capsys):
    assert evaluate_main([str(grid_run), "--episodes", "8"]) == 0
    greedy = (grid_run / "eval.json").read_text()
    assert evaluate_main([str(grid_run), "--episodes", "8", "--policy", "random"]) == 0
    assert evaluate_main([str(grid_run), "--episodes", "8", "--env-arg", "layout_seed=3"]) == 0
    assert (grid_run / "eval.json").read_text() == greedy
    assert json.loads((grid_run / "eval-random.json").read_text())["policy"] == "random"
    other = json.loads((grid_run / "eval-trained-layout_seed=3.json").read_text())
    assert other["env_kwargs"]["layout_seed"] == 3


@pytest.mark.slow  # renders an episode end to end
def test_render_writes_into_the_run_by_default(grid_run, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert render.main([str(grid_run), "--episodes", "1"]) == 0
    assert (grid_run / "traj.gif").is_file() and not list(tmp_path.iterdir())


def test_total_timesteps_are_rounded_up_to_whole_intervals_in_one_line(tmp_path, capsys):
    out = tmp_path / "r"
    flags = [*TINY_FLAGS, "--total-timesteps", "100", "--checkpoint-every", "40"]
    assert train_main([*flags, "--eval-episodes", "0", "--out", str(out)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert "--total-timesteps 100 rounded up to 128 (4 logging intervals of 32 env steps)" in said
    assert "--checkpoint-every 40 rounded to 32 (1 logging interval of 32 env steps)" in said
    doc = json.loads((out / "config.json").read_text())
    assert doc["config"]["total_timesteps"] == 128  # the steps it trained
    assert doc["checkpointing"]["checkpoint_every"] == 32
    assert (out / "metrics.csv").read_text().splitlines()[-1].split(",")[1] == "128"


def test_a_robot_run_of_a_million_steps_trains_five_intervals():
    from jaxnav.train.__main__ import prepare_training

    argv = ["--env", "RobotSimple-v0", "--algo", "pqn", "--total-timesteps", "1000000"]
    _, config, *_, notes, _ = prepare_training([*argv, "--out", "never-written"])
    assert config.total_timesteps == 1_024_000 and config.num_logs == 5
    assert notes == [
        "--total-timesteps 1000000 rounded up to 1024000 (5 logging intervals of 204800 env steps)"
    ]


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (["--total-timesteps", "-5"], "total_timesteps=-5"),
        (["--total-timesteps", "2000000001"], "total_timesteps=2000000001"),
        (["--total-timesteps", "1999999999", "--log-interval", "1500000000"], "exceeds"),
        (["--total-timesteps", "128", "--checkpoint-every", "0"], "--checkpoint-every 0"),
    ],
)
def test_step_counts_out_of_range_are_still_refused(flags, named, tmp_path, capsys):
    assert train_main([*TINY_FLAGS, *flags, "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and named in err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    ("env", "algo"),
    [
        (e, a)
        for e in ("GridMaze-v0", "RobotSimple-v0", "RobotNav-v0")
        for a in ("dqn", "pqn", "ppo")
    ],
)
def test_presets_train_whole_logging_intervals(env, algo):
    from jaxnav.config import TrainConfig

    config = TrainConfig.for_env(env, algo=algo)
    assert config.whole_intervals() == (config, "")


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--num-seed", "2"], "unrecognized arguments: --num-seed 2"),
        (["--backend", "kinematic"], "did you mean --env-arg backend=kinematic"),
        (["--obs-mode=paper"], "did you mean --env-arg obs_mode=paper"),
    ],
)
def test_no_abbreviated_flags_and_env_fields_get_a_hint(args, named, tmp_path, capsys):
    assert train_main([*args, "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and named in err


def test_parsers_never_abbreviate():
    p = Parser(prog="x")
    p.add_argument("--num-seeds", type=int)
    add_env_args(p)
    with pytest.raises(UsageError, match="--num-seed"):
        p.parse_args(["--num-seed", "5"])


def test_an_unfinished_run_says_so_and_how_to_finish_it(grid_run, tmp_path, capsys):
    out = tmp_path / "run"
    partial = tmp_path / ".run.partial"
    shutil.copytree(grid_run, partial)
    shutil.rmtree(partial / "params")
    (partial / "checkpoints").mkdir()
    for run in (out, partial):
        assert evaluate_main([str(run), "--episodes", "4"]) == 2
        err = capsys.readouterr().err
        assert "unfinished run" in err and f"--resume {out}" in err and err.count("\n") == 1
        assert "not found" not in err


def test_help_says_each_default_once_and_names_real_sections():
    text = evaluate_parser().format_help()
    flat = " ".join(text.split())
    assert "(default: None)" not in flat and "RUN/eval.json" in flat
    assert "test episodes per seed (default: 1000)" in flat
    assert "README: Mazes" not in flat and "README: Robot mazes" in flat
    assert "### Robot mazes" in README.read_text()
    assert "frames per second" in render.parser().format_help()


def test_progress_line_says_its_success_is_epsilon_greedy(tmp_path, capsys):
    flags = [*TINY_FLAGS, *STEPS, "--out", str(tmp_path / "r")]
    flags.remove("--quiet")
    assert train_main(flags) == 0
    out = capsys.readouterr().out
    assert "train success (eps-greedy)" in out and "trained (greedy)" in out
    # units: episode length in env steps, times in seconds
    progress = [line for line in out.splitlines() if line.startswith("[")]
    assert progress and all(" steps | " in line and "s] steps" in line for line in progress)
    assert all("length" in line and line.split("length")[1].split("|")[0].strip().endswith(
        "steps") for line in progress)
    # one maze: the worst 10% of mazes is n/a, not the success rate again
    header = next(line for line in out.splitlines() if line.startswith("| policy |"))
    row = next(line for line in out.splitlines() if line.startswith("| trained (greedy) |"))
    cells = dict(zip(header.split("|"), row.split("|"), strict=True))
    assert cells[" worst10_success "].strip() == "n/a"


def test_no_final_evaluation_finishes_with_nulls_not_zeros(tmp_path, capsys):
    flags = [*TINY_FLAGS, *STEPS, "--eval-episodes", "0", "--out", str(tmp_path / "r")]
    flags.remove("--quiet")
    assert train_main(flags) == 0
    assert "no final evaluation" in capsys.readouterr().out
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["trained"] is summary["random_policy"] is summary["trained_per_seed"] is None


@pytest.mark.slow
def test_robot_evaluation_measures_path_ratio_or_says_n_a(robot_run, capsys):
    assert evaluate_main([str(robot_run), "--episodes", "20"]) == 0
    result = json.loads((robot_run / "eval.json").read_text())
    assert result["mean_path_ratio"] is None or result["mean_path_ratio"] > 0.5


def test_wide_intervals_print_their_seed_count(capsys):
    from jaxnav.experiments import mean_ci, print_rows

    row = {"success_rate": mean_ci([0.5, 0.5]), "mean_return": mean_ci([1.0, 1.1]),
           "mean_steps": mean_ci([4.0, 40.0, None])}  # fmt: skip
    print_rows("s", {"random": row})
    out = capsys.readouterr().out
    assert "(n=2)" in out and out.count("(n=") == 1


def read_events(directory):
    """``{tag: [(step, value)]}`` of the event files in ``directory``, read as TensorBoard
    reads them: TFRecord frames (length, its CRC, the Event proto, its CRC)."""
    import struct

    from tensorboardX.proto import event_pb2

    scalars = {}
    for path in sorted(Path(directory).glob("events.out.tfevents.*")):
        data = path.read_bytes()
        i = 0
        while i < len(data):
            (n,) = struct.unpack("<Q", data[i : i + 8])
            event = event_pb2.Event.FromString(data[i + 12 : i + 12 + n])
            i += 12 + n + 4
            for v in event.summary.value:
                scalars.setdefault(v.tag, []).append((event.step, v.simple_value))
    return scalars


def test_tensorboard_event_files_hold_the_metrics_csv(tmp_path):
    import csv

    pytest.importorskip("tensorboardX")  # the dev extra has it; make test installs it
    out = tmp_path / "run"
    flags = [*TINY_FLAGS, *STEPS, "--num-seeds", "2", "--tensorboard", "--out", str(out)]
    assert train_main(flags) == 0
    scalars = read_events(out / "tensorboard")
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    seed1 = [(int(r["env_steps"]), float(r["success_rate"])) for r in rows if r["seed"] == "1"]
    assert [s for s, _ in scalars["seed1/success_rate"]] == [s for s, _ in seed1]
    assert [v for _, v in scalars["seed1/success_rate"]] == pytest.approx([v for _, v in seed1])
    assert [s for s, _ in scalars["train/loss"]] == [32, 64]


def test_missing_logging_packages_are_one_line_errors(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # import fails as if not installed
    monkeypatch.setitem(sys.modules, "wandb", None)
    for flag, named in (("--tensorboard", "tensorboard]"), ("--wandb", "pip install wandb")):
        assert train_main([*TINY_FLAGS, *STEPS, flag, "--out", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"{flag}: " in err and named in err
    assert not any(tmp_path.iterdir())


def test_wandb_gets_each_interval_when_asked(tmp_path, monkeypatch):
    import sys
    import types

    logged, runs = [], []

    class Run:
        def log(self, data, step):
            logged.append((step, data))

        def finish(self):
            runs.append("finished")

    fake = types.SimpleNamespace(init=lambda **kw: runs.append(kw) or Run())
    monkeypatch.setitem(sys.modules, "wandb", types.ModuleType("wandb"))
    monkeypatch.setattr(sys.modules["wandb"], "init", fake.init, raising=False)
    out = tmp_path / "run"
    assert train_main([*TINY_FLAGS, *STEPS, "--wandb", "--out", str(out)]) == 0
    assert runs[0]["name"] == "run" and runs[0]["config"]["total_timesteps"] == 64
    assert runs[-1] == "finished" and [s for s, _ in logged] == [32, 64]
    assert "train/success_rate" in logged[0][1]


def test_a_single_run_is_plotted_from_its_metrics(grid_run, capsys):
    from PIL import Image

    from jaxnav.experiments import main as experiments_main

    assert experiments_main(["plot", str(grid_run)]) == 0
    with Image.open(grid_run / "training_curves.png") as img:
        assert img.format == "PNG" and img.size[0] > 1000


def test_step_ticks_are_few_and_short():
    import matplotlib.pyplot as plt

    from jaxnav.plots import steps_axis

    fig, ax = plt.subplots()
    ax.plot([10_000, 600_000], [0, 1])
    steps_axis(ax)
    fig.canvas.draw()
    lo, hi = ax.get_xlim()
    labels = [t.get_text() for t in ax.get_xticklabels() if lo <= t.get_position()[0] <= hi]
    assert 2 <= len(labels) <= 6 and all(len(t) <= 5 for t in labels), labels
    plt.close(fig)


@pytest.mark.slow
def test_pictures_for_papers_vector_legend_outside_metre_scale_visible_robot(robot_run, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.patches import Circle

    svg = tmp_path / "t.svg"
    assert render.main([str(robot_run), "--episodes", "2", "--out", str(svg)]) == 0
    assert svg.read_text().lstrip().startswith("<?xml") and "<svg" in svg.read_text()

    captured = []
    original = render.trajectories_figure

    def keep(episodes, title=""):
        captured.append(original(episodes, title))
        return captured[-1]

    png = tmp_path / "t.png"
    with pytest.MonkeyPatch.context() as m:
        m.setattr(render, "trajectories_figure", keep)
        assert render.main([str(robot_run), "--episodes", "2", "--out", str(png)]) == 0
    fig = captured[0]
    ax = fig.axes[0]
    assert fig.legends and ax.get_legend() is None  # one legend, outside the mazes
    assert ax.get_xlabel() == "m" and len(ax.get_xticks()) >= 3  # a metre scale
    width = max(ax.get_xlim()[1], ax.get_ylim()[1])
    circles = [p for p in ax.patches if isinstance(p, Circle) and not p.get_fill()]
    assert circles and circles[0].get_radius() >= 0.02 * width  # the robot, large enough
    assert any(type(c).__name__ == "Annotation" for c in ax.get_children())  # its heading


def test_a_second_ctrl_c_says_it_stops_without_saving():
    import os
    import signal
    import subprocess
    import sys

    script = (
        "import os, signal, time\n"
        "from jaxnav import runner\n"
        "with runner.stop_on_signals([]):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(5)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(README.parent)}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert done.returncode == -signal.SIGINT
    assert "saving a checkpoint after this logging interval" in done.stderr
    assert "SIGINT again: stopping now without saving" in done.stderr


def test_experiment_tables_state_their_units():
    from jaxnav.experiments import LABELS, METRICS, results_markdown

    agent = next(iter(LABELS))
    row = {m: {"mean": 1.0, "ci95": None, "seeds": 1} for m in METRICS}
    record = {"env": "GridMaze-v0", "metrics": {"env_steps": [[64]]}, "compile_s": 1.0,
              "train_s": 2.0}  # fmt: skip
    results = {
        "experiment": "paper-grid", "seeds": [0], "command": "x", "wall_s": 3.0,
        "suites": {"grid": {"agents": {agent: row}}},
        "training": {"grid": {agent: record}},
    }  # fmt: skip
    table = results_markdown(results)
    assert "mean steps (successes)" in table and "mean episode length (steps)" in table
    assert "compile s | train s" in table and "Wall time 3 s" in table


def test_statistics_no_seed_measured_are_not_printed(capsys):
    from jaxnav.evaluate import print_seed_statistics, seed_statistics

    stats = {"success_rate": [0.9, 1.0], "worst10_success": [None, None]}
    print_seed_statistics({k: seed_statistics(v) for k, v in stats.items()})
    out = capsys.readouterr().out
    assert "success_rate over 2 seeds" in out and "worst10_success" not in out


def test_the_random_agent_has_no_intervals_over_seeds(tmp_path, capsys):
    out = tmp_path / "two"
    assert train_main([*TINY_FLAGS, *STEPS, "--num-seeds", "2", "--out", str(out)]) == 0
    capsys.readouterr()
    assert evaluate_main([str(out), "--episodes", "8"]) == 0
    assert "success_rate over 2 seeds" in capsys.readouterr().out
    assert evaluate_main([str(out), "--episodes", "8", "--policy", "random"]) == 0
    assert "over 2 seeds" not in capsys.readouterr().out


def test_readme_commands_run_as_written_no_placeholders():
    """Each line of the README's and docs' bash blocks is a command to paste: no RUN or PATH
    to fill."""
    pages = [README, *sorted((README.parent / "docs").glob("*.md"))]
    blocks = [b for page in pages for b in page.read_text().split("```bash")[1:]]
    lines = [ln for b in blocks for ln in b.split("```")[0].splitlines() if ln.strip()]
    assert len(lines) > 10
    for line in lines:
        words = line.split("#")[0].split()
        holes = [w for w in words if "=" not in w and w.isupper() and len(w) > 2]
        assert not holes, f"{line!r}: fill in {holes}"
