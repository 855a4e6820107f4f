"""Any-angle shortest paths through a maze's free cells, on the host (numpy): the reference
length of the robot envs' path ratio and SPL, a length no successful episode can beat.

The path is the robot's centre as a point: from the start to the closed goal disc (radius
``goal_radius``, where an episode succeeds) through the maze's free space, every wall cell (and
the arena's outside) grown by ``EPSILON`` cells on each side. A robot of radius r keeps its
centre more than r from every wall in an episode without collision, so its path lies in that
space and is at least as long as the shortest one there.

Method: an exact visibility graph. A shortest path among axis-aligned walls bends only at wall
corners that stick into free space (grid vertices with exactly one wall cell of four around),
and ends on the disc's circle either straight toward the goal from its last bend (the circle's
point nearest to it) or where the circle meets a wall's face. Nodes are the start, those
corners and those meeting points; an edge joins two nodes that see each other (the segment
between them enters no grown wall). Corner-to-corner distances are kept per maze
(``scipy.sparse.csgraph``), so an episode costs its start's and its goal's sight lines only.
"""

from __future__ import annotations

import functools

import numpy as np

from jaxnav.envs.robot.mazes import Maze

# how far (in cells) the walls are grown: closes the seam where two wall boxes touch and the
# point where two wall cells meet corner to corner, which no robot of positive radius passes
EPSILON = 1e-6
# a segment may run this far (cells) inside a grown wall and still count as free: float
# rounding at a face it runs along; less than EPSILON, so it never touches the wall itself
TOLERANCE = EPSILON / 4
MAX_PAIRS_PER_CHUNK = 2_000_000  # (segment, box) pairs tested at once: bounds the memory


