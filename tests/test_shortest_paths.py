"""The reference of the path ratio and SPL: the robot envs' any-angle shortest path to the goal
disc (``envs/robot/shortest_paths.py``), and SPL itself."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav
from jaxnav.envs.robot.shortest_paths import EPSILON, disc_distance
from jaxnav.evaluate import (
    EVAL_COLUMNS,
    Policy,
    random_policy,
    run_episodes,
    spl,
    summarize,
)


def test_spl_of_three_hand_made_episodes():
    # a success on the shortest path, a success at twice its length, a failure
    success = np.array([True, True, False])
    shortest = np.array([3.0, 2.0, 5.0])
    travelled = np.array([3.0, 4.0, 1.0])
    assert spl(success, shortest, travelled) == pytest.approx((1 + 0.5 + 0) / 3)
    ep = {
        "return": np.zeros(3),
        "steps": np.array([12, 16, 4]),
        "success": success,
        "collision": ~success,
        "timeout": np.zeros(3, bool),
        "shortest_path": shortest,
        "path_length": travelled,
        "layout": np.zeros(3, np.int32),
    }
    assert summarize(ep)["spl"] == pytest.approx(0.5)
    assert "spl" in EVAL_COLUMNS
    # unknown shortest paths (-1) are left out; none known: n/a, never 0
    assert summarize({**ep, "shortest_path": np.array([3.0, -1.0, -1.0])})["spl"] == 1.0
    assert summarize({**ep, "shortest_path": np.full(3, -1.0)})["spl"] is None


def test_open_room_shortest_path_is_the_straight_line_less_the_goal_radius():
    room = np.zeros((6, 8), bool)
    d = disc_distance(room, 0.5, (0.25, 0.25), (3.75, 2.75), 0.5)
    assert d == pytest.approx(math.hypot(3.5, 2.5) - 0.5, abs=1e-5)


# an L-shaped corridor of 1 m cells: east along the bottom row, then north up the last column
L_CORRIDOR = "###.\n###.\n....\n"


def test_l_corridor_shortest_path_turns_at_the_inner_corner(tmp_path):
    maze = tmp_path / "l.txt"
    maze.write_text(L_CORRIDOR)
    env, params = jaxnav.make("RobotMaze-v0", maze_file=str(maze), backend="kinematic")
    # from the bottom-left cell's centre (0.5, 0.5) to the top-right one's (3.5, 2.5): straight
    # to the inner corner (3, 1), then straight toward the goal until 0.5 m from it
    by_hand = math.hypot(2.5, 0.5) + math.hypot(0.5, 1.5) - 0.5
    grid = np.array([[c == "#" for c in row] for row in L_CORRIDOR.split()])
    assert disc_distance(grid, 1.0, (0.5, 0.5), (3.5, 2.5), 0.5) == pytest.approx(by_hand, abs=1e-5)
    _, state = env.reset_to(jax.random.key(0), params, jnp.array([0.5, 0.5, 0.0]), (3.5, 2.5))
    got = float(jax.jit(env.shortest_path_length)(state, params))
    assert got == pytest.approx(by_hand, abs=1e-5)
    # shorter than the 4-neighbour cell steps it replaces (5 steps less the goal radius)
    assert got < 5 * 1.0 - 0.5


def test_wall_inside_the_goal_disc_is_walked_around():
    # a 1-cell wall between start and goal; the 1 m disc reaches over it, the robot cannot
    grid = np.array([[False, False, False], [False, True, False], [False, False, False]])
    # to the wall's corner (2, 1), then up its east face to where the circle meets it,
    # (2, 2.5 - sqrt(0.75)): the circle's point nearest the corner lies inside the wall
    by_hand = math.hypot(0.5, 0.5) + (2.5 - math.sqrt(0.75) - 1.0)
    d = disc_distance(grid, 1.0, (1.5, 0.5), (1.5, 2.5), 1.0)
    assert d == pytest.approx(by_hand, abs=1e-5)


def steering_policy(bearing: int, num_actions: int) -> Policy:
    """A trained-like policy: toward the (sin, cos) bearing ``bearing`` fields from the end of the
    newest frame (forward within 0.2 rad, else turn), a random action one step in four."""
    explore = random_policy(num_actions)

    def policy(key: jax.Array, obs: jax.Array) -> jax.Array:
        k_coin, k_random = jax.random.split(key)
        sin, cos = obs[:, -bearing], obs[:, 1 - bearing]
        steer = jnp.where(cos > math.cos(0.2), 0, jnp.where(sin > 0, 2, 3))
        coin = jax.random.uniform(k_coin, obs.shape[:1]) < 0.25
        return jnp.where(coin, explore(k_random, obs), steer)

    return policy


@pytest.mark.slow  # whole episodes of a planner on every layout
@pytest.mark.parametrize(
    "env_id, overrides, bearing",
    [
        # the goal's bearing (the frame's last two fields)
        ("RobotRandom-v0", {"num_layouts": 6, "random_size": 5, "max_steps": 150}, 2),
        # 0.5 m cells where the robot may cut corners diagonally; the waypoint's bearing
        ("RobotNav-v0", {"num_layouts": 8, "max_steps": 150, "num_goal_cells": 8}, 3),
    ],
)
def test_no_successful_episode_beats_the_shortest_path(env_id, overrides, bearing):
    env, params = jaxnav.make(env_id, backend="kinematic", **overrides)
    n = 192
    policy = steering_policy(bearing, env.num_actions)
    out = jax.jit(run_episodes, static_argnums=(0, 2, 4, 5))(
        env, params, policy, jax.random.key(3), n, 150
    )
    ok = np.asarray(out["success"]) & (np.asarray(out["shortest_path"]) > 0)
    assert ok.sum() >= 20  # enough successes to mean something
    shortest = np.asarray(out["shortest_path"])[ok]
    travelled = np.asarray(out["path_length"])[ok]
    assert (travelled >= shortest * (1 - 1e-5)).all(), travelled / shortest
    assert summarize(out)["mean_path_ratio"] >= 1.0
    # between the straight line and the 4-neighbour cell steps, both less the goal radius
    obs, state = jax.vmap(env.reset_layout, in_axes=(0, None, 0))(
        jax.random.split(jax.random.split(jax.random.key(3))[0], n),
        params,
        jnp.arange(n) % env.num_layouts(params),
    )
    known = np.asarray(out["shortest_path"]) > 0
    radius = float(params.goal_radius)
    line = np.linalg.norm(np.asarray(state.pose[:, :2] - state.goal), axis=1) - radius
    steps = jax.vmap(env.goal_distance, in_axes=(0, 0, 0, None))(
        state.pose, state.goal, state.layout, params
    )
    cells = np.asarray(steps) - radius
    got = np.asarray(out["shortest_path"])
    assert (got[known] >= line[known] - 1e-4).all()
    assert (got[known] <= cells[known] + 1e-4 + 2 * EPSILON).all()
