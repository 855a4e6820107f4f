"""``jaxnav.deploy.lidar_map``, the numpy mirror of the robot's own map
(``jaxnav.envs.robot.lidar_map``), against the env: the same cells and field and the same
waypoint at every step of whole episodes; ``ScanObservation`` and ``Navigator`` run a
``lidar_map`` policy with no map and act as the simulator does."""

from __future__ import annotations

import functools
import math
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import LIDAR_SENSORS, TRAP_GOAL, TRAP_MAZE, TRAP_START

import jaxnav
from jaxnav import export, pretrained
from jaxnav.deploy import lidar_map as deploy_map
from jaxnav.deploy.lidar_map import LidarMap
from jaxnav.deploy.navigator import Navigator
from jaxnav.deploy.sensors import LaserScan, ScanObservation
from jaxnav.envs.robot import layout
from jaxnav.envs.robot import lidar_map as env_map

ROOT = Path(__file__).resolve().parents[1]
ROOMS = str(ROOT / "examples/mazes/rooms_doors.txt")
SENSORS = {**LIDAR_SENSORS, "lidar_map": 0.25}
TRAP = TRAP_MAZE
START, GOAL = TRAP_START, TRAP_GOAL
# The mazes here have 0.5 m cells and starts at cell centres, so wall faces lie on centres of
# the map's 0.25 m cells: a return's cell is never decided by float32 rounding (which the
# env's XLA functions and numpy round differently in the last bit)


@functools.cache
def maze_env(path: str):
    env, params = jaxnav.make("RobotMaze-v0", maze_file=path, **SENSORS)
    jitted = tuple(jax.jit(f) for f in (env.reset, env.step, env.lasers, env.own_waypoint))
    return env, params, jitted


