"""What a robot env's observation, actions and sensors are, value by value: the metadata an
exported policy carries (``jaxnav.export``) so a robot can build the same observation."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

TRAIL_ANGLES = tuple(np.linspace(0.0, 2 * np.pi, 8, endpoint=False))  # from the heading
TRAIL_SATURATION = 16  # steps in a trail cell that read as 1
# the robot's own map (``lidar_map``): cells per side, the start at the centre (24 m at 0.25 m
# cells), and Bellman sweeps of its field a control step
MAP_CELLS = 96
MAP_SWEEPS = 4
TRAIL_CELLS = 64  # the trail's cells per side, centred on the start (outside: not kept, reads 0)


def entry(name: str, scale: float = 1.0, clip: Sequence[float] | None = None, **more: Any):
    """One observation value: ``name``, ``scale`` (value = raw quantity x scale), ``clip``."""
    return {"name": name, "scale": scale, "clip": None if clip is None else list(clip), **more}


def frame_layout(env: Any, action_names: Sequence[str]) -> list[dict[str, Any]]:
    """One frame of a robot env's observation, value by value in the env's order (its
    ``_frame``): ``name``, ``scale`` (value = raw quantity x scale), ``clip`` (of the value,
    or None) and, for lasers, the beam's ``angle_rad`` from the heading (counter-clockwise)."""
    c = env.config
    inv_range = 1.0 / c.laser_range
    entries = [
        entry("laser", inv_range, (0.0, 1.0), beam=i, angle_rad=float(a))
        for i, a in enumerate(np.asarray(env.angles, np.float64))
    ]
    if c.obs_absolute:
        width, height = (float(v) for v in env.arena)
        entries += [
            entry("goal_x", 1.0 / width),
            entry("goal_y", 1.0 / height),
            entry("robot_x", 1.0 / width),
            entry("robot_y", 1.0 / height),
        ]
    if c.obs_proximity:
        entries.append(entry("goal_distance", 1.0 / (c.goal_range or c.laser_range), (0.0, 1.0)))
    if c.obs_heading:
        entries += [entry("heading_sin"), entry("heading_cos")]
    if c.obs_goal_bearing:
        entries += [entry("goal_bearing_sin"), entry("goal_bearing_cos")]
    if c.waypoint_distance:
        entries += [
            entry("waypoint_bearing_sin"),
            entry("waypoint_bearing_cos"),
            entry("waypoint_distance", inv_range, (0.0, 1.0)),
        ]
    if c.obs_last_action:
        entries += [entry(f"last_action_{name}") for name in action_names]
    if c.obs_radius:
        entries.append(entry("robot_radius", 1.0, (0.0, 1.0)))
    if c.trail_cell:
        saturation = 1.0 / TRAIL_SATURATION
        entries.append(entry("trail", saturation, (0.0, 1.0), cells=0, angle_rad=0.0))
        entries += [
            entry("trail", saturation, (0.0, 1.0), cells=k, angle_rad=float(a))
            for a in TRAIL_ANGLES
            for k in (1, 2)
        ]
    return entries


def quantities(action_names: Sequence[str]) -> dict[str, str]:
    """What each observation name of ``frame_layout`` measures."""
    return {
        "laser": "range in metres from the robot's centre along the beam, clipped to the laser "
        "range (no hit reads the range)",
        "goal_x": "goal x in metres, in the maze's frame (origin at its lower-left corner)",
        "goal_y": "goal y in metres, in the maze's frame",
        "robot_x": "robot x in metres, in the maze's frame",
        "robot_y": "robot y in metres, in the maze's frame",
        "goal_distance": "straight-line distance robot to goal in metres",
        "heading_sin": "sin of the heading (radians, counter-clockwise from +x)",
        "heading_cos": "cos of the heading",
        "goal_bearing_sin": "sin of the goal's direction minus the heading",
        "goal_bearing_cos": "cos of the goal's direction minus the heading",
        "waypoint_bearing_sin": "sin of the waypoint's direction minus the heading (the waypoint: "
        "about waypoint_distance_m metres ahead on a shortest path, from a planner)",
        "waypoint_bearing_cos": "cos of the waypoint's direction minus the heading",
        "waypoint_distance": "straight-line distance robot to waypoint in metres",
        **{
            f"last_action_{name}": f"1 if the previous action was {name}, else 0 (0 after a reset)"
            for name in action_names
        },
        "robot_radius": "the robot's radius in metres",
        "trail": "steps the robot's path has spent in the odometry trail's square cell (side "
        "trail_cell_m, in the frame of the episode's start pose) holding the point `cells` "
        "cells from the robot at `angle_rad` from its heading",
    }


