"""Maze layouts for the continuous robot environments: grids of wall cells, turned into boxes.

A maze is a grid of cells (``#`` wall, ``.`` free) of ``cell_size`` metres. The arena is the
grid's rectangle, ``cols * cell_size`` wide and ``rows * cell_size`` high, with x to the right,
y up and the origin at the arena's lower-left corner; row 0 is the *top* line of the text.

Simulators want walls as a fixed number of boxes per environment (batched model fields), so
``Maze.walls(num_slots)`` turns the wall cells into a few axis-aligned rectangles (runs of
cells along one axis, then identical runs merged along the other; whichever order gives fewer
boxes) plus 4 boundary walls just outside the arena. Slots left over are *parked*: inactive,
far outside the arena and tiny, so code that ignores ``Walls.active`` never touches them.

Text format (``load_maze(path)``, ``parse_maze(text)``)::

    ; a comment (any line whose first non-blank character is ';')
    cell_size: 0.5
    #.....#.
    #.##..#.
    S.#...#G

An optional ``cell_size: <metres>`` header (default 1.0) comes before the grid; the grid is
rows of ``#`` (wall), ``.`` (free), ``S`` and ``G`` (free cells marking the region of starts
and goals, below), at most one ``S`` and one ``G``. Blank lines may come before and after the
grid, not inside it; trailing whitespace is ignored. A malformed file raises ``MazeFileError`` (a
``ValueError``) whose message starts with ``path:line:column:`` (1-based; the column, or the
line, is left out where none applies).

Robots and goals are placed at *placement cells*: the free cells connected to ``S`` (or to
``G``, or the largest connected free region when the file has neither), so a random start and
goal are always joined by a path. ``S`` and ``G`` choose that region only: resets draw the
start and the goal at random among its cells (a fixed pair would make every test episode of a
held-out maze the same one). A cell centre is ``cell_size / 2`` from the nearest wall
cell along the axes, so a robot of radius below that fits at any placement centre.

Built-in layouts, in the spirit of the paper's Fig. 5 (a 10 m square arena): ``SIMPLE`` (a room
with two wall segments) and ``COMPLEX`` (a maze of 1 m corridors). ``random_maze_bank`` draws
random layouts (wall segments, then pockets filled), and ``stack_mazes`` batches any list of
mazes into arrays a JAX reset can index (``MazeBank``), once ``pad_mazes`` has brought mazes of
several sizes to one. ROS map_server occupancy maps (YAML + PGM/PNG) are read by ``occupancy``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import stat
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxnav.envs.maze_algorithms import (
    Cell,
    bank_distances,
    check_int,
    fill_pockets,
    is_number,
    largest_region_cell,
    region_labels,
)

WALL, FREE, START, GOAL = "#", ".", "S", "G"
CELL_CHARS = (WALL, FREE, START, GOAL)
NUM_BOUNDARY = 4
# Boundary walls lie outside the arena; their thickness only matters against tunnelling, so
# they are thick (2 m) to stop a fast robot stepping through them in one kinematic step.
BOUNDARY_HALF_THICKNESS = 1.0
# Parked (unused) slots: far outside any arena and tiny.
PARKED_CENTER = (-1000.0, -1000.0)
PARKED_HALF_SIZE = (1e-3, 1e-3)


class MazeFileError(ValueError):
    """A malformed maze: ``"{path}:{line}:{col}: {what}"`` (line and col when they apply)."""

    def __init__(self, path: str, what: str, line: int | None = None, col: int | None = None):
        self.path, self.what, self.line, self.col = path, what, line, col
        where = str(path)
        if line is not None:
            where += f":{line}"
            if col is not None:
                where += f":{col}"
        super().__init__(f"{where}: {what}")


# ------------------------------------------------------------------------------ walls
@struct.dataclass
class Walls:
    """Axis-aligned wall boxes in fixed slots (any leading batch axes before the slot axis)."""

    center: jax.Array  # float32[..., W, 2] box centre (x, y), metres
    half_size: jax.Array  # float32[..., W, 2] half width, half height
    active: jax.Array  # bool[..., W]; inactive slots are parked far away

    @property
    def num_slots(self) -> int:
        return self.center.shape[-2]

    def min_half_size(self) -> float:
        """The thinnest active wall's smaller half-size (host side, over every batch entry);
        parked slots are left out, as their tiny size would mislead e.g. substep counts."""
        h = np.asarray(self.half_size).min(axis=-1)
        return float(h[np.asarray(self.active)].min())


@struct.dataclass
class MazeBank:
    """A batch of mazes (leading axis B) for per-environment layouts; a reset picks a maze and
    two placement cells by index. Mazes of one bank share rows and cols; each has its own cell
    size (``cell_size``), so a bank can hold coarse mazes beside fine ones."""

    walls: Walls  # [B, W]
    free_xy: jax.Array  # float32[B, F, 2] placement-cell centres, padded with the first one
    free_cells: jax.Array  # int32[B, F, 2] the same cells as (row, col), padded alike
    num_free: jax.Array  # int32[B] valid entries of free_xy
    grid: jax.Array  # bool[B, rows, cols] True = wall
    start_xy: jax.Array  # float32[B, 2] the S cell's centre (free_xy[:, 0] when none)
    has_start: jax.Array  # bool[B]
    goal_xy: jax.Array  # float32[B, 2] the G cell's centre (free_xy[:, 0] when none)
    has_goal: jax.Array  # bool[B]
    # int16[B, G, rows, cols]: 4-neighbour steps from each goal source to every cell, -1 at
    # walls and unreachable; precomputed so a reset costs no BFS. With ``goal_index`` None
    # (the default) G = rows * cols and source g is the cell (g // cols, g % cols): every cell
    # can be a goal. That is 2 (rows * cols)^2 bytes a maze, 320 KB at 20 x 20, so large banks
    # of fine grids keep only K goal cells per maze (``stack_mazes(..., num_goals=K)``)
    goal_distance: jax.Array
    cell_size: jax.Array  # float32[B] each maze's cell side (metres)
    # With K goal cells: int32[B, K] indices into free_xy of the goal cells (source k of
    # goal_distance), and int32[B, rows * cols] the source of each flattened cell, -1 where the
    # cell is no goal cell; None for the full table
    goal_index: jax.Array | None = None
    goal_source: jax.Array | None = None
    # float32[B] the largest robot radius that passes each maze's narrowest gap (the env sets
    # it: a radius drawn per episode is capped there); None: not computed
    fit_radius: jax.Array | None = None
    # int32[B] the waypoint's lookahead in cells of each maze (the env sets it); None: none
    waypoint_cells: jax.Array | None = None

    @property
    def num_mazes(self) -> int:
        return self.free_xy.shape[0]

    @property
    def size_m(self) -> tuple[float, float]:
        """Arena (width, height) in metres: the largest maze's, where cell sizes differ."""
        rows, cols = self.grid.shape[1:]
        cell = float(np.max(np.asarray(self.cell_size)))
        return cols * cell, rows * cell


