"""GridMaze: spaces, dynamics, rewards, auto-reset, layouts, BFS and ``make`` validation."""

from __future__ import annotations

import functools
from collections import deque
from types import SimpleNamespace

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_rollout
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxnav
from jaxnav.agents import dqn
from jaxnav.envs import grid_maze as gm
from jaxnav.envs import maze_algorithms

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3
MOVE = {UP: (-1, 0), DOWN: (1, 0), LEFT: (0, -1), RIGHT: (0, 1)}
KEY = jax.random.key(0)
SETTINGS = settings(max_examples=25, deadline=None)


# ------------------------------------------------------------------------------ helpers
def bfs(obstacles, source) -> dict[tuple[int, int], int]:
    """Plain-Python BFS over free cells: {cell: steps from source}; {} if source is blocked."""
    obstacles = np.asarray(obstacles)
    h, w = obstacles.shape
    source = (int(source[0]), int(source[1]))
    if obstacles[source]:
        return {}
    dist = {source: 0}
    queue = deque([source])
    while queue:
        r, c = queue.popleft()
        for dr, dc in MOVE.values():
            n = (r + dr, c + dc)
            if 0 <= n[0] < h and 0 <= n[1] < w and not obstacles[n] and n not in dist:
                dist[n] = dist[(r, c)] + 1
                queue.append(n)
    return dist


def py_shortest(obstacles, start, goal) -> int:
    return bfs(obstacles, goal).get((int(start[0]), int(start[1])), -1)


def robot_cell(obs, size: int) -> tuple[int, int]:
    """(row, col) of the robot in an ``index`` observation (GridMaze-v0's default)."""
    obs = np.asarray(obs)
    assert obs.shape == (10,) and 0 <= obs[:2].min() and obs[:2].max() < size
    return int(obs[0]), int(obs[1])


@functools.cache
def jit_env(env):
    """Jitted entry points of ``env``, compiled once per env (eager dispatch is far slower)."""
    batched = (0, None)
    return SimpleNamespace(
        reset=jax.jit(env.reset),
        reset_to=jax.jit(env.reset_to),
        step=jax.jit(env.step),
        step_env=jax.jit(env.step_env),
        get_obs=jax.jit(env.get_obs),
        vreset=jax.jit(jax.vmap(env.reset, in_axes=batched)),
        vstep=jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None))),
    )


def start_at(env, params, start, goal, layout=0):
    return jit_env(env).reset_to(KEY, params, jnp.array(start), jnp.array(goal), layout)


def step(env, params, state, action, key=KEY):
    return jit_env(env).step(key, state, jnp.int32(action), params)


def free_neighbour_of_obstacle(obstacles):
    """A free cell, an action from it into an obstacle, and another free cell (a goal)."""
    obstacles = np.asarray(obstacles)
    size = obstacles.shape[0]
    for r in range(size):
        for c in range(size):
            if obstacles[r, c]:
                continue
            for a, (dr, dc) in MOVE.items():
                n = (r + dr, c + dc)
                if 0 <= n[0] < size and 0 <= n[1] < size and obstacles[n]:
                    goal = next(
                        (i, j)
                        for i in range(size)
                        for j in range(size)
                        if not obstacles[i, j] and (i, j) != (r, c)
                    )
                    return (r, c), a, goal
    raise AssertionError("layout has no obstacle next to a free cell")


