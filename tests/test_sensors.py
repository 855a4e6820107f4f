"""``jaxnav.deploy.sensors`` against the robot env's own observations: scans synthesized with
the env's ray caster at other resolutions, fed with the env's poses, goals and waypoints,
give ``env.get_obs``, frames stacked included; and what a real scan holds (inf, NaN, partial
fields of view, mounting) is read as documented."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxnav import export
from jaxnav.config import TrainConfig
from jaxnav.deploy.navigator import Navigator
from jaxnav.deploy.policy import Policy
from jaxnav.deploy.sensors import (
    TRAIL_ANGLES,
    LaserScan,
    OdometryTrail,
    ScanObservation,
    resample_scan,
    trail_points,
    yaw_from_quaternion,
)
from jaxnav.envs.robot import geometry
from jaxnav.train import Trainer

FORWARD, BACKWARD, LEFT, RIGHT = range(4)
CASES = {
    "paper": ("RobotSimple-v0", {"backend": "kinematic"}),  # 7 beams over 180, absolute x, y
    "generalist": ("RobotNav-v0", {"num_layouts": 8}),  # 32 beams all around, a waypoint
    "heading": ("RobotComplex-v0", {"backend": "kinematic", "obs_heading": True, "frames": 2}),
}


@pytest.fixture(scope="module", params=list(CASES))
def robot(request):
    """``(env, params, metadata)`` of a robot env and the export metadata of a policy on it."""
    env_id, kwargs = CASES[request.param]
    trainer = Trainer(TrainConfig.for_env(env_id, env_kwargs=kwargs, hidden_sizes=(8,)))
    return trainer.env, trainer.env_params, export.policy_metadata(trainer)


def cast(env, params, state, angles, max_range: float) -> np.ndarray:
    """Ranges along ``angles`` (from the heading) at ``state``'s pose, by the env's caster."""
    w = jax.tree.map(lambda x: x[state.layout], params.bank.walls)
    lo, hi = geometry.box_bounds(w.center, w.half_size, w.active)
    return np.asarray(geometry.lasers(state.pose, lo, hi, jnp.asarray(angles), max_range))


def synthesize(env, params, state, num: int, angle_min: float, range_max: float) -> LaserScan:
    """A 360-degree scan of ``num`` readings from ``angle_min`` cast by the env's own ray
    caster at ``state``'s pose; nothing within ``range_max`` reads +inf, as a lidar reports."""
    angles = angle_min + 2 * np.pi / num * np.arange(num)
    ranges = cast(env, params, state, angles, 1e6).astype(np.float64)
    ranges[ranges > range_max] = np.inf
    return LaserScan(
        angle_min=angle_min, angle_increment=2 * np.pi / num, range_max=range_max, ranges=ranges
    )


_JITTED: dict[int, tuple] = {}


def jitted(env):
    """``(reset, step_env, waypoint)`` of ``env``, compiled once per env."""
    if id(env) not in _JITTED:
        _JITTED[id(env)] = (jax.jit(env.reset), jax.jit(env.step_env), jax.jit(env.waypoint))
    return _JITTED[id(env)]


def episode(env, params, key, steps: int = 12):
    """``(obs, state, waypoint)`` of every step of an episode of random actions (no
    auto-reset), the waypoint the env's planner gives there."""
    reset, step_env, waypoint = jitted(env)
    obs, state = reset(key, params)
    out = []
    for k in [None, *jax.random.split(key, steps)]:
        if k is not None:
            action = jax.random.randint(k, (), 0, env.num_actions)
            obs, state, _, done, _ = step_env(k, state, action, params)
        point = waypoint(state.pose, state.goal, state.layout, params)
        out.append((obs, state, np.asarray(point)))
        if k is not None and bool(done):
            break
    return out


