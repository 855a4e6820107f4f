"""The continuous robot env (kinematic backend): motion, rewards, frames, auto-reset, errors."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import bfs_distances
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxnav
from jaxnav.envs.robot import geometry
from jaxnav.envs.robot.env import GENERALIST, GENERALIST_SENSORS, LASER_SCALE, NUM_LASERS

# the float64 face-by-face reference caster (tests/ is on sys.path under pytest)
from test_robot_geometry import ref_ray, well_conditioned  # noqa: E402  isort: skip

FORWARD, BACKWARD, LEFT, RIGHT = range(4)
KEY = jax.random.key(0)


@pytest.fixture(scope="module")
def simple():
    env, params = jaxnav.make("RobotSimple-v0", backend="kinematic")
    return env, params, jax.jit(env.step), jax.jit(env.step_env)


def terms(info) -> float:
    return sum(float(info[k]) for k in info if k.startswith("reward_"))


def start(env, params, x, y, heading, goal=(8.5, 8.5)):
    return env.reset_to(KEY, params, jnp.array([x, y, heading]), jnp.array(goal))


def test_forward_moves_along_heading_and_turns_only_change_yaw(simple):
    env, params, _, step_env = simple
    c = env.config
    heading = 0.3
    _, s = start(env, params, 2.5, 1.5, heading)
    _, s1, r, term, info = step_env(KEY, s, FORWARD, params)
    moved = np.asarray(s1.pose[:2] - s.pose[:2])
    np.testing.assert_allclose(
        moved, c.speed * c.dt * np.array([math.cos(heading), math.sin(heading)]), atol=1e-5
    )
    _, s2, _, _, _ = step_env(KEY, s, LEFT, params)
    np.testing.assert_allclose(s2.pose[:2], s.pose[:2], atol=1e-6)
    assert float(s2.pose[2] - s.pose[2]) == pytest.approx(c.turn_speed * c.dt, abs=1e-5)
    _, s3, _, _, _ = step_env(KEY, s, RIGHT, params)
    assert float(s3.pose[2] - s.pose[2]) == pytest.approx(-c.turn_speed * c.dt, abs=1e-5)
    assert not bool(term)
    # the step reward starts at -0.5 and falls towards -1 with the step count
    assert float(info["reward_step"]) == pytest.approx(c.step_reward_start)
    assert float(r) == pytest.approx(terms(info))
    late = s.replace(time=jnp.asarray(c.max_steps - 1))
    _, _, r_late, _, info = step_env(KEY, late, LEFT, params)
    assert float(info["reward_progress"]) == 0.0  # turning in place makes no progress
    assert c.step_reward_end <= float(r_late) < -0.99


def test_driving_into_a_wall_collides_stops_short_and_terminates(simple):
    env, params, _, step_env = simple
    # facing the arena's left boundary from 0.3 m away
    _, s = start(env, params, 0.3, 1.5, math.pi)
    for _ in range(5):
        _, s, r, term, info = step_env(KEY, s, FORWARD, params)
        if bool(term):
            break
    assert bool(term) and bool(info["collision"]) and float(r) == -5.0
    assert float(info["reward_collision"]) == -5.0 and float(info["reward_step"]) == 0.0
    assert float(s.pose[0]) >= env.config.radius - 1e-4  # never inside the wall
    assert float(info["penetration"]) == 0.0


def test_inactive_wall_slots_do_not_collide_wherever_they_lie():
    env, params = jaxnav.make("RobotRandom-v0", backend="kinematic", num_layouts=8)
    step_env = jax.jit(env.step_env)
    walls = params.bank.walls
    maze, slot = (int(i[0]) for i in np.nonzero(~np.asarray(walls.active)))  # an unused slot
    x, y = np.asarray(params.bank.free_xy[maze, 0])  # a cell centre: no wall within a step
    # that slot, still inactive, moved just ahead of the robot
    moved = walls.replace(
        center=walls.center.at[maze, slot].set(jnp.array([x + 0.45, y])),
        half_size=walls.half_size.at[maze, slot].set(jnp.array([0.1, 0.1])),
    )
    ghost = params.replace(bank=params.bank.replace(walls=moved))
    free = np.asarray(params.bank.free_xy[maze, : int(params.bank.num_free[maze])])
    far = free[np.argmax(np.hypot(free[:, 0] - x, free[:, 1] - y))]  # a goal out of reach
    _, s = env.reset_to(KEY, params, jnp.array([x, y, 0.0]), jnp.asarray(far), maze)
    _, s_ghost, _, term, info = step_env(KEY, s, FORWARD, ghost)
    assert not bool(term) and not bool(info["collision"])
    _, s_plain, _, _, _ = step_env(KEY, s, FORWARD, params)
    np.testing.assert_array_equal(s_ghost.pose, s_plain.pose)
    # made active, the same box stops the robot: the test above can fail
    solid = moved.replace(active=moved.active.at[maze, slot].set(True))
    solid_params = params.replace(bank=params.bank.replace(walls=solid))
    _, _, _, term, info = step_env(KEY, s, FORWARD, solid_params)
    assert bool(term) and bool(info["collision"])


def test_goal_reward_terminates(simple):
    env, params, _, step_env = simple
    _, s = start(env, params, 2.5, 1.5, 0.0, goal=(3.0, 1.5))
    _, _, r, term, info = step_env(KEY, s, FORWARD, params)
    assert bool(term) and bool(info["goal_reached"]) and float(r) == 10.0  # same cell: no progress
    assert terms(info) == 10.0 and float(info["reward_goal"]) == 10.0


def test_progress_reward_follows_the_geodesic_distance(simple):
    """The progress term pays per metre of BFS distance through free cells (not straight-line
    distance): it equals a numpy BFS on the maze's grid, and crossing a cell boundary towards the
    goal pays ``progress_reward`` x cell size."""
    env, params, _, step_env = simple
    maze = jaxnav.envs.robot.mazes.builtin_maze("simple")
    rng = np.random.default_rng(0)
    free = maze.free_cells()
    for _ in range(20):
        (r0, c0), (r1, c1) = free[rng.choice(len(free), 2, replace=False)]
        xy = maze.cell_center(r0, c0) + rng.uniform(-0.45, 0.45, 2) * maze.cell_size
        goal = np.array(maze.cell_center(r1, c1))
        want = bfs_distances(maze.grid, (r1, c1))[maze.cell_at(*xy)] * maze.cell_size
        got = env.goal_distance(jnp.array([*xy, 0.0]), jnp.array(goal), 0, params)
        assert float(got) == pytest.approx(want)
    # goal (8.5, 5.5) lies beyond the lower wall, whose gap is at x < 3: stepping left from
    # x = 3.05 to 2.8 moves away in a straight line but one cell closer along the free cells
    c = env.config
    _, s = start(env, params, 3.05, 1.5, math.pi, goal=(8.5, 5.5))
    _, _, r, _, info = step_env(KEY, s, FORWARD, params)
    assert float(info["reward_progress"]) == pytest.approx(c.progress_reward * maze.cell_size)
    assert float(r) == pytest.approx(terms(info))
    _, s = start(env, params, 2.95, 1.5, 0.0, goal=(8.5, 5.5))
    _, _, _, _, info = step_env(KEY, s, FORWARD, params)
    assert float(info["reward_progress"]) == pytest.approx(-c.progress_reward * maze.cell_size)


def test_clearance_reward_grows_as_a_wall_comes_near_and_is_off_by_default(simple):
    """``clearance_reward`` pays per step in proportion to how far inside ``clearance`` metres
    of free space a wall is (nearest laser less the radius), logged as ``reward_clearance``;
    the default 0 pays nothing."""
    env, params, _, step_env = simple
    c = env.config
    near = params.replace(clearance_reward=-2.0, clearance=0.5)
    # turning in place 0.3 m from the arena's left edge, facing it: under 0.3 m of free space
    _, s = start(env, params, 0.3, 1.5, math.pi)
    _, s_next, _, _, info = step_env(KEY, s, LEFT, params)
    assert float(info["reward_clearance"]) == 0.0
    _, s_next, r, _, info = step_env(KEY, s, LEFT, near)
    gap = float(env.lasers(s_next.pose, s_next.layout, near).min()) - c.radius
    assert 0.14 < gap < 0.3
    assert float(info["reward_clearance"]) == pytest.approx(-2.0 * (1.0 - gap / 0.5), abs=1e-5)
    assert float(r) == pytest.approx(terms(info))
    # in the open the term is 0
    _, s = start(env, params, 1.5, 1.5, 0.0)
    _, _, _, _, info = step_env(KEY, s, LEFT, near)
    assert float(info["reward_clearance"]) == 0.0
    for bad in (float("nan"), float("inf")):
        with pytest.raises(ValueError, match="clearance_reward"):
            jaxnav.make("RobotSimple-v0", backend="kinematic", clearance_reward=bad)
    with pytest.raises(ValueError, match="clearance"):
        jaxnav.make("RobotSimple-v0", backend="kinematic", clearance=0.0)


def test_frames_stack_oldest_first_and_lasers_normalized(simple):
    env, params, _, step_env = simple
    obs, s = start(env, params, 2.5, 1.5, 0.0)
    per = env.frame_size
    chex.assert_shape(obs, (4 * per,))
    assert np.all(obs.reshape(4, per) == obs[:per])  # reset repeats the first frame
    poses = [s.pose]
    for _ in range(3):
        obs, s, *_ = step_env(KEY, s, FORWARD, params)
        poses.append(s.pose)
    frames = np.asarray(obs).reshape(4, per)
    arena = env.arena
    for k, pose in enumerate(poses):  # oldest first: frame k is the pose after k steps
        np.testing.assert_allclose(
            frames[k, NUM_LASERS + 2 : NUM_LASERS + 4], pose[:2] / arena, atol=1e-6
        )
        lasers = env.lasers(pose, s.layout, params) / LASER_SCALE
        np.testing.assert_allclose(frames[k, :NUM_LASERS], lasers, atol=1e-6)
    assert np.all((frames[:, :NUM_LASERS] >= 0) & (frames[:, :NUM_LASERS] <= 1))


def test_lasers_read_each_episodes_own_maze():
    """With a bank of random mazes, an episode's lasers are the casts against its own maze's
    walls: the bank's box corners are indexed by the episode's layout."""
    env, params = jaxnav.make("RobotRandom-v0", backend="kinematic", num_layouts=6)
    ranges = []
    for layout, maze in enumerate(env.config.load_mazes()):
        walls = maze.walls(env.num_wall_slots)
        lo, hi = geometry.box_bounds(walls.center, walls.half_size, walls.active)
        cells = maze.free_cells()
        for row, col in cells[:: max(1, len(cells) // 4)]:
            pose = jnp.array([*maze.cell_center(int(row), int(col)), 0.3], jnp.float32)
            want = geometry.lasers(pose, lo, hi, env.angles, LASER_SCALE)
            got = env.lasers(pose, jnp.int32(layout), params)
            np.testing.assert_allclose(got, want, atol=1e-6)
        ranges.append(np.asarray(env.lasers(jnp.array([0.5, 0.5, 0.3]), layout, params)))
    assert len({r.tobytes() for r in ranges}) > 1  # the mazes differ, and so do their lasers


def test_auto_reset_keeps_final_observation_and_truncates(simple):
    env, params, step, _ = simple
    short = params.replace(max_steps_in_episode=3)
    obs, s = start(env, short, 2.5, 1.5, 0.0)
    for _ in range(3):
        prev = s
        obs, s, r, term, trunc, info = step(KEY, s, LEFT, short)
    assert bool(trunc) and not bool(term)
    assert int(s.time) == 0  # a fresh episode
    final = env.step_env(KEY, prev, LEFT, short)[0]
    np.testing.assert_allclose(info["final_observation"], final)
    np.testing.assert_allclose(obs, env.get_obs(s, short))


# ------------------------------------------------------------ invariants (hypothesis)
ROLLOUT_ENVS, ROLLOUT_STEPS, SHORT_LIMIT = 16, 60, 25  # the limit truncates within a rollout
FORWARD_BIASED = jnp.array([0.55, 0.15, 0.15, 0.15])


@functools.cache
def rollout_fn(env_id: str, backend: str):
    """``rollout(key) -> per step (pose, reward, terminated, truncated, info, obs, time)`` of
    random play over auto-resets, jitted once per (env, backend) and reused by every example."""
    kwargs = {"num_layouts": 16} if env_id == "RobotRandom-v0" else {}
    env, params = jaxnav.make(env_id, backend=backend, max_steps=SHORT_LIMIT, **kwargs)
    n = ROLLOUT_ENVS

    @jax.jit
    def rollout(key):
        k_reset, k_run = jax.random.split(key)
        _, s = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(k_reset, n), params)

        def body(s, k):
            ka, ks = jax.random.split(k)
            a = jax.random.choice(ka, 4, (n,), p=FORWARD_BIASED)  # reaches walls more
            obs, s_next, r, te, tr, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(ks, n), s, a, params
            )
            walls = params.bank.walls
            pen = jax.vmap(geometry.circle_box_penetration, in_axes=(0, None, 0, 0, 0))(
                s_next.pose[:, :2],
                env.config.radius,
                walls.center[s_next.layout],
                walls.half_size[s_next.layout],
                walls.active[s_next.layout],
            )
            return s_next, (obs, r, te, tr, info, s.time, pen)

        return jax.lax.scan(body, s, jax.random.split(k_run, ROLLOUT_STEPS))[1]

    return env, params, rollout


@pytest.mark.parametrize(
    "env_id, backend",
    [
        ("RobotSimple-v0", "kinematic"),
        ("RobotComplex-v0", "kinematic"),
        ("RobotRandom-v0", "kinematic"),
        ("RobotRandom-v0", "mjx"),  # per-env walls: the MJX model's batched geom fields
    ],
)
@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_rollout_invariants(env_id, backend, seed):
    """Random play: obs finite, lasers in [0, 1], rewards only +10, -5 or the step reward of
    that step, terminated exactly at goal or collision, episodes end by the step limit, the
    robot never inside a wall: not at all on the kinematic backend, and by at most one
    physics substep of travel (speed x timestep) on MJX, which detects contact after it."""
    env, params, rollout = rollout_fn(env_id, backend)
    obs, r, term, trunc, info, time_before, pen_after = rollout(jax.random.key(seed))
    c = env.config
    chex.assert_tree_all_finite((obs, r))
    frames = np.asarray(obs).reshape(ROLLOUT_STEPS, ROLLOUT_ENVS, c.frames, env.frame_size)
    lasers, positions = frames[..., :NUM_LASERS], frames[..., NUM_LASERS : NUM_LASERS + 4]
    assert (lasers >= 0).all() and (lasers <= 1).all()
    assert (positions >= 0).all() and (positions <= 1).all()
    goal, hit = np.asarray(info["goal_reached"]), np.asarray(info["collision"])
    np.testing.assert_array_equal(np.asarray(term), goal | hit)
    assert not (goal & hit).any()
    step_reward = c.step_reward_start + (c.step_reward_end - c.step_reward_start) * (
        np.asarray(time_before) / SHORT_LIMIT
    )
    want = np.where(goal, c.goal_reward, np.where(hit, c.collision_reward, step_reward))
    # plus the progress term: whole cells of BFS distance gained (a step crosses at most two
    # cell boundaries, at a corner), times progress_reward x cell size
    cell = float(params.bank.cell_size[0])
    progress = np.asarray(info["reward_progress"]) / (c.progress_reward * cell)
    np.testing.assert_allclose(progress, np.round(progress), atol=1e-5)
    assert np.abs(progress).max() <= 2 and np.abs(progress).max() >= 1
    np.testing.assert_allclose(r, want + np.asarray(info["reward_progress"]), rtol=1e-5, atol=1e-5)
    # episodes end by the limit: truncated exactly at its last step, never later
    assert (np.asarray(time_before) < SHORT_LIMIT).all()
    np.testing.assert_array_equal(
        np.asarray(trunc), (np.asarray(time_before) == SHORT_LIMIT - 1) & ~np.asarray(term)
    )
    # (whether any episode lasts to the limit depends on the seed: at 2.5 m/s with forward-
    # biased play all may collide first; test_auto_reset_... truncates deterministically)
    bound = 0.0 if backend == "kinematic" else c.speed * c.dt / c.mjx_substeps
    assert float(np.max(info["penetration"])) <= bound + 1e-6
    assert float(np.max(pen_after)) <= bound + 1e-6  # every state the env hands out


def test_bad_robot_overrides_are_refused(tmp_path):
    with pytest.raises(ValueError, match="maze_file=None"):
        jaxnav.make("RobotMaze-v0")
    with pytest.raises(ValueError, match="backend='warp'"):
        jaxnav.make("RobotSimple-v0", backend="warp")
    with pytest.raises(ValueError, match="goal_radius=6"):
        jaxnav.make("RobotSimple-v0", goal_radius=6.0)
    # sizes that would hang or exhaust memory are refused before any work
    with pytest.raises(ValueError, match="speed=1e\\+30, dt=0.1: one control step"):
        jaxnav.make("RobotSimple-v0", speed=1e30, backend="kinematic")
    with pytest.raises(ValueError, match="mjx_substeps=2: a physics substep would move"):
        jaxnav.make("RobotSimple-v0", speed=4.0)  # 0.2 m a substep > the 0.15 m radius
    with pytest.raises(ValueError, match="num_layouts=100000, random_size=10: too many"):
        jaxnav.make("RobotRandom-v0", num_layouts=100_000)
    with pytest.raises(ValueError, match="maze_file=5: must be a path"):
        jaxnav.make("RobotMaze-v0", maze_file=5)
    with pytest.raises(ValueError, match="/dev/zero: larger than 1,000,000 bytes"):
        jaxnav.make("RobotMaze-v0", maze_file="/dev/zero")
    bad = tmp_path / "bad.txt"
    bad.write_text("#..\n#.\n")
    with pytest.raises(ValueError, match=f"{bad}:2"):
        jaxnav.make("RobotMaze-v0", maze_file=str(bad))
    good = tmp_path / "good.txt"
    good.write_text("cell_size: 1.0\nS....\n.###.\n....G\n")
    env, params = jaxnav.make("RobotMaze-v0", maze_file=str(good))
    assert tuple(env.arena) == (5.0, 3.0)


def test_mjx_backend_agrees_with_kinematic_in_free_space_and_collides():
    # the clearances below are in 0.1 m steps; physics only, so no progress term (whose cell
    # boundaries at x, y = 5.0 would make a 1e-4 m difference change the reward)
    slow = {"speed": 1.0, "turn_speed": 2.0, "progress_reward": 0.0}
    kin, kp = jaxnav.make("RobotSimple-v0", backend="kinematic", **slow)
    mjx_env, mp = jaxnav.make("RobotSimple-v0", backend="mjx", **slow)
    actions = jnp.array([FORWARD, FORWARD, LEFT, FORWARD, RIGHT, RIGHT, FORWARD, BACKWARD] * 3)

    def rollout(env, params, pose):
        _, s = env.reset_to(KEY, params, pose, jnp.array([8.5, 8.5]))

        def body(s, a):
            obs, s, r, term, info = env.step_env(KEY, s, a, params)
            return s, (s.pose, r, term, info["collision"])

        return jax.jit(lambda s: jax.lax.scan(body, s, actions))(s)[1]

    open_floor = jnp.array([5.0, 5.0, 0.2])
    (kin_pose, kin_r, _, _), (mjx_pose, mjx_r, _, mjx_hit) = (
        rollout(kin, kp, open_floor),
        rollout(mjx_env, mp, open_floor),
    )
    assert not bool(mjx_hit.any())
    np.testing.assert_allclose(mjx_pose, kin_pose, atol=1e-3)  # stated tolerance: 1 mm, 1 mrad
    np.testing.assert_allclose(mjx_r, kin_r)
    # towards the left boundary wall, 0.2 m of clearance: two forward steps end touching it
    # (not a collision), the turn stays put, the next forward step collides (-5, terminated)
    _, r, term, hit = rollout(mjx_env, mp, jnp.array([0.35, 5.0, math.pi]))
    first = int(np.argmax(np.asarray(hit)))
    assert first == 3 and bool(term[first]) and float(r[first]) == -5.0


# ------------------------------------------------------- generalist: lidar, observation
EXAMPLE_MAZES = Path(__file__).parent.parent / "examples" / "mazes"
# the generalist's observation (GENERALIST_SENSORS) and wall slots, on a file maze
SENSORS = {**GENERALIST_SENSORS, "num_wall_slots": GENERALIST["num_wall_slots"]}


@functools.cache
def family_env(num_lasers: int, laser_fov: float):
    """A tiny families bank (4 mazes, one of each family) with the given lidar, jitted once."""
    env, params = jaxnav.make(
        "RobotNav-v0", num_layouts=4, num_lasers=num_lasers, laser_fov=laser_fov
    )
    return env, params, jax.jit(env.lasers)


def test_default_lidar_and_frame_are_the_papers():
    env, _ = jaxnav.make("RobotSimple-v0", backend="kinematic")
    c = env.config
    assert (c.num_lasers, c.laser_fov, c.laser_range, c.obs_absolute) == (
        7,
        180.0,
        LASER_SCALE,
        True,
    )
    np.testing.assert_array_equal(env.angles, geometry.laser_angles())  # bit for bit
    assert env.frame_size == 7 + 4 + 1 + 2
    assert env.config.maze_seed == 0 and env.config.num_goal_cells == 0


@pytest.mark.parametrize("num", [1, 2, 3, 7, 32])
def test_laser_angles_cover_the_field_of_view(num):
    full = np.asarray(geometry.laser_angles(num, 2 * math.pi), np.float64)
    assert len(full) == num and 0.0 in full  # one beam straight ahead
    assert (full > -math.pi).all() and (full <= math.pi + 1e-6).all() and (np.diff(full) > 0).all()
    if num > 1:  # evenly spaced all around: no duplicate back beam
        gaps = np.diff(np.append(full, full[0] + 2 * math.pi))
        np.testing.assert_allclose(gaps, 2 * math.pi / num, atol=1e-5)
        half = np.asarray(geometry.laser_angles(num, math.radians(120.0)))
        np.testing.assert_allclose(half[[0, -1]], np.radians([-60.0, 60.0]), atol=1e-6)


@settings(max_examples=12, deadline=None)
@given(
    num=st.integers(1, 40),
    fov=st.sampled_from([30.0, 90.0, 180.0, 270.0, 359.0, 360.0]),
    layout=st.integers(0, 3),
    cell=st.integers(0, 10_000),
    heading=st.floats(-math.pi, math.pi),
    offset=st.tuples(st.floats(-0.2, 0.2), st.floats(-0.2, 0.2)),
)
def test_lidar_matches_a_brute_force_cast_at_any_beam_count(
    num, fov, layout, cell, heading, offset
):
    """The env's lasers against the face-by-face float64 caster of test_robot_geometry, on the
    maze's own boxes, from a point in a free cell of a families maze."""
    env, params, lasers = family_env(num, fov)
    maze = env.config.load_mazes()[layout]
    cells = maze.free_cells()
    x, y = np.asarray(maze.cell_center(*cells[cell % len(cells)])) + np.asarray(offset)
    pose = np.array([x, y, heading], np.float32)
    got = np.asarray(lasers(jnp.asarray(pose), jnp.int32(layout), params))
    walls = maze.walls(env.num_wall_slots)
    c, h, a = (np.asarray(v) for v in (walls.center, walls.half_size, walls.active))
    theta = np.float64(pose[2]) + np.asarray(env.angles, np.float64)
    dirs = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    want = np.array([ref_ray(pose[:2], d, c, h, a, env.config.laser_range) for d in dirs])
    ok = well_conditioned(pose[:2], dirs, c, h, a)  # grazing rays are checked elsewhere
    assert ok.mean() > 0.5
    np.testing.assert_allclose(got[ok], want[ok], atol=2e-4)
    assert len(got) == num