# ------------------------------------------------------------------------------- spaces
@pytest.mark.parametrize("mode", gm.OBS_MODES)
def test_observation_shape_dtype_and_space(mode):
    size = 7
    env, params = jaxnav.make("GridMaze-v0", size=size, obstacle_density=0.2, obs_mode=mode)
    num_obstacles = int(np.asarray(params.bank.obstacles).sum())
    expected = {
        "index": 4 + 4 + 2,
        "onehot": 4 * size + 4 + 2,
        "paper": 4 + 2 * num_obstacles,
        "sensor": (2 * 2 + 1) ** 2 + 4 + 2,
    }[mode]
    space = env.observation_space(params)
    assert space.shape == (expected,)
    keys = jax.random.split(KEY, 16)
    obs, state = jit_env(env).vreset(keys, params)
    chex.assert_shape(obs, (16, expected))
    # index and onehot hold cells, bits and cell offsets, exact in int8 (less to write, store)
    assert obs.dtype == (jnp.int8 if mode in ("index", "onehot") else jnp.float32) == space.dtype
    actions = jax.random.randint(jax.random.key(1), (16,), 0, 4)
    obs2, *_ = jit_env(env).vstep(keys, state, actions, params)
    for o in np.concatenate([obs, obs2]):
        assert bool(space.contains(o))
    assert not bool(space.contains(np.full(expected, size, np.float32)))
    assert not bool(space.contains(np.zeros(expected + 1, np.float32)))


def test_observation_contents_of_each_mode():
    size = 7
    start, goal = (0, 2), (3, 6)
    obs = {}
    for mode in gm.OBS_MODES:
        env, params = jaxnav.make("GridMaze-v0", size=size, obstacle_density=0.0, obs_mode=mode)
        obs[mode] = np.asarray(start_at(env, params, start, goal)[0])
    offset = np.array([3, 4]) / (size - 1)  # (goal - robot) / (size - 1), (drow, dcol)
    np.testing.assert_array_equal(obs["index"], [*start, *goal, 1, 0, 0, 0, 3, 4])
    o = obs["onehot"]
    assert o[:size].argmax() == 0 and o[size : 2 * size].argmax() == 2
    assert o[2 * size : 3 * size].argmax() == 3 and o[3 * size : 4 * size].argmax() == 6
    np.testing.assert_array_equal(o[4 * size : 4 * size + 4], [1, 0, 0, 0])  # only up blocked
    np.testing.assert_array_equal(o[-2:], [3, 4])  # (goal - robot) in cells
    # paper: robot (x, y), goal (x, y) = (col, row) / (size - 1)
    np.testing.assert_allclose(obs["paper"][:4], np.array([2, 0, 6, 3]) / (size - 1))
    # sensor: 5x5 window (rows above the grid are blocked), free run up/down/left/right
    s = obs["sensor"]
    window = s[:25].reshape(5, 5)
    np.testing.assert_array_equal(window[:2], 1)
    np.testing.assert_array_equal(window[2:], 0)
    np.testing.assert_allclose(s[25:29], np.array([0, 6, 2, 4]) / (size - 1))
    np.testing.assert_allclose(s[-2:], offset)


# a hand-made 7x7 layout: from the left of row 4 to the left of row 2 the shortest path runs
# right along row 4, up column 4 and left along row 2 (10 moves); around the outside, 18
HAND_MADE = """
.......
.#####.
.....#.
####.#.
.....#.
.#####.
.......
"""


def hand_made_env(waypoint_cells: int):
    """GridMaze-v0 (every free cell a goal) on ``HAND_MADE`` with the waypoint."""
    obstacles = np.array([[c == "#" for c in row] for row in HAND_MADE.split()])
    env, params = jaxnav.make(
        "GridMaze-v0", size=7, obstacle_density=0.0, obs_mode="sensor",
        waypoint_cells=waypoint_cells,
    )  # fmt: skip
    return env, params.replace(bank=gm.build_bank(env.config, obstacles[None]))


@pytest.mark.parametrize(
    "k, start, waypoint",
    [
        (2, (4, 0), (4, 2)),  # straight along row 4
        (3, (4, 2), (3, 4)),  # round the corner at (4, 4)
        (4, (4, 3), (2, 3)),  # up column 4 and back left along row 2
        (2, (2, 1), (2, 0)),  # the goal, 1 move away, is nearer than k
        (3, (0, 0), (2, 0)),  # from the top-left corner down column 0 to the goal
        (2, (6, 0), (4, 0)),  # from below: up column 0
        (2, (6, 4), (6, 2)),  # a tie at (6, 4), 16 moves either way round: left before right
    ],
)
def test_waypoint_observation_on_a_hand_made_layout(k, start, waypoint):
    env, params = hand_made_env(k)
    goal = (2, 0)
    obs, state = start_at(env, params, start, goal)
    assert obs.shape == (env.obs_size,) == (25 + 4 + 2 + 2,)
    assert tuple(np.asarray(env.waypoint(state, params)).tolist()) == waypoint
    expected = (np.array(waypoint) - np.array(start)) / k
    np.testing.assert_allclose(obs[-2:], expected)  # (drow, dcol) / k, after the goal offset
    np.testing.assert_allclose(obs[-4:-2], (np.array(goal) - np.array(start)) / 6)
    assert bool(env.observation_space(params).contains(obs))


