"""A robot's sensor readings as an exported policy's observation, with numpy alone (no JAX).

``ScanObservation(policy.metadata)`` turns what a robot publishes, a 2D lidar scan (ROS
``sensor_msgs/LaserScan``'s ``angle_min``, ``angle_increment``, ``range_min``, ``range_max``,
``ranges``: ``LaserScan.from_msg(msg)``), its pose ``(x, y, yaw)`` (from odometry or a
localizer; ``yaw_from_quaternion`` converts a ROS orientation) and a goal ``(x, y)``, into the
observation the policy was trained on, frames stacked as the simulator stacks them::

    observe = ScanObservation(policy.metadata)
    observe.reset()                                  # at the start of every episode
    scan = LaserScan.from_msg(msg)                   # every control period (metadata's dt)
    action = policy.act(observe(scan, pose, goal))

Conventions, the simulator's (``jaxnav.envs.robot``): metres and radians, x forward, y left,
angles counter-clockwise from +x (ROS REP 103). The policy's beams (metadata ``sensors``
``beam_angles_rad``) are directions from the heading, cast from the robot's centre; here each
takes the scan reading nearest to it in angle (``beam_width`` > 0: the nearest range within
that window instead, a conservative reading for thin obstacles between beams). The scanner is
taken to sit at the robot's centre, turned by ``mount_yaw`` from the heading (a scan's angle
a is the direction a + mount_yaw from the heading; a scanner mounted backwards has pi).

Readings, as REP 117 defines them: +inf or above ``range_max``: nothing within range (the
policy reads its own range, as the simulator's rays that hit nothing); -inf: something closer
than ``range_min`` (reads 0); NaN and finite readings below ``range_min``: no valid return,
read as nothing within range, as the simulator's ``laser_dropout`` trains for. The policy's
range (metadata ``laser_range_m``) clips every reading; a scanner whose ``range_max`` is below
it reports walls beyond its range as free space. A beam of the policy outside the scan's
field of view is an error, unless ``fill_uncovered`` gives a range (metres) for it.

Policies trained with ``obs_absolute`` (the paper's layout) also read the goal and the robot
in the maze's frame (origin at its lower-left corner, metres, divided by the arena's size):
give pose and goal in that frame. Policies with a waypoint (metadata ``waypoint_distance_m``;
RobotNav-v0's: 1 m) read a point about that far ahead on a shortest path to the goal: a planner
on the robot's map provides it (``jaxnav.deploy.planner``, the simulator's own, as
``jaxnav.deploy.navigator.Navigator`` runs it; or the point of ROS nav2's global plan that
distance ahead, or the goal itself when closer), given as ``waypoint=(x, y)`` in the pose's
frame. A policy trained with its waypoint from its own lidar map (metadata ``lidar_map_m``)
needs no map: ``ScanObservation`` keeps that map itself (``jaxnav.deploy.lidar_map``, the
simulator's), from the scans and poses it is given, and plans on it where no ``waypoint`` is
passed; poses must then come from one continuous odometry, as for the trail below, the goal in
their frame, and ``reset()`` comes at every new goal.

Policies with an odometry trail (metadata ``trail_cell_m``; ``OdometryTrail``) count the
steps the robot's path spends in square cells of that side, in the frame of the first pose
after ``reset()``, and read the counts around the robot: give poses of one continuous odometry
(any fixed frame; a localizer's jumps would move the robot against its own trail), call once
per control step, and ``reset()`` at every new goal for a fresh trail, as an episode starts
one in the simulator.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from jaxnav.deploy.lidar_map import LidarMap


@dataclass(frozen=True, kw_only=True)
class LaserScan:
    """One 2D lidar sweep, as ROS ``sensor_msgs/LaserScan`` has it: reading i is at angle
    ``angle_min + i * angle_increment`` (radians; a negative increment sweeps clockwise).
    Keywords only, the fields named and ordered as ROS's (two ranges passed the other way
    round would read every obstacle as free space); ``LaserScan.from_msg(msg)`` copies a
    message's. ``angle_max`` (the last reading's angle; None: not checked) must agree with the
    readings' count: a scan of another size than its angles is refused."""

    angle_min: float
    angle_max: float | None = None
    angle_increment: float
    range_min: float = 0.0
    range_max: float
    ranges: Sequence[float] | np.ndarray

    @classmethod
    def from_msg(cls, msg: Any) -> LaserScan:
        """The scan of a ROS ``sensor_msgs/LaserScan`` message (or anything with its fields)."""
        return cls(
            angle_min=msg.angle_min,
            angle_max=getattr(msg, "angle_max", None),
            angle_increment=msg.angle_increment,
            range_min=msg.range_min,
            range_max=msg.range_max,
            ranges=msg.ranges,
        )