# ------------------------------------------------------------------------------- maze
# A cell's side in metres. The float32 step squares distances (collisions, lasers): a 1e20 m
# cell overflows them to inf and NaN; a micrometre cell leaves no robot radius MJX can simulate
CELL_SIZE_RANGE = (0.01, 100.0)


def check_cell_size(cell_size: float, prefix: str = "") -> None:
    """``ValueError`` naming ``cell_size`` unless it lies in ``CELL_SIZE_RANGE`` (metres)."""
    lo, hi = CELL_SIZE_RANGE
    if not lo <= cell_size <= hi:
        raise ValueError(f"{prefix}cell_size={cell_size!r}: must be in [{lo:g}, {hi:g}] metres")


@dataclasses.dataclass(frozen=True, eq=False)  # eq=False: arrays have no truth value
class Maze:
    """A maze layout on the host. ``grid`` is read-only bool (rows, cols), True = wall.

    ``lines`` gives the text line of each grid row (for error messages); ``None`` means row
    ``r`` is line ``r + 1``. ``origin`` is the world (x, y) of the grid's lower-left corner in
    the frame of the map it came from (an occupancy map's ``origin``; ``occupancy``): env
    coordinates are that frame's minus ``origin`` (``to_env``, ``to_map``). ``kind`` says what
    the maze was read from, for messages: "maze" (text) or "occupancy map" (an image).
    """

    grid: np.ndarray
    cell_size: float = 1.0
    start: Cell | None = None
    goal: Cell | None = None
    name: str = "<maze>"
    lines: tuple[int, ...] | None = None
    origin: tuple[float, float] = (0.0, 0.0)
    kind: str = "maze"

    def __post_init__(self) -> None:
        grid = np.array(self.grid, dtype=bool)  # a private copy, frozen below
        if grid.ndim != 2 or grid.size == 0:
            raise ValueError(f"{self.name}: grid must be a non-empty 2-D array, got {grid.shape}")
        grid.setflags(write=False)
        object.__setattr__(self, "grid", grid)
        cs = self.cell_size
        if not is_number(cs) or not math.isfinite(cs) or cs <= 0:
            raise ValueError(f"{self.name}: cell_size={cs!r}: must be a positive number (metres)")
        check_cell_size(cs, f"{self.name}: ")
        object.__setattr__(self, "cell_size", float(cs))
        for label in ("start", "goal"):
            cell = getattr(self, label)
            if cell is None:
                continue
            r, c = (int(v) for v in cell)
            if not (0 <= r < grid.shape[0] and 0 <= c < grid.shape[1]) or grid[r, c]:
                raise ValueError(f"{self.name}: {label}={cell!r} is not a free cell of the grid")
            object.__setattr__(self, label, (r, c))
        origin = tuple(self.origin)
        if len(origin) != 2 or not all(is_number(v) and math.isfinite(v) for v in origin):
            raise ValueError(f"{self.name}: origin={self.origin!r}: must be finite (x, y) metres")
        object.__setattr__(self, "origin", (float(origin[0]), float(origin[1])))
        if self.lines is not None and len(self.lines) != grid.shape[0]:
            raise ValueError(
                f"{self.name}: lines has {len(self.lines)} entries for {grid.shape[0]} rows"
            )

    # -- geometry -----------------------------------------------------------------
    @property
    def rows(self) -> int:
        return self.grid.shape[0]

    @property
    def cols(self) -> int:
        return self.grid.shape[1]

    @property
    def size_m(self) -> tuple[float, float]:
        """Arena (width, height) in metres."""
        return self.cols * self.cell_size, self.rows * self.cell_size

    def cell_center(self, row: int, col: int) -> tuple[float, float]:
        """Centre (x, y) in metres of cell (row, col); row 0 is the top line of the text."""
        return (col + 0.5) * self.cell_size, (self.rows - 1 - row + 0.5) * self.cell_size

    def cell_centers(self, cells: np.ndarray) -> np.ndarray:
        """float32[..., 2] centres (x, y) of int cells[..., 2] (row, col)."""
        cells = np.asarray(cells)
        x = (cells[..., 1] + 0.5) * self.cell_size
        y = (self.rows - 1 - cells[..., 0] + 0.5) * self.cell_size
        return np.stack([x, y], axis=-1).astype(np.float32)

    def cell_at(self, x: float, y: float) -> Cell:
        """The (row, col) containing point (x, y), clipped to the grid."""
        col = min(max(int(math.floor(x / self.cell_size)), 0), self.cols - 1)
        row = self.rows - 1 - min(max(int(math.floor(y / self.cell_size)), 0), self.rows - 1)
        return row, col

    def to_env(self, x: float, y: float) -> tuple[float, float]:
        """Env coordinates of the point (x, y) of the map's frame (minus ``origin``)."""
        return x - self.origin[0], y - self.origin[1]

    def to_map(self, x: float, y: float) -> tuple[float, float]:
        """The map frame's coordinates of the env point (x, y) (plus ``origin``)."""
        return x + self.origin[0], y + self.origin[1]

    # -- connectivity -------------------------------------------------------------
    def free_cells(self) -> np.ndarray:
        """int32[F, 2] all free cells (row, col) in reading order."""
        return np.argwhere(~self.grid).astype(np.int32)

    def connected(self, a: Cell, b: Cell) -> bool:
        """Whether free cells ``a`` and ``b`` (row, col) are joined by a 4-neighbour path."""
        labels = region_labels(self.grid)
        return bool(labels[a[0], a[1]] and labels[a[0], a[1]] == labels[b[0], b[1]])

    def placement_cells(self) -> np.ndarray:
        """int32[F, 2] cells where a robot or goal may be placed, in reading order: the free
        region of S, else of G, else the largest free region (first in reading order on a tie),
        so any two placement cells are connected."""
        return self._placement.copy()

    @functools.cached_property  # the grid is immutable; banks ask for this per maze
    def _placement(self) -> np.ndarray:
        labels = region_labels(self.grid)
        anchor = self.start or self.goal
        if anchor is None:
            anchor = largest_region_cell(self.grid)
        return np.argwhere(labels == labels[anchor]).astype(np.int32)

    # -- boxes --------------------------------------------------------------------
    def wall_boxes(self) -> np.ndarray:
        """int32[K, 4] (row0, col0, row1, col1), inclusive, rectangles of wall cells that cover
        the wall cells exactly, without overlap, sorted in reading order of their top-left
        cell. Greedy: runs along rows merged down identical runs, or the transpose, whichever
        gives fewer boxes (corridor mazes have both long horizontal and vertical walls)."""
        return self._boxes.copy()

    @functools.cached_property  # the grid is immutable; slots checks and walls both need it
    def _boxes(self) -> np.ndarray:
        by_rows = _merge_runs(self.grid)
        by_cols = _merge_runs(self.grid.T)[:, [1, 0, 3, 2]]
        boxes = by_rows if len(by_rows) <= len(by_cols) else by_cols
        order = np.lexsort((boxes[:, 1], boxes[:, 0])) if len(boxes) else np.zeros(0, int)
        return boxes[order].astype(np.int32).reshape(-1, 4)

    @property
    def num_boxes(self) -> int:
        """Wall slots this maze needs: the boundary's 4 plus its internal boxes."""
        return NUM_BOUNDARY + len(self.wall_boxes())

    def walls(self, num_slots: int) -> Walls:
        """The maze's walls in ``num_slots`` slots: 4 boundary walls first, then the internal
        boxes, then parked slots. ``MazeFileError`` (a ``ValueError``) if they do not fit."""
        center, half, active = _walls_np(self, num_slots)
        return Walls(
            center=jnp.asarray(center), half_size=jnp.asarray(half), active=jnp.asarray(active)
        )

    def line_of(self, row: int) -> int:
        """Text line of grid row ``row`` (1-based)."""
        return self.lines[row] if self.lines is not None else row + 1

    def to_text(self) -> str:
        """The maze in the text format; ``parse_maze(m.to_text())`` gives the same maze."""
        chars = np.where(self.grid, WALL, FREE).astype(object)
        if self.start is not None:
            chars[self.start] = START
        if self.goal is not None:
            chars[self.goal] = GOAL
        rows = "\n".join("".join(r) for r in chars)
        return f"cell_size: {self.cell_size!r}\n{rows}\n"


