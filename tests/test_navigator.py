"""``jaxnav.deploy.navigator.Navigator``, the deployment loop, against the simulator: fed what a
real robot has (a lidar of another beam count and angular offset, a noisy pose, a goal in the
map's frame), it drives the shipped policies to their goals as often as the env's own
evaluation does; it plans the env's waypoints in the map's frame; bad inputs get one line."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav
from jaxnav import pretrained
from jaxnav.deploy.navigator import Navigator
from jaxnav.deploy.planner import GridMap
from jaxnav.deploy.policy import Policy
from jaxnav.deploy.sensors import LaserScan
from jaxnav.envs.robot import geometry
from jaxnav.envs.robot.occupancy import load_grid_map
from jaxnav.export import env_for

ROOMS = "examples/mazes/rooms_doors.txt"
FLOOR = "examples/maps/floor.yaml"
# the robot's lidar: 450 readings all around (0.8 deg apart) from 0.37 deg past -180, so no
# reading lies on a policy beam (every 11.25 deg); 12 m range, +inf beyond
SCAN_BEAMS, SCAN_OFFSET, SCAN_RANGE = 450, math.radians(0.37), 12.0
POSE_NOISE = (0.02, 0.02, 0.02)  # std of x, y (metres) and yaw (radians), per control step


@functools.cache
def simulator(name: str, env_id: str | None, **overrides):
    """``(policy, env, params, reset, step, cast)`` for the shipped policy ``name`` on
    ``env_id`` (None: its own) with ``overrides``; ``cast`` gives the robot's scan ranges."""
    policy = pretrained.load(name)
    env_id, kwargs = env_for(policy, env_id, overrides)
    env, params = jaxnav.make(env_id, **kwargs)
    angles = jnp.asarray(-math.pi + SCAN_OFFSET + 2 * math.pi / SCAN_BEAMS * np.arange(SCAN_BEAMS))

    @jax.jit
    def cast(state):
        w = jax.tree.map(lambda x: x[state.layout], params.bank.walls)
        lo, hi = geometry.box_bounds(w.center, w.half_size, w.active)
        return geometry.lasers(state.pose, lo, hi, angles, 1e6)

    reset = jax.jit(env.reset)
    step = jax.jit(env.step_env)
    return policy, env, params, reset, step, cast


def robot_scan(ranges: np.ndarray) -> LaserScan:
    """What the robot's lidar publishes for the simulator's ``ranges``."""
    ranges = np.where(ranges > SCAN_RANGE, np.inf, np.asarray(ranges, np.float64))
    increment = 2 * math.pi / SCAN_BEAMS
    return LaserScan(
        angle_min=-math.pi + SCAN_OFFSET,
        angle_max=-math.pi + SCAN_OFFSET + increment * (SCAN_BEAMS - 1),
        angle_increment=increment,
        range_min=0.05,
        range_max=SCAN_RANGE,
        ranges=ranges,
    )


def episode(sim, key, navigator=None, origin=(0.0, 0.0), seed: int = 0) -> str:
    """One episode from ``env.reset(key)``: the policy on the env's own observations, or, with
    a ``navigator`` (None: build one per episode for the drawn radius), driven by it from
    scans and noisy poses in the map's frame (env + ``origin``). Its outcome."""
    policy, env, params, reset, step, cast = sim
    obs, state = reset(key, params)
    rng = np.random.default_rng(seed)
    if navigator is not None:
        navigator.reset(goal=np.asarray(state.goal) + origin)
    for _ in range(int(params.max_steps_in_episode)):
        if navigator is None:
            action = policy.act(np.asarray(obs))
        else:
            pose = np.asarray(state.pose, np.float64) + rng.normal(0, POSE_NOISE)
            pose[:2] += origin
            action = navigator.act(scan=robot_scan(np.asarray(cast(state))), pose=pose)
        obs, state, _, done, info = step(key, state, jnp.int32(action), params)
        if bool(done):
            return "goal" if bool(info["goal_reached"]) else "collision"
    return "timeout"


def success(outcomes: list[str]) -> float:
    return sum(o == "goal" for o in outcomes) / len(outcomes)


# the closed loop: the same episodes (starts, goals, robot sizes) both ways; the tolerance is
# about two standard errors of a difference of two success rates near 0.95 over 40 episodes
EPISODES, TOLERANCE = 40, 0.1


