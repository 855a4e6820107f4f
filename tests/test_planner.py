"""The waypoint planner that knows the robot's size (``jaxnav.deploy.planner``): its inflated
free space keeps the robot's clearance, it never routes through a gap narrower than the robot,
and the robot env's JAX tables and descent compute the same waypoints on the same grids."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import bfs_distances

import jaxnav
from jaxnav.deploy import planner
from jaxnav.deploy.planner import GridMap, Planner
from jaxnav.envs.robot.geometry import collides


def clearance_of_centres(grid: np.ndarray, cell_size: float) -> np.ndarray:
    """The oracle: metres from each cell's centre to the nearest wall cell's square or the
    grid's edge, by brute force over every wall cell."""
    rows, cols = grid.shape
    r, c = np.mgrid[:rows, :cols]
    centre = np.stack([c + 0.5, rows - r - 0.5], -1).reshape(-1, 1, 2)  # x, y in cells
    wr, wc = np.nonzero(grid)
    lo = np.stack([wc, rows - 1 - wr], -1)[None].astype(float)
    gap = np.maximum(np.maximum(lo - centre, centre - (lo + 1)), 0)
    to_wall = np.linalg.norm(gap, axis=-1).min(-1, initial=np.inf)
    flat = centre.reshape(-1, 2)
    to_edge = np.minimum.reduce([flat[:, 0], flat[:, 1], cols - flat[:, 0], rows - flat[:, 1]])
    return (np.minimum(to_wall, to_edge) * cell_size).reshape(rows, cols)


@pytest.mark.parametrize("clearance", [0.0, 0.04, 0.05, 0.12, 0.2, 0.31])
def test_passable_cells_are_the_free_cells_whose_centre_has_the_clearance(clearance):
    rng = np.random.default_rng(0)
    grid = rng.random((14, 17)) < 0.2
    ok = planner.passable(grid, 0.1, clearance)
    np.testing.assert_array_equal(ok, ~grid & (clearance_of_centres(grid, 0.1) >= clearance))
    if clearance <= 0.05:  # half a cell: no free cell is nearer a wall
        np.testing.assert_array_equal(ok, ~grid)


# A 2 m x 1.6 m room of 0.1 m cells split by a wall (rows 7-8) with two openings: a 0.3 m gap
# near the start and goal (columns 3-5) and a 0.8 m door at the far end (columns 11-18). The
# start is above the wall at column 4, the goal below it at column 4.
GAP_MAP = "\n".join(["." * 20] * 7 + ["###...#####........#"] * 2 + ["." * 20] * 7)
START, GOAL = (2, 4), (13, 4)  # (row, col)


def gap_map() -> GridMap:
    grid = np.array([[ch == "#" for ch in line] for line in GAP_MAP.splitlines()])
    return GridMap(grid, 0.1, origin=(-3.0, 2.0))


@pytest.mark.parametrize("moves", [4, 8])
def test_the_inflated_planner_never_routes_through_a_gap_narrower_than_the_robot(moves):
    """A robot of radius 0.2 m (0.4 m wide) keeping 0.05 m: the 0.3 m gap is closed to it, so
    its path (every cell of the descent) goes round through the 0.8 m door and keeps 0.25 m
    from walls all along; a robot of radius 0.08 m takes the gap, a shorter way."""
    grid_map = gap_map()
    start, goal = grid_map.centre(START), grid_map.centre(GOAL)
    big = Planner(grid_map, radius=0.2, margin=0.05, waypoint_distance=0.5, moves=moves)
    big.set_goal(goal)
    path = big.path(*start)
    assert path[0] == START and path[-1] == GOAL
    wall_rows = [cell for cell in path if cell[0] in (7, 8)]
    assert wall_rows and all(11 <= c <= 18 for _, c in wall_rows), wall_rows  # the door
    clearance = clearance_of_centres(grid_map.grid, 0.1)
    assert min(clearance[cell] for cell in path) >= 0.25
    small = Planner(grid_map, radius=0.08, margin=0.05, waypoint_distance=0.5, moves=moves)
    small.set_goal(goal)
    short = small.path(*start)
    assert any(cell[0] == 7 and 3 <= cell[1] <= 5 for cell in short)  # through the gap
    assert len(short) < len(path)
    # the waypoints hop along the same path, 5 cells (0.5 m) at a time, to the goal itself
    (x, y), hops = start, 1
    while (waypoint := big.waypoint(x, y)) != goal and hops < 100:
        assert grid_map.cell_of(*waypoint) in path
        (x, y), hops = waypoint, hops + 1
    assert waypoint == goal and hops <= math.ceil((len(path) - 1) / 5)


