"""The robot's own map for a map-free waypoint policy, with numpy alone (no JAX).

A policy trained with ``RobotConfig.lidar_map`` (metadata ``sensors`` ``lidar_map_m``) reads a
waypoint planned on a map the robot builds from its own lidar, not on a map of the place.
``LidarMap`` is that map as the simulator keeps it (``jaxnav.envs.robot.lidar_map``), float32
arithmetic in the simulator's order so that its cells and field are the simulator's:

- ``reset(pose, goal, ranges)`` at the first scan of an episode: a square grid of
  ``size`` x ``size`` cells of side ``cell`` metres, centred on the pose, its axes along the
  walls' direction in that scan (the heading where the scan holds no wall), the goal's cell
  fixed for the episode;
- ``observe(pose, ranges)`` at each later control step: the cells where a beam ended (a
  return) and the robot's own cell (visited) are marked, and the shortest-path field to the
  goal is swept ``sweeps`` times, unseen cells counting as free;
- ``waypoint(pose, goal)``: the point ``waypoint_steps`` 8-neighbour moves down that field
  from the robot's cell (``jaxnav.deploy.planner.waypoint_cell``), or the goal itself where
  the descent reaches the goal's cell or the robot's cell has no path.

Poses come from one continuous odometry (any fixed frame), the goal in the same frame; ranges
are the policy's beams in metres (``sensors.resample_scan``), inf or beyond the policy's range
read as no return. ``sensors.ScanObservation`` keeps one for such a policy by itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxnav.deploy.planner import waypoint_cell, waypoint_steps

# the simulator's (``jaxnav.envs.robot.layout`` and ``lidar_map``), written out here so that
# this module needs no JAX; tests/test_deploy_lidar_map.py checks they stay the same
MAP_CELLS = 96
MAP_SWEEPS = 4
FAR = 2**15 - 1  # a return's cell, and cells no path reaches
ALIGN_TOLERANCE = math.radians(1.0)  # two wall segments within this are one direction
FLOAT32_MAX = float(np.finfo(np.float32).max)

RETURN = 1  # cell values, as the simulator's (0: unseen)
VISITED = 2


# sin, cos and atan2 as the float32 of the exact value: XLA's float32 functions give that in
# about 99% (sin, cos) and 84% (atan2) of cases here, numpy's own float32 ones in 88% and 60%
def _cos(x: Any) -> np.ndarray:
    return np.cos(np.asarray(x, np.float64)).astype(np.float32)


def _sin(x: Any) -> np.ndarray:
    return np.sin(np.asarray(x, np.float64)).astype(np.float32)


def _atan2(y: Any, x: Any) -> np.ndarray:
    return np.arctan2(np.asarray(y, np.float64), np.asarray(x, np.float64)).astype(np.float32)


def _numbers(name: str, values: Any, size: int | None = None) -> np.ndarray:
    """``values`` as float64, or a one-line ``ValueError`` naming ``name``: not numbers or not
    ``size`` of them."""
    try:
        out = np.asarray(values, np.float64).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{name}={values!r}: must be numbers") from None
    if size is not None and out.size != size:
        raise ValueError(f"{name}={tuple(out.tolist())!r}: must be {size} numbers")
    return out


def _point(name: str, values: Any, size: int) -> np.ndarray:
    """A pose or goal as float32, as the simulator holds it; ``ValueError`` unless finite and
    within float32."""
    out = _numbers(name, values, size)
    if not np.isfinite(out).all():
        raise ValueError(f"{name}={tuple(out.tolist())!r}: must be finite")
    if np.abs(out).max() > FLOAT32_MAX:
        raise ValueError(f"{name}={tuple(out.tolist())!r}: beyond float32")
    return out.astype(np.float32)


def _positive(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if isinstance(value, bool) or not (0 < v <= FLOAT32_MAX) or np.float32(v) == 0:
        raise ValueError(f"{name}={value!r}: must be a positive number")
    return v


def _count(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name}={value!r}: must be a positive integer")
    return int(value)


class LidarMap:
    """The simulator's own map of a ``lidar_map`` policy (see the module docstring).

    After ``reset``: ``frame`` float32[3] the grid's origin (x, y) and axis angle,
    ``goal_cell`` (row, col), ``cells`` uint8[size, size] (0 unseen, 1 a return, 2 visited)
    and ``steps`` int16[size, size] (moves to the goal's cell; ``FAR``: none), as the
    simulator's ``MapState``; None before."""

    def __init__(
        self,
        cell: float,
        beam_angles: Sequence[float] | np.ndarray,
        laser_range: float,
        waypoint_distance: float,
        *,
        moves: int = 8,
        size: int = MAP_CELLS,
        sweeps: int = MAP_SWEEPS,
    ):
        """``cell``: the grid's cell side (metres; metadata ``lidar_map_m``); ``beam_angles``
        (radians from the heading) and ``laser_range`` (metres): the policy's beams;
        ``waypoint_distance`` (metres) and ``moves`` (4 or 8): the waypoint's; ``size``:
        cells per side (``lidar_map_cells``); ``sweeps``: field sweeps per scan."""
        self.cell = np.float32(_positive("lidar_map_m", cell))
        angles = _numbers("beam_angles_rad", beam_angles)
        if angles.size == 0 or not np.isfinite(angles).all():
            raise ValueError(f"beam_angles_rad={beam_angles!r}: must be finite angles")
        self.angles = angles.astype(np.float32)  # the simulator's beams are float32
        self.max_range = np.float32(_positive("laser_range_m", laser_range))
        distance = _positive("waypoint_distance_m", waypoint_distance)
        if isinstance(moves, bool) or moves not in (4, 8):
            raise ValueError(f"waypoint_moves={moves!r}: must be 4 or 8")
        self.moves = int(moves)
        self.size = _count("lidar_map_cells", size)
        self.sweeps = _count("lidar_map_sweeps", sweeps)
        # the simulator's lookahead: whole cells of the map, at least one
        self.waypoint_steps = waypoint_steps(distance, float(cell))
        self.frame: np.ndarray | None = None
        self.goal_cell: tuple[int, int] | None = None
        self.cells: np.ndarray | None = None
        self.steps: np.ndarray | None = None

    @classmethod
    def from_metadata(cls, metadata: dict[str, Any] | Any) -> LidarMap:
        """The map of an exported policy trained with ``lidar_map`` (``Policy.metadata`` or
        the ``Policy``); ``ValueError`` for one without ``sensors.lidar_map_m``."""
        metadata = getattr(metadata, "metadata", metadata)
        sensors = metadata.get("sensors") or {}
        cell = sensors.get("lidar_map_m")
        if not cell:
            raise ValueError(
                f"{metadata.get('env_id')}: not a lidar_map policy (no lidar_map_m in its "
                "metadata's sensors)"
            )
        distance = sensors.get("waypoint_distance_m")
        if not distance:
            raise ValueError(
                f"lidar_map_m={cell!r}: needs waypoint_distance_m (its planner gives the "
                "waypoint), the metadata has none"
            )
        return cls(
            cell,
            sensors["beam_angles_rad"],
            sensors["laser_range_m"],
            distance,
            moves=sensors.get("waypoint_moves") or 8,
            size=sensors.get("lidar_map_cells", MAP_CELLS),
            sweeps=sensors.get("lidar_map_sweeps", MAP_SWEEPS),
        )

    # ------------------------------------------------------------------ the simulator's maths
    def _ranges(self, ranges: Any) -> np.ndarray:
        """The beams' ranges as float32 clipped to the policy's range (inf: no return)."""
        r = _numbers("ranges", ranges)
        if r.size != self.angles.size:
            raise ValueError(f"ranges: {r.size} values, the policy has {self.angles.size} beams")
        bad = ~(r >= 0)  # NaN too
        if bad.any():
            raise ValueError(f"ranges: a beam reads {float(r[bad][0])!r}: must be >= 0 (inf: none)")
        return np.minimum(r, float(self.max_range)).astype(np.float32)

    def returns(self, pose: np.ndarray, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(points, hit)``: each beam's end (float32[beams, 2]) and whether it met a wall
        (read less than the range), for a float32 ``pose`` and ``ranges``."""
        direction = pose[2] + self.angles
        ends = np.stack([_cos(direction), _sin(direction)], -1)
        return pose[:2] + ranges[:, None] * ends, ranges < self.max_range

    def wall_angle(self, pose: np.ndarray, ranges: np.ndarray) -> np.float32:
        """The walls' direction modulo 90 degrees in one scan (the simulator's
        ``wall_angle``): the segment between neighbouring returns whose direction times 4 most
        others share, averaged over those; the heading where no two segments agree."""
        points, hit = self.returns(pose, ranges)
        seg = np.roll(points, -1, axis=0) - points
        both = hit & np.roll(hit, -1)
        four = np.float32(4.0) * _atan2(seg[:, 1], seg[:, 0])
        limit = np.float32(math.cos(4 * ALIGN_TOLERANCE))
        agree = (_cos(four[:, None] - four[None, :]) > limit) & both[None]
        votes = np.where(both, agree.sum(axis=1), 0)
        best = int(np.argmax(votes))
        rel = np.where(agree[best], four - four[best], np.float32(0.0))
        total = _atan2(_sin(rel), _cos(rel)).sum(dtype=np.float32)
        rel = total / np.float32(max(int(agree[best].sum()), 1))
        if votes[best] >= 2:
            return np.float32((four[best] + rel) / np.float32(4.0))
        return pose[2]

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(index, inside)``: the (row, col) int64[..., 2] of the cells holding float32
        points ``xy`` [..., 2] (clipped to the grid), and whether each is on the grid."""
        frame = self.frame
        d = xy - frame[:2]
        cos, sin = _cos(frame[2]), _sin(frame[2])
        local = np.stack([cos * d[..., 1] - sin * d[..., 0], cos * d[..., 0] + sin * d[..., 1]], -1)
        half = self.size // 2
        # compared as floats: a point far off the grid never wraps around in an integer cast
        index = np.floor(local / self.cell + np.float32(0.5)) + half
        inside = ((index >= 0) & (index < self.size)).all(axis=-1)
        return np.clip(index, 0, self.size - 1).astype(np.int64), inside

    def cell_centre(self, index: tuple[int, int]) -> np.ndarray:
        """The (x, y) float32[2] of the centre of cell ``index`` (row, col)."""
        half = self.size // 2
        local = np.asarray([index[0] - half, index[1] - half], np.float32) * self.cell
        cos, sin = _cos(self.frame[2]), _sin(self.frame[2])
        x = cos * local[1] - sin * local[0]
        y = sin * local[1] + cos * local[0]
        return self.frame[:2] + np.stack([x, y])

    def _sweep(self) -> None:
        """``sweeps`` Bellman updates of the field over the cells that are not returns (the
        grid's outside blocked), the goal's cell held at 0."""
        free = self.cells != RETURN
        d = self.steps
        for _ in range(self.sweeps):
            p = np.pad(d, 1, constant_values=FAR)
            low = np.minimum(
                np.minimum(p[:-2, 1:-1], p[2:, 1:-1]), np.minimum(p[1:-1, :-2], p[1:-1, 2:])
            )
            d = np.where(free, np.minimum(low, FAR - 1) + 1, FAR).astype(np.int16)
            d[self.goal_cell] = 0
        self.steps = d

    # ------------------------------------------------------------------ the robot's loop
    def clear(self) -> None:
        """Forget the map: the next scan must come through ``reset``."""
        self.frame = self.goal_cell = self.cells = self.steps = None

    def reset(self, pose: Sequence[float], goal: Sequence[float], ranges: Any) -> None:
        """Start a map at the first scan of an episode: ``pose`` (x, y, yaw), ``goal`` (x, y)
        in the same frame, ``ranges`` the policy's beams in metres."""
        pose = _point("pose", pose, 3)
        goal = _point("goal", goal, 2)
        ranges = self._ranges(ranges)
        self.frame = np.stack([pose[0], pose[1], self.wall_angle(pose, ranges)]).astype(np.float32)
        index, _ = self.cell_of(goal)
        self.goal_cell = (int(index[0]), int(index[1]))
        rows = np.arange(self.size)
        # the simulator starts the field from the Manhattan distances of an empty grid
        self.steps = (
            np.abs(rows[:, None] - self.goal_cell[0]) + np.abs(rows[None, :] - self.goal_cell[1])
        ).astype(np.int16)
        self.cells = np.zeros((self.size, self.size), np.uint8)
        self._add(pose, ranges)

    def observe(self, pose: Sequence[float], ranges: Any) -> None:
        """Add one control step's scan at ``pose`` and sweep the field."""
        if self.frame is None:
            raise ValueError("no map yet: reset(pose, goal, ranges) at the episode's first scan")
        self._add(_point("pose", pose, 3), self._ranges(ranges))

    def _add(self, pose: np.ndarray, ranges: np.ndarray) -> None:
        points, hit = self.returns(pose, ranges)
        index, inside = self.cell_of(points)
        mark = (hit & inside).astype(np.uint8)
        np.maximum.at(self.cells, (index[:, 0], index[:, 1]), mark)
        robot, _ = self.cell_of(pose[:2])  # clipped to the grid's edge, as the simulator's
        self.cells[robot[0], robot[1]] = VISITED
        self._sweep()

    def waypoint(self, pose: Sequence[float], goal: Sequence[float]) -> tuple[float, float]:
        """The waypoint (x, y) for the robot at ``pose``: ``waypoint_steps`` moves down the
        field from its cell, that cell's centre; ``goal`` itself where the descent reaches the
        goal's cell or the robot's cell has no path to it."""
        if self.frame is None:
            raise ValueError("no map yet: reset(pose, goal, ranges) at the episode's first scan")
        pose = _point("pose", pose, 3)
        _point("goal", goal, 2)
        gx, gy = (float(v) for v in np.asarray(goal, np.float64).ravel())
        start, _ = self.cell_of(pose[:2])
        field = np.where(self.steps < FAR, self.steps, -1)  # the planner's "no path"
        cell = waypoint_cell(field, (int(start[0]), int(start[1])), self.waypoint_steps, self.moves)
        if cell is None:
            return gx, gy
        x, y = self.cell_centre(cell)
        return float(x), float(y)

    def update(
        self, pose: Sequence[float], goal: Sequence[float], ranges: Any
    ) -> tuple[float, float]:
        """One control step: ``reset`` at the first scan (after ``clear``), else ``observe``;
        then the ``waypoint``."""
        if self.frame is None:
            self.reset(pose, goal, ranges)
        else:
            self.observe(pose, ranges)
        return self.waypoint(pose, goal)