@pytest.fixture(scope="module")
def trap(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("mazes") / "trap.txt"
    path.write_text(TRAP)
    return str(path)


def metadata(env, params) -> dict:
    """What an exported policy on ``env`` carries, but the network."""
    return {
        "env_id": "RobotMaze-v0",
        "observation": env.observation_layout(params),
        "actions": env.action_layout(),
        "sensors": env.sensor_layout(),
    }


def beam_scan(env, ranges: np.ndarray) -> LaserScan:
    """The env's own ranges as a scan with one reading per policy beam."""
    angles = np.asarray(env.angles, np.float64)
    return LaserScan(
        angle_min=float(angles[0]),
        angle_increment=float(angles[1] - angles[0]),
        range_max=12.0,
        ranges=np.asarray(ranges, np.float64),
    )


def test_the_constants_are_the_simulators():
    """The deploy module writes them out (it imports no JAX): they must stay the env's."""
    assert deploy_map.MAP_CELLS == layout.MAP_CELLS == env_map.MAP_CELLS
    assert deploy_map.MAP_SWEEPS == layout.MAP_SWEEPS == env_map.SWEEPS
    assert deploy_map.FAR == env_map.FAR
    assert deploy_map.ALIGN_TOLERANCE == env_map.ALIGN_TOLERANCE


@pytest.mark.parametrize("maze", ["rooms_doors", "trap"])
def test_the_map_and_waypoint_are_the_envs_over_whole_episodes(maze, trap):
    """Fed the env's ranges and poses over 150 steps of random play (auto-resets included),
    ``LidarMap`` keeps the env's cells and field exactly and gives its waypoint within 1e-5 m
    at every step; ``ScanObservation`` fed the same builds the env's observation."""
    env, params, (reset, step, lasers, own_waypoint) = maze_env(ROOMS if maze != "trap" else trap)
    own = LidarMap.from_metadata(metadata(env, params))
    observe = ScanObservation(metadata(env, params))
    assert (own.size, own.sweeps, own.waypoint_steps) == (96, 4, 4)
    key = jax.random.key(5)
    obs, state = reset(key, params)
    planned = 0
    for k in jax.random.split(key, 150):
        ranges = np.asarray(lasers(state.pose, state.layout, params), np.float64)
        pose, goal = np.asarray(state.pose, np.float64), np.asarray(state.goal, np.float64)
        point = own.update(pose, goal, ranges)
        m = state.own_map
        np.testing.assert_array_equal(own.cells, np.asarray(m.cells))
        np.testing.assert_array_equal(own.steps, np.asarray(m.steps))
        assert own.goal_cell == tuple(np.asarray(m.goal).tolist())
        # the wall angle sums float32 terms in another order than XLA: the last bit may differ
        np.testing.assert_allclose(own.frame, np.asarray(m.frame), rtol=0, atol=1e-6)
        want = np.asarray(own_waypoint(state.pose, state.goal, m))
        np.testing.assert_allclose(point, want, rtol=0, atol=1e-5)
        planned += not np.allclose(want, goal)
        got = observe(beam_scan(env, ranges), pose, goal)
        np.testing.assert_allclose(got, np.asarray(obs), rtol=0, atol=1e-5)
        np.testing.assert_allclose(observe.own_waypoint, want, rtol=0, atol=1e-5)
        action = jax.random.randint(k, (), 0, env.num_actions)
        obs, state, _, terminated, truncated, _ = step(k, state, action, params)
        if bool(terminated | truncated):
            own.clear()
            observe.reset()
    assert planned >= 100  # waypoints on the way, not only the goal itself
    assert (own.cells == 1).sum() > 50 and (own.cells == 2).sum() > 1


@pytest.mark.slow  # whole episodes of the shipped 1024-512-256 policy
def test_a_lidar_map_policy_runs_map_free_and_acts_as_in_the_simulator(trap):
    """The shipped map-free policy (robotnav-mapfree) run by a ``Navigator`` with no map, fed
    the env's ranges and poses: round the dead end to the goal, the env's own-map waypoint and
    the policy's action on the env's observation at every step."""
    policy = pretrained.load("robotnav-mapfree")
    overrides = {"maze_file": trap, "radius_range": None, "radius": 0.15}
    env_id, kwargs = export.env_for(policy, "RobotMaze-v0", overrides)
    env, params = jaxnav.make(env_id, **kwargs)
    sensors = env.sensor_layout()
    for k in ("lidar_map_m", "lidar_map_cells", "lidar_map_sweeps", "waypoint_distance_m"):
        assert policy.metadata["sensors"][k] == sensors[k]
    assert sensors["lidar_map_m"] == 0.25
    assert env.observation_layout(params)["entries"] == policy.metadata["observation"]["entries"]
    nav = Navigator(policy)
    assert nav.map is None and nav.planner is None and nav.uses_lidar_map
    reset_to, step, lasers = jax.jit(env.reset_to), jax.jit(env.step_env), jax.jit(env.lasers)
    own_waypoint = jax.jit(env.own_waypoint)
    steps = planned = 0
    for heading in (0.0, 2.0):  # toward the dead end, and away from it
        pose = jnp.asarray([*START, heading])
        obs, state = reset_to(jax.random.key(0), params, pose, jnp.asarray(GOAL))
        nav.reset(goal=GOAL)
        for _ in range(int(params.max_steps_in_episode)):
            ranges = np.asarray(lasers(state.pose, state.layout, params), np.float64)
            action = nav.act(scan=beam_scan(env, ranges), pose=np.asarray(state.pose, np.float64))
            want = np.asarray(own_waypoint(state.pose, state.goal, state.own_map))
            np.testing.assert_allclose(nav.waypoint, want, rtol=0, atol=1e-5)
            np.testing.assert_array_equal(nav.observe.lidar_map.cells, state.own_map.cells)
            planned += not np.allclose(want, GOAL)
            assert action == policy.act(np.asarray(obs))
            obs, state, _, done, info = step(jax.random.key(0), state, jnp.int32(action), params)
            steps += 1
            if bool(done):
                break
        assert bool(info["goal_reached"])
    assert steps >= 20 and planned >= steps // 2


def test_bad_inputs_are_named_in_one_line():
    angles = np.linspace(-math.pi, math.pi, 32, endpoint=False)
    own = LidarMap(0.25, angles, 3.5, 1.0)
    with pytest.raises(ValueError, match=r"^no map yet: reset\(pose, goal, ranges\)"):
        own.observe((0.0, 0.0, 0.0), np.full(32, 2.0))
    with pytest.raises(ValueError, match=r"^ranges: 31 values, the policy has 32 beams"):
        own.reset((0.0, 0.0, 0.0), (2.0, 0.0), np.full(31, 2.0))
    with pytest.raises(ValueError, match=r"^pose=\(0.0, nan, 0.0\): must be finite"):
        own.reset((0.0, math.nan, 0.0), (2.0, 0.0), np.full(32, 2.0))
    with pytest.raises(ValueError, match=r"^goal=\(inf, 0.0\): must be finite"):
        own.reset((0.0, 0.0, 0.0), (math.inf, 0.0), np.full(32, 2.0))
    for bad in (-1.0, math.nan):
        with pytest.raises(ValueError, match=rf"^ranges: a beam reads {bad}: must be >= 0"):
            own.reset((0.0, 0.0, 0.0), (2.0, 0.0), np.r_[np.full(31, 2.0), bad])
    assert own.frame is None  # a refused scan starts nothing
    for kwargs, named in [
        ({"cell": -0.25}, "lidar_map_m=-0.25: must be a positive number"),
        ({"laser_range": 0}, "laser_range_m=0: must be a positive number"),
        ({"waypoint_distance": math.nan}, "waypoint_distance_m=nan: must be a positive number"),
        ({"moves": 6}, "waypoint_moves=6: must be 4 or 8"),
        ({"sweeps": 0}, "lidar_map_sweeps=0: must be a positive integer"),
        ({"size": 9.5}, "lidar_map_cells=9.5: must be a positive integer"),
    ]:
        args = {"cell": 0.25, "beam_angles": angles, "laser_range": 3.5, "waypoint_distance": 1.0}
        with pytest.raises(ValueError, match="^" + named.replace("(", r"\(")):
            LidarMap(**{**args, **kwargs})
    with pytest.raises(ValueError, match=r"not a lidar_map policy"):
        LidarMap.from_metadata({"env_id": "RobotNav-v0", "sensors": {"laser_range_m": 3.5}})
    sensors = {"lidar_map_m": 0.25, "waypoint_distance_m": None}
    with pytest.raises(ValueError, match=r"^lidar_map_m=0.25: needs waypoint_distance_m"):
        LidarMap.from_metadata({"sensors": sensors})


def test_the_map_clears_and_plans_around_what_it_saw():
    """In an empty square with no wall near the start, the waypoint is straight toward the
    goal; a wall seen across the way turns it; ``clear`` forgets the map."""
    angles = np.linspace(-math.pi, math.pi, 32, endpoint=False)
    own = LidarMap(0.25, angles, 3.5, 1.0)
    far = np.full(32, np.inf)  # nothing within range
    assert own.update((0.0, 0.0, 0.0), (3.0, 0.0), far) == pytest.approx((1.0, 0.0), abs=1e-6)
    assert own.frame[2] == 0.0  # no wall seen: the heading's axes
    near = own.waypoint((2.6, 0.0, 0.0), (3.0, 0.0))
    assert near == (3.0, 0.0)  # the descent reaches the goal's cell: the goal itself
    own.clear()
    # a wall across the way at x = 1 m, 2 m wide: its returns block the straight line
    cos = np.cos(angles)
    wall = np.where((cos > 0) & (np.abs(np.tan(angles)) <= 1.0), 1.0 / np.maximum(cos, 1e-9), far)
    own.reset((0.0, 0.0, 0.0), (3.0, 0.0), wall)
    assert abs(abs(float(own.frame[2])) - math.pi / 2) < 1e-6  # the wall's direction
    for _ in range(30):  # the field settles around the wall
        own.observe((0.0, 0.0, 0.0), wall)
    x, y = own.waypoint((0.0, 0.0, 0.0), (3.0, 0.0))
    assert x < 1.0 and abs(y) >= 0.5, (x, y)
    own.clear()
    assert own.frame is None and own.cells is None
    with pytest.raises(ValueError, match=r"^no map yet"):
        own.waypoint((0.0, 0.0, 0.0), (3.0, 0.0))


def test_the_deploy_module_imports_no_jax():
    code = (
        "import sys\n"
        "import jaxnav.deploy.lidar_map, jaxnav.deploy.sensors, jaxnav.deploy.navigator\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'flax'))\n"
        "assert not bad, bad\n"
    )
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