@pytest.mark.slow
def test_the_navigator_reaches_goals_as_often_as_the_envs_evaluation_with_a_map():
    """robotnav-pqn (a waypoint policy) on the six-room maze: the Navigator plans on the maze
    file itself (radius 0.15 m, 0.05 m margin) and reads the robot's lidar and noisy pose."""
    sim = simulator("robotnav-pqn", "RobotMaze-v0", maze_file=ROOMS, num_wall_slots=40)
    nav = Navigator(sim[0], map=load_grid_map(ROOMS))
    keys = jax.random.split(jax.random.key(7), EPISODES)
    own = [episode(sim, k) for k in keys]
    driven = [episode(sim, k, nav, seed=i) for i, k in enumerate(keys)]
    print(f"env {success(own):.3f}, navigator {success(driven):.3f} over {EPISODES} episodes")
    assert success(own) >= 0.9
    assert abs(success(driven) - success(own)) <= TOLERANCE, (own, driven)


@pytest.mark.slow  # whole episodes on 16 levels, stepped one at a time from numpy
def test_the_navigator_reaches_goals_as_often_as_the_envs_evaluation_without_a_map():
    """robotjaxnav-mapfree (no waypoint; reads its radius and last action) on 16 JaxNav levels
    with the robot's radius drawn per episode: one Navigator per episode with that radius."""
    sim = simulator("robotjaxnav-mapfree", None, num_layouts=16)
    policy, env, params, reset, *_ = sim
    keys = jax.random.split(jax.random.key(8), EPISODES)
    own = [episode(sim, k) for k in keys]
    driven = []
    for i, k in enumerate(keys):
        radius = float(reset(k, params)[1].radius)
        driven.append(episode(sim, k, Navigator(policy, radius=radius), seed=i))
    print(f"env {success(own):.3f}, navigator {success(driven):.3f} over {EPISODES} episodes")
    assert success(own) >= 0.9
    assert abs(success(driven) - success(own)) <= TOLERANCE, (own, driven)


def test_on_an_occupancy_map_the_navigator_plans_the_envs_waypoints_in_the_maps_frame():
    """On the floor plan (a map_server map whose origin is (-6, -4)), with poses and goals in
    the map's frame: the Navigator's waypoint is the env's plus the origin and, fed a scan
    with the policy's own beams and the true pose, its action is the policy's on the env's
    observation, step after step of an episode."""
    sim = simulator("robotnav-pqn", "RobotMaze-v0", maze_file=FLOOR, num_wall_slots=64)
    policy, env, params, reset, step, _ = sim
    origin = np.asarray(env.layout_origins[0])
    assert origin.tolist() == [-6.0, -4.0]
    nav = Navigator(policy, map=load_grid_map(FLOOR))
    beams = jnp.asarray(policy.metadata["sensors"]["beam_angles_rad"])
    waypoint, lasers = jax.jit(env.waypoint), jax.jit(env.lasers)
    steps = planned = 0
    for k in jax.random.split(jax.random.key(3), 3):
        obs, state = reset(k, params)
        nav.reset(goal=np.asarray(state.goal) + origin)
        for _ in range(20):
            ranges = np.asarray(lasers(state.pose, state.layout, params))
            increment = float(beams[1] - beams[0])
            scan = LaserScan(
                angle_min=float(beams[0]), angle_increment=increment, range_max=1e6, ranges=ranges
            )
            pose = np.asarray(state.pose, np.float64) + [*origin, 0.0]
            action = nav.act(scan=scan, pose=pose)
            want = np.asarray(waypoint(state.pose, state.goal, state.layout, params)) + origin
            np.testing.assert_allclose(nav.waypoint, want, atol=1e-4)
            assert action == policy.act(np.asarray(obs))
            steps, planned = steps + 1, planned + (nav.waypoint != nav.goal)
            obs, state, _, done, _ = step(k, state, jnp.int32(action), params)
            if bool(done):
                break
    assert steps >= 30 and planned >= 10  # waypoints on the way, not only the goal itself


# --------------------------------------------------------------------------- bad inputs
@pytest.fixture(scope="module")
def nav() -> Navigator:
    grid = np.zeros((8, 8), bool)
    grid[3, 2:6] = True
    return Navigator(pretrained.path("robotnav-pqn"), map=GridMap(grid, 0.5, origin=(10.0, 0.0)))


def full_scan(num: int = 360, **fields) -> LaserScan:
    kw = {"angle_min": -math.pi, "angle_increment": 2 * math.pi / num, "range_max": 12.0}
    return LaserScan(**{**kw, "ranges": np.full(num, 2.0), **fields})


