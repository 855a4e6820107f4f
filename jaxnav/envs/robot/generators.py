"""Maze families for training a generalist robot: several layout styles on one fine grid.

A bank (``mazes.stack_mazes``) needs one grid shape, so every family is drawn on the same fine
grid, by default 20 x 20 cells of 0.5 m (a 10 m arena, the paper's), and scale varies inside
it: a 1 m corridor is 2 fine cells, a 0.5 m one is 1 cell (the robot's 0.15 m
radius fits a 0.5 m cell with 0.1 m to spare each side), and about a third of the mazes use
only a smaller sub-arena (12 to 19 cells a side) with the rest walled off. Walls are 1 fine
cell (0.5 m) thick or, for the coarse segments, 2.

Families (``FAMILIES``):

- ``rooms``: recursive division into rooms by straight walls, each wall with one door of 1 or
  2 cells (0.5 or 1 m), down to rooms of at least 4 cells a side.
- ``corridors``: a depth-first (recursive backtracker) maze like the built-in COMPLEX, with
  corridors of 1 or 2 cells between 1-cell walls, plus a few extra openings for loops.
- ``segments``: today's random wall segments (``mazes.random_maze_bank``'s style), drawn on a
  grid of 1 m cells (scaled up by 2) or of 0.5 m cells.
- ``pillars``: an open hall with square pillars (1 or 2 cells) on a jittered lattice, some
  left out.

Not among the default ``FAMILIES``, for mixed banks (``families=(..., "jaxnav")``):

- ``jaxnav``: a JaxNav level (``jaxnav_levels``) drawn at 2 x 2 fine cells a 1 m cell, 18 x 18
  in the 20 x 20 arena. Unlike ``RobotJaxNav-v0``'s levels, the redraw below can drop a level
  whose filled pockets leave it too small, so heavy fills are a little rarer here.
- ``jaxnav_coarse``: the same level in cells twice the bank's (``CELL_SCALE``; 1 m, JaxNav's
  own), 9 x 9 in a 10 x 10 arena, the grid padded with wall cells to the bank's 20 x 20 (a
  maze of 1 m cells; the padding lies above and right of the level). A robot fits under half a
  cell (``RobotConfig.validate``), so only these cells admit JaxNav's robot (0.25 m) and larger
  in a bank with 0.5 m cells.

Every maze goes through ``fill_pockets``: free cells outside the largest connected region
become walls, so any two free cells are joined and a random start and goal always have a path.
A draw is redone (up to ``max_tries``) when fewer than ``MIN_FREE_FRACTION`` of the cells stay
free or, with ``num_slots``, when its boxes do not fit the wall slots.

Determinism: maze ``i`` of seed ``s`` depends only on ``(s, i)`` (its family is
``families[i % len(families)]``, its random stream ``default_rng([_TAG, s, i])``), so a larger
bank extends a smaller one; a held-out seed draws from streams no training seed uses (a
repeated maze would need two independent streams to produce the same 400-cell grid; the tests
check a held-out seed against the training seed's bank).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from jaxnav.envs.maze_algorithms import check_int, fill_pockets
from jaxnav.envs.robot.jaxnav_levels import INTERIOR, drawn_obstacles
from jaxnav.envs.robot.mazes import Maze, random_segments

FAMILIES = ("rooms", "corridors", "segments", "pillars")
ROWS = COLS = 20  # the fine grid: 0.5 m cells over a 10 m arena
CELL_SIZE = 0.5
MIN_FREE_FRACTION = 0.3  # of the (sub-)arena's cells; fewer would be mostly wall
SUB_ARENA_PROB = 1 / 3  # mazes drawn on a smaller sub-arena, for scale variety
MIN_SUB = 12  # smallest sub-arena side (6 m at 0.5 m cells)
MAX_ROOMS = 7  # corridor mazes: rooms (corridor junctions) a side
_TAG = 0x6A61786E  # "jaxn": keeps these streams apart from random_maze_bank's [seed, i]

Generator = Callable[[np.random.Generator, int, int], np.ndarray]


def _rooms(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """Recursive division: split a room by a 1-cell wall with one door while both halves keep
    at least ``min_room`` cells a side."""
    grid = np.zeros((rows, cols), bool)
    min_room = int(rng.integers(4, 7))
    door = int(rng.integers(1, 3))

    def split(r0: int, c0: int, r1: int, c1: int) -> None:  # inclusive free rectangle
        h, w = r1 - r0 + 1, c1 - c0 + 1
        can_h, can_v = h >= 2 * min_room + 1, w >= 2 * min_room + 1
        if not (can_h or can_v):
            return
        horizontal = can_h and (not can_v or (h > w if h != w else rng.random() < 0.5))
        if horizontal:
            r = int(rng.integers(r0 + min_room, r1 - min_room + 1))
            grid[r, c0 : c1 + 1] = True
            d = int(rng.integers(c0, c1 - door + 2))
            grid[r, d : d + door] = False
            split(r0, c0, r - 1, c1)
            split(r + 1, c0, r1, c1)
        else:
            c = int(rng.integers(c0 + min_room, c1 - min_room + 1))
            grid[r0 : r1 + 1, c] = True
            d = int(rng.integers(r0, r1 - door + 2))
            grid[d : d + door, c] = False
            split(r0, c0, r1, c - 1)
            split(r0, c + 1, r1, c1)

    split(0, 0, rows - 1, cols - 1)
    return grid


def _corridors(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """Depth-first maze: rooms of ``width`` x ``width`` cells on a pitch of ``width + 1``,
    passages carved between them, then ``loops`` extra walls opened. Cells left over at the
    bottom/right edge (when the pitch does not divide the size) stay walls."""
    width = int(rng.integers(1, 3))
    pitch = width + 1
    # at most MAX_ROOMS rooms a side: a 10 x 10 maze of 0.5 m corridors needs ~70 wall boxes
    # (rays cost beams x boxes), 7 x 7 at most ~40; the rest of the arena stays wall
    nr, nc = min((rows + 1) // pitch, MAX_ROOMS), min((cols + 1) // pitch, MAX_ROOMS)
    grid = np.ones((rows, cols), bool)
    r0 = int(rng.integers(rows + 1 - (nr * pitch - 1)))
    c0 = int(rng.integers(cols + 1 - (nc * pitch - 1)))
    for i in range(nr):
        for j in range(nc):
            grid[
                r0 + i * pitch : r0 + i * pitch + width, c0 + j * pitch : c0 + j * pitch + width
            ] = False

    def open_between(a: tuple[int, int], b: tuple[int, int]) -> None:
        (i, j), (k, m) = a, b
        top, left = r0 + i * pitch, c0 + j * pitch
        if i == k:  # horizontal neighbours: the wall column between them
            grid[top : top + width, c0 + min(j, m) * pitch + width] = False
        else:
            grid[r0 + min(i, k) * pitch + width, left : left + width] = False

    seen = np.zeros((nr, nc), bool)
    stack = [(int(rng.integers(nr)), int(rng.integers(nc)))]
    seen[stack[0]] = True
    while stack:
        i, j = stack[-1]
        nbrs = [
            (i + di, j + dj)
            for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1))
            if 0 <= i + di < nr and 0 <= j + dj < nc and not seen[i + di, j + dj]
        ]
        if not nbrs:
            stack.pop()
            continue
        nxt = nbrs[int(rng.integers(len(nbrs)))]
        open_between((i, j), nxt)
        seen[nxt] = True
        stack.append(nxt)
    # loops: a perfect maze has one route between two places; a few more make it less of a tree
    for _ in range(int(rng.integers(2, 6))):
        i, j = int(rng.integers(nr)), int(rng.integers(nc))
        if rng.random() < 0.5 and j + 1 < nc:
            open_between((i, j), (i, j + 1))
        elif i + 1 < nr:
            open_between((i, j), (i + 1, j))
    return grid


def _segments(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """Random straight wall segments at 20% density, on 1 m cells (scaled up by 2: today's
    RobotRandom look) or on the fine 0.5 m cells."""
    scale = int(rng.integers(1, 3))
    r, c = rows // scale, cols // scale
    coarse = random_segments(rng, r, c, round(0.2 * r * c), 4 * (3 - scale))
    grid = np.ones((rows, cols), bool)  # cells beyond a whole number of coarse cells: walls
    grid[: r * scale, : c * scale] = np.kron(coarse, np.ones((scale, scale), bool))
    return grid


def _pillars(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """An open hall: square pillars of 1 or 2 cells on a lattice of 4 to 6 cells, each
    jittered by up to a cell and dropped with probability 0.25."""
    grid = np.zeros((rows, cols), bool)
    size = int(rng.integers(1, 3))
    spacing = int(rng.integers(4, 7))
    for r in range(spacing // 2, rows - size, spacing):
        for c in range(spacing // 2, cols - size, spacing):
            if rng.random() < 0.25:
                continue
            rr = min(max(r + int(rng.integers(-1, 2)), 1), rows - size - 1)
            cc = min(max(c + int(rng.integers(-1, 2)), 1), cols - size - 1)
            grid[rr : rr + size, cc : cc + size] = True
    return grid


def _jaxnav_level(per_cell: int) -> Generator:
    """A JaxNav level (``jaxnav_levels``: 9 x 9 cells, up to 47 random obstacles) drawn at
    ``per_cell`` x ``per_cell`` grid cells a level cell, at a random place in the arena; the
    rest is wall."""

    def draw(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
        side = per_cell * INTERIOR
        grid = np.ones((rows, cols), bool)
        r0, c0 = int(rng.integers(rows - side + 1)), int(rng.integers(cols - side + 1))
        level = np.kron(drawn_obstacles(rng), np.ones((per_cell, per_cell), bool))
        grid[r0 : r0 + side, c0 : c0 + side] = level
        return grid

    return draw


# the last two are not among the default FAMILIES: RobotNav-v0's bank stays as it was
GENERATORS: dict[str, Generator] = {
    "rooms": _rooms,
    "corridors": _corridors,
    "segments": _segments,
    "pillars": _pillars,
    "jaxnav": _jaxnav_level(2),
    "jaxnav_coarse": _jaxnav_level(1),
}
# a family's cells in cells of the bank (default 1): its grid is drawn that much smaller
CELL_SCALE: dict[str, int] = {"jaxnav_coarse": 2}
# the smallest (sub-)arena a family draws on, in its own cells (default MIN_SUB)
MIN_SIZE: dict[str, int] = {"jaxnav": 2 * INTERIOR, "jaxnav_coarse": INTERIOR}


def check_families(families: Sequence[str]) -> tuple[str, ...]:
    """``families`` as a tuple of known names; ``ValueError`` naming the first unknown one."""
    if isinstance(families, str):  # "rooms,pillars", e.g. from the command line
        families = [f.strip() for f in families.split(",") if f.strip()]
    if not isinstance(families, (list, tuple)):
        raise ValueError(f"families={families!r}: must be a list of {', '.join(FAMILIES)}")
    out = tuple(families)
    if not out:
        raise ValueError("families=(): choose at least one of " + ", ".join(FAMILIES))
    for f in out:
        if not isinstance(f, str) or f not in GENERATORS:
            raise ValueError(f"families: unknown family {f!r}; choices: {', '.join(GENERATORS)}")
    return out


def family_maze(
    seed: int,
    index: int,
    families: Sequence[str] = FAMILIES,
    rows: int = ROWS,
    cols: int = COLS,
    cell_size: float = CELL_SIZE,
    num_slots: int | None = None,
    max_tries: int = 100,
) -> Maze:
    """Maze ``index`` of seed ``seed``: family ``families[index % len(families)]``, connected
    (pockets filled), with at least ``MIN_FREE_FRACTION`` of its arena free and, with
    ``num_slots``, walls that fit the slots; ``rows`` x ``cols`` cells of ``cell_size``, or of
    the family's ``CELL_SCALE`` times that, padded with walls to ``rows`` x ``cols``. Depends
    only on the arguments."""
    families = check_families(families)
    check_int("seed", seed, 0)
    check_int("index", index, 0)
    family = families[index % len(families)]
    gen = GENERATORS[family]
    scale = CELL_SCALE.get(family, 1)
    own_rows, own_cols = rows // scale, cols // scale
    smallest = MIN_SIZE.get(family, MIN_SUB)
    if family in MIN_SIZE and min(own_rows, own_cols) < smallest:  # a level needs its room
        raise ValueError(
            f"family_maze: {family} needs {smallest * scale} x {smallest * scale} cells or "
            f"more; rows={rows}, cols={cols}"
        )
    rng = np.random.default_rng([_TAG, seed, index])
    for _ in range(max_tries):
        h, w = own_rows, own_cols
        if rng.random() < SUB_ARENA_PROB and min(own_rows, own_cols) > smallest:
            h = int(rng.integers(smallest, own_rows))
            w = int(rng.integers(smallest, own_cols))
        grid = np.ones((own_rows, own_cols), bool)
        r0, c0 = int(rng.integers(own_rows - h + 1)), int(rng.integers(own_cols - w + 1))
        grid[r0 : r0 + h, c0 : c0 + w] = gen(rng, h, w)
        grid = fill_pockets(grid)
        if (~grid).sum() < max(2, MIN_FREE_FRACTION * h * w):
            continue
        # the bank's shape: walls above and right, so the lower-left corner stays the origin
        grid = np.pad(grid, ((rows - own_rows, 0), (0, cols - own_cols)), constant_values=True)
        maze = Maze(grid, cell_size * scale, name=f"{family}[{seed}:{index}]")
        if num_slots is None or maze.num_boxes <= num_slots:
            return maze
    raise ValueError(
        f"family_maze: no acceptable {family} maze in {max_tries} draws for seed={seed}, "
        f"index={index}, rows={rows}, cols={cols}, num_slots={num_slots}; allow more slots"
    )


def family_maze_bank(
    num: int,
    seed: int = 0,
    families: Sequence[str] = FAMILIES,
    rows: int = ROWS,
    cols: int = COLS,
    cell_size: float = CELL_SIZE,
    num_slots: int | None = None,
) -> list[Maze]:
    """Mazes ``0 .. num - 1`` of ``family_maze(seed, i, ...)``: the families in turn."""
    check_int("num", num, 1)
    return [family_maze(seed, i, families, rows, cols, cell_size, num_slots) for i in range(num)]
