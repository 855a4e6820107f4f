"""Generalization families (``experiments.Family``): a run's policy on another env id gets every
setting of the run's env that shapes its observation or motion, but not the run's mazes."""

from __future__ import annotations

import functools

import jaxnav
from jaxnav.config import TrainConfig
from jaxnav.envs.grid_maze import HELD_OUT_LAYOUT_SEED
from jaxnav.envs.robot.env import GENERALIST, RobotConfig
from jaxnav.experiments import OWN, Family, default_families

# a small bank on another seed: the run's own maze-picking overrides must stay behind too
RUN = TrainConfig.for_env("RobotNav-v0", algo="pqn", env_kwargs={"num_layouts": 4, "maze_seed": 7})


@functools.cache
def obs_size(env_id: str, **kwargs) -> int:
    env, params = jaxnav.make(env_id, **kwargs)
    return env.observation_space(params).shape[0]


def test_another_env_gets_the_generalists_settings_less_its_mazes():
    env, kwargs = Family("RobotComplex-v0", "RobotComplex-v0").for_run(RUN)
    assert env == "RobotComplex-v0"
    # the id's own settings (RobotNav-v0's sensors, backend, motion, reward), not just overrides
    want = {
        "num_lasers": 32,
        "laser_fov": 360.0,
        "laser_range": 3.5,
        "obs_absolute": False,
        "waypoint_distance": 1.0,
        "backend": "kinematic",
        "turn_speed": 2.0,
        "max_steps": 800,
        "speed": 1.5,
        "collision_reward": -10.0,
    }
    assert {k: kwargs.get(k) for k in want} == want
    for key in ("maze", "num_layouts", "num_goal_cells", "families", "maze_seed"):
        assert key not in kwargs, key
    assert not set(kwargs) & RobotConfig.MAZE_FIELDS
    # only what differs from the target's own config: the frame count is the same
    assert "frames" not in kwargs and "radius" not in kwargs
    # the same observation as the run's env, on the paper's complex maze
    assert obs_size(env, **kwargs) == obs_size("RobotNav-v0", **RUN.env_kwargs)
    assert jaxnav.make(env, **kwargs)[0].config.maze == "complex"


def test_a_familys_own_values_beat_the_carried_ones_and_own_keeps_everything():
    family = Family("short lidar", "RobotSimple-v0", {"laser_range": 5.0, "max_steps": 50})
    env, kwargs = family.for_run(RUN)
    assert env == "RobotSimple-v0" and kwargs["laser_range"] == 5.0 and kwargs["max_steps"] == 50
    assert kwargs["num_lasers"] == 32 and "maze_seed" not in kwargs
    env, kwargs = Family("own", OWN, {"maze_seed": 11}).for_run(RUN)
    assert env == "RobotNav-v0" and kwargs == {"num_layouts": 4, "maze_seed": 11}


def test_every_default_family_of_the_generalist_fits_its_policy():
    """The held-out bank, the paper's mazes and every example maze file: each builds with the
    run's observation size, so ``generalization`` skips none of them."""
    families = default_families(RUN)
    assert len(families) >= 4
    want = obs_size("RobotNav-v0", **RUN.env_kwargs)
    for family in families:
        env, kwargs = family.for_run(RUN)
        assert obs_size(env, **kwargs) == want, family.name
        if env != "RobotNav-v0":
            assert kwargs["waypoint_distance"] == GENERALIST["waypoint_distance"], family.name


def test_a_grid_runs_default_families_are_held_out_layouts_and_its_training_ones():
    """A GridMaze run is tested on the layouts of the held-out ``layout_seed`` (the one whose
    bank shares no layout with training's, tests/test_grid_maze.py) and on its own; a robot
    family would not fit its observations."""
    run = TrainConfig.for_env("GridMaze-Random-v0", env_kwargs={"size": 7, "num_layouts": 8})
    held_out, training = default_families(run)
    assert held_out.for_run(run) == (
        "GridMaze-Random-v0",
        {"size": 7, "num_layouts": 8, "layout_seed": HELD_OUT_LAYOUT_SEED},
    )
    assert training.for_run(run) == ("GridMaze-Random-v0", {"size": 7, "num_layouts": 8})