def test_obs_absolute_false_drops_positions_and_keeps_distance_and_bearing():
    env, params = jaxnav.make("RobotSimple-v0", backend="kinematic", obs_absolute=False)
    full, _ = jaxnav.make("RobotSimple-v0", backend="kinematic")
    assert env.frame_size == full.frame_size - 4 == 7 + 1 + 2
    assert env.observation_space(params).shape == (4 * env.frame_size,)
    pose, goal = jnp.array([2.5, 1.5, 0.3]), jnp.array([8.5, 8.5])
    obs, s = env.reset_to(KEY, params, pose, goal)
    full_obs, _ = full.reset_to(KEY, params, pose, goal)
    frame, full_frame = np.asarray(obs[: env.frame_size]), np.asarray(full_obs[: full.frame_size])
    np.testing.assert_array_equal(frame[:7], full_frame[:7])  # lasers
    np.testing.assert_array_equal(frame[7:], full_frame[11:])  # distance, bearing
    to_goal = np.asarray(goal - pose[:2])
    assert frame[7] == pytest.approx(np.linalg.norm(to_goal) / LASER_SCALE)
    bearing = math.atan2(to_goal[1], to_goal[0]) - 0.3
    np.testing.assert_allclose(frame[8:], [math.sin(bearing), math.cos(bearing)], atol=1e-6)
    # the frame does not depend on where the maze is: the same scene shifted gives the same
    _, s1, *_ = env.step_env(KEY, s, FORWARD, params)
    assert env.get_obs(s1, params).shape == obs.shape


