"""Hostile input (hypothesis): random and malformed command lines, env overrides and maze
files get a clean answer (one line naming the value, exit code 2, nothing written) or a valid
run; never a traceback, a hang or a partial run directory."""

from __future__ import annotations

import contextlib
import io
import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY_FLAGS  # pytest puts tests/ on sys.path
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import jaxnav
from jaxnav import run_dir
from jaxnav.cli import UsageError
from jaxnav.envs.grid_maze import GridMazeConfig
from jaxnav.envs.robot.env import RobotConfig
from jaxnav.train.__main__ import main as train_main
from jaxnav.train.__main__ import prepare_training

# a run small enough to train in a second or two; fuzzed flags come after and override it
BASE = [*TINY_FLAGS, "--total-timesteps", "64", "--eval-episodes", "4"]

INT_FLAGS = [
    "--seed", "--num-seeds", "--total-timesteps", "--num-envs", "--buffer-size", "--batch-size",
    "--learning-starts", "--n-step", "--target-update-period",
    "--eps-decay-steps", "--log-interval", "--eval-episodes", "--checkpoint-every",
    "--keep-checkpoints",
]  # fmt: skip
FLOAT_FLAGS = [
    "--gamma",
    "--lr",
    "--lr-end",
    "--max-grad-norm",
    "--tau",
    "--eps-start",
    "--eps-end",
    "--replay-ratio",
]
CHOICES = {
    "--env": jaxnav.registered_envs(),
    "--loss": ["huber", "mse"],
    "--optimizer": ["adam", "sgd"],
    "--dueling": ["true", "false"],
    "--double": ["true", "false"],
}
ENV_KEYS = sorted(
    {f for cfg in (GridMazeConfig, RobotConfig) for f in cfg.__dataclass_fields__} | {"colour"}
)

junk = st.sampled_from(
    ["", "abc", "1e3", "0x10", "nan", "inf", "-inf", "1.5", " 3", "1_000", "--", "None", "[1]",
     "\u0663", "-0", "+7", "1,2", "true"]
) | st.text(max_size=6)  # fmt: skip
small_int = st.sampled_from([0, 1, 2, 3, 4, 8, 16, 32, 64, 100])
any_int = st.one_of(small_int, st.integers(-(2**40), 2**40)).map(str)
any_float = st.one_of(
    st.sampled_from([0.0, 0.5, 0.9, 1.0, 1e-3, 10.0]), st.floats(allow_nan=True), st.integers()
).map(str)
env_value = st.one_of(
    st.sampled_from(
        ['0', '1', '5', '7', '-1', '0.5', '1e9', 'NaN', 'Infinity', 'true', 'null', '[]', '{}',
         '"x"', 'paper', 'index', 'onehot', 'sensor', 'kinematic', 'mjx', 'simple', 'random', '256']
    ),
    st.integers(-(10**7), 10**7).map(str),
    st.text(max_size=6),
)  # fmt: skip
flag_and_value = st.one_of(
    st.tuples(st.sampled_from(INT_FLAGS), st.one_of(any_int, junk)),
    st.tuples(st.sampled_from(FLOAT_FLAGS), st.one_of(any_float, junk)),
    st.sampled_from(sorted(CHOICES)).flatmap(
        lambda f: st.tuples(st.just(f), st.one_of(st.sampled_from(CHOICES[f]), junk))
    ),
    st.tuples(
        st.just("--hidden-sizes"),
        st.one_of(
            st.lists(st.integers(-4, 70000), max_size=4).map(lambda v: ",".join(map(str, v))), junk
        ),
    ),
    st.tuples(
        st.just("--env-arg"),
        st.one_of(st.tuples(st.sampled_from(ENV_KEYS), env_value).map("=".join), junk),
    ),
    st.tuples(st.sampled_from(["--bogus", "--resume", "--maze-file", "-x", "--seed="]), junk),
)


