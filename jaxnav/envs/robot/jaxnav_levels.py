"""JaxNav's levels (``maze="jaxnav"``, ``RobotJaxNav-v0``): the single-robot benchmark of
JaxMARL's JaxNav as SFL (Rutherford et al. 2024, "No Regrets: Investigating and Improving
Regret Approximations for Curriculum Discovery") trains and evaluates on it.

A JaxNav level is an 11 x 11 grid of 1 m cells whose border ring is wall. Its 9 x 9 interior
gets ``n`` filled cells, ``n`` uniform in ``[0, floor(0.6 * 81))`` = ``[0, 48)``, placed
uniformly at random without replacement among the 81 interior cells. Here a level is that
9 x 9 interior with ``cell_size`` 1.0: our arena's boundary walls (``mazes.Maze.walls``, just
outside the grid) are the border ring, so the free space is the same 9 m x 9 m.

Start and goal: JaxNav's grid sampler draws the start among the free interior cells and the
goal among the other free cells (of the start's 4-connected region when its path check is on,
which SFL's training configuration leaves off), so a start in a walled-off pocket gets a goal in
that pocket or, without the check, possibly none it can reach. Here the pockets are filled
(``fill_pockets``: free cells outside the largest 4-connected region become walls) and resets
draw start and goal among the remaining free cells (the env's placement rule), so every pair is
joined by a path and no episode is played in a pocket; levels with pockets have that many more
wall cells than drawn (``drawn_obstacles`` gives the draw itself, uniform as above).

One redraw rule: a draw that leaves fewer than 2 free cells after the pockets are filled is
drawn again from the same stream. That needs every free cell cut off from the others (34 or
more free cells, no two side by side), a chance of 1.8e-17 a level (the independent sets of
the 9 x 9 grid counted by size), so the fill counts stay uniform.

Determinism: level ``i`` of seed ``s`` depends only on ``(s, i)`` (its stream is
``default_rng([_TAG, s, i])``), so a larger bank extends a smaller one, and another seed draws
from streams of its own. Levels with few obstacles do repeat across seeds (there is one empty
level, and 81 of one obstacle, each drawn with chance 1/48 / 81), as they repeat within one.
"""

from __future__ import annotations

import numpy as np

from jaxnav.envs.maze_algorithms import check_int, fill_pockets
from jaxnav.envs.robot.mazes import Maze

SIDE = 11  # JaxNav's map, border ring included
INTERIOR = SIDE - 2  # the level's grid here: 9 x 9
CELL_SIZE = 1.0
FILL = 0.6  # JaxNav's map fill: at most this fraction of the interior, exclusive
MAX_FILLED = int(np.floor(FILL * INTERIOR * INTERIOR))  # 48: counts are drawn in [0, 48)
MAX_TRIES = 100
_TAG = 0x4A4E4156  # "JNAV": keeps these streams apart from the families' and random banks'


def drawn_obstacles(rng: np.random.Generator) -> np.ndarray:
    """bool[9, 9] one JaxNav draw of the interior (True = filled): a count uniform in
    ``[0, MAX_FILLED)``, then that many cells uniformly without replacement."""
    cells = INTERIOR * INTERIOR
    count = int(rng.integers(0, MAX_FILLED))
    grid = np.zeros(cells, bool)
    grid[rng.choice(cells, size=count, replace=False)] = True
    return grid.reshape(INTERIOR, INTERIOR)


def level_draw(seed: int, index: int) -> np.ndarray:
    """bool[9, 9] the obstacles level ``index`` of ``seed`` drew (before its pockets were
    filled): the draw ``jaxnav_level`` kept."""
    return _draw(seed, index)[0]


def _draw(seed: int, index: int) -> tuple[np.ndarray, np.ndarray]:
    check_int("seed", seed, 0)
    check_int("index", index, 0)
    rng = np.random.default_rng([_TAG, seed, index])
    for _ in range(MAX_TRIES):
        drawn = drawn_obstacles(rng)
        grid = fill_pockets(drawn)
        if (~grid).sum() >= 2:
            return drawn, grid
    raise ValueError(f"jaxnav_level: no level with 2 free cells in {MAX_TRIES} draws")


def jaxnav_level(seed: int, index: int) -> Maze:
    """Level ``index`` of seed ``seed``: the 9 x 9 interior of 1 m cells, pockets filled."""
    return Maze(_draw(seed, index)[1], CELL_SIZE, name=f"jaxnav[{seed}:{index}]")


def jaxnav_level_bank(num: int, seed: int = 0, num_slots: int | None = None) -> list[Maze]:
    """Levels ``0 .. num - 1`` of ``seed``. With ``num_slots``, a level whose walls need more
    wall slots is refused (``ValueError`` naming it), never redrawn: a redraw would bias the
    fill counts towards fewer boxes."""
    check_int("num", num, 1)
    levels = [jaxnav_level(seed, i) for i in range(num)]
    if num_slots is not None:
        for level in levels:
            if level.num_boxes > num_slots:
                raise ValueError(
                    f"num_wall_slots={num_slots}: level {level.name} needs {level.num_boxes} "
                    "wall slots; allow more"
                )
    return levels
