"""Fault injection, round two: hostile values that used to pass validation and fail later (NaN
observations, silent float32 overflow, shape tracebacks, memory errors after ``.partial``,
flax tracebacks, starts inside walls, a wrong exit code, a cache that runs code). Each ends in
one line naming the value (exit 2 for the commands). Tiny configs."""

from __future__ import annotations

import re

import pytest
from conftest import TINY_FLAGS  # pytest puts tests/ on sys.path

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