def test_generalist_env_resets_to_goal_cells_and_rolls_out():
    env, params = jaxnav.make("RobotNav-v0", num_layouts=8)
    c = env.config
    assert (c.maze, c.backend, c.num_lasers, c.laser_fov, c.obs_absolute) == (
        "families",
        "kinematic",
        32,
        360.0,
        False,
    )
    # lasers, D, goal bearing, waypoint (sin, cos, distance)
    assert env.observation_space(params).shape == (c.frames * (32 + 1 + 2 + 3),)
    assert env.num_wall_slots <= c.num_wall_slots
    bank = params.bank
    assert bank.goal_distance.shape == (8, c.num_goal_cells, 20, 20)
    obs, s = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(KEY, 64), params)
    goals = np.asarray(bank.free_xy)[
        np.asarray(s.layout)[:, None], np.asarray(bank.goal_index)[np.asarray(s.layout)]
    ]
    assert (np.abs(goals - np.asarray(s.goal)[:, None]).max(-1) < 1e-6).any(1).all()
    d = jax.vmap(env.goal_distance, in_axes=(0, 0, 0, None))(s.pose, s.goal, s.layout, params)
    assert (np.asarray(d) > 0).all()  # a known geodesic distance, start != goal
    assert np.isfinite(np.asarray(obs)).all() and (np.abs(np.asarray(obs)) <= 1).all()
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    for i in range(20):
        keys = jax.random.split(jax.random.key(i), 64)
        obs, s, r, term, trunc, info = step(keys, s, jnp.full((64,), i % 4), params)
        assert np.isfinite(np.asarray(obs)).all() and (np.abs(np.asarray(obs)) <= 1).all()
        assert float(np.max(info["penetration"])) == 0.0
    # a goal that is no goal cell has no known geodesic distance: no progress reward
    layout = int(s.layout[0])
    goal_cells = {int(i) for i in np.asarray(bank.goal_index[layout])}
    other = next(i for i in range(int(bank.num_free[layout])) if i not in goal_cells)
    d = env.goal_distance(s.pose[0], bank.free_xy[layout, other], layout, params)
    assert float(d) == -1.0


