"""Environment ids and ``make``.

``RobotJaxNav-v0`` (``ROBOT_JAXNAV``) is JaxMARL's JaxNav single-robot benchmark as SFL
(Rutherford et al. 2024) trains and evaluates on it, in our robot env: its levels
(``envs/robot/jaxnav_levels.py``, a training bank of 4,096 levels of ``maze_seed`` 0), its
protocol (``goal_radius`` 0.3 m, ``max_steps`` 500, ``dt`` 0.1 s) and robot size, on the
kinematic backend with the map-free sensors (``robot.MAPFREE_SENSORS``: 32 lasers all around
read to 3.5 m, the goal's distance read to 16 m and its bearing, the previous action, the
robot's radius; 8 frames, 320 inputs). ``radius_range`` (e.g. 0.1-0.25) trains one policy for
robots of any size in it. JaxNav's robot is a 0.5 m square (corners 0.354 m from its centre;
SFL's collision radius setting is 0.3 m); ours is a disc, and a disc of radius 0.25 m is the
square's inscribed circle: it passes where the square's corners would touch, the square's own
footprint at any heading. Speeds: JaxNav's robot moves at up to 1.0 m/s and turns at up to 0.6
rad/s in SFL's configuration (1.0 rad/s JaxNav's default), with acceleration limits and
continuous or 15 discrete (v, omega) commands; ours keeps the generalist's 1.5 m/s and 2 rad/s
and its 4 actions (forward, backward, turn left, turn right), since JaxNav's robot is no
faster. Its lidar is 200 beams to 6 m; its reward is its own (ours is the generalist's).
``num_wall_slots`` 28: the most a level needed over 60,000 levels of seed 0 was 24 (10,000 of
seed 1,000,003: 24).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from jaxnav.environment import Environment, EnvParams
from jaxnav.envs import grid_maze
from jaxnav.envs.robot import env as robot
from jaxnav.envs.robot import generators

# RobotJaxNav-v0: JaxNav's levels and protocol with the generalist's map-free sensors (the
# module docstring says how its robot compares with JaxNav's)
ROBOT_JAXNAV: dict[str, Any] = {
    **robot.GENERALIST,
    "maze": "jaxnav",
    "maze_seed": 0,
    "num_layouts": 4096,
    "num_goal_cells": 0,  # every cell: a 9 x 9 level's full table is 13 KB
    "num_wall_slots": 28,
    **robot.MAPFREE_SENSORS,  # map-free, as JaxNav's robot
    "radius": 0.25,
    "goal_radius": 0.3,
    "max_steps": 500,
    "dt": 0.1,
    "backend": "kinematic",
}

# RobotNavMapfree-v0: the map-free generalist's env (benchmarks/mapfree_sweep.py row 14): the
# four families and JaxNav's levels in one bank, the map-free sensors with an odometry trail,
# robots of radius 0.10-0.245 m, JaxNav's goal radius
ROBOT_NAV_MAPFREE: dict[str, Any] = {
    **robot.GENERALIST,
    **robot.MAPFREE_SENSORS,
    "families": (*generators.FAMILIES, "jaxnav"),
    "radius_range": (0.1, 0.245),
    "goal_radius": 0.3,
    "trail_cell": 0.5,
}

# id -> (environment class, its default_config(), overrides that define the id)
_REGISTRY: dict[str, tuple[Callable[..., Environment], Callable[[], Any], dict[str, Any]]] = {
    "GridMaze-v0": (grid_maze.GridMaze, grid_maze.default_config, {}),
    "GridMaze-Random-v0": (
        grid_maze.GridMaze,
        grid_maze.default_config,
        # a waypoint 3 cells ahead: see grid_maze's docstring and benchmarks/grid_random_sweep.py
        {"random_layouts": True, "obs_mode": "sensor", "waypoint_cells": 3},
    ),
    "RobotSimple-v0": (robot.RobotNav, robot.default_config, {"maze": "simple"}),
    "RobotComplex-v0": (robot.RobotNav, robot.default_config, {"maze": "complex"}),
    "RobotRandom-v0": (robot.RobotNav, robot.default_config, {"maze": "random"}),
    "RobotMaze-v0": (robot.RobotNav, robot.default_config, {"maze": "file"}),
    "RobotNav-v0": (robot.RobotNav, robot.default_config, robot.GENERALIST),
    "RobotJaxNav-v0": (robot.RobotNav, robot.default_config, ROBOT_JAXNAV),
    "RobotNavMapfree-v0": (robot.RobotNav, robot.default_config, ROBOT_NAV_MAPFREE),
}


def _entry(env_id: str) -> tuple[Callable[..., Environment], Callable[[], Any], dict[str, Any]]:
    """``env_id``'s registry entry; ``ValueError`` naming the valid ids if there is none."""
    if not isinstance(env_id, str) or env_id not in _REGISTRY:
        raise ValueError(f"unknown env id {env_id!r}; valid ids: {', '.join(registered_envs())}")
    return _REGISTRY[env_id]


def env_family(env_id: str) -> str:
    """The family of ``env_id``'s env class ("grid", "robot"): presets are per family."""
    return _entry(env_id)[0].family


def registered_envs() -> list[str]:
    """The ids ``make`` accepts."""
    return list(_REGISTRY)


def env_config(env_id: str, **overrides: Any) -> Any:
    """The validated config ``make(env_id, **overrides)`` would build, without building it."""
    _, default_config, id_overrides = _entry(env_id)
    config = dataclasses.replace(default_config(), **id_overrides)
    valid = [f.name for f in dataclasses.fields(config)]
    for name in overrides:
        if name not in valid:
            raise ValueError(
                f"unknown override {name!r} for {env_id}; valid overrides: {', '.join(valid)}"
            )
    for name, value in overrides.items():  # e.g. --env-arg obs_heading=False: the string
        if isinstance(getattr(config, name), bool) and not isinstance(value, bool):
            raise ValueError(f"{name}={value!r}: must be true or false (JSON, lower case)")
    config = dataclasses.replace(config, **overrides)
    config.validate()
    return config


def config_fields(env_id: str) -> frozenset[str]:
    """The names of the settings ``env_config(env_id, ...)`` takes."""
    return frozenset(f.name for f in dataclasses.fields(_entry(env_id)[1]()))


def make(env_id: str, **overrides: Any) -> tuple[Environment, EnvParams]:
    """``env, params = make("GridMaze-v0", size=11)``; ``ValueError`` on a bad id or value."""
    config = env_config(env_id, **overrides)
    env = _entry(env_id)[0](config, name=env_id)
    return env, env.default_params