def check_finite(
    name: str, values: Sequence[float] | float, size: int | None = None
) -> tuple[float, ...]:
    """``values`` as floats; ``ValueError`` (one line, naming ``name`` and the values) unless
    they are ``size`` finite numbers: no action is ever computed from a NaN or an infinite
    input."""
    try:
        floats = tuple(float(v) for v in np.asarray(values, np.float64).ravel())
    except (TypeError, ValueError):
        raise ValueError(f"{name}={values!r}: must be numbers") from None
    if size is not None and len(floats) != size:
        raise ValueError(f"{name}={floats!r}: must be {size} numbers")
    if not all(math.isfinite(v) for v in floats):
        shown = floats[0] if np.ndim(values) == 0 else floats
        raise ValueError(f"{name}={shown!r}: must be finite")
    return floats


def check_scan(scan: LaserScan) -> tuple[float, float, float, float]:
    """``ValueError`` (one line, naming the field and its value) for a scan whose angles or
    range limits make no sense, each of which would read walls as free space or worse:
    angles must be finite, the increment nonzero and at most a full turn, ``range_min`` finite
    and non-negative, ``range_max`` above it (+inf allowed: every finite reading counts).
    Returns ``(angle_min, angle_increment, range_min, range_max)`` as floats."""
    (angle_min,) = check_finite("angle_min", scan.angle_min, 1)
    (increment,) = check_finite("angle_increment", scan.angle_increment, 1)
    if increment == 0 or abs(increment) > 2 * math.pi:
        raise ValueError(f"angle_increment={increment!r}: must be nonzero and at most 2*pi in size")
    (low,) = check_finite("range_min", scan.range_min, 1)
    if low < 0:
        raise ValueError(f"range_min={low!r}: must be non-negative")
    try:
        high = float(scan.range_max)
    except (TypeError, ValueError):
        raise ValueError(f"range_max={scan.range_max!r}: must be a number") from None
    if not high > low:  # NaN too
        raise ValueError(f"range_max={high!r}: must be above range_min={low!r}")
    return angle_min, increment, low, high


def check_scan_size(scan: LaserScan, size: int) -> None:
    """``ValueError`` (one line) for ``size`` readings that do not fit the scan's angles: more
    than a full turn of them (a reading at both -pi and pi is allowed), or a last reading's
    angle other than ``angle_max`` (by more than half an increment) where it is given."""
    step = abs(float(scan.angle_increment))
    span = (size - 1) * step
    if span > 2 * math.pi + step / 2:
        raise ValueError(
            f"ranges: {size} readings every {math.degrees(step):.4g} deg span "
            f"{math.degrees(span):.1f} deg, more than a full turn"
        )
    if scan.angle_max is not None:
        (angle_max,) = check_finite("angle_max", scan.angle_max, 1)
        last = float(scan.angle_min) + (size - 1) * float(scan.angle_increment)
        if abs(last - angle_max) > step / 2 + 1e-9:
            want = round((angle_max - float(scan.angle_min)) / float(scan.angle_increment)) + 1
            raise ValueError(
                f"ranges: {size} readings, but angle_min={float(scan.angle_min):g}, "
                f"angle_max={angle_max:g} and angle_increment={float(scan.angle_increment):g} "
                f"make {want}"
            )


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """The yaw (rotation about z, radians) of an orientation quaternion, as ROS odometry
    (``nav_msgs/Odometry``'s ``pose.pose.orientation``) gives it."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def bearing(dx: float, dy: float, yaw: float) -> tuple[float, float]:
    """(sin, cos) of the direction of the offset (dx, dy) relative to the heading ``yaw``, as
    the robot env's observation has them."""
    angle = math.atan2(dy, dx) - yaw
    return math.sin(angle), math.cos(angle)


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(angle, np.float64) + np.pi) % (2 * np.pi) - np.pi