@pytest.mark.parametrize("path", sorted(EXAMPLE_MAZES.glob("*.txt")), ids=lambda p: p.name)
def test_file_mazes_with_the_generalists_sensors(path):
    env, params = jaxnav.make("RobotMaze-v0", maze_file=str(path), backend="kinematic", **SENSORS)
    nav, nav_params = jaxnav.make("RobotNav-v0", num_layouts=2)
    # the same observation layout as the generalist's, whatever the arena
    assert env.observation_space(params).shape == nav.observation_space(nav_params).shape
    obs, s = env.reset(KEY, params)
    obs, s, r, *_ = env.step(KEY, s, FORWARD, params)
    assert np.isfinite(np.asarray(obs)).all() and (np.abs(np.asarray(obs)) <= 1).all()


def test_maze_seed_and_new_fields_are_validated():
    a, _ = jaxnav.make("RobotRandom-v0", backend="kinematic", num_layouts=4)
    b, _ = jaxnav.make("RobotRandom-v0", backend="kinematic", num_layouts=4, maze_seed=0)
    c, _ = jaxnav.make("RobotRandom-v0", backend="kinematic", num_layouts=4, maze_seed=7)
    grids = [np.asarray(e.default_params.bank.grid) for e in (a, b, c)]
    np.testing.assert_array_equal(grids[0], grids[1])
    assert not np.array_equal(grids[0], grids[2])
    for bad, match in [
        ({"laser_fov": 0.0}, "laser_fov=0.0"),
        ({"laser_fov": 361.0}, "laser_fov=361.0"),
        ({"num_lasers": 0}, "num_lasers=0"),
        ({"laser_range": -1.0}, "laser_range=-1.0"),
        ({"obs_absolute": "no"}, "obs_absolute='no'"),
        ({"maze_seed": -1}, "maze_seed=-1"),
        ({"families": ("rooms", "caves")}, "unknown family 'caves'"),
        ({"num_goal_cells": 0, "num_layouts": 4096}, "geodesic progress table would take"),
    ]:
        with pytest.raises(ValueError, match=match):
            jaxnav.make("RobotNav-v0", **bad)