def test_waypoint_descends_the_shortest_path_in_random_layouts(random_maze):
    """From every free cell of a bank layout, to a bank goal: the waypoint is min(k, d)
    moves from the robot (Manhattan offset at most that) and d - min(k, d) from the goal,
    against a plain-Python BFS; between cells every step of the way is a free cell."""
    k = 3
    base, _ = random_maze
    env, params = jaxnav.make("GridMaze-Random-v0", **{**vars(base.config), "waypoint_cells": k})
    bank = params.bank
    cases = []  # (layout, goal, start, BFS steps from the goal)
    for layout in range(3):
        goal = tuple(np.asarray(bank.free_cells[layout, bank.goal_slots[layout, 0]]).tolist())
        to_goal = bfs(np.asarray(bank.obstacles[layout]), goal)
        cases += [(layout, goal, cell, to_goal) for cell in sorted(to_goal) if cell != goal]
    layouts, goals, starts = (jnp.array([c[i] for c in cases]) for i in range(3))

    @jax.jit
    def waypoints(starts, goals, layouts):
        _, states = jax.vmap(env.reset_to, in_axes=(None, None, 0, 0, 0))(
            KEY, params, starts, goals, layouts
        )
        return jax.vmap(env.waypoint, in_axes=(0, None))(states, params)

    points = np.asarray(waypoints(starts, goals, layouts))
    for (layout, _, cell, to_goal), point in zip(cases, points, strict=True):
        d, point = to_goal[cell], tuple(point.tolist())
        ahead = min(k, d)
        assert to_goal[point] == d - ahead, (layout, cell, point)
        assert bfs(np.asarray(bank.obstacles[layout]), cell)[point] == ahead
        assert abs(point[0] - cell[0]) + abs(point[1] - cell[1]) <= ahead


def test_waypoint_for_a_goal_without_a_distance_field_points_at_the_goal():
    env, params = jaxnav.make(
        "GridMaze-Random-v0", size=7, obstacle_density=0.0, num_layouts=1, goals_per_layout=1,
        waypoint_cells=2,
    )  # fmt: skip
    bank_goal = tuple(np.asarray(params.bank.free_cells[0, params.bank.goal_slots[0, 0]]))
    goal = (0, 0) if bank_goal != (0, 0) else (6, 6)
    start = (6 - goal[0], 6 - goal[1])  # the opposite corner
    obs, state = start_at(env, params, start, goal)
    step_ = np.sign(np.array(goal) - np.array(start)) * 2  # clipped to 2 cells on each axis
    np.testing.assert_array_equal(env.waypoint(state, params), np.array(start) + step_)
    np.testing.assert_allclose(obs[-2:], step_ / 2)


def test_waypoint_needs_the_sensor_observation_and_is_off_in_the_papers_grid():
    assert jaxnav.make("GridMaze-v0", size=5)[0].config.waypoint_cells == 0
    with pytest.raises(ValueError, match="waypoint_cells=2: .* obs_mode='sensor'"):
        jaxnav.make("GridMaze-v0", size=5, waypoint_cells=2)
    with pytest.raises(ValueError, match="waypoint_cells=-1"):
        jaxnav.make("GridMaze-Random-v0", size=5, waypoint_cells=-1)


