"""The deployment loop in one object: an exported policy, a map (for the waypoint policies),
the robot's pose, a lidar scan and a goal in, the action out; numpy and the standard library
alone (a map *file* needs the simulator's install, below).

::

    nav = Navigator("policy.npz", map=GridMap.from_occupancy_grid(...), radius=0.15)
    nav.reset(goal=(gx, gy))                          # at every new goal, map frame
    while driving:                                    # every control period
        action = nav.act(scan=LaserScan.from_msg(msg), pose=(x, y, yaw))
        v, omega = nav.speeds(action)

What it does each ``act``: checks the inputs (one-line ``ValueError`` naming the bad value: a
NaN pose, a scan whose size does not fit its angles or whose field of view misses the
policy's beams, a goal off the map or inside a wall, a pose with no path to the goal); plans
the waypoint with ``planner.Planner`` (walls inflated by the robot's ``radius`` plus
``margin``, the same descent as the simulator's) for a policy that reads one, or on the
robot's own lidar map for a policy trained so (metadata ``lidar_map_m``: ``ScanObservation``
keeps the map, ``jaxnav.deploy.lidar_map``, and no map is needed); converts the
scan to the policy's beams (``sensors.ScanObservation``: any beam count, angular range and
mounting) and stacks frames; acts greedily (``Policy.act``, after ``reset()`` at each goal
for a policy with memory); and records the action for a policy that reads its last one.

Frames: pose and goal are in the map's frame (a ROS map's, e.g. ``map``); the policy sees the
simulator's, whose origin is the map's lower-left corner (``GridMap.origin``). Map-free
policies, lidar map ones included, take any fixed frame and no map (one given is used to check
the goal); a lidar map needs poses of one continuous odometry.

Maps: a ``planner.GridMap``, numpy only: ``GridMap.from_occupancy_grid`` reads a ROS
``nav_msgs/OccupancyGrid`` (map_server's ``/map``). A text maze or a map_server YAML file is
read as the simulator reads it by ``jaxnav.envs.robot.occupancy.load_grid_map`` (that needs
the simulator's install: JAX, Pillow and PyYAML).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence

from jaxnav.deploy.planner import DEFAULT_MARGIN, GridMap, Planner
from jaxnav.deploy.policy import Policy
from jaxnav.deploy.sensors import LaserScan, ScanObservation, check_finite


class Navigator:
    """An exported policy driving a robot to goals; the module docstring says how."""

    def __init__(
        self,
        policy: str | os.PathLike[str] | Policy,
        *,
        map: GridMap | None = None,
        radius: float | None = None,
        margin: float = DEFAULT_MARGIN,
        mount_yaw: float = 0.0,
        beam_width: float = 0.0,
        fill_uncovered: float | None = None,
        shielded: bool | None = None,
    ):
        """``policy``: an npz file or a loaded ``Policy``; ``map``: a ``GridMap`` (None for a
        map-free policy); ``radius``: the robot's, metres (None: the one the policy was trained
        with); ``margin``: metres more the planned path keeps from walls; ``mount_yaw``,
        ``beam_width``, ``fill_uncovered``: as ``ScanObservation``'s; ``shielded``: act only
        among the moves the lidar does not show blocked over the next step, for a robot of
        ``radius`` (``jaxnav.deploy.shield``; None: where the policy was trained so)."""
        self.policy = policy if isinstance(policy, Policy) else Policy.load(policy)
        meta = self.policy.metadata
        sensors = meta.get("sensors")
        if sensors is None:
            raise ValueError(
                f"{meta.get('env_id')}: not a laser policy (no sensors in its metadata)"
            )
        if radius is None:
            radius = sensors["robot_radius_m"]
        (self.radius,) = check_finite("radius", [radius], 1)
        if self.radius <= 0:
            raise ValueError(f"radius={radius!r}: must be a positive number of metres")
        self.observe = ScanObservation(
            meta, mount_yaw, beam_width, fill_uncovered, radius=self.radius
        )
        if map is not None and not isinstance(map, GridMap):
            raise ValueError(
                f"map={map!r}: must be a GridMap or None (a map file: "
                "jaxnav.envs.robot.occupancy.load_grid_map(path))"
            )
        names = {e["name"] for e in self.observe.frame_entries}
        # a lidar map policy plans on the map ScanObservation builds from its scans
        self.uses_lidar_map = self.observe.lidar_map is not None
        plans = self.observe.needs_waypoint and not self.uses_lidar_map
        for needs, what in (
            (plans, "a waypoint on a planned path"),
            ("robot_x" in names, "positions in the map's frame"),
        ):
            if needs and map is None:
                raise ValueError(f"this policy reads {what}: pass map=<GridMap>")
        self.map = map
        self.planner = None
        if map is not None:
            self.planner = Planner(
                map,
                radius=self.radius,
                margin=margin,
                waypoint_distance=sensors["waypoint_distance_m"] or 1.0,
                moves=sensors["waypoint_moves"] or 8,
            )
        self.actions = meta["actions"]
        self.shield = None
        if shielded is None:
            shielded = "collision_monitor" in sensors
        if shielded:  # the observation's radius where it has one, else this robot's
            self.shield = dataclasses.replace(self.policy.shield, radius=self.radius)
        self.goal: tuple[float, float] | None = None
        self.waypoint: tuple[float, float] | None = None  # the last act's, map frame

    def reset(self, goal: Sequence[float]) -> None:
        """Start driving to ``goal`` (x, y), in the map's frame: plans to it, forgets the
        stacked frames, the last action, the odometry trail, the lidar map and the policy's
        memory; ``ValueError`` naming a goal that is not finite, off the map or inside a wall."""
        gx, gy = check_finite("goal", goal, 2)
        if self.planner is not None:
            self.planner.set_goal((gx, gy))
        self.goal, self.waypoint = (gx, gy), None
        self.observe.reset()
        reset = getattr(self.policy, "reset", None)  # a policy with memory starts afresh
        if callable(reset):
            reset()

    def act(self, *, scan: LaserScan, pose: Sequence[float]) -> int:
        """The action (an index into the policy's ``actions``) for the robot at ``pose``
        (x, y, yaw; map frame, radians) seeing ``scan``; ``ValueError`` naming a bad input."""
        if self.goal is None:
            raise ValueError("no goal: call reset(goal) first")
        x, y, yaw = check_finite("pose", pose, 3)
        if not isinstance(scan, LaserScan):
            raise ValueError(
                f"scan={type(scan).__name__}: must be a LaserScan (LaserScan(ranges=..., "
                "angle_min=..., ...) or LaserScan.from_msg(msg))"
            )
        ox, oy = (0.0, 0.0) if self.map is None else self.map.origin
        waypoint = None
        if self.observe.needs_waypoint and not self.uses_lidar_map:
            self.waypoint = self.planner.waypoint(x, y)
            waypoint = (self.waypoint[0] - ox, self.waypoint[1] - oy)
        gx, gy = self.goal
        obs = self.observe(scan, (x - ox, y - oy, yaw), (gx - ox, gy - oy), waypoint)
        if self.uses_lidar_map:
            wx, wy = self.observe.own_waypoint
            self.waypoint = (wx + ox, wy + oy)
        action = self.policy.act(obs, self.shield)
        self.observe.acted(action)
        return action

    def speeds(self, action: int) -> tuple[float, float]:
        """``(v, omega)``: the action's forward speed (m/s) and turn rate (rad/s, left +)."""
        a = self.actions[action]
        return float(a["v_mps"]), float(a["omega_radps"])