def test_map_free_odometry_fields_read_the_goal_far_the_last_action_and_the_radius():
    """goal_range, obs_last_action and obs_radius: what a map-free robot knows of itself."""
    env, params = jaxnav.make(
        "RobotSimple-v0",
        backend="kinematic",
        obs_absolute=False,
        laser_range=3.5,
        goal_range=16.0,
        obs_last_action=True,
        obs_radius=True,
        radius_range=(0.1, 0.25),
    )
    base = 7 + 1 + 2  # lasers, distance, bearing
    assert env.frame_size == base + 4 + 1
    pose, goal = jnp.array([1.5, 1.5, 0.0]), jnp.array([8.5, 8.5])
    obs, s = env.reset_to(KEY, params, pose, goal)
    frame = np.asarray(obs[-env.frame_size :])
    # 9.9 m away: beyond the 3.5 m lidar, yet read unclipped against the 16 m goal range
    assert frame[7] == pytest.approx(float(jnp.linalg.norm(goal - pose[:2])) / 16.0)
    np.testing.assert_array_equal(frame[base : base + 4], 0.0)  # no action before the first
    assert 0.1 <= frame[-1] <= 0.25 and frame[-1] == pytest.approx(float(s.radius))
    for action in (LEFT, FORWARD, RIGHT):
        obs, s, *_ = env.step_env(KEY, s, action, params)
        frame = np.asarray(obs[-env.frame_size :])
        np.testing.assert_array_equal(frame[base : base + 4], np.eye(4)[action])
        assert frame[-1] == pytest.approx(float(s.radius))  # the episode's radius stays
    with pytest.raises(ValueError, match="goal_range=-1.0"):
        jaxnav.make("RobotSimple-v0", backend="kinematic", goal_range=-1.0)