def resample_scan(
    scan: LaserScan,
    beam_angles: Sequence[float] | np.ndarray,
    mount_yaw: float = 0.0,
    beam_width: float = 0.0,
    fill_uncovered: float | None = None,
) -> np.ndarray:
    """Ranges in metres ``float64[beams]`` along ``beam_angles`` (radians from the heading)
    from ``scan`` (see the module docstring for readings, mounting and windows); ``inf``
    where nothing is within the scan's range. ``ValueError`` for a beam outside the scan's
    field of view unless ``fill_uncovered`` gives its range."""
    angle_min, increment, range_min, range_max = check_scan(scan)
    (mount_yaw,) = check_finite("mount_yaw", mount_yaw, 1)
    (beam_width,) = check_finite("beam_width", beam_width, 1)
    if beam_width < 0:
        raise ValueError(f"beam_width={beam_width!r}: must be a width >= 0 in radians")
    if fill_uncovered is not None:
        given = fill_uncovered
        try:
            fill_uncovered = float(fill_uncovered)
        except (TypeError, ValueError):
            fill_uncovered = math.nan
        if not fill_uncovered >= 0:  # NaN too
            raise ValueError(f"fill_uncovered={given!r}: must be a range >= 0 (or inf)")
    try:
        ranges = np.asarray(scan.ranges, np.float64)
    except (TypeError, ValueError):
        raise ValueError("ranges: must be numbers") from None
    if ranges.ndim != 1:
        raise ValueError(f"ranges of shape {ranges.shape}: must be one sweep of readings")
    if ranges.size == 0:
        raise ValueError("ranges: the scan has no readings")
    check_scan_size(scan, ranges.size)
    reading = np.where(np.isneginf(ranges), 0.0, ranges)  # REP 117: -inf is "too close"
    valid = np.isfinite(reading) & (reading >= range_min) & (reading <= range_max)
    reading = np.where(np.isneginf(ranges) | valid, reading, np.inf)
    step = abs(increment)
    angles = angle_min + increment * np.arange(ranges.size) + mount_yaw
    beams = np.asarray(beam_angles, np.float64).ravel()
    offset = _wrap(angles[None, :] - beams[:, None])  # [beams, readings]
    distance = np.abs(offset)
    nearest = distance.argmin(axis=1)
    # a beam is covered if a reading lies within half a step of it (a full circle of
    # readings covers every direction)
    covered = distance[np.arange(beams.size), nearest] <= step / 2 + 1e-9
    out = reading[nearest]
    if beam_width > 0:
        window = distance <= beam_width / 2
        windowed = np.where(window, reading[None, :], np.inf).min(axis=1)
        out = np.where(window.any(axis=1), np.minimum(windowed, out), out)
    if not covered.all():
        if fill_uncovered is None:
            first = math.degrees(beams[~covered][0])
            low = math.degrees(min(angles[0], angles[-1]))
            high = math.degrees(max(angles[0], angles[-1]))
            raise ValueError(
                f"policy beam at {first:.1f} deg is outside the scan's field of view "
                f"[{low:.1f}, {high:.1f}] deg (mount_yaw included); pass fill_uncovered"
            )
        out = np.where(covered, out, fill_uncovered)
    return out


