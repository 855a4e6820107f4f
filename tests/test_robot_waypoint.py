"""The planner's waypoint of the robot env (``waypoint_distance``): the point that many metres
(in whole cells of the maze) ahead on a shortest path to the goal, checked against an
independent BFS on the maze grid, and its (sin, cos, distance) in the observation frame."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import bfs_distances

import jaxnav
from jaxnav.envs.robot.env import GENERALIST, GENERALIST_SENSORS
from jaxnav.registration import env_config

KEY = jax.random.key(0)
FORWARD, LEFT = 0, 2


def tiny(env_id: str) -> dict:
    """A small bank for the generalist, the fast backend for the paper's mazes."""
    return {"num_layouts": 4} if env_id == "RobotNav-v0" else {"backend": "kinematic"}


@functools.cache
def make(env_id: str, **overrides):
    """A tiny env (cached per id and overrides) and its jitted, batched ``waypoint``."""
    env, params = jaxnav.make(env_id, **{**tiny(env_id), **overrides})
    waypoint = jax.jit(jax.vmap(env.waypoint, in_axes=(0, 0, 0, None)))
    return env, params, waypoint


# (env id, overrides): the generalist (K = 32 goal cells per maze, 1 m = 2 cells of 0.5 m) and
# the paper's complex maze (every cell a goal) with other waypoint distances
ENVS = [
    ("RobotNav-v0", ()),
    ("RobotNav-v0", (("waypoint_distance", 2.5),)),
    ("RobotComplex-v0", (("waypoint_distance", 0.5),)),
    ("RobotComplex-v0", (("waypoint_distance", 1.5),)),
]
STRAIGHT = (("waypoint_moves", 4),)  # the planner's moves up, down, left and right only
ENV_IDS = ["generalist", "generalist-5-cells", "complex-1-cell", "complex-3-cells"]


def cell_of(xy, rows: int, cell_size: float) -> tuple[int, int]:
    """(row, col) of the cell holding point ``xy`` (row 0 at the top)."""
    return rows - 1 - int(math.floor(xy[1] / cell_size)), int(math.floor(xy[0] / cell_size))


def episodes(params, n: int, seed: int):
    """``n`` (layout, start xy, goal xy) with the goal one a reset may draw (a goal cell of the
    maze where the bank keeps only some) and the start another free cell."""
    bank = jax.device_get(params.bank)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        layout = int(rng.integers(bank.num_mazes))
        free = int(bank.num_free[layout])
        if bank.goal_index is None:
            goal, start = rng.choice(free, 2, replace=False)
        else:
            goal = int(rng.choice(bank.goal_index[layout]))
            start = int(rng.choice([i for i in range(free) if i != goal]))
        out.append((layout, bank.free_xy[layout, start], bank.free_xy[layout, goal]))
    return out


def start_poses(env, params, n: int, seed: int):
    """``(layout, pose, goal)`` arrays of ``n`` episodes: starts anywhere the robot fits in a
    free cell (as far off the centre as its radius allows), random headings."""
    eps = episodes(params, n, seed=seed)
    cs = float(params.bank.cell_size[0])  # one cell size in these banks
    layout = np.array([e[0] for e in eps], np.int32)
    goal = np.stack([e[2] for e in eps]).astype(np.float32)
    rng = np.random.default_rng(1)
    room = cs / 2 - env.config.radius
    start = np.stack([e[1] for e in eps]) + rng.uniform(-room, room, (len(eps), 2))
    pose = np.concatenate([start, rng.uniform(-np.pi, np.pi, (len(eps), 1))], 1)
    return layout, pose.astype(np.float32), goal


def bfs_to_goals(bank, layout, pose, goal) -> tuple[list[np.ndarray], np.ndarray]:
    """The reference: each episode's BFS steps to its goal cell on its maze's grid (an
    independent BFS), and the steps from its start."""
    rows, cs = bank.grid.shape[1], float(bank.cell_size[0])
    ref = [
        bfs_distances(np.asarray(bank.grid[lay]), cell_of(g, rows, cs))
        for lay, g in zip(layout, goal, strict=True)
    ]
    steps = np.array([r[cell_of(p, rows, cs)] for r, p in zip(ref, pose, strict=True)])
    return ref, steps