def _merge_runs(grid: np.ndarray) -> np.ndarray:
    """Rectangles (r0, c0, r1, c1): maximal runs of True per row, a run extended downwards
    while the next row has the identical run."""
    rows = grid.shape[0]
    runs: list[list[tuple[int, int]]] = [[] for _ in range(rows + 1)]  # the last row: none
    # every row's run edges in one pass; in reading order a run's start and end are neighbours
    edge_rows, edge_cols = np.nonzero(np.diff(np.pad(grid, ((0, 0), (1, 1))).astype(np.int8)))
    starts, ends = edge_cols[::2].tolist(), edge_cols[1::2].tolist()
    for r, c0, c1 in zip(edge_rows[::2].tolist(), starts, ends, strict=True):
        runs[r].append((c0, c1 - 1))
    boxes: list[tuple[int, int, int, int]] = []
    open_runs: dict[tuple[int, int], int] = {}  # (c0, c1) -> first row
    for r, row_runs in enumerate(runs):
        still_open = {run: open_runs.pop(run, r) for run in row_runs}
        boxes.extend((r0, c0, r - 1, c1) for (c0, c1), r0 in open_runs.items())
        open_runs = still_open
    return np.array(boxes, dtype=np.int32).reshape(-1, 4)


def check_slots(maze: Maze, num_slots: int) -> None:
    """``MazeFileError`` naming the maze (its file) and the first box that does not fit when
    its walls need more than ``num_slots`` slots."""
    if isinstance(num_slots, bool) or not isinstance(num_slots, (int, np.integer)):
        raise ValueError(f"num_slots={num_slots!r}: must be an integer")
    if num_slots < NUM_BOUNDARY:
        raise ValueError(f"num_slots={num_slots}: must be at least {NUM_BOUNDARY} (the boundary)")
    boxes = maze.wall_boxes()
    room = num_slots - NUM_BOUNDARY
    if len(boxes) > room:
        r0, c0 = int(boxes[room, 0]), int(boxes[room, 1])
        if maze.kind != "maze":  # an image has no text lines: name the cell
            raise MazeFileError(
                maze.name,
                f"too many walls for {num_slots} wall slots: the {maze.kind} needs "
                f"{NUM_BOUNDARY + len(boxes)} boxes ({NUM_BOUNDARY} boundary + {len(boxes)} "
                f"internal) at {maze.cell_size:g} m cells, the first that does not fit at cell "
                f"(row {r0}, col {c0}); use num_wall_slots={NUM_BOUNDARY + len(boxes)} or a "
                "larger map_cell_size",
            )
        raise MazeFileError(
            maze.name,
            f"too many walls for {num_slots} wall slots: the maze needs {NUM_BOUNDARY + len(boxes)}"
            f" boxes ({NUM_BOUNDARY} boundary + {len(boxes)} internal) and the wall box starting"
            " here is the first that does not fit; merge walls into longer straight runs or use"
            f" num_wall_slots={NUM_BOUNDARY + len(boxes)}",
            maze.line_of(r0),
            c0 + 1,
        )