def test_a_robot_within_the_margin_of_a_wall_plans_from_the_nearest_passable_cell():
    grid_map = gap_map()
    p = Planner(grid_map, radius=0.2, margin=0.05)
    p.set_goal(grid_map.centre(GOAL))
    x, y = grid_map.centre((2, 0))  # beside the room's left edge: 0.05 m from it
    assert p.steps[2, 0] < 0 and p.start_cell(x, y) == (2, 2)
    wx, wy = p.waypoint(x, y)
    assert p.steps[grid_map.cell_of(wx, wy)] >= 0


def test_bad_goals_and_poses_are_named():
    p = Planner(gap_map(), radius=0.2)
    with pytest.raises(ValueError, match=r"^goal=\(-2.95, 2.75\): inside a wall of the map"):
        p.set_goal((-2.95, 2.75))  # row 8, col 0
    with pytest.raises(ValueError, match=r"^goal=\(5, 2.5\): off the map"):
        p.set_goal((5.0, 2.5))
    with pytest.raises(ValueError, match="no goal"):
        p.waypoint(-2.5, 3.0)
    # a goal in a pocket the robot cannot reach
    walled = np.zeros((10, 10), bool)
    walled[:, 5] = True
    q = Planner(GridMap(walled, 0.5), radius=0.15)
    q.set_goal((4.0, 4.0))
    with pytest.raises(ValueError, match=r"^pose=\(1, 1\): no path to goal=\(4, 4\) for a robot"):
        q.waypoint(1.0, 1.0)
    for bad in ({"radius": -0.1}, {"radius": float("nan")}, {"moves": 6}, {"margin": True}):
        with pytest.raises(ValueError, match=f"^{next(iter(bad))}="):
            Planner(gap_map(), **{"radius": 0.2, **bad})


def test_an_occupancy_grid_message_reads_bottom_row_first():
    """nav_msgs/OccupancyGrid: data from the origin's cell, rows going +y; occupied at 65%
    and unknown (-1) are walls, unless unknown cells are taken as free."""
    data = [0, 100, 0, -1, 50, 0]  # bottom row: free, wall, free; top: unknown, 50%, free
    m = GridMap.from_occupancy_grid(data=data, width=3, height=2, resolution=0.5, origin=(1, 2))
    np.testing.assert_array_equal(m.grid, [[True, False, False], [False, True, False]])
    assert m.cell_of(1.6, 2.1) == (1, 1) and m.centre((1, 1)) == (1.75, 2.25)
    free = GridMap.from_occupancy_grid(
        data=data, width=3, height=2, resolution=0.5, origin=(1, 2), unknown_free=True
    )
    assert not free.grid[0, 0]
    with pytest.raises(ValueError, match="data has 6 cells; width=4 x height=2 needs 8"):
        GridMap.from_occupancy_grid(data=data, width=4, height=2, resolution=0.5, origin=(0, 0))


# ------------------------------------------------------------- the env's planner is this one
ENVS = [
    ("RobotNav-v0", {"num_layouts": 4}),  # 32 goal cells per maze, radius 0.15 m, 0.5 m cells
    ("RobotNav-v0", {"num_layouts": 4, "radius_range": (0.1, 0.24), "waypoint_moves": 4}),
    ("RobotComplex-v0", {"backend": "kinematic", "waypoint_distance": 1.5}),  # every cell a goal
    # 0.5 m and 1 m cells in one bank: a lookahead of 2 cells and of 1, robots past 0.25 m
    (
        "RobotNav-v0",
        {"num_layouts": 4, "families": ("rooms", "jaxnav_coarse"), "radius_range": (0.1, 0.35)},
    ),
]


@functools.cache
def make(index: int):
    env_id, kwargs = ENVS[index]
    env, params = jaxnav.make(env_id, **kwargs)
    waypoint = jax.jit(jax.vmap(env.waypoint, in_axes=(0, 0, 0, None)))
    return env, params, waypoint