def test_held_out_layout_seed_shares_no_layout_with_the_training_bank():
    """The default training bank of GridMaze-Random-v0 (and, a superset, one of 16,384
    layouts from its layout_seed) and the held-out bank of ``HELD_OUT_LAYOUT_SEED`` that
    benchmarks/grid_random_sweep.py tests on have no layout in common."""
    cfg = jaxnav.registration.env_config("GridMaze-Random-v0")
    train = gm.generate_layouts(
        cfg.size, cfg.obstacle_density, max(cfg.num_layouts, 16384), cfg.layout_seed
    )
    small = gm.generate_layouts(cfg.size, cfg.obstacle_density, cfg.num_layouts, cfg.layout_seed)
    np.testing.assert_array_equal(train[: cfg.num_layouts], small)  # a larger bank extends it
    held_out = gm.generate_layouts(cfg.size, cfg.obstacle_density, 1024, gm.HELD_OUT_LAYOUT_SEED)
    seen = {b.tobytes() for b in train}
    assert len(seen) == len(train)  # no repeats within the training bank either
    assert not seen & {b.tobytes() for b in held_out}


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_index_observation_is_the_onehot_one_before_encoding(maze, seed):
    """``obs_onehot_sizes`` expands ``index`` observations to exactly the ``onehot`` ones,
    after resets and after steps (neighbour bits and offsets change)."""
    env, params = maze
    onehot_env, _ = jaxnav.make("GridMaze-v0", **{**vars(env.config), "obs_mode": "onehot"})
    assert onehot_env.obs_onehot_sizes is None
    keys = jax.random.split(jax.random.key(seed), 64)
    actions = jax.random.randint(jax.random.key(seed), (64,), 0, 4)

    def observations(e):  # same keys, same states: only the encoding differs
        obs, state = jit_env(e).vreset(keys, params)
        return jnp.concatenate([obs, jit_env(e).vstep(keys, state, actions, params)[0]])

    index = dqn.expand_onehot(observations(env), env.obs_onehot_sizes)
    np.testing.assert_array_equal(index, observations(onehot_env))


def test_large_grid_offsets_do_not_overflow():
    """Above 128 cells a side, offsets leave int8's range; the observation widens to int16."""
    env, params = jaxnav.make(
        "GridMaze-v0", size=200, obstacle_density=0.0, random_layouts=True, num_layouts=1,
        goals_per_layout=1, layout_seed=3
    )  # fmt: skip
    goal = np.asarray(params.bank.free_cells[0, params.bank.goal_slots[0, 0]])
    start = (199 - goal[0], 199 - goal[1])  # far from the goal
    obs, _ = start_at(env, params, start, tuple(goal))
    assert obs.dtype == jnp.int16 == env.observation_space(params).dtype
    np.testing.assert_array_equal(obs[:4], [*start, *goal])
    np.testing.assert_array_equal(obs[-2:], goal - np.array(start))


def test_paper_observation_lists_every_obstacle():
    size = 7
    env, params = jaxnav.make("GridMaze-v0", size=size, obstacle_density=0.2, obs_mode="paper")
    obs, _ = jit_env(env).reset(KEY, params)
    xy = np.rint(np.asarray(obs[4:]).reshape(-1, 2) * (size - 1)).astype(int)
    rows, cols = np.nonzero(np.asarray(params.bank.obstacles[0]))
    assert len(xy) == len(rows) > 0
    assert {(int(x), int(y)) for x, y in xy} == set(zip(cols.tolist(), rows.tolist(), strict=True))


def test_action_space(open_maze):
    env, params = open_maze
    space = env.action_space(params)
    assert space.n == 4 == env.num_actions
    samples = jax.vmap(space.sample)(jax.random.split(KEY, 200))
    assert set(np.asarray(samples).tolist()) == {0, 1, 2, 3}
    assert all(bool(space.contains(a)) for a in range(4))
    assert not bool(space.contains(-1)) and not bool(space.contains(4))