def outcome(argv: list[str]) -> tuple[int, str]:
    """``train_main``'s exit code and stderr, in a fresh directory that must stay clean on
    error; the run directory is checked for completeness on success."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = train_main([*argv, "--out", str(out)])
        left = sorted(p.name for p in Path(tmp).iterdir())
        if code == 0:
            assert left == ["run"], left  # complete, renamed, no partial directory
            assert {"config.json", "metrics.csv", "params", "summary.json"} <= {
                p.name for p in out.iterdir()
            }
        elif code == 3:  # a legitimately diverging config: its last good state is kept
            assert left == [run_dir.partial_dir(out).name], left
        else:
            assert code == 2 and left == [], (code, left)
        return code, err.getvalue()


RUN_LIMIT = 3  # end-to-end runs per session (each compiles); later valid ones are validated
TRAINED: list[list[str]] = []


def cheap(config) -> bool:
    """Valid configs run end to end only when they train in a second or two."""
    kw = config.env_kwargs
    return (
        config.env.startswith("GridMaze")
        and config.num_seeds * config.iterations * config.num_envs <= 1024
        and config.num_envs <= 32
        and config.buffer_size <= 4096
        and config.batch_size <= 64
        and (config.algo == "pqn" or config.updates_per_iteration <= 4)
        and config.n_step <= 8
        and len(config.hidden_sizes) <= 2
        and max(config.hidden_sizes) <= 64
        and config.eval_episodes <= 32
        and kw.get("size", 15) <= 9
        and kw.get("num_layouts", 1024) * kw.get("goals_per_layout", 16) <= 20_000
        and kw.get("sensor_radius", 2) <= 4
    )


@pytest.mark.slow  # 150 command lines through the CLI
@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(extra=st.lists(flag_and_value, min_size=1, max_size=4))
def test_random_command_lines_give_a_clean_error_or_a_valid_run(extra):
    argv = [*BASE, *(x for pair in extra for x in pair)]
    try:
        args, config, *_ = prepare_training([*argv, "--out", "/nonexistent/never/written"])
    except (UsageError, ValueError) as e:
        message = str(e)
        assert message and "\n" not in message
        code, err = outcome(argv)
        assert code == 2 and err.count("\n") == 1 and err.startswith("jaxnav.train: error: ")
        event("refused")
        return
    if args.resume is None and cheap(config) and len(TRAINED) < RUN_LIMIT:
        code, err = outcome(argv)
        TRAINED.append(argv)
        assert code in (0, 3), err
        event("trained" if code == 0 else "diverged")
    else:
        event("validated only")  # valid but too big to train here; nothing was written


# ------------------------------------------------------------------------ maze files
maze_text = st.one_of(
    st.text(alphabet="#.SG\n", max_size=120),
    st.lists(st.text(alphabet="#.#..", min_size=3, max_size=8), min_size=1, max_size=8).map(
        lambda rows: "\n".join(rows)
    ),
    st.text(alphabet="#.SGx ;:\t\r\ncel_sz0123456789.-e", max_size=160),
    st.builds(
        lambda header, rows: header + "\n".join(rows),
        st.sampled_from(
            [
                "",
                "cell_size: 1.0\n",
                "cell_size: 0\n",
                "cell_size: nan\n",
                "cell_size: 1e-9\n",
                "; comment\n",
                "cell_size: 2\ncell_size: 3\n",
            ]
        ),
        st.lists(st.text(alphabet="#..SG", min_size=2, max_size=6), min_size=1, max_size=6),
    ),  # fmt: skip
)


@settings(max_examples=150, deadline=None)
@given(content=st.one_of(maze_text.map(str.encode), st.binary(max_size=64)))
def test_random_maze_files_give_an_error_naming_the_file_or_a_valid_env(content):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "maze.txt"
        path.write_bytes(content)
        # the kinematic backend: building the MJX model is beside the point here
        argv = ["--maze-file", str(path), "--env-arg", "backend=kinematic"]
        try:
            *_, trainer = prepare_training([*argv, "--out", str(Path(tmp) / "run")])
        except (UsageError, ValueError) as e:
            message = str(e)
            assert "\n" not in message and str(path) in message, message
            event("refused")
        else:  # a valid maze: robot and goal start in free space, lasers in range
            env, params = trainer.env, trainer.env_params
            bank = params.bank
            assert int(bank.num_free.min()) >= 2
            assert np.isfinite(np.asarray(bank.free_xy)).all()
            assert env.observation_space(params).shape == (trainer.obs_size,)
            event("accepted")
        assert sorted(p.name for p in Path(tmp).iterdir()) == ["maze.txt"]  # nothing written