@pytest.mark.slow  # builds the generalist's whole maze bank
def test_a_drawn_radius_fits_the_mazes_narrowest_gap():
    """radius_range is capped per maze at half its narrowest gap less FIT_MARGIN and under
    half a cell: 0.5 m corridors hold robots up to 0.15 m, JaxNav levels' 1 m gaps in 0.5 m
    cells up to 0.249 m, so the range's top."""
    from jaxnav.envs.maze_algorithms import narrowest_gap
    from jaxnav.envs.robot.env import FIT_MARGIN, HALF_CELL_FILL

    grid = np.zeros((5, 6), bool)
    grid[2, :4] = True  # a wall with a 2-cell gap at the right edge
    assert narrowest_gap(grid) == 2 and narrowest_gap(np.ones((2, 2), bool)) == 0
    grid[:, 4] = True
    assert narrowest_gap(grid) == 1  # the last column: a 1-cell corridor
    families = ("corridors", "jaxnav")
    env, params = jaxnav.make(
        "RobotNav-v0", num_layouts=8, families=families, radius_range=(0.1, 0.24)
    )
    fit = np.asarray(params.bank.fit_radius)
    gaps = [narrowest_gap(np.asarray(g)) for g in params.bank.grid]
    want = np.minimum(np.array(gaps) * 0.5 / 2 - FIT_MARGIN, HALF_CELL_FILL * 0.5)
    np.testing.assert_allclose(fit, want, atol=1e-6)
    assert fit[1::2].min() >= 0.249 - 1e-6  # jaxnav levels: 2 fine cells = 1 m at least
    keys = jax.random.split(KEY, 256)
    _, s = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    radius, layout = np.asarray(s.radius), np.asarray(s.layout)
    assert (radius <= np.minimum(0.24, fit[layout]) + 1e-6).all() and (radius >= 0.1).all()
    assert radius[layout % 2 == 1].max() > 0.2  # the jaxnav levels draw the whole range