# ---------------------------------------------------------------- jit, vmap, determinism
def test_jit_and_vmap_match_unbatched(maze):
    env, params = maze
    n = 8
    keys = jax.random.split(KEY, n)
    j = jit_env(env)
    obs, state = j.vreset(keys, params)
    chex.assert_shape(obs, (n, env.obs_size))
    actions = jnp.arange(n, dtype=jnp.int32) % 4
    out = j.vstep(keys, state, actions, params)
    chex.assert_shape(out[2], (n,))
    for i in range(n):
        obs_i, state_i = j.reset(keys[i], params)
        np.testing.assert_array_equal(obs[i], obs_i)
        out_i = j.step(keys[i], state_i, actions[i], params)
        for batched, single in zip(jax.tree.leaves(out), jax.tree.leaves(out_i), strict=True):
            np.testing.assert_array_equal(batched[i], single)


def test_step_traced_once(random_maze):
    env, params = random_maze

    @jax.jit
    @chex.assert_max_traces(n=1)
    def jitted_step(key, state, action, params):
        return env.step(key, state, action, params)

    _, state = jit_env(env).reset(KEY, params)
    for i in range(30):  # crosses episode ends (auto-reset) and different actions
        out = jitted_step(jax.random.key(i), state, jnp.int32(i % 4), params)
        state = out[1]
    chex.assert_tree_all_finite(out[0])


def test_same_key_same_episode_different_keys_different_episodes(random_maze):
    env, params = random_maze
    reset = jit_env(env).vreset
    keys = jax.random.split(jax.random.key(3), 64)
    (obs_a, state_a), (obs_b, state_b) = reset(keys, params), reset(keys, params)
    np.testing.assert_array_equal(obs_a, obs_b)
    for a, b in zip(jax.tree.leaves(state_a), jax.tree.leaves(state_b), strict=True):
        np.testing.assert_array_equal(a, b)
    episodes = {
        (int(lay), *map(int, pos), *map(int, goal))
        for lay, pos, goal in zip(state_a.layout, state_a.pos, state_a.goal, strict=True)
    }
    assert len(episodes) > 32  # 64 draws over hundreds of (layout, start, goal) choices
    # a step from a state is deterministic too (also when it auto-resets)
    first = jax.tree.map(lambda x: x[0], state_a)
    s1, s2 = step(env, params, first, UP), step(env, params, first, UP)
    for a, b in zip(jax.tree.leaves(s1), jax.tree.leaves(s2), strict=True):
        np.testing.assert_array_equal(a, b)


# ------------------------------------------------------------ rewards and termination
def test_free_move_gives_step_reward_and_moves(open_maze):
    env, params = open_maze
    for action, (dr, dc) in MOVE.items():
        _, state = start_at(env, params, (3, 3), (0, 0))
        obs, state, reward, terminated, truncated, info = step(env, params, state, action)
        assert float(reward) == 0.0 and not bool(terminated) and not bool(truncated)
        assert tuple(np.asarray(state.pos)) == (3 + dr, 3 + dc)
        assert robot_cell(obs, env.size) == (3 + dr, 3 + dc)
        assert int(state.time) == 1
        np.testing.assert_array_equal(info["final_observation"], obs)  # no reset: same obs


@pytest.mark.parametrize("action", [UP, DOWN, LEFT, RIGHT])
def test_goal_step_terminates_with_goal_reward_and_resets(open_maze, action):
    env, params = open_maze
    goal = (3, 3)
    start = (goal[0] - MOVE[action][0], goal[1] - MOVE[action][1])
    _, state0 = start_at(env, params, start, goal)
    obs, state, reward, terminated, truncated, info = step(env, params, state0, action)
    assert float(reward) == 4.0
    assert bool(terminated) and not bool(truncated) and bool(info["goal_reached"])
    # the last observation of the finished episode: the robot on the goal
    pre_reset = state0.replace(pos=jnp.array(goal, jnp.int32), time=jnp.int32(1))
    final = info["final_observation"]
    np.testing.assert_array_equal(final, jit_env(env).get_obs(pre_reset, params))
    assert robot_cell(final, env.size) == goal
    # the returned state is a fresh episode, and obs is its observation
    assert int(state.time) == 0
    assert not np.array_equal(state.pos, state.goal)
    assert int(state.shortest_path) > 0
    np.testing.assert_array_equal(obs, jit_env(env).get_obs(state, params))


