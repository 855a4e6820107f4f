"""The robot's own map (``RobotConfig.lidar_map``): its grid holds only what the lidar saw, its
axes follow the walls, its field is the BFS distance on it, the observation carries nothing of
walls the robot has not seen, and a waypoint policy gets out of a dead end with it."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import LIDAR_SENSORS, TRAP_GOAL, TRAP_MAZE, TRAP_START

import jaxnav
from jaxnav.deploy import planner
from jaxnav.envs.robot import lidar_map

SENSORS = LIDAR_SENSORS
OPEN = """cell_size: 1.0
###########
#.........#
#.........#
#.........#
#.........#
###########
"""
# the same room with a wall 7 m from the start, beyond the lidar's 3.5 m: a gap at the top only
WALLED = OPEN.replace("#.........#\n#.........#\n#.........#\n#.........#", (
    "#.........#\n#.......#.#\n#.......#.#\n#.......#.#"
))  # fmt: skip
TRAP, S_XY, G_XY = TRAP_MAZE, TRAP_START, TRAP_GOAL


@functools.cache
def maze_env(text: str, tmp: str, **overrides):
    path = f"{tmp}/maze_{abs(hash(text))}.txt"
    with open(path, "w") as f:
        f.write(text)
    return jaxnav.make("RobotMaze-v0", maze_file=path, **{**SENSORS, **overrides})


@pytest.fixture(scope="module")
def tmp(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("mazes"))


def test_axes_follow_the_walls(tmp):
    env, params = maze_env(TRAP, tmp, lidar_map=0.25)
    headings = jnp.linspace(-math.pi, math.pi, 13)
    poses = jnp.stack([jnp.full(13, 0.75), jnp.full(13, 4.25), headings], axis=1)
    _, states = jax.vmap(env.reset_to, (None, None, 0, None))(
        jax.random.key(0), params, poses, jnp.array([2.75, 2.75])
    )
    angle = np.asarray(states.own_map.frame[:, 2])
    off = np.abs((angle + math.pi / 4) % (math.pi / 2) - math.pi / 4)  # from a multiple of 90
    np.testing.assert_array_less(off, 1e-4)


def test_returns_only_where_walls_are(tmp):
    """Every cell marked as a return holds a point of a wall's face: its centre lies within
    half a cell's diagonal of a wall box."""
    env, params = maze_env(TRAP, tmp, lidar_map=0.25)
    _, state = env.reset(jax.random.key(1), params)
    step = jax.jit(env.step)
    for k in jax.random.split(jax.random.key(2), 40):
        _, state, _, term, trunc, _ = step(k, state, jax.random.randint(k, (), 2, 4), params)
    m = state.own_map
    rows, cols = np.nonzero(np.asarray(m.cells) == 1)
    assert len(rows) > 20
    centres = np.asarray(
        jax.vmap(lidar_map.cell_centre, (None, 0, None))(
            m.frame, jnp.stack([rows, cols], 1), 0.25
        )
    )
    w = params.bank.walls
    active = np.asarray(w.active[state.layout], bool)
    c, h = np.asarray(w.center[state.layout])[active], np.asarray(w.half_size[state.layout])[active]
    gap = np.maximum(np.abs(centres[:, None, :] - c[None]) - h[None], 0.0)
    nearest = np.linalg.norm(gap, axis=-1).min(axis=1)
    np.testing.assert_array_less(nearest, 0.25 * math.sqrt(2) / 2 + 1e-4)


