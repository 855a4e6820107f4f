"""A waypoint planner that knows the robot's size, with numpy and the standard library alone.

A robot's deployment loop (``jaxnav.deploy.navigator``) plans with the functions here, and the
robot env builds its BFS tables on ``passable``'s cells and descends them in JAX as ``descend``
does (``RobotNav.waypoint``; tests/test_planner.py compares the two), so a policy sees the same
waypoint on the same grid in the simulator and on the robot:

1. ``passable(grid, cell_size, clearance)``: the free cells whose centre is at least
   ``clearance`` metres (the robot's radius plus a margin, as Nav2's inflation layer makes
   every cell within the robot's inscribed radius lethal) from every wall cell and from the
   grid's edge. A path of 4-neighbour moves between passable centres keeps that clearance all
   along (a move's straight segment is never nearer a wall cell than its two ends), and so does
   a diagonal move between passable cells whose two cells beside it are passable too: so no gap
   narrower than ``2 * clearance`` lies on a path. Measured at cell centres, a corridor of an
   even number of cells offers half a cell less than its width.
2. ``distance_field(passable, goal)``: 4-neighbour BFS steps from every cell to the goal's
   cell through passable cells; -1 where there is no such path.
3. ``descend(steps, cell, num_steps, moves)``: ``num_steps`` moves down that field from a cell,
   each to the neighbour with the fewest steps if fewer than the cell's own (up, down, left,
   right, then the diagonals: the first of equals wins; a diagonal only where both cells beside
   it have a path), and ``waypoint_cell`` on top of it: that cell, or None for "the goal
   itself" (the descent reached the goal's cell, or the start has no path).

``Planner`` ties them to a map in metres (``GridMap``: a grid of wall cells, its cell size and
the map frame's origin of its lower-left corner) for a robot's pose and goal. Grids are bool
``[rows, cols]``, True for a wall, row 0 at the top (+y) edge, as ``jaxnav.envs.robot.mazes``
has them.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# the planner's moves (row, column): up, down, left, right, then the diagonals
MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1))
# metres a deployed robot keeps between itself and a wall on a planned path, beyond its radius
DEFAULT_MARGIN = 0.05
UNREACHABLE = -1
Cell = tuple[int, int]  # (row, col)


def waypoint_steps(distance: float, cell_size: float) -> int:
    """The waypoint's lookahead in whole cells: ``distance`` metres rounded to the nearest
    number of ``cell_size`` cells, at least one; 0 for no waypoint (``distance`` 0)."""
    return max(1, round(distance / cell_size)) if distance else 0


def passable(grid: np.ndarray, cell_size: float, clearance: float) -> np.ndarray:
    """bool[rows, cols]: the free cells of ``grid`` whose centre is at least ``clearance``
    metres from every wall cell and from the grid's edge (beyond it counts as wall)."""
    walls = np.asarray(grid, bool)
    if walls.ndim != 2:
        raise ValueError(f"grid of shape {walls.shape}: must be 2-D (rows, cols)")
    if not clearance >= 0 or not math.isfinite(clearance):
        raise ValueError(f"clearance={clearance!r}: must be a finite number of metres >= 0")
    # a wall cell k cells away along one axis and j along the other is this far from a centre:
    # only offsets nearer than the clearance can block
    reach = int(math.ceil(clearance / cell_size + 0.5))
    padded = np.pad(walls, reach, constant_values=True)
    rows, cols = walls.shape
    blocked = walls.copy()
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            gap = math.hypot(max(abs(dr) - 0.5, 0.0), max(abs(dc) - 0.5, 0.0)) * cell_size
            if gap < clearance:
                blocked |= padded[reach + dr : reach + dr + rows, reach + dc : reach + dc + cols]
    return ~blocked


def distance_field(passable_cells: np.ndarray, goal: Cell) -> np.ndarray:
    """int32[rows, cols]: 4-neighbour BFS steps from each cell to ``goal`` (row, col) through
    ``passable_cells``; -1 (``UNREACHABLE``) where there is no path, everywhere for a goal
    cell that is not passable."""
    ok = np.asarray(passable_cells, bool)
    rows, cols = ok.shape
    out = np.full(rows * cols, UNREACHABLE, np.int32)
    r, c = goal
    if not (0 <= r < rows and 0 <= c < cols) or not ok[r, c]:
        return out.reshape(rows, cols)
    flat = ok.ravel()
    frontier = np.array([r * cols + c])
    out[frontier] = 0
    distance = 0
    while frontier.size:  # one BFS level at a time, as arrays: fast on a fine map too
        distance += 1
        row, col = np.divmod(frontier, cols)
        step = np.concatenate(
            [
                frontier[row > 0] - cols,
                frontier[row < rows - 1] + cols,
                frontier[col > 0] - 1,
                frontier[col < cols - 1] + 1,
            ]
        )
        frontier = np.unique(step[flat[step] & (out[step] < 0)])
        out[frontier] = distance
    return out.reshape(rows, cols)