@pytest.mark.parametrize(
    "start,action", [((0, 3), UP), ((6, 3), DOWN), ((3, 0), LEFT), ((3, 6), RIGHT)]
)
def test_off_grid_move_collides_and_robot_stays(open_maze, start, action):
    env, params = open_maze
    _, state0 = start_at(env, params, start, (5, 5) if start != (5, 5) else (1, 1))
    _, state, reward, terminated, truncated, info = step(env, params, state0, action)
    assert float(reward) == -1.0
    assert bool(terminated) and not bool(truncated) and bool(info["collision"])
    assert robot_cell(info["final_observation"], env.size) == start
    assert int(state.time) == 0  # auto-reset
    _, state_env, *_ = jit_env(env).step_env(KEY, state0, jnp.int32(action), params)
    assert tuple(np.asarray(state_env.pos)) == start


def test_obstacle_move_collides_and_robot_stays(maze):
    env, params = maze
    cell, action, goal = free_neighbour_of_obstacle(params.bank.obstacles[0])
    _, state0 = start_at(env, params, cell, goal)
    _, state, reward, terminated, truncated, info = step(env, params, state0, action)
    assert float(reward) == -1.0
    assert bool(terminated) and not bool(truncated) and bool(info["collision"])
    assert not bool(info["goal_reached"])
    pre_reset = state0.replace(time=jnp.int32(1))  # same cell, one step later
    final = info["final_observation"]
    np.testing.assert_array_equal(final, jit_env(env).get_obs(pre_reset, params))
    assert robot_cell(final, env.size) == cell
    _, state_env, *_ = jit_env(env).step_env(KEY, state0, jnp.int32(action), params)
    assert tuple(np.asarray(state_env.pos)) == cell


def test_time_limit_truncates_and_resets():
    env, params = jaxnav.make("GridMaze-v0", size=7, obstacle_density=0.0, max_steps=3)
    _, state = start_at(env, params, (3, 3), (0, 0))
    for t, action in enumerate([DOWN, UP], start=1):
        _, state, _, terminated, truncated, _ = step(env, params, state, action)
        assert not bool(terminated) and not bool(truncated) and int(state.time) == t
    obs, state, reward, terminated, truncated, info = step(env, params, state, DOWN)
    assert bool(truncated) and not bool(terminated) and float(reward) == 0.0
    assert robot_cell(info["final_observation"], env.size) == (4, 3)
    assert int(state.time) == 0
    np.testing.assert_array_equal(obs, jit_env(env).get_obs(state, params))


def test_goal_on_last_step_is_terminated_not_truncated():
    env, params = jaxnav.make("GridMaze-v0", size=7, obstacle_density=0.0, max_steps=1)
    _, state = start_at(env, params, (1, 0), (0, 0))
    _, _, reward, terminated, truncated, _ = step(env, params, state, UP)
    assert bool(terminated) and not bool(truncated) and float(reward) == 4.0


def test_reward_terms_sum_to_reward():
    env, params = jaxnav.make("GridMaze-v0", size=7, obstacle_density=0.0, step_reward=-0.25)
    cases = {  # (start, goal, action) -> (goal, collision, step) terms
        ((1, 0), (0, 0), UP): (4.0, 0.0, 0.0),
        ((0, 0), (3, 3), UP): (0.0, -1.0, 0.0),
        ((2, 2), (3, 3), DOWN): (0.0, 0.0, -0.25),
    }
    for (start, goal, action), terms in cases.items():
        _, state = start_at(env, params, start, goal)
        _, _, reward, *_, info = step(env, params, state, action)
        got = tuple(float(info[k]) for k in ("reward_goal", "reward_collision", "reward_step"))
        assert got == terms
        assert float(reward) == sum(terms)