def test_field_is_the_bfs_distance():
    """Swept long enough, the field is the 4-neighbour BFS distance on the cells that are not
    returns (the goal's cell free); cells cut off from the goal count up past every reachable
    one (by one a sweep, toward FAR)."""
    rng = np.random.default_rng(0)
    n = lidar_map.MAP_CELLS
    cells = (rng.random((n, n)) < 0.3).astype(np.uint8)
    goal = np.array([n // 2, n // 3])
    steps = jnp.zeros((n, n), jnp.int16)  # any start: the sweeps correct it both ways
    free = jnp.asarray(cells != 1).at[goal[0], goal[1]].set(True)
    out = np.asarray(lidar_map.sweep(steps, free, jnp.asarray(goal), 4 * n * n // 10))
    free_np = np.asarray(free)
    want = planner.distance_field(free_np, tuple(goal))
    reachable = want >= 0
    np.testing.assert_array_equal(out[reachable], want[reachable])
    assert (~reachable).sum() > 0 and out[~reachable].min() > want.max()


def test_observation_holds_no_unseen_wall(tmp):
    """Two rooms that differ only in a wall 7 m away: the same observations with the robot's own
    map (over a few steps), different ones with the maze's waypoint."""
    pose, goal = jnp.array([1.5, 3.5, 0.3]), jnp.array([9.5, 3.5])
    actions = [0, 0, 2, 0, 3, 0]

    def frames(text: str, own: bool):
        env, params = maze_env(text, tmp, lidar_map=0.25 if own else 0.0)
        obs, state = env.reset_to(jax.random.key(0), params, pose, goal)

        def step(state, action):
            obs, state, *_ = env.step(jax.random.key(0), state, action, params)
            return state, obs

        _, rest = jax.jit(lambda s: jax.lax.scan(step, s, jnp.array(actions)))(state)
        return np.concatenate([np.asarray(obs)[None], np.asarray(rest)])

    np.testing.assert_array_equal(frames(OPEN, True), frames(WALLED, True))
    assert not np.array_equal(frames(OPEN, False), frames(WALLED, False))


@pytest.mark.slow  # compiles a whole recorded episode with the map
def test_a_drawn_episode_shows_the_waypoint_the_policy_reads(tmp):
    """In the walled room the maze's waypoint goes round the unseen wall; the one drawn is the
    own map's, straight at the goal."""
    from jaxnav import render

    env, params = maze_env(WALLED, tmp, lidar_map=0.25)
    pose, goal = jnp.array([[1.5, 3.5, 0.0]]), jnp.array([9.5, 3.5])
    obs, state = jax.vmap(env.reset_to, (None, None, 0, None))(
        jax.random.key(0), params, pose, goal
    )
    (ep,) = render.record(env, params, lambda key, obs: jnp.zeros(obs.shape[:1], int), obs, state)
    first = jax.tree.map(lambda x: x[0], state)
    own = env.own_waypoint(first.pose, first.goal, first.own_map)
    maze = env.waypoint(first.pose, first.goal, first.layout, params)
    np.testing.assert_allclose(ep["waypoint"][0], own)
    assert abs(float(own[1]) - 3.5) < 0.3 < abs(float(maze[1]) - 3.5)


@pytest.mark.slow  # whole episodes of the shipped 1024-512-256 policy
def test_waypoint_policy_leaves_a_dead_end(tmp):
    """The shipped waypoint policy, its waypoint from its own map: round a dead end that the
    straight line to the goal leads into, from every heading."""
    from jaxnav import export, pretrained
    from jaxnav.evaluate import play

    path = f"{tmp}/trap.txt"
    with open(path, "w") as f:
        f.write(TRAP)
    policy = pretrained.load("robotnav-sizes")
    overrides = {"maze_file": path, "lidar_map": 0.25, "radius_range": None, "radius": 0.15}
    trainer, stacked = export.to_trainer(policy, "RobotMaze-v0", overrides)
    env, params = trainer.env, trainer.env_params
    n = 8
    headings = jnp.linspace(-math.pi, math.pi, n, endpoint=False)
    poses = jnp.stack([jnp.full(n, S_XY[0]), jnp.full(n, S_XY[1]), headings], axis=1)
    obs, state = jax.vmap(env.reset_to, (None, None, 0, None))(
        jax.random.key(0), params, poses, jnp.asarray(G_XY)
    )
    act = trainer.greedy_policy(jax.tree.map(lambda x: x[0], stacked))
    out = play(env, params, act, jax.random.key(1), obs, state, params.max_steps_in_episode)
    assert np.all(out["success"]), out


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"lidar_map": -1.0}, "lidar_map=-1.0"),
        ({"lidar_map": 0.25, "waypoint_distance": 0.0}, "needs a waypoint_distance"),
        ({"lidar_map": 0.25, "laser_noise": 0.01}, "laser noise"),
    ],
)
def test_bad_settings_are_refused(overrides, match):
    with pytest.raises(ValueError, match=match):
        jaxnav.make("RobotSimple-v0", **{**SENSORS, **overrides})