def test_bad_inputs_are_named_in_one_line(nav):
    with pytest.raises(ValueError, match=r"^no goal: call reset\(goal\) first"):
        fresh = Navigator(pretrained.path("robotnav-pqn"), map=nav.map)
        fresh.act(scan=full_scan(), pose=(11, 1, 0))
    with pytest.raises(ValueError, match=r"^goal=\(11.2, 2.3\): inside a wall of the map"):
        nav.reset(goal=(11.2, 2.3))
    with pytest.raises(ValueError, match=r"^goal=\(1, 1\): off the map"):
        nav.reset(goal=(1.0, 1.0))
    with pytest.raises(ValueError, match=r"^goal=\(nan, 1.0\): must be finite"):
        nav.reset(goal=(float("nan"), 1.0))
    nav.reset(goal=(13.7, 0.3))
    with pytest.raises(ValueError, match=r"^pose=\(11.0, nan, 0.0\): must be finite"):
        nav.act(scan=full_scan(), pose=(11.0, float("nan"), 0.0))
    with pytest.raises(ValueError, match=r"^pose=\(3, 1\): off the map"):
        nav.act(scan=full_scan(), pose=(3.0, 1.0, 0.0))
    with pytest.raises(ValueError, match=r"^ranges: 359 readings, but angle_min=.* make 360"):
        nav.act(
            scan=full_scan(359, angle_increment=2 * math.pi / 360, angle_max=math.pi - 0.0175),
            pose=(11.0, 1.0, 0.0),
        )
    with pytest.raises(ValueError, match=r"^ranges: 720 readings every 1 deg span 719.0 deg"):
        nav.act(scan=full_scan(720, angle_increment=2 * math.pi / 360), pose=(11.0, 1.0, 0.0))
    with pytest.raises(ValueError, match=r"^policy beam at .* outside the scan's field of view"):
        partial = full_scan(90, angle_increment=2 * math.pi / 360)  # 90 of 360 degrees
        nav.act(scan=partial, pose=(11.0, 1.0, 0.0))
    with pytest.raises(ValueError, match=r"^scan=list: must be a LaserScan"):
        nav.act(scan=[1.0] * 360, pose=(11.0, 1.0, 0.0))
    with pytest.raises(TypeError):
        nav.act(full_scan(), (11.0, 1.0, 0.0))  # keywords only: no positional mix-up
    assert nav.act(scan=full_scan(), pose=(11.0, 1.0, 0.0)) in range(4)
    with pytest.raises(ValueError, match=r"^this policy reads a waypoint on a planned path: pass"):
        Navigator(pretrained.path("robotnav-pqn"))
    with pytest.raises(ValueError, match=r"^map='rooms.txt': must be a GridMap or None"):
        Navigator(pretrained.path("robotnav-pqn"), map="rooms.txt")
    with pytest.raises(ValueError, match=r"^radius=-0.1: must be a positive number"):
        Navigator(pretrained.path("robotnav-pqn"), map=nav.map, radius=-0.1)


def test_reset_starts_a_policy_with_memory_afresh(nav):
    """A policy with a ``reset()`` (memory) has it called at every goal, before acting."""

    class Remembering(Policy):
        resets = 0

        def reset(self) -> None:
            self.resets += 1

    base = nav.policy
    policy = Remembering(base.arrays, base.metadata)
    n = Navigator(policy, map=nav.map)
    n.reset(goal=(13.7, 0.3))
    n.act(scan=full_scan(), pose=(11.0, 1.0, 0.0))
    n.reset(goal=(13.7, 3.7))
    assert policy.resets == 2


def test_a_shielded_navigator_only_turns_when_walls_close_in_ahead_and_behind():
    """Boxed in 0.3 m ahead and behind (a 0.25 m robot), with the goal straight ahead: the
    shielded navigator turns; its monitor reads the navigator's radius."""
    nav = Navigator(pretrained.path("robotjaxnav-mapfree"), radius=0.25, shielded=True)
    assert nav.shield is not None and nav.shield.radius == 0.25
    nav.reset(goal=(5.0, 0.0))
    num = 360
    angles = -np.pi + np.arange(num) * (2 * np.pi / num)
    ranges = np.where(
        np.abs(np.cos(angles)) > 0.5, 0.3 / np.maximum(np.abs(np.cos(angles)), 1e-6), 3.0
    )
    scan = LaserScan(
        angle_min=-np.pi,
        angle_increment=2 * np.pi / num,
        range_max=3.5,
        ranges=np.minimum(ranges, 3.0),
    )
    names = [a["name"] for a in nav.actions]
    for _ in range(5):
        assert names[nav.act(scan=scan, pose=(0.0, 0.0, 0.0))] in ("turn_left", "turn_right")