# --------------------------------------------------------------- invariants (hypothesis)
@SETTINGS
@given(seed=st.integers(0, 2**32 - 1))
def test_reset_gives_valid_reachable_episode(random_maze, seed):
    env, params = random_maze
    _, state = jit_env(env).reset(jax.random.key(seed), params)
    obstacles = np.asarray(params.bank.obstacles[int(state.layout)])
    pos, goal = tuple(np.asarray(state.pos)), tuple(np.asarray(state.goal))
    assert not obstacles[pos] and not obstacles[goal]
    assert pos != goal
    assert int(state.time) == 0
    assert int(state.shortest_path) > 0
    assert int(state.shortest_path) == py_shortest(obstacles, pos, goal)


@functools.cache
def _rollout_fn(env, n, steps):
    vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    return jax.jit(lambda key, params: random_rollout(vstep, env, params, key, n, steps))


@pytest.mark.parametrize("env_fixture", ["maze", "random_maze"])  # GridMaze-v0, -Random-v0
@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_rollout_invariants(env_fixture, request, seed):
    """Random play over auto-resets: never on an obstacle or the goal, time below the limit,
    observations finite and in the observation space, rewards only the documented values and
    the sum of their terms, every fresh episode's shortest path is the BFS one."""
    env, params = request.getfixturevalue(env_fixture)
    obs, state, reward, terminated, truncated, info = _rollout_fn(env, 8, 40)(
        jax.random.key(seed), params
    )
    space = env.observation_space(params)
    chex.assert_shape(obs, (40, 8, *space.shape))
    assert np.isfinite(obs).all() and (obs >= space.low).all() and (obs <= space.high).all()
    c = env.config
    assert np.isin(reward, [c.goal_reward, c.collision_reward, c.step_reward]).all()
    obstacles = np.asarray(params.bank.obstacles)
    layout, pos, goal = (np.asarray(x) for x in (state.layout, state.pos, state.goal))
    time, shortest = np.asarray(state.time), np.asarray(state.shortest_path)
    assert not obstacles[layout, pos[..., 0], pos[..., 1]].any()
    assert not obstacles[layout, goal[..., 0], goal[..., 1]].any()
    assert not (pos == goal).all(-1).any()
    assert (time < params.max_steps_in_episode).all()
    done = np.asarray(terminated | truncated)
    assert ((time == 0) == done).all()  # reset exactly at episode ends
    assert not (np.asarray(terminated) & np.asarray(truncated)).any()
    assert done.any()  # 40 steps > the 12-step limit
    terms = info["reward_goal"] + info["reward_collision"] + info["reward_step"]
    np.testing.assert_array_equal(terms, reward)
    np.testing.assert_array_equal(np.asarray(terminated), info["goal_reached"] | info["collision"])
    cache: dict = {}
    for t, e in zip(*np.nonzero(time == 0), strict=True):
        key = (layout[t, e], *goal[t, e])
        if key not in cache:
            cache[key] = bfs(obstacles[layout[t, e]], goal[t, e])
        assert shortest[t, e] == cache[key][tuple(pos[t, e])]


_shortest_jit = jax.jit(maze_algorithms.shortest_path_length)
_field_jit = jax.jit(maze_algorithms.distance_field)
SIDE = 6
cell = st.tuples(st.integers(0, SIDE - 1), st.integers(0, SIDE - 1))


@settings(max_examples=60, deadline=None)
@given(
    cells=st.lists(st.booleans(), min_size=SIDE * SIDE, max_size=SIDE * SIDE),
    start=cell,
    goal=cell,
)
def test_shortest_path_length_matches_python_bfs(cells, start, goal):
    obstacles = np.array(cells).reshape(SIDE, SIDE)
    got = int(_shortest_jit(jnp.asarray(obstacles), jnp.array(start), jnp.array(goal)))
    assert got == py_shortest(obstacles, start, goal)
    field = np.asarray(_field_jit(jnp.asarray(obstacles), jnp.array(goal)))
    expected = np.full((SIDE, SIDE), maze_algorithms.UNREACHABLE)
    for c, d in bfs(obstacles, goal).items():
        expected[c] = d
    np.testing.assert_array_equal(field, expected)