def observation_layout(env: Any, action_names: Sequence[str]) -> dict[str, Any]:
    """The observation's layout: ``entries`` (one per input value, in order: ``index``,
    ``frame`` (0 the oldest), ``name``, ``scale``, ``clip`` and the entry's own fields), the
    frame stacking and what each name means."""
    frame = frame_layout(env, action_names)
    frames = env.config.frames
    entries = [
        {"index": f * len(frame) + i, "frame": f, **e}
        for f in range(frames)
        for i, e in enumerate(frame)
    ]
    return {
        "size": len(entries),
        "frames": frames,
        "frame_size": len(frame),
        "stacking": "the last `frames` frames, oldest first; after a reset every frame is "
        "the first one",
        "env_dtype": "float32",
        "entries": entries,
        "quantities": quantities(action_names),
        "value": "clip(raw quantity x scale) where clip is given, else raw x scale",
    }


def action_layout(env: Any, action_names: Sequence[str]) -> list[dict[str, Any]]:
    """What each action index does: the robot's speeds (m/s, rad/s)."""
    c = env.config
    speeds = ((c.speed, 0.0), (-c.speed, 0.0), (0.0, c.turn_speed), (0.0, -c.turn_speed))
    return [
        {"index": i, "name": n, "v_mps": v, "omega_radps": w}
        for i, (n, (v, w)) in enumerate(zip(action_names, speeds, strict=True))
    ]


def sensor_layout(env: Any) -> dict[str, Any]:
    """The robot's lidar, frames and control period as the policy was trained with them."""
    c = env.config
    out = {
        "num_lasers": c.num_lasers,
        "laser_fov_deg": c.laser_fov,
        "laser_range_m": c.laser_range,
        "beam_angles_rad": [float(a) for a in np.asarray(env.angles, np.float64)],
        "beam_origin": "the robot's centre",
        "angle_convention": "radians from the heading, counter-clockwise (left) positive; for a "
        "field of view under 360 degrees index 0 is the rightmost beam",
        "frames": c.frames,
        "control_period_s": c.dt,
        "robot_radius_m": c.radius,
        "goal_radius_m": c.goal_radius,
        "arena_m": [float(v) for v in env.arena] if c.obs_absolute else None,
        "waypoint_distance_m": c.waypoint_distance or None,
        "waypoint_moves": c.waypoint_moves if c.waypoint_distance else None,
    }
    if c.shielded:  # (absent without, as the trail's)
        out["collision_monitor"] = (
            "trained with jaxnav.deploy.shield: a move it blocks is not executed"
        )
    if c.trail_cell:  # (absent without: the metadata of policies without a trail stays as it was)
        out |= {
            "trail_cell_m": c.trail_cell,
            "trail_cells": TRAIL_CELLS,
            "trail_saturation": TRAIL_SATURATION,
            "trail_frame": "the pose of the robot's first observation after a reset (its "
            "odometry's origin); cell (trail_cells // 2, trail_cells // 2) is centred on it",
        }
    if c.lidar_map:  # (absent without)
        out |= {
            "lidar_map_m": c.lidar_map,
            "lidar_map_cells": MAP_CELLS,
            "lidar_map_sweeps": MAP_SWEEPS,
            "waypoint_source": "a planner on the robot's own lidar map "
            "(jaxnav.envs.robot.lidar_map): unseen cells free, no map of the maze",
        }
    return out