@pytest.mark.parametrize("env_id, overrides", ENVS, ids=ENV_IDS)
def test_following_straight_waypoints_walks_a_shortest_path_to_the_goal(env_id, overrides):
    """With 4 moves, from random start points (anywhere the robot fits in a free cell, any
    heading), jumping to each waypoint in turn: every waypoint is a free cell's centre exactly
    k = ``waypoint_steps`` BFS steps closer to the goal than the last, until the goal itself
    comes within k; so the goal is reached in ceil(d / k) hops."""
    env, params, waypoint = make(env_id, **dict(overrides + STRAIGHT))
    k = env.waypoint_steps
    bank = jax.device_get(params.bank)
    rows, cols = bank.grid.shape[1:]
    cs = float(bank.cell_size[0])
    layout, pose, goal = start_poses(env, params, 48, seed=k)
    ref, steps = bfs_to_goals(bank, layout, pose, goal)
    assert (steps > 0).all()  # reachable, and not from the goal's own cell
    hops = np.zeros(len(layout), int)
    done = np.zeros(len(layout), bool)
    for _ in range(int(steps.max()) + 2):  # a bound: each hop must come at least a step closer
        if done.all():
            break
        wp = np.asarray(waypoint(jnp.asarray(pose), jnp.asarray(goal), jnp.asarray(layout), params))
        for i in np.flatnonzero(~done):
            hops[i] += 1
            left = ref[i][cell_of(pose[i], rows, cs)]
            if left <= k:  # within reach: the goal itself, to the bit
                np.testing.assert_array_equal(wp[i], goal[i])
                done[i] = True
                continue
            row, col = cell_of(wp[i], rows, cs)
            assert not bank.grid[layout[i], row, col], f"episode {i}: waypoint in a wall"
            centre = np.array([(col + 0.5) * cs, (rows - 0.5 - row) * cs])
            np.testing.assert_allclose(wp[i], centre, atol=1e-5)
            assert ref[i][row, col] == left - k, f"episode {i}: not {k} steps closer"
            pose[i, :2] = wp[i]
    assert done.all()
    np.testing.assert_array_equal(hops, -(-steps // k))  # ceil(d / k)


@pytest.mark.parametrize("env_id, overrides", ENVS, ids=ENV_IDS)
def test_following_diagonal_waypoints_reaches_the_goal_without_cutting_corners(env_id, overrides):
    """With 8 moves (the default), jumping to each waypoint in turn: every waypoint is a free
    cell's centre at most k = ``waypoint_steps`` king moves away (Chebyshev distance), between k
    and 2k BFS steps closer to the goal (a diagonal move saves two straight ones), and no move
    of the descent cuts a wall's corner; the goal is reached in at most ceil(d / k) hops."""
    env, params, waypoint = make(env_id, **dict(overrides))
    assert env.config.waypoint_moves == 8
    k = env.waypoint_steps
    bank = jax.device_get(params.bank)
    rows, cols = bank.grid.shape[1:]
    cs = float(bank.cell_size[0])
    layout, pose, goal = start_poses(env, params, 48, seed=k)
    ref, steps = bfs_to_goals(bank, layout, pose, goal)
    hops = np.zeros(len(layout), int)
    done = np.zeros(len(layout), bool)
    diagonal = 0
    for _ in range(int(steps.max()) + 2):
        if done.all():
            break
        wp = np.asarray(waypoint(jnp.asarray(pose), jnp.asarray(goal), jnp.asarray(layout), params))
        for i in np.flatnonzero(~done):
            hops[i] += 1
            here = cell_of(pose[i], rows, cs)
            left = ref[i][here]
            if np.array_equal(wp[i], goal[i]):
                done[i] = True
                continue
            there = cell_of(wp[i], rows, cs)
            assert not bank.grid[layout[i], there[0], there[1]], f"episode {i}: in a wall"
            assert max(abs(there[0] - here[0]), abs(there[1] - here[1])) <= k
            assert k <= left - ref[i][there] <= 2 * k, f"episode {i}: {left} -> {ref[i][there]}"
            diagonal += left - ref[i][there] > k
            pose[i, :2] = wp[i]
    assert done.all() and (hops <= -(-steps // k)).all()
    assert diagonal > 0  # the mazes have room for diagonal moves


# the planner's moves in its documented order: up, down, left, right, then the diagonals
MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1))


def reference_waypoint(ref, here, goal, k, moves, cs):
    """The documented descent on an independent BFS: ``k`` times, to the first neighbour in
    ``MOVES`` order with the fewest steps to the goal, if fewer than the cell's own (a diagonal
    only with both cells beside it known); the goal itself once in its cell, or from a cell
    with no known path; else the cell's centre."""
    rows, cols = ref.shape
    far = np.iinfo(np.int64).max

    def steps(r, c):
        inside = 0 <= r < rows and 0 <= c < cols
        return int(ref[r, c]) if inside and ref[r, c] >= 0 else far

    row, col = here
    if steps(row, col) == far:
        return goal
    for _ in range(k):
        lowest, move = steps(row, col), (0, 0)
        for dr, dc in MOVES[:moves]:
            if dr and dc and far in (steps(row + dr, col), steps(row, col + dc)):
                continue
            if steps(row + dr, col + dc) < lowest:
                lowest, move = steps(row + dr, col + dc), (dr, dc)
        row, col = row + move[0], col + move[1]
    if steps(row, col) == 0:
        return goal
    return np.array([(col + 0.5) * cs, (rows - 0.5 - row) * cs], np.float32)


@pytest.mark.parametrize("moves", [4, 8])
@pytest.mark.parametrize("env_id, overrides", ENVS, ids=ENV_IDS)
def test_waypoint_is_the_documented_descent_with_its_order_among_equals(env_id, overrides, moves):
    """From random start points, the waypoint equals the reference descent on an independent
    BFS exactly: the same cell where several neighbours tie (the first in the documented order
    wins), no move to a neighbour only as close as the cell, the goal where the path ends."""
    env, params, waypoint = make(env_id, **dict(overrides + (("waypoint_moves", moves),)))
    bank = jax.device_get(params.bank)
    rows, cs = bank.grid.shape[1], float(bank.cell_size[0])
    layout, pose, goal = start_poses(env, params, 64, seed=moves)
    ref, _ = bfs_to_goals(bank, layout, pose, goal)
    wp = np.asarray(waypoint(jnp.asarray(pose), jnp.asarray(goal), jnp.asarray(layout), params))
    for i in range(len(layout)):
        here = cell_of(pose[i], rows, cs)
        want = reference_waypoint(ref[i], here, goal[i], env.waypoint_steps, moves, cs)
        np.testing.assert_allclose(wp[i], want, atol=1e-5, err_msg=f"episode {i}")


def test_a_diagonal_move_never_cuts_a_walls_corner(tmp_path):
    """On 1 m cells with one wall cell at (row 1, col 2) and the goal in the top-right cell
    (0, 3): from (2, 2), just below the wall, the diagonal to (1, 3) would cut the wall's
    corner, so the planner steps right to (2, 3); from (3, 0), with both cells beside the
    diagonal free, it steps diagonally to (2, 1)."""
    maze = tmp_path / "corner.txt"
    maze.write_text("cell_size: 1.0\n....\n..#.\n....\n....\n")
    env, params = jaxnav.make(
        "RobotMaze-v0", maze_file=str(maze), backend="kinematic", waypoint_distance=1.0
    )
    goal = jnp.asarray([3.5, 3.5], jnp.float32)
    below_wall = env.waypoint(jnp.asarray([2.5, 1.5, 0.0]), goal, jnp.int32(0), params)
    assert cell_of(np.asarray(below_wall), 4, 1.0) == (2, 3)
    open_corner = env.waypoint(jnp.asarray([0.5, 0.5, 0.0]), goal, jnp.int32(0), params)
    assert cell_of(np.asarray(open_corner), 4, 1.0) == (2, 1)


def test_waypoint_is_the_goal_where_no_path_is_known():
    """In the generalist's bank only the maze's goal cells have a BFS table: for any other goal
    the waypoint is the goal itself, and in the goal's own cell too."""
    env, params, waypoint = make("RobotNav-v0")
    bank = jax.device_get(params.bank)
    layout = 0
    goal_cells = set(bank.goal_index[layout].tolist())
    others = [i for i in range(int(bank.num_free[layout])) if i not in goal_cells][:8]
    goal = bank.free_xy[layout, others[::-1]]  # goals that are no goal cell
    pose = np.concatenate([bank.free_xy[layout, others], np.zeros((len(others), 1))], 1)
    lay = jnp.zeros(len(others), jnp.int32)
    wp = waypoint(jnp.asarray(pose, jnp.float32), jnp.asarray(goal), lay, params)
    np.testing.assert_array_equal(np.asarray(wp), goal)
    # a known goal, from a point of its own cell other than the goal: the goal
    g = bank.free_xy[layout, bank.goal_index[layout, 0]]
    near = jnp.asarray([[g[0] + 0.1, g[1] - 0.1, 1.0]], jnp.float32)
    wp = waypoint(near, jnp.asarray(g[None]), lay[:1], params)
    np.testing.assert_array_equal(np.asarray(wp)[0], g)


# ------------------------------------------------------------------------ observation
def waypoint_values(env, params, pose, goal, layout) -> np.ndarray:
    """The frame's waypoint values by their formula: (sin, cos) of the waypoint's bearing
    relative to the heading, its distance / laser_range clipped at 1."""
    wp = np.asarray(env.waypoint(pose, goal, layout, params), np.float64)
    offset = wp - np.asarray(pose[:2], np.float64)
    angle = math.atan2(offset[1], offset[0]) - float(pose[2])
    distance = min(np.linalg.norm(offset) / env.config.laser_range, 1.0)
    return np.array([math.sin(angle), math.cos(angle), distance])


@pytest.mark.parametrize(
    "env_id, overrides, frame",
    [
        ("RobotNav-v0", (), 32 + 1 + 2 + 3),  # lasers, D, goal bearing, waypoint
        ("RobotComplex-v0", (("waypoint_distance", 1.5),), 7 + 4 + 1 + 2 + 3),  # + goal, robot xy
        # a short range: the waypoint (up to 1.5 m away) is clipped at 1
        ("RobotComplex-v0", (("waypoint_distance", 1.5), ("laser_range", 0.6), ("frames", 2)), 17),
        (
            "RobotComplex-v0",
            (("waypoint_distance", 0.5), ("obs_heading", True), ("obs_proximity", False)),
            7 + 4 + 2 + 2 + 3,
        ),
    ],
    ids=["generalist", "complex", "clipped", "heading"],
)
def test_frame_ends_with_the_waypoints_bearing_and_distance(env_id, overrides, frame):
    env, params, _ = make(env_id, **dict(overrides))
    c = env.config
    assert env.frame_size == frame
    assert env.observation_space(params).shape == (c.frames * frame,)
    # the same frame less the waypoint's 3 values without it
    plain, plain_params = jaxnav.make(
        env_id, **{**dict(overrides), "waypoint_distance": 0.0, **tiny(env_id)}
    )
    step = jax.jit(env.step_env)
    clipped = 0
    for layout, start, goal in episodes(params, 6, seed=3):
        pose = jnp.asarray([*start, 0.7], jnp.float32)
        goal = jnp.asarray(goal, jnp.float32)
        obs, s = env.reset_to(KEY, params, pose, goal, layout)
        obs0, _ = plain.reset_to(KEY, plain_params, pose, goal, layout)
        for t in range(3):  # the newest frame is the last
            newest = np.asarray(obs).reshape(c.frames, frame)[-1]
            want = waypoint_values(env, params, s.pose, s.goal, s.layout)
            np.testing.assert_allclose(newest[-3:], want, atol=1e-5)
            clipped += want[2] == 1.0
            if t == 0:
                np.testing.assert_array_equal(newest[:-3], np.asarray(obs0)[: frame - 3])
            obs, s, *_ = step(KEY, s, jnp.int32(LEFT if t else FORWARD), params)
    assert np.isfinite(np.asarray(obs)).all() and (np.abs(np.asarray(obs)) <= 1).all()
    assert (clipped > 0) == (c.laser_range < env.waypoint_steps * float(params.bank.cell_size[0]))


@pytest.mark.parametrize("env_id", ["RobotSimple-v0", "RobotComplex-v0"])
def test_waypoint_distance_zero_leaves_observations_bit_for_bit_unchanged(env_id):
    default, params = jaxnav.make(env_id, backend="kinematic")
    off, off_params = jaxnav.make(env_id, backend="kinematic", waypoint_distance=0)
    assert default.config.waypoint_distance == 0 and off.frame_size == default.frame_size
    free = np.asarray(params.bank.free_xy[0, : int(params.bank.num_free[0])])
    far = free[np.argmax(np.hypot(*(free - free[0]).T))]  # free cells: reset_to refuses walls
    pose, goal = jnp.array([*free[0], 0.4]), jnp.asarray(far)
    a, sa = default.reset_to(KEY, params, pose, goal)
    b, sb = off.reset_to(KEY, off_params, pose, goal)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    for t in range(6):
        action = jnp.int32((FORWARD, LEFT)[t % 2])
        a, sa, ra, *_ = default.step_env(KEY, sa, action, params)
        b, sb, rb, *_ = off.step_env(KEY, sb, action, off_params)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert float(ra) == float(rb)


@pytest.mark.parametrize("bad", [0, 6, True, "8", 8.0])
def test_waypoint_moves_other_than_4_or_8_are_refused(bad):
    with pytest.raises(ValueError, match=r"^waypoint_moves=.*must be 4 or 8"):
        env_config("RobotComplex-v0", waypoint_moves=bad)


@pytest.mark.parametrize("bad", [-1, -0.5, 10.5, float("nan"), float("inf"), True, "2"])
def test_out_of_range_waypoint_distances_are_refused(bad):
    with pytest.raises(ValueError, match=r"^waypoint_distance=.*metres in \[0, 10\]"):
        env_config("RobotComplex-v0", waypoint_distance=bad)
    with pytest.raises(ValueError, match="waypoint_distance="):
        jaxnav.make("RobotNav-v0", num_layouts=2, waypoint_distance=bad)


def test_waypoint_distance_range_ends_are_accepted():
    assert env_config("RobotComplex-v0", waypoint_distance=10).waypoint_distance == 10
    assert env_config("RobotNav-v0", waypoint_distance=0).waypoint_distance == 0


@pytest.mark.parametrize(
    "env_id, cell_size, distance, steps",
    [
        ("RobotComplex-v0", 0.5, 1.0, 2),  # the generalist's training mazes' cell size
        ("RobotSimple-v0", 1.0, 1.0, 1),  # 1 m cells: one cell, not two (2 m)
        ("RobotSimple-v0", 1.0, 1.6, 2),
        ("RobotMaze-v0", 0.75, 1.0, 1),  # warehouse.txt: nearest whole number of cells
        ("RobotMaze-v0", 0.75, 0.1, 1),  # at least one cell
    ],
)
def test_the_waypoints_lookahead_is_a_distance_in_whole_cells(env_id, cell_size, distance, steps):
    """The same ``waypoint_distance`` looks about as far ahead on mazes of any cell size: the
    nearest whole number of the maze's cells, at least one."""
    kw = {"maze_file": "examples/mazes/warehouse.txt", "num_wall_slots": 64}
    env, params = jaxnav.make(
        env_id, backend="kinematic", waypoint_distance=distance,
        **(kw if env_id == "RobotMaze-v0" else {}),
    )  # fmt: skip
    assert float(params.bank.cell_size[0]) == cell_size and env.waypoint_steps == steps


def test_a_waypoint_beyond_64_cells_of_the_maze_is_refused(tmp_path):
    maze = tmp_path / "fine.txt"
    maze.write_text("cell_size: 0.1\n" + "..........\n" * 10)
    with pytest.raises(ValueError, match=r"^waypoint_distance=7: more than 64 cells of the"):
        env_config(
            "RobotMaze-v0", maze_file=str(maze), backend="kinematic", radius=0.04, goal_radius=0.2,
            waypoint_distance=7.0,
        )  # fmt: skip


def test_generalist_settings_reach_the_env():
    """RobotNav-v0's planner hint, lidar, turn rate and reward as its params and config carry
    them, and the sensors a policy of it needs elsewhere include the waypoint."""
    env, params, _ = make("RobotNav-v0")
    c = env.config
    assert (c.waypoint_distance, env.waypoint_steps, c.laser_range, c.turn_speed) == (
        1.0, 2, 3.5, 2.0
    )
    assert params.max_steps_in_episode == 800 and params.collision_reward == -10.0
    assert c.speed == 1.5
    assert (params.step_reward_start, params.step_reward_end) == (-0.1, -0.2)
    assert GENERALIST_SENSORS["waypoint_distance"] == GENERALIST["waypoint_distance"] == 1.0
    # a turn is 0.2 rad
    start = jnp.append(params.bank.free_xy[0, 1], 0.0)
    _, s = env.reset_to(KEY, params, start, params.bank.free_xy[0, 0])
    _, s1, *_ = env.step_env(KEY, s, jnp.int32(LEFT), params)
    assert float(s1.pose[2]) == pytest.approx(0.2, abs=1e-6)