def test_scans_at_the_env_beams_give_the_env_observation(robot):
    """A scan whose readings include the policy's beam angles (here 4 per 1/lcm of beam
    spacings) reproduces the observation within float32 rounding, over whole episodes."""
    env, params, meta = robot
    observe = ScanObservation(meta)
    num = 4 * 7 * 32 * 6  # multiples of both the 30-degree and 11.25-degree beam spacings
    for seed in range(3):
        observe.reset()
        for obs, state, waypoint in episode(env, params, jax.random.key(seed)):
            scan = synthesize(env, params, state, num, -math.pi, range_max=12.0)
            got = observe(scan, np.asarray(state.pose), np.asarray(state.goal), waypoint)
            np.testing.assert_allclose(got, np.asarray(obs), atol=2e-6, rtol=0)
            assert got.dtype == np.float32 and got.shape == (meta["observation"]["size"],)


def test_a_coarser_lidar_gives_close_observations(robot):
    """A 1-degree lidar whose readings are 0.3 degrees off: each beam reads the reading
    nearest to it in angle (the env's ray cast there, exactly), so the observation differs
    only by that angle: a few millimetres for most beams, more where a beam grazes a wall."""
    env, params, meta = robot
    observe = ScanObservation(meta)
    c = env.config
    angle_min, inc = math.radians(-179.7), math.radians(1.0)  # no beam halfway: no ties
    # the reading nearest to each beam: reading i looks along angle_min + i * inc
    nearest = angle_min + inc * (np.round((np.asarray(env.angles) - angle_min) / inc) % 360)
    errors, rest = [], []
    for seed in range(8):
        observe.reset()
        for obs, state, waypoint in episode(env, params, jax.random.key(100 + seed)):
            scan = synthesize(env, params, state, 360, angle_min, range_max=12.0)
            got = observe(scan, np.asarray(state.pose), np.asarray(state.goal), waypoint)
            at_nearest = cast(env, params, state, nearest, c.laser_range)
            np.testing.assert_allclose(
                got[-env.frame_size :][: c.num_lasers], at_nearest / c.laser_range, atol=2e-6
            )
            diff = (got - np.asarray(obs)).reshape(-1, env.frame_size)
            errors.append(np.abs(diff[:, : c.num_lasers]).ravel() * c.laser_range)  # metres
            rest.append(np.abs(diff[:, c.num_lasers :]).ravel())
    errors = np.concatenate(errors)
    assert np.concatenate(rest).max() < 2e-6  # pose, goal and waypoint values are exact
    assert np.median(errors) < 0.01 and np.percentile(errors, 90) < 0.1, np.percentile(errors, 90)


def test_readings_follow_rep117():
    """+inf and readings above range_max: nothing (the policy's range); -inf: closer than
    range_min (0); NaN and readings below range_min: no valid return (the policy's range)."""
    scan = LaserScan(
        ranges=[1.0, np.inf, -np.inf, np.nan, 0.05, 9.0, 2.0, 3.0],
        angle_min=0.0,
        angle_increment=math.pi / 4,
        range_max=8.0,
        range_min=0.1,
    )
    beams = np.arange(8) * math.pi / 4
    got = resample_scan(scan, beams)
    np.testing.assert_array_equal(got, [1.0, np.inf, 0.0, np.inf, np.inf, np.inf, 2.0, 3.0])


def test_a_scan_is_built_by_ros_field_names_only():
    """Positional ranges could swap range_min and range_max (a wall 0.3 m away then reads as
    free space): construction takes keywords, in ROS's field order, or a ROS message."""
    fields = [f.name for f in dataclasses.fields(LaserScan)]
    assert fields == [
        "angle_min", "angle_max", "angle_increment", "range_min", "range_max", "ranges"
    ]  # fmt: skip
    with pytest.raises(TypeError):
        LaserScan(0.0, math.pi / 4, 0.1, 8.0, [0.3] * 8)  # the mistake, refused
    msg = types.SimpleNamespace(
        header=None, angle_min=0.0, angle_max=7 * math.pi / 4, angle_increment=math.pi / 4,
        time_increment=0.0, scan_time=0.1, range_min=0.1, range_max=8.0, ranges=[0.3] * 8,
        intensities=[],
    )  # fmt: skip
    scan = LaserScan.from_msg(msg)
    assert (scan.range_min, scan.range_max, scan.angle_max) == (0.1, 8.0, 7 * math.pi / 4)
    np.testing.assert_array_equal(resample_scan(scan, [0.0, math.pi]), [0.3, 0.3])
    # a message whose readings do not fit its angles: a reading lost, or one too many
    for ranges in ([0.3] * 7, [0.3] * 9):
        short = LaserScan.from_msg(types.SimpleNamespace(**{**vars(msg), "ranges": ranges}))
        with pytest.raises(ValueError, match=rf"^ranges: {len(ranges)} readings, but .* make 8$"):
            resample_scan(short, [0.0])