def descend(steps: np.ndarray, cell: Cell, num_steps: int, moves: int = 8) -> Cell:
    """The cell ``num_steps`` moves down the distance field ``steps`` from ``cell``: each move
    to the neighbour (``MOVES[:moves]``) with the fewest steps if fewer than the cell's own,
    the first of equals; a diagonal only where both cells beside it have a path."""
    rows, cols = steps.shape
    far = np.iinfo(np.int64).max

    def value(r: int, c: int) -> int:
        inside = 0 <= r < rows and 0 <= c < cols
        return int(steps[r, c]) if inside and steps[r, c] >= 0 else far

    row, col = cell
    for _ in range(num_steps):
        lowest, move = value(row, col), (0, 0)
        for dr, dc in MOVES[:moves]:
            if dr and dc and far in (value(row + dr, col), value(row, col + dc)):
                continue  # no cutting a wall's (or a blocked cell's) corner
            v = value(row + dr, col + dc)
            if v < lowest:
                lowest, move = v, (dr, dc)
        row, col = row + move[0], col + move[1]
    return row, col


def waypoint_cell(steps: np.ndarray, cell: Cell, num_steps: int, moves: int = 8) -> Cell | None:
    """The waypoint's cell from ``cell`` (``descend``), or None where the waypoint is the goal
    itself: the descent ends in the goal's cell, or ``cell`` has no path to it."""
    if steps[cell] < 0:
        return None
    end = descend(steps, cell, num_steps, moves)
    return None if steps[end] == 0 else end


@dataclass(frozen=True, eq=False)  # eq=False: arrays have no truth value
class GridMap:
    """A map as the planner reads it: ``grid`` bool [rows, cols] (True = wall, row 0 at the top,
    +y, edge) of ``cell_size`` metres, whose lower-left corner is ``origin`` (x, y) in the map's
    frame (a ROS map's ``origin``)."""

    grid: np.ndarray
    cell_size: float
    origin: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        grid = np.array(self.grid, dtype=bool)
        if grid.ndim != 2 or grid.size == 0:
            raise ValueError(f"map grid of shape {grid.shape}: must be a non-empty 2-D array")
        grid.setflags(write=False)
        object.__setattr__(self, "grid", grid)
        cs = self.cell_size
        if isinstance(cs, bool) or not isinstance(cs, (int, float)) or not 0 < cs < math.inf:
            raise ValueError(f"cell_size={cs!r}: must be a positive number of metres")
        ox, oy = (float(v) for v in self.origin)
        if not (math.isfinite(ox) and math.isfinite(oy)):
            raise ValueError(f"origin={self.origin!r}: must be finite (x, y) metres")
        object.__setattr__(self, "origin", (ox, oy))

    @classmethod
    def from_occupancy_grid(
        cls,
        *,
        data: Sequence[int] | np.ndarray,
        width: int,
        height: int,
        resolution: float,
        origin: tuple[float, float],
        occupied: int = 65,
        unknown_free: bool = False,
    ) -> GridMap:
        """The map of a ROS ``nav_msgs/OccupancyGrid`` (``data`` row-major from the origin's
        cell, rows going +y; ``info.width``, ``info.height``, ``info.resolution`` and
        ``info.origin.position`` (x, y)): a cell of occupancy ``occupied`` percent or more is
        a wall, and an unknown one (-1) unless ``unknown_free``."""
        values = np.asarray(data, np.int64).ravel()
        if values.size != width * height:
            raise ValueError(
                f"data has {values.size} cells; width={width} x height={height} needs "
                f"{width * height}"
            )
        cells = values.reshape(height, width)[::-1]  # row 0 at the top, as the grid has it
        wall = (cells >= occupied) | ((cells < 0) & (not unknown_free))
        return cls(wall, float(resolution), (float(origin[0]), float(origin[1])))

    @property
    def rows(self) -> int:
        return self.grid.shape[0]

    @property
    def cols(self) -> int:
        return self.grid.shape[1]

    def cell_of(self, x: float, y: float) -> Cell | None:
        """The (row, col) holding the map-frame point (x, y); None off the grid."""
        col = math.floor((x - self.origin[0]) / self.cell_size)
        up = math.floor((y - self.origin[1]) / self.cell_size)
        if not (0 <= col < self.cols and 0 <= up < self.rows):
            return None
        return self.rows - 1 - up, col

    def centre(self, cell: Cell) -> tuple[float, float]:
        """The map-frame (x, y) of a cell's centre."""
        row, col = cell
        return (
            self.origin[0] + (col + 0.5) * self.cell_size,
            self.origin[1] + (self.rows - 0.5 - row) * self.cell_size,
        )