def test_the_odometry_trail_counts_steps_per_cell_from_each_episodes_start():
    """trail_cell: reset counts the start once in a fresh trail whose origin is the start
    pose, every step counts the new pose's cell, the frame's last 17 values read the counts
    (/ 16, clipped at 1) around the robot, and an auto-reset starts a fresh trail."""
    from jaxnav.envs.robot import layout
    from jaxnav.envs.robot.env import TRAIL_CELLS

    env, params = jaxnav.make("RobotSimple-v0", backend="kinematic", trail_cell=0.5)
    n = 1 + 2 * len(layout.TRAIL_ANGLES)
    plain, _ = jaxnav.make("RobotSimple-v0", backend="kinematic")
    obs_layout = env.observation_layout(params)
    assert env.frame_size == plain.frame_size + n == obs_layout["frame_size"]
    entries = obs_layout["entries"]
    assert len(entries) == env.observation_space(params).shape[0] == 4 * env.frame_size
    assert [e["name"] for e in entries[-n:]] == ["trail"] * n
    assert [(e["cells"], e["angle_rad"]) for e in entries[-n + 1 : -n + 3]] == [(1, 0), (2, 0)]
    pose = jnp.array([2.5, 1.5, -1.0])
    obs, s = env.reset_to(KEY, params, pose, jnp.array([8.5, 8.5]))
    np.testing.assert_array_equal(s.origin, pose)
    assert s.trail.shape == (TRAIL_CELLS, TRAIL_CELLS) and s.trail.dtype == jnp.uint8
    centre = TRAIL_CELLS // 2
    assert int(s.trail.sum()) == 1 and int(s.trail[centre, centre]) == 1
    trail = np.asarray(obs[-n:])
    assert trail[0] == 1 / 16 and (trail[1:] == 0).all()  # only the start is counted
    step_env = jax.jit(env.step_env)
    # two turns left (heading 0) and 0.5 m along +x: into the cell (1, 1) of the start's frame
    for k, action in enumerate((LEFT, LEFT, FORWARD, FORWARD)):
        obs, s, *_ = step_env(KEY, s, action, params)
        assert int(s.trail.sum()) == k + 2  # one more step counted
        np.testing.assert_array_equal(s.origin, pose)  # the odometry frame stays the start's
    assert int(s.trail[centre, centre]) == 4 and int(s.trail[centre + 1, centre + 1]) == 1
    trail = np.asarray(obs[-n:])
    # own cell: 1 step; one cell behind (angle pi, the 5th angle: value 1 + 2 * 4) the start
    want = np.zeros(n, np.float32)
    want[0], want[1 + 2 * 4] = 1 / 16, 4 / 16
    np.testing.assert_array_equal(trail, want)
    for _ in range(20):  # turning in place: the own cell's reading saturates at 1
        obs, s, *_ = step_env(KEY, s, LEFT, params)
    assert float(obs[-n]) == 1.0 and int(s.trail[centre + 1, centre + 1]) == 21
    assert (np.asarray(obs[-n:]) >= 0).all() and (np.asarray(obs[-n:]) <= 1).all()
    full = s.trail.at[centre + 1, centre + 1].set(255)  # counts stop at uint8's 255
    assert int(env._visit(full, s.origin, s.pose)[centre + 1, centre + 1]) == 255
    # an auto-reset inside step: a fresh trail at the new episode's start
    short = params.replace(max_steps_in_episode=int(s.time) + 1)
    obs, s2, _, _, truncated, _ = jax.jit(env.step)(KEY, s, LEFT, short)
    assert bool(truncated) and int(s2.time) == 0
    assert int(s2.trail.sum()) == 1
    np.testing.assert_array_equal(s2.origin, s2.pose)
    assert float(obs[-n]) == 1 / 16 and (np.asarray(obs[-n + 1 :]) == 0).all()