@pytest.mark.parametrize(
    ("field", "value", "named"),
    [
        ("range_max", math.nan, "range_max=nan: must be above range_min=0.1"),
        ("range_min", 9.0, "range_max=8.0: must be above range_min=9.0"),
        ("range_min", -1.0, "range_min=-1.0: must be non-negative"),
        ("range_min", math.nan, "range_min=nan: must be finite"),
        ("angle_increment", 1e20, "angle_increment=1e+20: must be nonzero and at most 2*pi"),
        ("angle_increment", 0.0, "angle_increment=0.0"),
        ("angle_min", math.inf, "angle_min=inf: must be finite"),
        ("ranges", [], "ranges: the scan has no readings"),
    ],
)
def test_a_scan_that_would_read_walls_as_free_space_is_refused(field, value, named):
    """Each of these read an obstacle 0.3 m away as free space, or garbage, before."""
    scan = {"angle_min": 0.0, "angle_increment": math.pi / 4, "range_min": 0.1, "range_max": 8.0}
    scan = {**scan, "ranges": [0.3] * 8, field: value}
    with pytest.raises(ValueError, match=re.escape(named)) as e:
        resample_scan(LaserScan(**scan), [0.0])
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("bad", ["pose", "goal", "waypoint"])
@pytest.mark.parametrize("value", [math.nan, math.inf])
def test_a_non_finite_pose_goal_or_waypoint_gives_no_observation(robot, bad, value):
    _, _, meta = robot
    scan = LaserScan(
        angle_min=-math.pi, angle_increment=math.pi / 360, range_max=12.0, ranges=[2.0] * 720
    )
    where = {"pose": [1.0, 1.0, 0.0], "goal": [3.0, 2.0], "waypoint": [2.0, 1.5]}
    where[bad][1] = value
    with pytest.raises(ValueError, match=rf"{bad}=\(.*{value}.*\): must be finite"):
        ScanObservation(meta)(scan, **where)


def test_beams_take_the_nearest_reading_and_mounting_turns_the_scan():
    ranges = np.arange(360, dtype=float) / 100 + 1  # reading i at i degrees
    scan = LaserScan(
        angle_min=0.0, angle_increment=math.radians(1.0), range_max=10.0, ranges=ranges
    )
    beams = np.radians([0.0, 10.4, -90.0, 179.6])  # -90 is reading 270; 179.6 -> 180
    np.testing.assert_allclose(resample_scan(scan, beams), [1.0, 1.10, 3.70, 2.80])
    # a scanner turned 90 degrees left: its reading 0 looks along the robot's +90 degrees
    np.testing.assert_allclose(
        resample_scan(scan, np.radians([90.0]), mount_yaw=math.pi / 2), [1.0]
    )
    # a clockwise scan (negative increment) reads the same directions
    clockwise = LaserScan(
        angle_min=math.radians(359.0),
        angle_increment=math.radians(-1.0),
        range_max=10.0,
        ranges=ranges[::-1],
    )
    np.testing.assert_allclose(resample_scan(clockwise, beams), [1.0, 1.10, 3.70, 2.80])
    # beam_width: the nearest range within the window
    np.testing.assert_allclose(resample_scan(scan, np.radians([20.0]), beam_width=0.2), [1.15])


def test_beams_outside_a_partial_scan_are_refused_or_filled():
    scan = LaserScan(  # 270 degrees
        angle_min=math.radians(-135),
        angle_increment=math.radians(1.0),
        range_max=10.0,
        ranges=np.ones(271),
    )
    beams = np.radians([0.0, 135.0, 180.0])
    with pytest.raises(
        ValueError, match=r"policy beam at 180.0 deg is outside .*\[-135.0, 135.0\]"
    ):
        resample_scan(scan, beams)
    np.testing.assert_array_equal(resample_scan(scan, beams, fill_uncovered=np.inf), [1, 1, np.inf])