def wall_boxes(grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` float64[K, 2]: the corners, in cells (x right, y up, origin at the arena's
    lower-left corner), of the maze's wall boxes and 4 boxes outside the arena, grown by
    ``EPSILON``."""
    grid = np.asarray(grid, bool)
    rows, cols = grid.shape
    boxes = Maze(grid=grid).wall_boxes().astype(np.float64)  # (row0, col0, row1, col1)
    lo = np.stack([boxes[:, 1], rows - 1 - boxes[:, 2]], axis=1)
    hi = np.stack([boxes[:, 3] + 1, rows - boxes[:, 0]], axis=1)
    outside_lo = np.array([[-1, -1], [cols, -1], [-1, -1], [-1, rows]], np.float64)
    outside_hi = np.array(
        [[0, rows + 1], [cols + 1, rows + 1], [cols + 1, 0], [cols + 1, rows + 1]]
    )
    lo = np.concatenate([lo, outside_lo]) - EPSILON
    hi = np.concatenate([hi, outside_hi]) + EPSILON
    return lo, hi


def corners(grid: np.ndarray) -> np.ndarray:
    """float64[N, 2] the nodes where a shortest path may bend, in cells: each grid vertex with
    exactly one wall cell of the four around it (the arena's outside counts as wall), moved
    ``EPSILON`` diagonally away from that cell (to the grown wall's corner)."""
    up = np.pad(np.asarray(grid, bool)[::-1], 1, constant_values=True)  # [y + 1, x + 1], y up
    sw, se, nw, ne = up[:-1, :-1], up[:-1, 1:], up[1:, :-1], up[1:, 1:]
    one = (sw.astype(int) + se + nw + ne) == 1
    y, x = np.nonzero(one)
    dx = np.where(sw[one] | nw[one], 1.0, -1.0)  # away from a wall on the west: east
    dy = np.where(sw[one] | se[one], 1.0, -1.0)
    return np.stack([x + dx * EPSILON, y + dy * EPSILON], axis=1)


def visible(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """bool[...]: whether the segment from each point ``a[..., 2]`` to ``b[..., 2]`` (broadcast)
    stays out of every box (``lo``, ``hi``; it may run along a face or touch a corner)."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    shape = a.shape[:-1]
    a, b = a.reshape(-1, 2), b.reshape(-1, 2)
    out = np.ones(len(a), bool)
    chunk = max(1, MAX_PAIRS_PER_CHUNK // max(len(lo), 1))
    for s in range(0, len(a), chunk):
        p, d = a[s : s + chunk, None, :], (b - a)[s : s + chunk, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):  # resolved by ``moving``
            t1, t2 = (lo - p) / d, (hi - p) / d
        moving = d != 0
        # an axis the segment does not move along: all of it or none of it between the faces
        inside = (lo < p) & (p < hi)
        t_min = np.where(moving, np.minimum(t1, t2), np.where(inside, -np.inf, np.inf))
        t_max = np.where(moving, np.maximum(t1, t2), np.where(inside, np.inf, -np.inf))
        enter = np.maximum(t_min.max(axis=-1), 0.0)
        leave = np.minimum(t_max.min(axis=-1), 1.0)
        length = np.linalg.norm(d[..., 0, :], axis=-1)[:, None]
        with np.errstate(invalid="ignore"):  # a point, not a segment: NaN, not inside
            inside_length = (leave - enter) * length
        out[s : s + chunk] = ~((inside_length > TOLERANCE).any(axis=-1))
    return out.reshape(shape)


def circle_wall_points(
    goal: np.ndarray, radius: float, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """float64[M, 2]: where the circle of ``radius`` around ``goal`` (cells) meets a face of a
    box, outside every box: where a shortest path ends when a wall hides the circle's point
    nearest to its last bend."""
    points = []
    for axis in (0, 1):  # faces at x = const (axis 0), then at y = const
        other = 1 - axis
        for face in (lo[:, axis], hi[:, axis]):
            off = face - goal[axis]
            h = np.sqrt(np.maximum(radius**2 - off**2, 0.0))
            for sign in (-1.0, 1.0):
                along = goal[other] + sign * h
                ok = (np.abs(off) <= radius) & (lo[:, other] <= along) & (along <= hi[:, other])
                p = np.empty((int(ok.sum()), 2))
                p[:, axis], p[:, other] = face[ok], along[ok]
                points.append(p)
    pts = np.concatenate(points) if points else np.zeros((0, 2))
    inside = ((lo < pts[:, None]) & (pts[:, None] < hi)).all(-1).any(-1)
    return pts[~inside]


class MazeGraph:
    """A maze's corners and their geodesic distances through free space (cells), the part of
    every episode's shortest path that does not depend on its start or goal."""

    def __init__(self, grid: np.ndarray):
        self.lo, self.hi = wall_boxes(grid)
        self.corners = corners(grid)
        c = self.corners
        sight = visible(c[:, None], c[None], self.lo, self.hi)
        direct = np.where(sight, np.linalg.norm(c[:, None] - c[None], axis=-1), np.inf)
        np.fill_diagonal(direct, 0.0)
        from scipy.sparse.csgraph import shortest_path  # loaded once a path is asked for

        # dense input: infinite entries are missing edges
        self.between = shortest_path(direct, method="D", directed=False) if len(c) else direct

    @functools.lru_cache(maxsize=2**16)  # noqa: B019 - a bank of 2048 mazes x 32 goals
    def to_disc(self, goal: tuple[float, float], radius: float) -> np.ndarray:
        """float64[N]: each corner's distance (cells) to the closed disc through free space."""
        return (self.between + self.straight_to_disc(self.corners, np.array(goal), radius)).min(1)

    def straight_to_disc(self, points: np.ndarray, goal: np.ndarray, radius: float) -> np.ndarray:
        """float64[P]: the length of the shortest straight free segment from each point to the
        closed disc (inf where none), with the circle's points where it meets walls."""
        off = points - goal
        dist = np.linalg.norm(off, axis=-1)
        nearest = goal + radius * off / np.maximum(dist, 1e-300)[:, None]
        radial = np.where(visible(points, nearest, self.lo, self.hi), dist - radius, np.inf)
        out = np.where(dist <= radius, 0.0, radial)
        ends = circle_wall_points(goal, radius, self.lo, self.hi)
        if len(ends):
            seen = visible(points[:, None], ends[None], self.lo, self.hi)
            far = np.linalg.norm(points[:, None] - ends[None], axis=-1)
            out = np.minimum(out, np.where(seen, far, np.inf).min(axis=1))
        return out

    def distances(self, starts: np.ndarray, goal: np.ndarray, radius: float) -> np.ndarray:
        """float64[P]: cells from each of ``starts[P, 2]`` to the closed disc of ``radius``
        around ``goal`` through free space (inf where there is no path)."""
        best = self.straight_to_disc(starts, goal, radius)
        if len(self.corners):
            seen = visible(starts[:, None], self.corners[None], self.lo, self.hi)
            to = np.linalg.norm(self.corners[None] - starts[:, None], axis=-1)
            rest = self.to_disc((float(goal[0]), float(goal[1])), radius)
            via = np.where(seen, to + rest, np.inf)
            best = np.minimum(best, via.min(axis=1))
        return best


@functools.lru_cache(maxsize=4096)  # a bank's mazes; a slice of a bank has the same grids
def maze_graph(grid_bytes: bytes, rows: int, cols: int) -> MazeGraph:
    return MazeGraph(np.frombuffer(grid_bytes, bool).reshape(rows, cols))


def disc_distances(
    grid: np.ndarray, cell_size: float, starts: np.ndarray, goal: np.ndarray, goal_radius: float
) -> np.ndarray:
    """float64[P]: metres of the shortest path of a point from each of ``starts[P, 2]`` (x, y
    metres) to the closed disc of ``goal_radius`` around ``goal`` through the free cells of
    ``grid`` (bool[rows, cols], True = wall, row 0 at the top), walls grown by ``EPSILON``
    cells; inf where there is none."""
    grid = np.ascontiguousarray(grid, bool)
    graph = maze_graph(grid.tobytes(), *grid.shape)
    s = np.asarray(starts, np.float64).reshape(-1, 2) / cell_size
    g = np.asarray(goal, np.float64)[:2] / cell_size
    return graph.distances(s, g, float(goal_radius) / cell_size) * cell_size


def disc_distance(
    grid: np.ndarray, cell_size: float, start: np.ndarray, goal: np.ndarray, goal_radius: float
) -> float:
    """``disc_distances`` of one start (x, y metres)."""
    start = np.asarray(start, np.float64)[:2]
    return float(disc_distances(grid, cell_size, start[None], goal, goal_radius)[0])


def shortest_path_lengths(
    grids: np.ndarray,
    cell_size: np.ndarray,
    layout: np.ndarray,
    start: np.ndarray,
    goal: np.ndarray,
    goal_radius: np.ndarray,
) -> np.ndarray:
    """float32[...]: ``disc_distances`` of each episode (``grids`` bool[B, rows, cols] and
    ``cell_size`` float[B], a bank; ``layout``, ``start[..., 2]``, ``goal[..., 2]`` and
    ``goal_radius`` broadcast over the leading axes), -1 where there is no path or it is not
    positive (the start in the disc). ``grids`` and ``cell_size`` may carry leading axes of
    size 1 (a host callback's unbatched arguments)."""
    grids = np.asarray(grids, bool)
    grids = grids.reshape(grids.shape[-3:])
    cell_size = np.asarray(cell_size, np.float64).reshape(grids.shape[:1])
    layout = np.asarray(layout)
    start, goal = np.asarray(start)[..., :2], np.asarray(goal)[..., :2]
    radius = np.asarray(goal_radius, np.float64)
    shape = np.broadcast_shapes(layout.shape, start.shape[:-1], goal.shape[:-1], radius.shape)
    layout = np.broadcast_to(layout, shape).ravel()
    start = np.broadcast_to(start, shape + (2,)).reshape(-1, 2)
    goal = np.broadcast_to(goal, shape + (2,)).reshape(-1, 2)
    radius = np.broadcast_to(radius, shape).ravel()
    out = np.empty(len(layout), np.float64)
    # the episodes of one maze and goal at once: a bank's resets share a few goals per maze
    task = np.stack([layout, goal[:, 0], goal[:, 1], radius], axis=1)
    _, group = np.unique(task, axis=0, return_inverse=True)
    for g in np.unique(group):
        idx = np.flatnonzero(group.ravel() == g)
        i = idx[0]
        cell = float(cell_size[layout[i]])
        out[idx] = disc_distances(grids[layout[i]], cell, start[idx], goal[i], radius[i])
    good = np.isfinite(out) & (out > 0)
    return np.where(good, out, -1.0).astype(np.float32).reshape(shape)