# the simulator's (``jaxnav.envs.robot.layout``: its TRAIL_ANGLES, TRAIL_CELLS and
# TRAIL_SATURATION), written out here so that this module needs no JAX
TRAIL_ANGLES = tuple(float(a) for a in np.linspace(0.0, 2 * np.pi, 8, endpoint=False))
TRAIL_CELLS = 64
TRAIL_SATURATION = 16
TRAIL_COUNT_MAX = 255  # a cell's count is a uint8 and stops there, as the simulator's
FLOAT32_MAX = float(np.finfo(np.float32).max)  # the simulator's poses and sizes are float32


def trail_points(angles: Sequence[float] = TRAIL_ANGLES) -> list[tuple[int, float]]:
    """``(cells away, angle from the heading)`` of the simulator's trail readings, in its
    order: the robot's own cell, then for each angle the point 1 and 2 cells away."""
    return [(0, 0.0)] + [(k, float(a)) for a in angles for k in (1, 2)]


class OdometryTrail:
    """The robot env's odometry trail (``RobotConfig.trail_cell``) with numpy alone, float32
    arithmetic in the env's order so that a cell's count is the env's: steps the robot spent
    in each square cell of side ``cell`` metres of a ``cells`` x ``cells`` grid in the frame of
    the origin (the first pose ``visit`` gets after ``reset``, at the centre of cell
    ``(cells // 2, cells // 2)``); counts stop at 255; points off the grid are not counted
    and read 0. ``reading(pose)``: the counts at ``points`` (cells away, angle from the
    heading), each / ``saturation`` clipped at 1."""

    def __init__(
        self,
        cell: float,
        cells: int = TRAIL_CELLS,
        saturation: float = TRAIL_SATURATION,
        points: Sequence[tuple[float, float]] | None = None,
    ):
        """``points``: None for the simulator's 17 (``trail_points()``)."""
        (size,) = check_finite("trail_cell_m", [cell], 1)
        if not 0 < size <= FLOAT32_MAX or np.float32(size) == 0:
            raise ValueError(f"trail_cell_m={cell!r}: must be a positive number of metres")
        if isinstance(cells, bool) or not isinstance(cells, (int, np.integer)) or cells < 1:
            raise ValueError(f"trail_cells={cells!r}: must be a positive integer")
        (sat,) = check_finite("trail_saturation", [saturation], 1)
        if sat <= 0:
            raise ValueError(f"trail_saturation={saturation!r}: must be a positive number")
        points = trail_points() if points is None else list(points)
        flat = check_finite("trail points", [v for p in points for v in p], 2 * len(points))
        self.cell = np.float32(size)  # the env divides by its config's float in float32
        self.cells = int(cells)
        self.saturation = np.float32(sat)
        self.reach = np.asarray(flat[0::2], np.float32)  # cells away
        self.angles = np.asarray(flat[1::2], np.float32)  # from the heading
        self.grid = np.zeros((self.cells, self.cells), np.uint8)
        self.origin: np.ndarray | None = None  # float32 x, y, heading

    def reset(self) -> None:
        """Forget the trail: the next ``visit`` sets the origin and counts the start."""
        self.grid[:] = 0
        self.origin = None

    @staticmethod
    def _pose(pose: Sequence[float]) -> np.ndarray:
        x, y, yaw = check_finite("pose", pose, 3)
        if max(abs(x), abs(y), abs(yaw)) > FLOAT32_MAX:
            raise ValueError(f"pose={(x, y, yaw)!r}: beyond float32")
        return np.asarray([x, y, yaw], np.float32)

    def _cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(row, col, inside)`` of the cells holding points ``xy`` (float32 [n, 2]), as the
        env's ``_trail_cell``: the offset from the origin turned by minus its heading."""
        d = xy - self.origin[:2]
        cos, sin = np.cos(self.origin[2]), np.sin(self.origin[2])
        local = np.stack([cos * d[:, 0] + sin * d[:, 1], cos * d[:, 1] - sin * d[:, 0]])
        index = np.floor(local / self.cell + np.float32(0.5))
        half = self.cells // 2
        # compared as floats: a point far off the grid never wraps around in an integer cast
        inside = ((index >= -half) & (index < self.cells - half)).all(axis=0)
        index = np.where(inside, index, -half).astype(np.int64) + half
        return index[0], index[1], inside

    def visit(self, pose: Sequence[float]) -> None:
        """Count one step at ``pose`` (x, y, yaw); the first after ``reset`` is the origin."""
        pose = self._pose(pose)
        if self.origin is None:
            self.origin = pose
        row, col, inside = self._cells(pose[None, :2])
        if inside[0] and self.grid[row[0], col[0]] < TRAIL_COUNT_MAX:
            self.grid[row[0], col[0]] += 1

    def counts(self, pose: Sequence[float]) -> np.ndarray:
        """Steps spent in the cells of ``points`` around ``pose`` (0 off the grid), ``int64``."""
        if self.origin is None:
            raise ValueError("no trail yet: visit(pose) first (after reset())")
        pose = self._pose(pose)
        step = self.cell * self.reach  # float32, as the env's trail_cell * [1, 2]
        angles = pose[2] + self.angles
        ring = np.stack([np.cos(angles), np.sin(angles)], -1) * step[:, None]
        # the robot's own cell is read at the pose itself, as the env reads it
        points = np.where((self.reach == 0)[:, None], pose[None, :2], pose[None, :2] + ring)
        row, col, inside = self._cells(points.astype(np.float32))
        return np.where(inside, self.grid[row, col], 0).astype(np.int64)

    def reading(self, pose: Sequence[float]) -> np.ndarray:
        """The observation's trail values at ``pose``: ``min(count / saturation, 1)``,
        ``float32[len(points)]``."""
        counts = self.counts(pose).astype(np.float32)
        return np.minimum(counts / self.saturation, np.float32(1.0))