def test_the_frame_stack_and_the_waypoint_are_kept_as_documented(robot):
    env, params, meta = robot
    observe = ScanObservation(meta)
    steps = episode(env, params, jax.random.key(5), steps=4)
    scans = [synthesize(env, params, s, 720, -math.pi, 12.0) for _, s, _ in steps]
    args = [(np.asarray(s.pose), np.asarray(s.goal), w) for _, s, w in steps]
    first = observe(scans[0], *args[0])
    frames = meta["observation"]["frames"]
    np.testing.assert_array_equal(first, np.tile(first[: env.frame_size], frames))
    second = observe(scans[1], *args[1])
    np.testing.assert_array_equal(second[: -env.frame_size], first[env.frame_size :])
    observe.reset()
    np.testing.assert_array_equal(observe(scans[0], *args[0]), first)
    if env.config.waypoint_distance:
        with pytest.raises(ValueError, match="this policy reads a waypoint"):
            observe(scans[0], *args[0][:2])


def test_grid_policies_have_no_scan_observation():
    trainer = Trainer(TrainConfig(env_kwargs={"size": 5}, hidden_sizes=(8,)))
    with pytest.raises(ValueError, match="GridMaze-v0: not a laser policy"):
        ScanObservation(export.policy_metadata(trainer))


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5, math.pi])
def test_yaw_from_quaternion(yaw):
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    assert math.isclose(math.cos(yaw_from_quaternion(*q) - yaw), 1.0, abs_tol=1e-12)


