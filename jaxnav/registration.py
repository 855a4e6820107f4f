"""Environment ids and ``make``."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from jaxnav.environment import Environment, EnvParams
from jaxnav.envs import grid_maze
from jaxnav.envs.robot import env as robot

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
}


def _entry(env_id: str) -> tuple[Callable[..., Environment], Callable[[], Any], dict[str, Any]]:
    """``env_id``'s registry entry; ``ValueError`` naming the valid ids if there is none."""
    if not isinstance(env_id, str) or env_id not in _REGISTRY:
        raise ValueError(f"unknown env id {env_id!r}; valid ids: {', '.join(registered_envs())}")
    return _REGISTRY[env_id]


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


def make(env_id: str, **overrides: Any) -> tuple[Environment, EnvParams]:
    """``env, params = make("GridMaze-v0", size=11)``; ``ValueError`` on a bad id or value."""
    config = env_config(env_id, **overrides)
    env = _entry(env_id)[0](config, name=env_id)
    return env, env.default_params