@pytest.mark.parametrize(
    "index", range(len(ENVS)), ids=["generalist", "radius-range", "complex", "two-cell-sizes"]
)
def test_the_envs_tables_and_waypoints_are_the_host_planners(index):
    """On the env's own mazes, from random points anywhere in free cells: the env's BFS table
    is the host planner's distance field on the grid inflated for the largest robot the maze
    draws (the free cells, as every robot fits a cell), and ``env.waypoint`` is the host
    planner's waypoint, to the bit."""
    env, params, waypoint = make(index)
    bank = jax.device_get(params.bank)
    c = env.config
    rows = bank.grid.shape[1]
    rng = np.random.default_rng(index)
    layout, pose, goal = [], [], []
    for lay in range(bank.num_mazes):
        grid, cs = np.asarray(bank.grid[lay]), float(bank.cell_size[lay])
        grid_map = GridMap(grid, cs)
        p = Planner(
            grid_map, radius=float(env.plan_radius[lay]), margin=0.0,
            waypoint_distance=c.waypoint_distance, moves=c.waypoint_moves,
        )  # fmt: skip
        free = np.argwhere(~grid)
        if bank.goal_index is None:
            goals = free[rng.choice(len(free), 3, replace=False)]
        else:
            goals = np.asarray(bank.free_cells[lay, bank.goal_index[lay, :3]])
        for g in goals:
            g = tuple(int(v) for v in g)
            p.set_goal(grid_map.centre(g))
            np.testing.assert_array_equal(p.steps, bfs_distances(grid, g))
            np.testing.assert_array_equal(p.steps, np.asarray(env._steps_to_goal(
                jnp.asarray(grid_map.centre(g), jnp.float32), lay, params.bank
            )))  # fmt: skip
            starts = free[rng.choice(len(free), 12, replace=False)]
            xy = (starts[:, ::-1] + rng.uniform(0.05, 0.95, (12, 2))) * [1, -1] + [0, rows]
            for x, y in xy * cs:
                layout.append(lay)
                pose.append((x, y, rng.uniform(-np.pi, np.pi)))
                goal.append(grid_map.centre(g))
    want = []
    for lay, (x, y, _), g in zip(layout, pose, goal, strict=True):
        p = Planner(
            GridMap(np.asarray(bank.grid[lay]), float(bank.cell_size[lay])),
            radius=float(env.plan_radius[lay]),
            margin=0.0, waypoint_distance=c.waypoint_distance, moves=c.waypoint_moves,
        )  # fmt: skip
        p.set_goal(g)
        want.append(p.waypoint(x, y))
    got = waypoint(
        jnp.asarray(pose, jnp.float32), jnp.asarray(goal, jnp.float32),
        jnp.asarray(layout, jnp.int32), params,
    )  # fmt: skip
    np.testing.assert_allclose(np.asarray(got), np.asarray(want, np.float32), atol=1e-5)
    assert len(want) >= 36


def test_a_radius_range_plans_for_the_largest_robot_each_maze_draws():
    env, params, _ = make(1)
    fit = np.asarray(params.bank.fit_radius)
    np.testing.assert_allclose(env.plan_radius, np.minimum(0.24, fit))
    assert env.plan_radius.max() == pytest.approx(0.24)  # mazes of 1 m corridors draw the top


def test_a_bank_of_two_cell_sizes_draws_each_robot_under_half_its_mazes_cell():
    """Radii up to 0.35 m on the 1 m cells, capped under half a cell (0.249 m) on the 0.5 m
    ones, every episode starting clear of walls."""
    env, params, _ = make(3)
    np.testing.assert_array_equal(params.bank.cell_size, [0.5, 1.0, 0.5, 1.0])
    np.testing.assert_array_equal(params.bank.waypoint_cells, [2, 1, 2, 1])
    keys = jax.random.split(jax.random.key(3), 400)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    cell = np.asarray(params.bank.cell_size)[np.asarray(state.layout)]
    radius = np.asarray(state.radius)
    assert radius[cell == 1.0].max() > 0.3 and radius[cell == 0.5].max() <= 0.249
    walls = params.bank.walls
    hits = jax.vmap(
        lambda s: collides(
            s.pose[:2], s.radius, walls.center[s.layout], walls.half_size[s.layout],
            walls.active[s.layout],
        )
    )(state)  # fmt: skip
    assert not np.asarray(hits).any()


def test_a_bank_refuses_a_plan_that_blocks_its_placement_cells():
    """Every start and goal must be a cell the robot stands on: a planner's grid that blocks
    one of them is refused, naming the maze (the env's robot, narrower than a cell, never is)."""
    from jaxnav.envs.robot.mazes import builtin_maze, stack_mazes

    maze = builtin_maze("simple")
    plan = np.asarray(maze.grid).copy()
    stack_mazes([maze], 24, plan_grids=plan[None])  # the free cells: accepted
    plan[0, 0] = True
    with pytest.raises(ValueError, match=r"^simple: the planner blocks placement cells"):
        stack_mazes([maze], 24, plan_grids=plan[None])
