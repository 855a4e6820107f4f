"""Maze layouts of the robot environments: the text format and its errors, wall boxes, the
built-in and random mazes, and batching."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import bfs_distances
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxnav.envs.robot import generators as G
from jaxnav.envs.robot import mazes as M
from jaxnav.envs.robot.env import GENERALIST


def inside(walls: M.Walls, pts: np.ndarray, active_only: bool = False) -> np.ndarray:
    """bool[P]: whether each point is strictly inside some box (of any slot, or active ones)."""
    c, h = np.asarray(walls.center), np.asarray(walls.half_size)
    hit = np.all(np.abs(pts[:, None, :] - c[None]) < h[None], axis=-1)
    if active_only:
        hit &= np.asarray(walls.active)[None]
    return hit.any(axis=1)


def cell_samples(maze: M.Maze, cells: np.ndarray, rng: np.random.Generator, k: int = 8):
    """k points strictly inside each cell (away from its edges by 1% of a cell)."""
    lo = np.stack([cells[:, 1], maze.rows - 1 - cells[:, 0]], axis=1) * maze.cell_size
    u = rng.uniform(0.01, 0.99, size=(len(cells), k, 2))
    return (lo[:, None, :] + u * maze.cell_size).reshape(-1, 2)


def some_mazes() -> list[M.Maze]:
    return [
        M.builtin_maze("simple"),
        M.builtin_maze("complex"),
        M.parse_maze("cell_size: 0.25\n#..#\n.##.\n.#..\n##.#\n"),
        *M.random_maze_bank(3, rows=7, cols=9, cell_size=0.7, seed=5, wall_density=0.3),
    ]


# ------------------------------------------------------------------------------ parsing
def test_parse_header_comments_start_and_goal():
    text = "; my maze\ncell_size: 0.5\n\n; row comment\n#S..\n..#G\n; between rows\n....\n\n\n"
    m = M.parse_maze(text, name="t")
    assert m.cell_size == 0.5 and m.name == "t"
    np.testing.assert_array_equal(
        m.grid, [[True, False, False, False], [False, False, True, False], [False] * 4]
    )
    assert m.start == (0, 1) and m.goal == (1, 3)
    assert m.lines == (5, 6, 8)
    assert m.size_m == (2.0, 1.5)
    # row 0 is the top line of the text: y = (rows - 1 - row + 0.5) * cell_size
    assert m.cell_center(0, 0) == (0.25, 1.25)
    assert m.cell_center(2, 3) == (1.75, 0.25)
    assert m.cell_at(1.75, 0.25) == (2, 3)
    np.testing.assert_allclose(
        m.cell_centers(np.array([[0, 0], [2, 3]])), [[0.25, 1.25], [1.75, 0.25]]
    )


def test_parse_defaults_crlf_and_round_trip():
    m = M.parse_maze("..#\r\n...\r\n")
    assert m.cell_size == 1.0 and m.start is None and m.goal is None
    assert m.grid.shape == (2, 3) and m.grid[0, 2] and not m.grid.flags.writeable
    back = M.parse_maze(M.builtin_maze("complex").to_text())
    np.testing.assert_array_equal(back.grid, M.builtin_maze("complex").grid)
    assert back.cell_size == 0.5
    sg = M.parse_maze("S.\n.G\n")
    assert M.parse_maze(sg.to_text()).start == (0, 0) and M.parse_maze(sg.to_text()).goal == (1, 1)


def test_load_maze_from_file(tmp_path):
    path = tmp_path / "room.txt"
    path.write_text("cell_size: 2\nS...\n.##.\n...G\n")
    m = M.load_maze(path, num_slots=8)
    assert m.name == str(path) and m.cell_size == 2.0 and m.size_m == (8.0, 6.0)
    assert m.connected(m.start, m.goal)


def test_a_run_parses_its_maze_file_once(tmp_path, monkeypatch):
    """Preparing a training run validates the config several times and builds the env: one
    parse of the file; a changed file is read anew."""
    from jaxnav.train.__main__ import prepare_training

    path = tmp_path / "maze.txt"
    path.write_text(M.SIMPLE)
    parsed = []
    parse = M.parse_maze
    monkeypatch.setattr(
        M, "parse_maze", lambda text, name, **kw: parsed.append(name) or parse(text, name, **kw)
    )
    flags = ["--maze-file", str(path), "--env-arg", "backend=kinematic", "--num-envs", "4"]
    flags += ["--batch-size", "32"]  # the preset's replay ratio 8: one gradient step of 32
    args, config, *_, trainer = prepare_training([*flags, "--out", str(tmp_path / "run")])
    assert config.env == "RobotMaze-v0" and trainer.env.config.maze_file == str(path)
    assert parsed == [str(path)]
    M.load_maze(path)
    assert parsed == [str(path)]
    path.write_text(M.COMPLEX)  # another size
    assert M.load_maze(path).cell_size == 0.5 and parsed == [str(path)] * 2


def test_connectivity_helpers():
    m = M.parse_maze(".#.\n.#.\n...\n")
    assert m.connected((0, 0), (0, 2))
    d = bfs_distances(m.grid, (0, 0))
    assert d[0, 2] == 6 and d[0, 1] == -1
    walled = M.parse_maze("..#.\n..#.\n")
    assert not walled.connected((0, 0), (0, 3))
    # the largest region is where robots are placed
    np.testing.assert_array_equal(walled.placement_cells(), [[0, 0], [0, 1], [1, 0], [1, 1]])
    np.testing.assert_array_equal(len(walled.free_cells()), 6)


ERRORS = [
    # (file text, line, col or None, fragment of the message)
    ("...\n..\n", 2, 3, "ragged row: 2 cells, but the first row (line 1) has 3"),
    ("...\n....\n", 2, 4, "ragged row: 4 cells"),
    ("; c\n\n...\n...\n..\n", 5, 3, "ragged row"),
    ("..x\n...\n", 1, 3, "unknown character 'x'"),
    ("...\n.\t.\n", 2, 2, "unknown character '\\t'"),
    ("; header next\ncell_size: abc\n..\n", 2, 12, "cell_size 'abc' is not a number"),
    ("cell_size:   0\n..\n", 1, 14, "must be a positive number"),
    ("cell_size: -1.5\n..\n", 1, 12, "must be a positive number"),
    ("cell_size: nan\n..\n", 1, 12, "must be a positive number"),
    ("cell_size: inf\n..\n", 1, 12, "must be a positive number"),
    ("cell_size: 1\ncell_size: 2\n..\n", 2, 1, "second cell_size (first on line 1)"),
    ("size: 2\n..\n", 1, 1, "unknown header 'size'"),
    ("..\ncell_size: 2\n", 2, 1, "header after the grid"),
    ("S..\n..S\n", 2, 3, "second start 'S' (the first is at line 1, column 1)"),
    ("G..\n.G.\n", 2, 2, "second goal 'G' (the first is at line 1, column 1)"),
    ("; all walls\n###\n###\n", 2, None, "no free cell"),
    ("#.#\n###\n", 1, None, "only one free cell"),
    (".#.\n#.#\n", 1, None, "no two free cells are connected"),
    ("..\n\n..\n", 2, None, "blank line inside the grid"),
    ("; c\nS#.\n.#G\n", 2, 1, "no path from the start 'S' (line 2, column 1) to the goal 'G'"),
    ("..#\n.#S\n", 2, 3, "start 'S' is walled in"),
]


@pytest.mark.parametrize("text,line,col,fragment", ERRORS)
def test_load_errors_name_file_line_and_column(tmp_path, text, line, col, fragment):
    path = tmp_path / "bad.maze"
    path.write_text(text)
    with pytest.raises(M.MazeFileError) as e:
        M.load_maze(path)
    where = f"{path}:{line}" + (f":{col}" if col is not None else "")
    msg = str(e.value)
    assert msg.startswith(where + ": "), msg
    assert fragment in msg, msg
    assert (e.value.path, e.value.line, e.value.col) == (str(path), line, col)
    assert isinstance(e.value, ValueError)
    # parse_maze reports the same, under its name
    with pytest.raises(M.MazeFileError, match=f"^<string>:{line}"):
        M.parse_maze(text)


def test_file_level_errors(tmp_path):
    missing = tmp_path / "nope.txt"
    with pytest.raises(M.MazeFileError, match=f"^{missing}: cannot read the maze file"):
        M.load_maze(missing)
    empty = tmp_path / "empty.txt"
    empty.write_text("; nothing but a comment\n\n")
    with pytest.raises(M.MazeFileError, match=f"^{empty}: no maze grid"):
        M.load_maze(empty)
    binary = tmp_path / "bin.txt"
    binary.write_bytes(b"...\n.\xff.\n")
    with pytest.raises(M.MazeFileError, match=f"^{binary}:2:2: not UTF-8"):
        M.load_maze(binary)


def test_too_many_walls_for_the_slots(tmp_path):
    path = tmp_path / "walls.txt"
    # three separate boxes: line 3 col 1, line 3 col 4, line 5 col 2
    path.write_text("; three walls\n\n#..#\n....\n.#..\n")
    m = M.load_maze(path)
    assert m.num_boxes == 7
    assert m.walls(7).num_slots == 7
    with pytest.raises(M.MazeFileError) as e:
        M.load_maze(path, num_slots=6)
    assert str(e.value).startswith(f"{path}:5:2: too many walls for 6 wall slots")
    assert "7 boxes (4 boundary + 3 internal)" in str(e.value)
    assert str(e.value).endswith("use num_wall_slots=7")  # the option and the value that fits
    with pytest.raises(M.MazeFileError, match=f"^{path}:3:4: "):
        M.check_slots(m, 5)
    with pytest.raises(M.MazeFileError, match=f"^{path}:3:4: "):
        m.walls(5)
    with pytest.raises(ValueError, match="at least 4"):
        M.check_slots(m, 3)


# -------------------------------------------------------------------------------- walls
@pytest.mark.parametrize("index", range(6))
def test_walls_cover_exactly_the_wall_cells(index):
    maze = some_mazes()[index]
    walls = maze.walls(maze.num_boxes + 3)
    rng = np.random.default_rng(index)
    wall_cells = np.argwhere(maze.grid)
    assert inside(walls, cell_samples(maze, wall_cells, rng), active_only=True).all()
    # no point of a free cell is in any box, parked ones included
    free_pts = cell_samples(maze, maze.free_cells(), rng)
    assert not inside(walls, free_pts).any()
    centres = maze.cell_centers(maze.free_cells())
    assert not inside(walls, centres).any()
    # internal boxes do not overlap: their areas add up to the wall cells' area
    h = np.asarray(walls.half_size)[M.NUM_BOUNDARY : maze.num_boxes]
    np.testing.assert_allclose(
        (4 * h[:, 0] * h[:, 1]).sum(), len(wall_cells) * maze.cell_size**2, rtol=1e-5
    )


@pytest.mark.parametrize("index", range(6))
def test_boundary_walls_enclose_the_arena(index):
    maze = some_mazes()[index]
    w, h = maze.size_m
    walls = maze.walls(maze.num_boxes)
    boundary = M.Walls(
        center=walls.center[:4], half_size=walls.half_size[:4], active=walls.active[:4]
    )
    e = 1e-3
    t = np.linspace(-0.5, 1.5, 41)
    outside = np.concatenate(
        [
            np.stack([np.full_like(t, -e), t * h], 1),
            np.stack([np.full_like(t, w + e), t * h], 1),
            np.stack([t * w, np.full_like(t, -e)], 1),
            np.stack([t * w, np.full_like(t, h + e)], 1),
            [[-e, -e], [w + e, -e], [-e, h + e], [w + e, h + e]],
        ]
    )
    outside = outside[(outside[:, 0] >= -1.5) & (outside[:, 0] <= w + 1.5)]
    outside = outside[(outside[:, 1] >= -1.5) & (outside[:, 1] <= h + 1.5)]
    assert inside(boundary, outside).all()
    u = np.random.default_rng(0).uniform(e, 1 - e, size=(500, 2))
    assert not inside(boundary, u * np.array([w, h])).any()
    assert np.asarray(walls.active[:4]).all()


def test_parked_slots():
    maze = M.builtin_maze("simple")
    walls = maze.walls(16)
    active = np.asarray(walls.active)
    assert walls.center.shape == (16, 2) and walls.half_size.shape == (16, 2)
    assert walls.center.dtype == np.float32 and active.dtype == bool
    assert active.sum() == maze.num_boxes == 6 and active[:6].all()
    parked_c = np.asarray(walls.center)[~active]
    parked_h = np.asarray(walls.half_size)[~active]
    np.testing.assert_array_equal(parked_c, np.tile(M.PARKED_CENTER, (10, 1)))
    assert (parked_h <= 1e-3).all() and (parked_h > 0).all()
    # nowhere near the arena, its boundary walls included
    assert (np.abs(parked_c) - parked_h > 100).all()
    assert walls.min_half_size() == 0.5  # the parked slots' tiny size is left out


# ---------------------------------------------------------------------------- built-ins
@pytest.mark.parametrize("name", ["simple", "complex"])
def test_builtins_parse_and_are_connected(name):
    m = M.builtin_maze(name)
    assert m.size_m == (10.0, 10.0)
    free = m.free_cells()
    np.testing.assert_array_equal(m.placement_cells(), free)  # one free region
    d = bfs_distances(m.grid, tuple(free[0]))
    assert (d[~m.grid] >= 0).all()
    again = M.parse_maze(M.BUILTIN_MAZES[name])
    np.testing.assert_array_equal(again.grid, m.grid)


def test_builtins_simple_and_complex():
    simple, complex_ = M.builtin_maze("simple"), M.builtin_maze("complex")
    assert simple.grid.shape == (10, 10) and simple.cell_size == 1.0
    assert 1 <= len(simple.wall_boxes()) <= 4
    assert complex_.grid.shape == (20, 20) and complex_.cell_size == 0.5
    assert len(complex_.wall_boxes()) >= 10
    # corridors: the BFS path across the complex maze is much longer than the straight line
    d = bfs_distances(complex_.grid, (19, 0))
    assert d[0, 19] > 2 * 19
    with pytest.raises(ValueError, match="unknown built-in maze 'medium'; choices: simple"):
        M.builtin_maze("medium")


# ------------------------------------------------------------------------- random bank
@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    rows=st.integers(3, 12),
    cols=st.integers(3, 12),
    density=st.floats(0.0, 0.35),
)
def test_random_bank_free_cells_connected(seed, rows, cols, density):
    bank = M.random_maze_bank(4, rows, cols, 0.5, seed, density)
    assert len(bank) == 4
    for m in bank:
        assert m.grid.shape == (rows, cols) and m.cell_size == 0.5
        free = m.free_cells()
        assert len(free) >= 2
        np.testing.assert_array_equal(m.placement_cells(), free)  # one region
        assert (bfs_distances(m.grid, tuple(free[0]))[~m.grid] >= 0).all()
        assert m.grid.mean() <= density + 0.1 + 1e-9


def test_random_bank_determinism_density_and_slots():
    a = M.random_maze_bank(6, seed=3, wall_density=0.25)
    b = M.random_maze_bank(3, seed=3, wall_density=0.25)
    for x, y in zip(a[:3], b, strict=True):
        np.testing.assert_array_equal(x.grid, y.grid)  # maze i depends on (seed, i) only
    assert len({m.grid.tobytes() for m in a}) == 6
    assert 0.2 <= np.mean([m.grid.mean() for m in a]) <= 0.35
    fitted = M.random_maze_bank(20, seed=1, wall_density=0.3, num_slots=14)
    assert max(m.num_boxes for m in fitted) <= 14
    with pytest.raises(ValueError, match="wall_density=1.0"):
        M.random_maze_bank(2, wall_density=1.0)
    with pytest.raises(ValueError, match="no acceptable maze"):
        M.random_maze_bank(1, wall_density=0.5, num_slots=4, max_tries=3)


# ----------------------------------------------------------------------------- batching
def test_stack_walls_and_mazes():
    mazes = M.random_maze_bank(5, rows=8, cols=6, cell_size=0.5, seed=2, wall_density=0.3)
    mazes.append(M.parse_maze("cell_size: 0.5\n" + "S.....\n" + "......\n" * 6 + ".##..G\n"))
    num_slots = max(m.num_boxes for m in mazes) + 2
    walls = M.stack_walls(mazes, num_slots)
    assert walls.center.shape == (6, num_slots, 2) and walls.half_size.shape == (6, num_slots, 2)
    assert walls.active.shape == (6, num_slots)
    np.testing.assert_array_equal(np.asarray(walls.active).sum(1), [m.num_boxes for m in mazes])
    for i, m in enumerate(mazes):
        np.testing.assert_array_equal(walls.center[i], m.walls(num_slots).center)

    bank = M.stack_mazes(mazes, num_slots)
    fmax = max(len(m.placement_cells()) for m in mazes)
    assert bank.num_mazes == 6 and bank.size_m == (3.0, 4.0)
    np.testing.assert_array_equal(bank.cell_size, [0.5] * 6)
    assert bank.free_xy.shape == (6, fmax, 2) and bank.free_xy.dtype == np.float32
    assert bank.free_cells.shape == (6, fmax, 2) and bank.grid.shape == (6, 8, 6)
    assert bank.num_free.dtype == np.int32
    for i, m in enumerate(mazes):
        n = int(bank.num_free[i])
        assert n == len(m.placement_cells())
        np.testing.assert_allclose(bank.free_xy[i, :n], m.cell_centers(m.placement_cells()))
        # padding repeats a valid cell, so any index below fmax is a free cell
        cells = np.asarray(bank.free_cells[i])
        assert not m.grid[cells[:, 0], cells[:, 1]].any()
        assert not inside(walls_of(bank, i), np.asarray(bank.free_xy[i])).any()
    np.testing.assert_array_equal(bank.has_start, [False] * 5 + [True])
    np.testing.assert_array_equal(bank.has_goal, [False] * 5 + [True])
    np.testing.assert_allclose(bank.start_xy[5], mazes[5].cell_center(0, 0))
    np.testing.assert_allclose(bank.goal_xy[5], mazes[5].cell_center(7, 5))

    with pytest.raises(ValueError, match="a bank needs one shape"):
        M.stack_mazes([mazes[0], M.builtin_maze("simple")], 32)
    # one shape, two cell sizes: each maze keeps its own, the arena is the largest
    coarse = dataclasses.replace(mazes[0], cell_size=1.0)
    mixed = M.stack_mazes([mazes[0], coarse], num_slots)
    np.testing.assert_array_equal(mixed.cell_size, [0.5, 1.0])
    assert mixed.size_m == (6.0, 8.0)
    np.testing.assert_allclose(mixed.free_xy[1], 2 * mixed.free_xy[0])
    with pytest.raises(M.MazeFileError, match="^complex:"):
        M.stack_walls([M.builtin_maze("simple"), M.builtin_maze("complex")], 8)


def walls_of(bank: M.MazeBank, i: int) -> M.Walls:
    return M.Walls(
        center=bank.walls.center[i], half_size=bank.walls.half_size[i], active=bank.walls.active[i]
    )


def test_maze_constructor_validates():
    grid = np.array([[False, True], [False, False]])
    with pytest.raises(ValueError, match="start=\\(0, 1\\) is not a free cell"):
        M.Maze(grid, start=(0, 1))
    with pytest.raises(ValueError, match="cell_size=0"):
        M.Maze(grid, cell_size=0)
    with pytest.raises(ValueError, match="non-empty 2-D"):
        M.Maze(np.zeros((0, 3), bool))


# ------------------------------------------------------------------------ maze families
EXAMPLES = sorted((Path(__file__).parent.parent / "examples" / "mazes").glob("*.txt"))


def assert_connected(m: M.Maze) -> None:
    """Every free cell is a placement cell and reachable from every other."""
    free = m.free_cells()
    assert len(free) >= 2
    np.testing.assert_array_equal(m.placement_cells(), free)
    assert (bfs_distances(m.grid, tuple(free[0]))[~m.grid] >= 0).all()


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1), index=st.integers(0, 10_000), family=st.sampled_from(G.FAMILIES)
)
def test_family_mazes_are_connected_and_fit_the_generalists_slots(seed, index, family):
    m = G.family_maze(seed, index, (family,))
    assert m.grid.shape == (G.ROWS, G.COLS) and m.cell_size == G.CELL_SIZE
    assert m.name.startswith(family)
    assert_connected(m)  # any start reaches any goal
    # drawn without a slot limit, yet within the generalist's slots (the tightest family,
    # corridors, needs at most 39 boxes over the first 2,048 mazes of seed 0)
    assert m.num_boxes <= 44
    fitted = G.family_maze(seed, index, (family,), num_slots=GENERALIST["num_wall_slots"])
    assert fitted.num_boxes <= GENERALIST["num_wall_slots"]


def test_family_bank_is_deterministic_extends_and_held_out_seeds_are_disjoint():
    small = G.family_maze_bank(8, seed=3)
    big = G.family_maze_bank(40, seed=3)
    for a, b in zip(small, big[:8], strict=True):
        np.testing.assert_array_equal(a.grid, b.grid)  # maze i depends on (seed, i) only
    assert [m.name.split("[")[0] for m in big[:4]] == list(G.FAMILIES)  # families in turn
    train = {m.grid.tobytes() for m in G.family_maze_bank(200, seed=0)}
    held_out = {m.grid.tobytes() for m in G.family_maze_bank(200, seed=1)}
    assert len(train) == 200 and len(held_out) == 200  # no repeats within a seed either
    assert not train & held_out
    # 0.5 m (1-cell) and 1 m (2-cell) corridors both occur
    corridors = G.family_maze_bank(40, seed=0, families=("corridors",))
    widths = {_corridor_width(m) for m in corridors}
    assert widths == {1, 2}
    with pytest.raises(ValueError, match="unknown family 'caves'"):
        G.family_maze_bank(2, families=("rooms", "caves"))
    assert G.check_families("rooms, pillars") == ("rooms", "pillars")


def _corridor_width(m: M.Maze) -> int:
    """The narrowest run of free cells along a row (corridor mazes: the corridor width)."""
    widths = []
    for row in ~m.grid:
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row.astype(np.int8), [0]])))
        widths += (edges[1::2] - edges[::2]).tolist()
    return min(widths)


def test_bank_with_k_goal_cells_matches_bfs():
    mazes = G.family_maze_bank(6, seed=2)
    k = 5
    bank = M.stack_mazes(mazes, 44, num_goals=k)
    rows, cols = G.ROWS, G.COLS
    assert bank.goal_distance.shape == (6, k, rows, cols)
    assert bank.goal_distance.dtype == np.int16
    assert M.goal_table_bytes(6, rows, cols, k) == bank.goal_distance.nbytes
    assert M.goal_table_bytes(6, rows, cols, None) == 2 * 6 * 400 * 400
    again = M.stack_mazes(mazes[3:], 44, num_goals=k)  # goal cells depend on the maze only
    np.testing.assert_array_equal(again.goal_index, bank.goal_index[3:])
    for b, m in enumerate(mazes):
        idx = np.asarray(bank.goal_index[b])
        assert len(set(idx.tolist())) == k and (idx < int(bank.num_free[b])).all()
        source = np.asarray(bank.goal_source[b])
        assert (source >= 0).sum() == k
        for j, i in enumerate(idx):
            r, c = (int(v) for v in bank.free_cells[b, i])
            np.testing.assert_array_equal(bank.goal_distance[b, j], bfs_distances(m.grid, (r, c)))
            assert source[r * cols + c] == j
    full = M.stack_mazes(mazes[:1], 44)
    assert full.goal_index is None and full.goal_source is None
    assert full.goal_distance.shape == (1, rows * cols, rows, cols)


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_maze_files_load_are_connected_and_fit(path):
    m = M.load_maze(path, num_slots=GENERALIST["num_wall_slots"])
    assert_connected(m)
    assert 0.5 <= m.cell_size <= 1.0
    assert all(8.0 <= side <= 12.0 for side in m.size_m)
    if m.start is not None and m.goal is not None:
        assert m.connected(m.start, m.goal)


def test_there_are_example_mazes_of_each_kind():
    names = {p.stem for p in EXAMPLES}
    assert {
        "rooms_doors",
        "warehouse",
        "corridors_1cell",
        "corridors_2cell",
        "pillar_hall",
    } <= names