def _waypoint_reading(waypoint: Sequence[float], pose: Sequence[float]) -> dict[str, float]:
    """The waypoint's bearing (sin, cos) and distance from ``pose`` (x, y, yaw)."""
    (wx, wy), (x, y, yaw) = waypoint, pose
    sin, cos = bearing(wx - x, wy - y, yaw)
    distance = math.hypot(wx - x, wy - y)
    return {"waypoint_bearing_sin": sin, "waypoint_bearing_cos": cos, "waypoint_distance": distance}


class ScanObservation:
    """Builds a policy's observations from scans, poses, goals (and waypoints), keeping the
    last ``frames`` frames (and an odometry trail, ``OdometryTrail``, and a lidar map,
    ``lidar_map.LidarMap``) as the simulator does; ``reset()`` at each episode's start."""

    def __init__(
        self,
        metadata: dict[str, Any] | Any,
        mount_yaw: float = 0.0,
        beam_width: float = 0.0,
        fill_uncovered: float | None = None,
        radius: float | None = None,
    ):
        """``metadata``: an exported policy's (``Policy.metadata``, or the ``Policy``);
        ``radius``: the robot's, in metres, for a policy that reads it (``robot_radius``)."""
        metadata = getattr(metadata, "metadata", metadata)
        sensors = metadata.get("sensors")
        if sensors is None:
            raise ValueError(
                f"{metadata.get('env_id')}: not a laser policy (no sensors in its metadata)"
            )
        obs = metadata["observation"]
        self.frame_entries = [e for e in obs["entries"] if e["frame"] == 0]
        self.frames = int(obs["frames"])
        self.size = int(obs["size"])
        self.beam_angles = np.asarray(sensors["beam_angles_rad"], np.float64)
        self.laser_range = float(sensors["laser_range_m"])
        self.needs_waypoint = any(e["name"].startswith("waypoint") for e in self.frame_entries)
        names = [e["name"] for e in self.frame_entries]
        # a map-free policy's own odometry: its previous action (one-hot) and its radius
        self.action_entries = [n for n in names if n.startswith("last_action_")]
        self.radius = None
        if "robot_radius" in names:
            if radius is None:
                raise ValueError(
                    "this policy reads the robot's radius (robot_radius): pass radius=<metres>"
                )
            (self.radius,) = check_finite("radius", [radius], 1)
            if self.radius <= 0:
                raise ValueError(f"radius={radius!r}: must be a positive number of metres")
        # an odometry trail: built from the pose each call, cleared by reset()
        self._trail_slots = [i for i, e in enumerate(self.frame_entries) if e["name"] == "trail"]
        trail = [self.frame_entries[i] for i in self._trail_slots]
        self.trail = self._trail(metadata, trail) if trail else None
        # a waypoint from the robot's own lidar map (``lidar_map``): built from the scans
        self.lidar_map = LidarMap.from_metadata(metadata) if sensors.get("lidar_map_m") else None
        self.own_waypoint: tuple[float, float] | None = None  # the last frame's, pose frame
        self._last_action: int | None = None
        self._acted = True  # no action is owed before the first observation
        self.mount_yaw = float(mount_yaw)
        self.beam_width = float(beam_width)
        self.fill_uncovered = fill_uncovered
        self._stack: list[np.ndarray] = []

    @staticmethod
    def _trail(metadata: dict[str, Any], entries: list[dict[str, Any]]) -> OdometryTrail:
        """The trail of a policy that reads one, as the metadata gives it."""
        sensors = metadata["sensors"]
        cell = sensors.get("trail_cell_m")
        if cell is None:  # exported before the metadata had it: the env config's field
            cell = (metadata.get("env_config") or {}).get("trail_cell")
        if not cell:
            raise ValueError(
                "this policy reads an odometry trail, but its metadata gives no trail_cell_m"
            )
        # before the metadata had them, every trail had the simulator's grid and saturation
        return OdometryTrail(
            cell,
            sensors.get("trail_cells", TRAIL_CELLS),
            sensors.get("trail_saturation", TRAIL_SATURATION),
            [(e["cells"], e["angle_rad"]) for e in entries],
        )

    def reset(self) -> None:
        """Forget the stacked frames (the next call fills every frame with its own), the
        previous action, the odometry trail (the next pose is its new origin) and the lidar
        map (the next scan starts it)."""
        self._stack = []
        self._last_action = None
        self._acted = True
        if self.trail is not None:
            self.trail.reset()
        if self.lidar_map is not None:
            self.lidar_map.clear()
            self.own_waypoint = None

    def acted(self, action: int) -> None:
        """Record the action the robot executed after the last observation: a policy that
        reads its previous action (``last_action_*``) needs it before the next one."""
        if isinstance(action, bool) or not isinstance(action, (int, np.integer)):
            raise ValueError(f"action={action!r}: must be an action index")
        if self.action_entries and not 0 <= action < len(self.action_entries):
            raise ValueError(
                f"action={action!r}: must be an index in [0, {len(self.action_entries)})"
            )
        self._last_action, self._acted = int(action), True

    def frame(
        self,
        scan: LaserScan,
        pose: Sequence[float],
        goal: Sequence[float],
        waypoint: Sequence[float] | None = None,
    ) -> np.ndarray:
        """One frame ``float32[frame_size]`` (no stacking). A policy with an odometry trail
        counts ``pose`` in it as this control step's visit, one with a lidar map adds the scan
        to it: one call per step. A lidar map policy reads its map's waypoint where
        ``waypoint`` is None."""
        x, y, yaw = check_finite("pose", pose, 3)
        gx, gy = check_finite("goal", goal, 2)
        own = self.lidar_map is not None and waypoint is None  # the map's waypoint, below
        if self.needs_waypoint and waypoint is None and not own:
            raise ValueError(
                "this policy reads a waypoint (waypoint_distance_m): pass waypoint=(x, y), "
                "a point that far ahead on a planned path to the goal"
            )
        ranges = resample_scan(
            scan, self.beam_angles, self.mount_yaw, self.beam_width, self.fill_uncovered
        )
        raw = {
            "goal_x": gx,
            "goal_y": gy,
            "robot_x": x,
            "robot_y": y,
            "goal_distance": math.hypot(gx - x, gy - y),
            "heading_sin": math.sin(yaw),
            "heading_cos": math.cos(yaw),
        }
        raw["goal_bearing_sin"], raw["goal_bearing_cos"] = bearing(gx - x, gy - y, yaw)
        for i, name in enumerate(self.action_entries):
            raw[name] = float(self._last_action == i)
        raw["robot_radius"] = self.radius
        if waypoint is not None:
            raw |= _waypoint_reading(check_finite("waypoint", waypoint, 2), (x, y, yaw))
        values = np.empty(len(self.frame_entries), np.float64)
        for i, e in enumerate(self.frame_entries):
            if e["name"] == "trail" or (own and e["name"].startswith("waypoint")):
                values[i] = 0.0  # below, once every input is checked
            else:
                values[i] = self._value(e, raw, ranges)
        too_large = ~(np.abs(values) <= np.finfo(np.float32).max)  # NaN or beyond float32
        if too_large.any():  # a pose or goal in other units or frame: no action from it
            e = self.frame_entries[int(np.argmax(too_large))]
            raise ValueError(
                f"{e['name']}={raw.get(e['name'], values[too_large][0]):g} in the observation: "
                "beyond float32 (check the units and frame of the pose, goal and waypoint)"
            )
        values = values.astype(np.float32)
        if self.lidar_map is not None:  # added after the checks: a refused input leaves it
            self.own_waypoint = self.lidar_map.update(pose, (gx, gy), ranges)
        if own:
            raw |= _waypoint_reading(self.own_waypoint, (x, y, yaw))
            for i, e in enumerate(self.frame_entries):
                if e["name"].startswith("waypoint"):
                    values[i] = self._value(e, raw, ranges)
        if self.trail is not None:  # counted last: a refused input leaves the trail as it was
            self.trail.visit(pose)
            values[self._trail_slots] = self.trail.reading(pose)
        return values

    def _value(self, entry: dict[str, Any], raw: dict[str, Any], ranges: np.ndarray) -> float:
        """The observation's value of ``entry`` from the beams' ``ranges`` and ``raw``
        quantities: scaled, then clipped."""
        if entry["name"] == "laser":
            value = min(ranges[entry["beam"]], self.laser_range) * entry["scale"]
        else:
            value = raw[entry["name"]] * entry["scale"]
        if entry["clip"] is not None:
            value = min(max(value, entry["clip"][0]), entry["clip"][1])
        return value

    def __call__(
        self,
        scan: LaserScan,
        pose: Sequence[float],
        goal: Sequence[float],
        waypoint: Sequence[float] | None = None,
    ) -> np.ndarray:
        """The observation ``float32[size]``: this frame after the last ``frames - 1`` ones,
        oldest first (right after ``reset()``, this frame in every slot)."""
        if self.action_entries and not self._acted:
            raise ValueError(
                "this policy reads its previous action (last_action_*): call acted(action) "
                "with the action executed since the last observation"
            )
        f = self.frame(scan, pose, goal, waypoint)
        self._acted = not self.action_entries
        self._stack = [f] * self.frames if not self._stack else [*self._stack[1:], f]
        return np.concatenate(self._stack)