@pytest.mark.parametrize("bad", [-1.0, "0.5", math.nan, math.inf, True])
def test_a_bad_trail_cell_is_refused_in_one_line(bad):
    with pytest.raises(ValueError, match=r"^trail_cell=.*: must be a positive number") as e:
        jaxnav.make("RobotSimple-v0", backend="kinematic", trail_cell=bad)
    assert "\n" not in str(e.value)


def test_potential_based_progress_discounts_the_next_distance_and_a_crash_refunds_nothing():
    """``progress_discount`` g: the progress term is k (d - g d') a step (Ng et al.'s shaping
    for potential -k d), also on a crash: a crash keeps the distance still to go as a loss
    instead of refunding it, so crashing is never a way out of a search."""
    env, params = jaxnav.make("RobotSimple-v0", backend="kinematic", progress_discount=0.9)
    step_env = jax.jit(env.step_env)
    k = env.config.progress_reward
    _, s = start(env, params, 3.05, 1.5, math.pi, goal=(8.5, 5.5))
    d = float(env.goal_distance(s.pose, s.goal, s.layout, params))
    _, s1, _, term, info = step_env(KEY, s, FORWARD, params)
    d1 = float(env.goal_distance(s1.pose, s.goal, s.layout, params))
    assert not bool(term) and d1 < d  # one cell closer along the free cells
    assert float(info["reward_progress"]) == pytest.approx(k * (d - 0.9 * d1))
    _, s = start(env, params, 1.5, 0.26, -math.pi / 2, goal=(8.5, 5.5))  # facing the wall
    d = float(env.goal_distance(s.pose, s.goal, s.layout, params))
    _, s1, _, term, info = step_env(KEY, s, FORWARD, params)
    d1 = float(env.goal_distance(s1.pose, s.goal, s.layout, params))
    assert bool(info["collision"]) and d1 > 1.0
    assert float(info["reward_progress"]) == pytest.approx(k * (d - 0.9 * d1))
    for bad in (-0.5, 1.5, float("nan"), "0.9", True):
        with pytest.raises(ValueError, match=r"^progress_discount="):
            jaxnav.make("RobotSimple-v0", progress_discount=bad)