def _walls_np(maze: Maze, num_slots: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    check_slots(maze, num_slots)
    cs, (width, height), t = maze.cell_size, maze.size_m, BOUNDARY_HALF_THICKNESS
    # left, right, bottom, top; each spans the corners, so they overlap there and no seam
    # (a face shared by two boxes) is left for a point or ray to slip through
    center = [(-t, height / 2), (width + t, height / 2), (width / 2, -t), (width / 2, height + t)]
    side, cap = (t, height / 2 + 2 * t), (width / 2 + 2 * t, t)
    half = [side, side, cap, cap]
    for r0, c0, r1, c1 in maze.wall_boxes():
        center.append(((c0 + c1 + 1) / 2 * cs, (2 * maze.rows - r0 - r1 - 1) / 2 * cs))
        half.append(((c1 - c0 + 1) / 2 * cs, (r1 - r0 + 1) / 2 * cs))
    n = len(center)
    center += [PARKED_CENTER] * (num_slots - n)
    half += [PARKED_HALF_SIZE] * (num_slots - n)
    active = np.arange(num_slots) < n
    return np.array(center, np.float32), np.array(half, np.float32), active


# -------------------------------------------------------------------------- text format
MAX_FILE_BYTES = 1_000_000


def load_maze(path: str | os.PathLike[str], num_slots: int | None = None) -> Maze:
    """Read a maze file (format in the module docstring); ``MazeFileError`` naming the file,
    line and column if it is unreadable or malformed, or (with ``num_slots``) if its walls do
    not fit the slots. A file read before and unchanged since (the same size and modification
    time) is not read again: one run validates and builds its env several times."""
    name = os.fspath(path)
    try:
        info = os.stat(name)
    except OSError:
        info = None  # reading it says why
    if info is not None and (stat.S_ISFIFO(info.st_mode) or stat.S_ISSOCK(info.st_mode)):
        # reading a FIFO blocks until a writer comes: forever, for a run started by mistake
        raise MazeFileError(name, "a FIFO or socket, not a maze file")
    if info is not None and stat.S_ISREG(info.st_mode):
        maze = _load_file(name, info.st_dev, info.st_ino, info.st_mtime_ns, info.st_size)
    else:
        maze = _read_maze(name)
    if num_slots is not None:
        check_slots(maze, num_slots)
    return maze


@functools.lru_cache(maxsize=64)  # mazes are immutable; a changed file has another key
def _load_file(name: str, device: int, inode: int, mtime_ns: int, size: int) -> Maze:
    return _read_maze(name)


def _read_maze(name: str) -> Maze:
    try:
        with open(name, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)  # bounded: /dev/zero is not a maze
    except OSError as e:
        raise MazeFileError(name, f"cannot read the maze file: {e.strerror or e}") from e
    if len(data) > MAX_FILE_BYTES:
        raise MazeFileError(name, f"larger than {MAX_FILE_BYTES:,} bytes: not a maze file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        col = e.start - (data.rfind(b"\n", 0, e.start) + 1) + 1
        raise MazeFileError(name, "not UTF-8 text", line, col) from e
    return parse_maze(text, name=name)


def parse_maze(text: str, name: str = "<string>", num_slots: int | None = None) -> Maze:
    """Parse a maze from text (format in the module docstring); errors as ``load_maze``.
    A leading UTF-8 byte order mark (Windows editors write one) is skipped."""
    text = text.removeprefix("\ufeff")

    def fail(what: str, line: int | None = None, col: int | None = None) -> MazeFileError:
        return MazeFileError(name, what, line, col)

    cell_size, cell_size_line = 1.0, None
    rows: list[tuple[int, str]] = []  # (line number, row text)
    blank_after_grid = None
    for lineno, raw in enumerate(text.split("\n"), start=1):
        line = raw.rstrip()  # also drops the '\r' of CRLF files
        stripped = line.lstrip()
        if stripped.startswith(";"):
            continue
        if not stripped:
            if rows and blank_after_grid is None:
                blank_after_grid = lineno
            continue
        if blank_after_grid is not None:
            raise fail(
                "blank line inside the grid (blank lines may only come before or after it)",
                blank_after_grid,
            )
        if ":" in line:  # a header; grid rows never contain ':'
            key, _, value = line.partition(":")
            if rows:
                raise fail("header after the grid started; headers come first", lineno, 1)
            if key.strip() != "cell_size":
                raise fail(
                    f"unknown header {key.strip()!r}; the only header is 'cell_size: <metres>'",
                    lineno,
                    len(key) - len(key.lstrip()) + 1,
                )
            if cell_size_line is not None:
                raise fail(f"second cell_size (first on line {cell_size_line})", lineno, 1)
            col = len(key) + 2 + len(value) - len(value.lstrip())
            cell_size = _parse_cell_size(value.strip(), fail, lineno, col)
            cell_size_line = lineno
            continue
        rows.append((lineno, line))
    if not rows:
        raise fail("no maze grid: expected rows of '#' (wall), '.' (free), 'S' and 'G'")

    width = len(rows[0][1])
    marks: dict[str, tuple[int, int, int]] = {}  # 'S'/'G' -> (row, line, col)
    for r, (lineno, line) in enumerate(rows):
        for c, ch in enumerate(line[:width]):
            if ch not in CELL_CHARS:
                raise fail(
                    f"unknown character {ch!r}; expected '#' (wall), '.' (free), 'S' (start) "
                    "or 'G' (goal)",
                    lineno,
                    c + 1,
                )
            if ch in (START, GOAL):
                what = "start 'S'" if ch == START else "goal 'G'"
                if ch in marks:
                    _, first_line, first_col = marks[ch]
                    raise fail(
                        f"second {what} (the first is at line {first_line}, column {first_col})",
                        lineno,
                        c + 1,
                    )
                marks[ch] = (r, lineno, c + 1)
        if len(line) != width:
            raise fail(
                f"ragged row: {len(line)} cells, but the first row (line {rows[0][0]}) has {width}",
                lineno,
                min(len(line), width) + 1,
            )

    grid = np.array([[ch == WALL for ch in line] for _, line in rows], dtype=bool)
    lines = tuple(lineno for lineno, _ in rows)
    cells = {k: (r, int(col) - 1) for k, (r, _, col) in marks.items()}
    maze = Maze(grid, cell_size, cells.get(START), cells.get(GOAL), name, lines)

    first_line = rows[0][0]
    num_free = int((~grid).sum())
    if num_free == 0:
        raise fail("no free cell: every cell is a wall '#'", first_line)
    if num_free < 2:
        raise fail("only one free cell; a start and a goal need at least 2", first_line)
    if START in marks and GOAL in marks and not maze.connected(cells[START], cells[GOAL]):
        _, sl, sc = marks[START]
        _, gl, gc = marks[GOAL]
        raise fail(
            f"no path from the start 'S' (line {sl}, column {sc}) to the goal 'G' (line {gl}, "
            f"column {gc})",
            sl,
            sc,
        )
    if len(maze.placement_cells()) < 2:
        if START in marks or GOAL in marks:
            k = START if START in marks else GOAL
            _, kl, kc = marks[k]
            what = "start 'S'" if k == START else "goal 'G'"
            raise fail(f"the {what} is walled in: no other free cell is reachable from it", kl, kc)
        raise fail("no two free cells are connected; a start and a goal need a path", first_line)
    if num_slots is not None:
        check_slots(maze, num_slots)
    return maze


def _parse_cell_size(value: str, fail: Any, line: int, col: int) -> float:
    try:
        v = float(value)
    except ValueError:
        raise fail(f"cell_size {value!r} is not a number (metres)", line, col) from None
    if not math.isfinite(v) or v <= 0:
        raise fail(f"cell_size {value!r} must be a positive number of metres", line, col)
    lo, hi = CELL_SIZE_RANGE
    if not lo <= v <= hi:
        raise fail(f"cell_size {value!r} must be in [{lo:g}, {hi:g}] metres", line, col)
    return v


# ----------------------------------------------------------------------------- built-ins
# A 10 m x 10 m room with two wall segments, from opposite sides: an S-shaped route.
SIMPLE = """\
; RobotSimple: a 10 m x 10 m room with two wall segments
cell_size: 1.0
..........
..........
..........
#######...
..........
..........
...#######
..........
..........
..........
"""

# A randomized depth-first maze on 7 x 7 rooms of 2 x 2 cells, plus 4 extra openings for
# loops (drawn once and frozen here): many corridors and dead ends, 16 internal wall boxes.
COMPLEX = """\
; RobotComplex: a 10 m x 10 m maze of 1 m corridors (2 cells) between 0.5 m walls, with loops
cell_size: 0.5
..#........#........
..#........#........
..#..####..#..####..
...........#.....#..
...........#.....#..
..#..#..#..#..#..#..
..#..#..#..#.....#..
..#..#..#..#.....#..
..#..#..#..####..#..
..#.....#........#..
..#.....#........#..
..################..
.................#..
.................#..
###############..#..
..............#..#..
..............#..#..
..#..##########..#..
..#.................
..#.................
"""

BUILTIN_MAZES = {"simple": SIMPLE, "complex": COMPLEX}


@functools.cache  # mazes are immutable, so one parse serves every caller
def builtin_maze(name: str) -> Maze:
    """The built-in maze ``"simple"`` or ``"complex"``."""
    if name not in BUILTIN_MAZES:
        raise ValueError(f"unknown built-in maze {name!r}; choices: {', '.join(BUILTIN_MAZES)}")
    return parse_maze(BUILTIN_MAZES[name], name=name)


# --------------------------------------------------------------------------- random mazes
def random_maze_bank(
    num: int,
    rows: int = 10,
    cols: int = 10,
    cell_size: float = 1.0,
    seed: int = 0,
    wall_density: float = 0.2,
    num_slots: int | None = None,
    max_segment: int = 4,
    max_tries: int = 200,
) -> list[Maze]:
    """``num`` random mazes whose free cells are all connected.

    Each maze gets straight wall segments (horizontal or vertical, 1..``max_segment`` cells,
    random positions) until ``round(wall_density * rows * cols)`` cells are walls; free cells
    outside the largest connected region are then filled. Segments rather than single cells
    look like walls and need few boxes. A draw is redone (up to ``max_tries`` times) when the
    filling overshoots the density by more than 0.1, fewer than 2 cells stay free, or, with
    ``num_slots``, the walls do not fit the slots. Maze ``i`` depends only on (seed, i), so a
    larger bank extends a smaller one.
    """
    check_int("num", num, 1)
    check_int("rows", rows, 1)
    check_int("cols", cols, 1)
    check_int("max_segment", max_segment, 1)
    check_int("max_tries", max_tries, 1)
    check_int("seed", seed, 0)
    if rows * cols < 2:
        raise ValueError(f"rows={rows}, cols={cols}: a maze needs at least 2 cells")
    if not is_number(cell_size) or not math.isfinite(cell_size) or cell_size <= 0:
        raise ValueError(f"cell_size={cell_size!r}: must be a positive number (metres)")
    check_cell_size(cell_size)
    if not is_number(wall_density) or not 0.0 <= wall_density < 1.0:
        raise ValueError(f"wall_density={wall_density!r}: must be a number in [0, 1)")
    if num_slots is not None:
        check_slots(Maze(np.zeros((rows, cols), bool), cell_size), num_slots)  # validates it
    target = round(wall_density * rows * cols)
    mazes = []
    for i in range(num):
        rng = np.random.default_rng([seed, i])
        for _ in range(max_tries):
            grid = fill_pockets(random_segments(rng, rows, cols, target, max_segment))
            if (~grid).sum() < 2 or grid.mean() > wall_density + 0.1:
                continue
            maze = Maze(grid, cell_size, name=f"random[{seed}:{i}]")
            if num_slots is None or maze.num_boxes <= num_slots:
                break
        else:
            raise ValueError(
                f"random_maze_bank: no acceptable maze in {max_tries} draws for rows={rows}, "
                f"cols={cols}, wall_density={wall_density}, num_slots={num_slots}; lower the "
                "density or allow more slots"
            )
        mazes.append(maze)
    return mazes


def random_segments(
    rng: np.random.Generator, rows: int, cols: int, target: int, max_segment: int
) -> np.ndarray:
    grid = np.zeros((rows, cols), bool)
    while grid.sum() < target:
        length = int(rng.integers(1, max_segment + 1))
        r, c = int(rng.integers(rows)), int(rng.integers(cols))
        dr, dc = (0, 1) if rng.random() < 0.5 else (1, 0)  # horizontal or vertical
        cells = [(r + k * dr, c + k * dc) for k in range(length)]
        for rr, cc in cells:
            if rr < rows and cc < cols and grid.sum() < target:  # stop exactly at the target
                grid[rr, cc] = True
    return grid


# ------------------------------------------------------------------------------ batching
def pad_mazes(mazes: Sequence[Maze]) -> list[Maze]:
    """The mazes padded with wall cells to the largest rows and cols among them, added along
    the top and the right so each grid's lower-left corner (its ``origin``) stays where it was;
    a ``ValueError`` naming two mazes of different cell sizes (a bank has one)."""
    if len(mazes) == 0:
        raise ValueError("pad_mazes: no mazes")
    m0 = mazes[0]
    for m in mazes[1:]:
        if m.cell_size != m0.cell_size:
            raise ValueError(
                f"{m.name}: {m.cell_size:g} m cells, but {m0.name} has {m0.cell_size:g} m; one "
                "bank needs one cell size (set map_cell_size for occupancy maps)"
            )
    rows, cols = max(m.rows for m in mazes), max(m.cols for m in mazes)
    out = []
    for m in mazes:
        top = rows - m.rows
        if top == 0 and m.cols == cols:
            out.append(m)
            continue
        grid = np.pad(m.grid, ((top, 0), (0, cols - m.cols)), constant_values=True)
        start, goal = ((c[0] + top, c[1]) if c is not None else None for c in (m.start, m.goal))
        lines = None if m.lines is None else (m.lines[0],) * top + m.lines
        out.append(dataclasses.replace(m, grid=grid, start=start, goal=goal, lines=lines))
    return out


def stack_walls(mazes: Sequence[Maze], num_slots: int) -> Walls:
    """Walls of several mazes with a leading batch axis: [B, num_slots]. Every maze must fit
    (``MazeFileError`` naming the first that does not)."""
    if len(mazes) == 0:
        raise ValueError("stack_walls: no mazes")
    parts = [_walls_np(m, num_slots) for m in mazes]
    return Walls(
        center=jnp.asarray(np.stack([p[0] for p in parts])),
        half_size=jnp.asarray(np.stack([p[1] for p in parts])),
        active=jnp.asarray(np.stack([p[2] for p in parts])),
    )


def stack_mazes(
    mazes: Sequence[Maze],
    num_slots: int,
    num_goals: int | None = None,
    plan_grids: np.ndarray | None = None,
) -> MazeBank:
    """A ``MazeBank`` of mazes that share rows and cols (cell sizes may differ): walls,
    placement-cell centres padded to the bank's largest count (with the maze's first cell, so
    any index below the padded size is a valid cell) and the S/G cells.

    ``plan_grids`` (bool[B, rows, cols], True = blocked; None: the mazes' grids): the cells the
    geodesic tables route around, the walls and the free cells a robot's centre cannot stand
    on (``jaxnav.deploy.planner.passable``). A ``ValueError`` names a maze whose placement
    cells it blocks: every start and goal must be a cell the robot stands on.

    ``num_goals`` None: the geodesic table covers every cell as a goal ([B, rows * cols, rows,
    cols]). ``num_goals=K``: only K goal cells per maze ([B, K, rows, cols], ``goal_index``),
    drawn without replacement from its placement cells by a generator seeded with the grid
    itself (the same maze gets the same goal cells in any bank; a maze with fewer than K
    placement cells repeats them). Resets then draw goals from these cells only.
    """
    if len(mazes) == 0:
        raise ValueError("stack_mazes: no mazes")
    m0 = mazes[0]
    for m in mazes[1:]:
        if m.grid.shape != m0.grid.shape:
            raise ValueError(
                f"stack_mazes: {m.name} is {m.rows}x{m.cols} cells, but {m0.name} is "
                f"{m0.rows}x{m0.cols}; a bank needs one shape"
            )
    placement = [m.placement_cells() for m in mazes]
    fmax = max(len(p) for p in placement)
    cells = np.stack([np.concatenate([p, np.repeat(p[:1], fmax - len(p), 0)]) for p in placement])
    free_xy = np.stack([m.cell_centers(c) for m, c in zip(mazes, cells, strict=True)])

    def mark(label: str) -> tuple[np.ndarray, np.ndarray]:
        cell = [getattr(m, label) for m in mazes]
        xy = [
            m.cell_center(*c) if c is not None else tuple(f[0])
            for m, c, f in zip(mazes, cell, free_xy, strict=True)
        ]
        return np.array(xy, np.float32), np.array([c is not None for c in cell])

    start_xy, has_start = mark("start")
    goal_xy, has_goal = mark("goal")
    grids = np.stack([m.grid for m in mazes])
    if plan_grids is None:
        plan_grids = grids
    for m, p, blocked in zip(mazes, placement, plan_grids, strict=True):
        if blocked[p[:, 0], p[:, 1]].any():
            raise ValueError(
                f"{m.name}: the planner blocks placement cells (too large a robot for them)"
            )
    goal_index = goal_source = None
    if num_goals is None:
        goal_distance = _all_pairs_distances(plan_grids)
    else:
        check_int("num_goals", num_goals, 1)
        goal_index = np.stack(
            [_goal_choice(m.grid, len(p), num_goals) for m, p in zip(mazes, placement, strict=True)]
        )
        sources = np.take_along_axis(cells, goal_index[..., None], axis=1)  # [B, K, 2]
        goal_distance = bank_distances(jnp.asarray(plan_grids), jnp.asarray(sources))
        rows, cols = m0.grid.shape
        flat = sources[..., 0] * cols + sources[..., 1]
        goal_source = np.full((len(mazes), rows * cols), -1, np.int32)
        for b in range(len(mazes)):  # reversed: a repeated cell maps to its first source
            goal_source[b, flat[b, ::-1]] = np.arange(num_goals - 1, -1, -1, dtype=np.int32)
        goal_index, goal_source = jnp.asarray(goal_index, jnp.int32), jnp.asarray(goal_source)
    return MazeBank(
        walls=stack_walls(mazes, num_slots),
        free_xy=jnp.asarray(free_xy, jnp.float32),
        free_cells=jnp.asarray(cells, jnp.int32),
        num_free=jnp.asarray([len(p) for p in placement], jnp.int32),
        grid=jnp.asarray(np.stack([m.grid for m in mazes])),
        start_xy=jnp.asarray(start_xy),
        has_start=jnp.asarray(has_start),
        goal_xy=jnp.asarray(goal_xy),
        has_goal=jnp.asarray(has_goal),
        goal_distance=goal_distance,
        cell_size=jnp.asarray([m.cell_size for m in mazes], jnp.float32),
        goal_index=goal_index,
        goal_source=goal_source,
    )


def _goal_choice(grid: np.ndarray, num_placement: int, num_goals: int) -> np.ndarray:
    """int32[num_goals] placement indices of a maze's goal cells: a random subset, seeded by
    the grid's own bits so it depends on the maze only, repeated when there are too few."""
    rng = np.random.default_rng([*np.packbits(grid).tolist(), *grid.shape])
    chosen = np.sort(rng.permutation(num_placement)[:num_goals])
    return np.resize(chosen, num_goals).astype(np.int32)


def goal_table_bytes(num_mazes: int, rows: int, cols: int, num_goals: int | None) -> int:
    """Bytes of a bank's geodesic table (int16[B, G, rows, cols])."""
    sources = rows * cols if num_goals is None else num_goals
    return 2 * num_mazes * sources * rows * cols


def _all_pairs_distances(grids: np.ndarray) -> jax.Array:
    """int16[B, rows * cols, rows, cols] BFS steps from every cell of every maze."""
    num, rows, cols = grids.shape
    every_cell = np.stack(np.divmod(np.arange(rows * cols, dtype=np.int32), cols), axis=-1)
    sources = np.broadcast_to(every_cell, (num, rows * cols, 2))
    return bank_distances(jnp.asarray(grids), jnp.asarray(sources))