def test_shortest_path_unreachable_and_trivial_cases():
    walled = np.zeros((5, 5), bool)
    walled[:, 2] = True  # a wall splits the grid
    sp = lambda s, g: int(_shortest_jit(jnp.asarray(walled), jnp.array(s), jnp.array(g)))  # noqa: E731
    assert sp((0, 0), (0, 4)) == -1
    assert sp((0, 0), (4, 1)) == 5
    assert sp((3, 3), (3, 3)) == 0
    assert sp((0, 2), (0, 0)) == -1  # start on an obstacle


# ------------------------------------------------------------------------------ layouts
@settings(max_examples=30, deadline=None)
@given(
    size=st.integers(3, 12),
    density=st.floats(0.0, 0.45),
    seed=st.integers(0, 2**31 - 1),
)
def test_generated_layouts_connected_and_at_least_requested_density(size, density, seed):
    layouts = gm.generate_layouts(size, density, 4, seed)
    assert layouts.shape == (4, size, size) and layouts.dtype == bool
    requested = round(density * size * size)
    for obstacles in layouts:
        assert obstacles.sum() >= requested  # pockets are filled, never emptied
        free = list(zip(*np.nonzero(~obstacles), strict=True))
        if free:
            assert len(bfs(obstacles, free[0])) == len(free)  # one connected region


@pytest.mark.parametrize("density", [0.1, 0.2])
def test_layout_density_close_to_requested(density):
    """Filling pockets adds obstacles; at the densities used (default 0.2) only a few."""
    layouts = gm.generate_layouts(15, density, 200, seed=1)
    fraction = layouts.reshape(200, -1).mean(axis=1)
    assert fraction.min() >= round(density * 225) / 225
    assert fraction.mean() <= density + 0.03


def test_random_env_draws_many_layouts(random_maze):
    env, params = random_maze
    bank = np.asarray(params.bank.obstacles)
    assert bank.shape == (8, 7, 7)
    assert len({b.tobytes() for b in bank}) == 8  # the bank's layouts differ
    _, state = jit_env(env).vreset(jax.random.split(KEY, 64), params)
    assert len(set(np.asarray(state.layout).tolist())) >= 6


def test_fixed_env_has_one_layout_chosen_by_layout_seed(maze):
    env, params = maze
    assert params.bank.obstacles.shape == (1, 7, 7)
    _, state = jit_env(env).vreset(jax.random.split(KEY, 32), params)
    assert (np.asarray(state.layout) == 0).all()
    _, same = jaxnav.make("GridMaze-v0", size=7, obstacle_density=0.2)
    np.testing.assert_array_equal(same.bank.obstacles, params.bank.obstacles)
    _, other = jaxnav.make("GridMaze-v0", size=7, obstacle_density=0.2, layout_seed=1)
    assert not np.array_equal(other.bank.obstacles, params.bank.obstacles)


# --------------------------------------------------------------------------------- make
def test_registered_envs_lists_both_ids():
    ids = jaxnav.registered_envs()
    assert "GridMaze-v0" in ids and "GridMaze-Random-v0" in ids
    for env_id in ids:
        if env_id == "RobotMaze-v0":
            continue  # needs a maze file; tests/test_robot_env.py makes it
        # small banks: the robot ids' thousands of mazes take seconds to build
        overrides = {"size": 5} if env_id.startswith("GridMaze") else {"num_layouts": 8}
        env, params = jaxnav.make(env_id, **overrides)
        assert env.name == env_id


def test_make_unknown_id():
    with pytest.raises(ValueError, match="GridMaze-v9"):
        jaxnav.make("GridMaze-v9")


def test_make_unknown_override():
    with pytest.raises(ValueError, match="gridsize"):
        jaxnav.make("GridMaze-v0", gridsize=5)


@pytest.mark.parametrize(
    "override,message",
    [
        ({"size": 0}, "size=0"),
        ({"obstacle_density": 1.0}, "obstacle_density=1.0"),
        ({"obs_mode": "x"}, "obs_mode='x'"),
        ({"max_steps": -1}, "max_steps=-1"),
    ],
)
def test_make_bad_values(override, message):
    with pytest.raises(ValueError, match=message):
        jaxnav.make("GridMaze-v0", **override)