def test_the_drive_from_scans_example_agrees_with_the_simulator(tmp_path, capsys):
    """``examples/drive_from_scans.py`` end to end on a small exported policy: with the
    policy's beam directions among the scan's readings every action is the simulator's."""
    import importlib.util
    from pathlib import Path

    kwargs = {"backend": "kinematic", "obs_absolute": False, "num_lasers": 16, "laser_fov": 360.0}
    trainer = Trainer(TrainConfig(env="RobotSimple-v0", env_kwargs=kwargs, hidden_sizes=(32,)))
    params = trainer.network.init(jax.random.key(0), jnp.zeros((1, trainer.obs_size)))
    arrays = export.policy_arrays(trainer.network, params)
    npz = export.write_policy(arrays, export.policy_metadata(trainer), tmp_path / "p.npz", "npz")
    path = Path(__file__).resolve().parents[1] / "examples" / "drive_from_scans.py"
    spec = importlib.util.spec_from_file_location("drive_from_scans", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    log = tmp_path / "scans.npz"
    argv = [str(npz), "--episodes", "2", "--scan-beams", "64", "--log", str(log), "--quiet"]
    assert example.main(argv) == 0
    out = capsys.readouterr().out
    assert "recorded 2 episodes" in out and "(100.0%) the simulator's" in out
    assert example.drive(npz, log, quiet=True) == 1.0


def test_a_map_free_policy_reads_its_previous_action_and_radius_as_the_env_does():
    """RobotJaxNav-v0's observation (previous action, radius, goal read to 16 m): scans, poses,
    ``acted`` and ``radius=`` reproduce it over whole episodes; forgetting either is refused."""
    kwargs = {"num_layouts": 8, "radius_range": (0.1, 0.25)}
    trainer = Trainer(TrainConfig.for_env("RobotJaxNav-v0", env_kwargs=kwargs, hidden_sizes=(8,)))
    env, params, meta = trainer.env, trainer.env_params, export.policy_metadata(trainer)
    with pytest.raises(ValueError, match=r"reads the robot's radius \(robot_radius\)"):
        ScanObservation(meta)
    reset, step_env, _ = jitted(env)
    for seed in range(2):
        key = jax.random.key(seed)
        obs, state = reset(key, params)
        observe = ScanObservation(meta, radius=float(state.radius))
        for k in jax.random.split(key, 12):
            scan = synthesize(env, params, state, 4 * 32 * 6, -math.pi, range_max=12.0)
            got = observe(scan, np.asarray(state.pose), np.asarray(state.goal))
            np.testing.assert_allclose(got, np.asarray(obs), atol=2e-6, rtol=0)
            with pytest.raises(ValueError, match=r"call acted\(action\)"):
                observe(scan, np.asarray(state.pose), np.asarray(state.goal))
            action = int(jax.random.randint(k, (), 0, env.num_actions))
            observe.acted(action)
            obs, state, _, done, _ = step_env(k, state, action, params)
            if bool(done):
                break
    with pytest.raises(ValueError, match=r"action=7: must be an index in \[0, 4\)"):
        observe.acted(7)


# a map-free policy with the odometry trail (RobotNav-v0's mazes, the kinematic backend)
TRAIL_KWARGS = {
    "num_layouts": 8, "backend": "kinematic", "waypoint_distance": 0.0, "trail_cell": 0.5,
    "goal_range": 16.0, "obs_last_action": True, "frames": 2,
}  # fmt: skip


@pytest.fixture(scope="module")
def trail_robot():
    """``(env, params, metadata, trainer)`` of a map-free policy with the odometry trail."""
    config = TrainConfig.for_env("RobotNav-v0", env_kwargs=TRAIL_KWARGS, hidden_sizes=(8,))
    trainer = Trainer(config)
    return trainer.env, trainer.env_params, export.policy_metadata(trainer), trainer


def env_scan(env, params, state) -> LaserScan:
    """The env's own laser ranges at ``state`` as a scan with one reading per beam."""
    angles = np.asarray(env.angles, np.float64)
    return LaserScan(
        angle_min=float(angles[0]),
        angle_increment=float(angles[1] - angles[0]),
        range_max=12.0,
        ranges=cast(env, params, state, env.angles, env.config.laser_range),
    )


def test_the_odometry_trail_is_the_envs_over_whole_episodes(trail_robot):
    """Fed the env's laser ranges, its poses (odometry) and goals, ``ScanObservation`` builds
    the env's observation, trail included, at each of 60 steps of random play (auto-resets
    included: ``reset()`` at each new episode), and keeps the env's count grid."""
    env, params, meta, _ = trail_robot
    n = 1 + 2 * len(TRAIL_ANGLES)
    step = jax.jit(env.step)
    observe = ScanObservation(meta)
    assert observe.trail is not None and observe.trail.grid.shape == (64, 64)
    key = jax.random.key(3)
    obs, state = jax.jit(env.reset)(key, params)
    read_around = 0
    for k in jax.random.split(key, 60):
        got = observe(env_scan(env, params, state), np.asarray(state.pose), np.asarray(state.goal))
        np.testing.assert_allclose(got, np.asarray(obs), atol=1e-5, rtol=0)
        np.testing.assert_array_equal(observe.trail.grid, np.asarray(state.trail))
        np.testing.assert_array_equal(observe.trail.origin, np.asarray(state.origin))
        read_around += int((got[-n + 1 :] > 0).any())
        action = int(jax.random.randint(k, (), 0, env.num_actions))
        observe.acted(action)
        obs, state, _, terminated, truncated, _ = step(k, state, action, params)
        if bool(terminated | truncated):
            observe.reset()
    assert read_around > 0  # the readings around the robot were exercised, not only its cell


def test_the_trail_counts_and_reads_as_documented():
    """``OdometryTrail`` alone: the start counted once, counts stop at 255, points off the
    grid read 0, a refused pose leaves the trail as it was, reset forgets it."""
    trail = OdometryTrail(0.5)
    assert trail_points()[:3] == [(0, 0.0), (1, 0.0), (2, 0.0)] and len(trail_points()) == 17
    with pytest.raises(ValueError, match=r"no trail yet"):
        trail.reading((0.0, 0.0, 0.0))
    trail.visit((3.0, 4.0, 0.5))
    assert trail.grid.sum() == 1 and trail.grid[32, 32] == 1
    np.testing.assert_array_equal(trail.origin, np.float32([3.0, 4.0, 0.5]))
    for _ in range(300):
        trail.visit((3.0, 4.0, 2.0))  # turning in place: the start's cell
    assert trail.grid[32, 32] == 255 and trail.reading((3.0, 4.0, 0.0))[0] == 1.0
    trail.visit((300.0, 4.0, 0.0))  # 297 m away: off the 32 m grid, not counted
    assert trail.grid.sum() == 255 and (trail.reading((300.0, 4.0, 0.0)) == 0).all()
    with pytest.raises(ValueError, match=r"pose=\(.*nan.*\): must be finite"):
        trail.visit((math.nan, 4.0, 0.0))
    with pytest.raises(ValueError, match=r"pose=.*: beyond float32"):
        trail.visit((1e39, 4.0, 0.0))
    assert trail.grid.sum() == 255
    trail.reset()
    assert trail.grid.sum() == 0 and trail.origin is None
    for bad, named in [
        ({"cell": -0.5}, "trail_cell_m=-0.5"),
        ({"cell": math.nan}, "trail_cell_m=(nan,): must be finite"),
        ({"cell": 0.5, "cells": 0}, "trail_cells=0"),
        ({"cell": 0.5, "saturation": 0}, "trail_saturation=0"),
    ]:
        with pytest.raises(ValueError, match=re.escape(named)):
            OdometryTrail(**bad)


def test_a_policy_exported_with_the_trail_runs_from_its_file(trail_robot, tmp_path):
    """The export round trip: the trail's cell, grid and saturation in the metadata;
    ``Policy.load``, ``ScanObservation`` and ``Navigator`` (fresh trail per goal) take it;
    policies without the trail have no trail keys; another env id carries the trail."""
    env, params, meta, trainer = trail_robot
    arrays = export.policy_arrays(
        trainer.network, trainer.network.init(jax.random.key(0), jnp.zeros((1, trainer.obs_size)))
    )
    npz = export.write_policy(arrays, meta, tmp_path / "trail.npz", "npz")
    policy = Policy.load(npz)
    sensors = policy.metadata["sensors"]
    assert (sensors["trail_cell_m"], sensors["trail_cells"], sensors["trail_saturation"]) == (
        0.5, 64, 16
    )  # fmt: skip
    _, state = env.reset(jax.random.key(1), params)
    args = (env_scan(env, params, state), np.asarray(state.pose), np.asarray(state.goal))
    obs = ScanObservation(policy)(*args)
    assert obs.shape == (policy.metadata["observation"]["size"],) and obs[-17] == 1 / 16
    assert 0 <= policy.act(obs) < 4
    # a file exported before the metadata had the trail's keys: the env config's trail_cell
    old = json.loads(json.dumps(policy.metadata))
    for key in ("trail_cell_m", "trail_cells", "trail_saturation", "trail_frame"):
        del old["sensors"][key]
    np.testing.assert_array_equal(ScanObservation(old)(*args), obs)
    old["env_config"]["trail_cell"] = 0.0
    with pytest.raises(ValueError, match="reads an odometry trail, but .* no trail_cell_m"):
        ScanObservation(old)
    nav = Navigator(policy)
    for _ in range(2):  # a goal's trail starts afresh
        nav.reset(goal=args[2])
        for _ in range(3):
            nav.act(scan=args[0], pose=args[1])
        assert nav.observe.trail.grid.sum() == 3
    plain = Trainer(TrainConfig.for_env("RobotNav-v0", env_kwargs={"num_layouts": 8}))
    assert not any(k.startswith("trail") for k in export.policy_metadata(plain)["sensors"])
    _, kwargs = export.env_for(policy, "RobotComplex-v0")
    assert kwargs["trail_cell"] == 0.5
    with pytest.raises(ValueError, match=r"--env-arg trail_cell=0: .* with trail_cell=0.5"):
        export.env_for(policy, "RobotComplex-v0", {"trail_cell": 0})


def test_the_numpy_trail_constants_are_the_simulators():
    """``jaxnav.deploy.sensors`` writes the trail's constants out (it imports no JAX): they
    must stay the simulator's."""
    from jaxnav.deploy import sensors
    from jaxnav.envs.robot import layout

    assert sensors.TRAIL_ANGLES == tuple(float(a) for a in layout.TRAIL_ANGLES)
    assert (sensors.TRAIL_CELLS, sensors.TRAIL_SATURATION) == (
        layout.TRAIL_CELLS,
        layout.TRAIL_SATURATION,
    )