class Planner:
    """Waypoints on a ``GridMap`` for a robot of ``radius`` metres keeping ``margin`` metres
    more from walls: ``set_goal(goal)`` plans (one distance field per goal), ``waypoint(x, y)``
    is the point ``waypoint_distance`` metres (whole cells, at least one) ahead on the path, in
    the map's frame. A robot whose own cell is not passable (within the margin of a wall) plans
    from the nearest passable cell it can reach through free cells."""

    def __init__(
        self,
        grid_map: GridMap,
        *,
        radius: float,
        margin: float = DEFAULT_MARGIN,
        waypoint_distance: float = 1.0,
        moves: int = 8,
    ):
        for name, v in (("radius", radius), ("margin", margin)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < math.inf:
                raise ValueError(f"{name}={v!r}: must be a finite number of metres >= 0")
        if moves not in (4, 8) or isinstance(moves, bool):
            raise ValueError(f"moves={moves!r}: must be 4 or 8")
        if not isinstance(waypoint_distance, (int, float)) or not waypoint_distance > 0:
            raise ValueError(f"waypoint_distance={waypoint_distance!r}: must be positive metres")
        self.map = grid_map
        self.radius, self.margin, self.moves = float(radius), float(margin), moves
        self.num_steps = waypoint_steps(waypoint_distance, grid_map.cell_size)
        self.passable = passable(grid_map.grid, grid_map.cell_size, self.radius + self.margin)
        self.goal: tuple[float, float] | None = None
        self.steps: np.ndarray | None = None

    def set_goal(self, goal: Sequence[float]) -> None:
        """Plan to ``goal`` (x, y) in the map's frame; ``ValueError`` naming it for a goal off
        the map or in a wall cell."""
        gx, gy = (float(v) for v in goal)
        cell = self.map.cell_of(gx, gy)
        if cell is None:
            raise ValueError(f"goal=({gx:g}, {gy:g}): off the map")
        if self.map.grid[cell]:
            raise ValueError(f"goal=({gx:g}, {gy:g}): inside a wall of the map (cell {cell})")
        # the goal's own cell may be within the margin of a wall: the robot need only come
        # within the goal radius of it
        ok = self.passable.copy()
        ok[cell] = True
        self.goal, self.steps = (gx, gy), distance_field(ok, cell)

    def start_cell(self, x: float, y: float) -> Cell | None:
        """The cell the robot at (x, y) plans from: its own, or where that has no path, the
        nearest (in 4-neighbour moves through free cells, no more than the clearance's cells
        and one) that has one; None if none does."""
        if self.steps is None:
            raise ValueError("no goal: call set_goal(goal) first")
        cell = self.map.cell_of(x, y)
        if cell is None:
            return None
        if self.steps[cell] >= 0:
            return cell
        free, rows, cols = ~self.map.grid, self.map.rows, self.map.cols
        # a robot within the margin of a wall is a few cells from passable space; farther
        # off, it is cut off from the goal, and the search need not cover its whole region
        depth = math.ceil((self.radius + self.margin) / self.map.cell_size) + 1
        seen, queue = {cell}, collections.deque([(cell, 0)])
        while queue:
            (r, c), d = queue.popleft()
            for dr, dc in MOVES[:4]:
                n = (r + dr, c + dc)
                if 0 <= n[0] < rows and 0 <= n[1] < cols and free[n] and n not in seen:
                    if self.steps[n] >= 0:
                        return n
                    seen.add(n)
                    if d + 1 < depth:
                        queue.append((n, d + 1))
        return None

    def waypoint(self, x: float, y: float) -> tuple[float, float]:
        """The map-frame point about ``waypoint_distance`` ahead of the robot at (x, y) on a
        shortest passable path to the goal: a cell's centre, or the goal once the path reaches
        its cell; ``ValueError`` where the robot has no path to the goal."""
        if self.map.cell_of(x, y) is None:
            raise ValueError(f"pose=({x:g}, {y:g}): off the map")
        start = self.start_cell(x, y)
        if start is None:
            raise ValueError(
                f"pose=({x:g}, {y:g}): no path to goal=({self.goal[0]:g}, {self.goal[1]:g}) "
                f"for a robot of radius {self.radius:g} m keeping {self.margin:g} m from walls"
            )
        cell = waypoint_cell(self.steps, start, self.num_steps, self.moves)
        return self.goal if cell is None else self.map.centre(cell)

    def path(self, x: float, y: float) -> list[Cell]:
        """Every cell of the descent from the robot at (x, y) to the goal's cell, one move at
        a time (the waypoints are every ``num_steps``-th); empty where there is no path."""
        cell = self.start_cell(x, y)
        if cell is None:
            return []
        out = [cell]
        while self.steps[cell] > 0:  # a BFS field always has a lower neighbour: it ends
            cell = descend(self.steps, cell, 1, self.moves)
            out.append(cell)
        return out
