"""Shared, session-scoped fixtures: environments and compiled trainers are built once per
worker, so each test pays for its assertions, not for compilation."""

from __future__ import annotations

import collections
import dataclasses
import os

# two CPU devices for the sharding tests (set before JAX starts its backend; single-device
# code runs on the first one as before)
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
).strip()

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import jaxnav  # noqa: E402
from jaxnav.config import TrainConfig  # noqa: E402
from jaxnav.envs.robot.env import GENERALIST_SENSORS  # noqa: E402
from jaxnav.train import Trainer  # noqa: E402

MAZE_SIZE = 7

# The slow tier (``make test-slow``; CI runs both tiers, ``make test`` the fast one): tests that
# run whole programs end to end, in other processes (the CLI, two processes as one run, the
# notebooks, the benchmarks' smoke runs) or through the caches and recovery paths, each
# compiling and running programs of its own. Besides these modules, the tests marked
# ``@pytest.mark.slow`` where they are written.
SLOW_MODULES = {
    "test_benchmarks_smoke.py",
    "test_compare_smoke.py",
    "test_experiments.py",
    "test_multihost.py",
    "test_notebooks.py",
    "test_programs.py",
    "test_train_throughput_smoke.py",
    "test_xla_options_smoke.py",
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.name in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def open_maze():
    """7x7 GridMaze-v0 without obstacles: every move's outcome is known."""
    return jaxnav.make("GridMaze-v0", size=MAZE_SIZE, obstacle_density=0.0)


@pytest.fixture(scope="session")
def maze():
    """7x7 GridMaze-v0 with obstacles (one fixed layout)."""
    return jaxnav.make("GridMaze-v0", size=MAZE_SIZE, obstacle_density=0.2)


@pytest.fixture(scope="session")
def random_maze():
    """7x7 GridMaze-Random-v0 with a bank of 8 layouts, short episodes."""
    return jaxnav.make(
        "GridMaze-Random-v0", size=MAZE_SIZE, num_layouts=8, goals_per_layout=4, max_steps=12
    )


# ---------------------------------------------------------------------------- training
# the generalist's sensors with a waypoint: what the lidar map tests run a robot env with
LIDAR_SENSORS = {**GENERALIST_SENSORS, "backend": "kinematic"}
# a U whose bottom stands between the start (S) and the goal (G): the straight line from one to
# the other is a dead end
TRAP_MAZE = """cell_size: 0.5
############
#..........#
#..........#
#...#####..#
#.......#..#
#S......#G.#
#.......#..#
#...#####..#
#..........#
#..........#
############
"""
TRAP_START, TRAP_GOAL = (0.75, 2.75), (4.75, 2.75)


TINY_TRAIN = TrainConfig(
    env="GridMaze-v0",
    env_kwargs={"size": 5},
    hidden_sizes=(16,),
    num_envs=4,
    batch_size=8,
    replay_ratio=2.0,  # 8 sampled per step of the 4 envs: one gradient step an iteration
    buffer_size=64,
    learning_starts=8,
    total_timesteps=96,
    log_interval=32,
    target_update_period=10,  # not a multiple of num_envs
    eps_decay_steps=64,
    eval_episodes=0,
)


# TINY_TRAIN's network, replay and schedule as command-line flags, for tests of the CLI (they
# add the step counts they need)
TINY_FLAGS = [
    "--env-arg", "size=5",
    "--hidden-sizes", "16",
    "--num-envs", "4",
    "--batch-size", "8",
    "--replay-ratio", "2",
    "--buffer-size", "64",
    "--learning-starts", "8",
    "--log-interval", "32",
    "--target-update-period", "10",
    "--eps-decay-steps", "64",
    "--quiet",
]  # fmt: skip


# a 7x7 grid run of 2 seeds that learns it in 4,000 steps, for tests of what the CLI writes
SMALL_GRID_FLAGS = [
    "--env-arg", "size=7",
    "--hidden-sizes", "32,32",
    "--num-envs", "8",
    "--total-timesteps", "4000",
    "--learning-starts", "800",
    "--buffer-size", "2000",
    "--batch-size", "32",
    "--replay-ratio", "4",
    "--log-interval", "1000",
    "--eval-episodes", "50",
    "--num-seeds", "2",
]  # fmt: skip


@pytest.fixture(scope="session")
def tiny_config() -> TrainConfig:
    return TINY_TRAIN


@pytest.fixture(scope="session")
def tiny_trainer(tiny_config) -> Trainer:
    return Trainer(tiny_config)


@pytest.fixture(scope="session")
def train_one(tiny_trainer):
    """``jit(trainer.train)``: one seed with the config's hyperparameters."""
    return jax.jit(tiny_trainer.train)


@pytest.fixture(scope="session")
def train_many(tiny_trainer):
    """``jit(vmap(trainer.train))`` over (keys, HParams), both batched."""
    return jax.jit(jax.vmap(tiny_trainer.train))


@pytest.fixture(scope="session")
def seed0_run(train_one):
    """Final state and metrics of seed 0 (computed once)."""
    return jax.block_until_ready(train_one(jax.random.key(0)))


@pytest.fixture(scope="session")
def stepwise_trainer(tiny_config) -> Trainer:
    """The tiny config with one iteration (num_envs env steps) per logging interval."""
    cfg = dataclasses.replace(tiny_config, log_interval=tiny_config.num_envs, total_timesteps=60)
    return Trainer(cfg)


@pytest.fixture(scope="session")
def stepwise_run_one(stepwise_trainer):
    """``jit(lambda ts, it: trainer.run(ts, it, 1))``: one iteration of the stepwise trainer."""
    return jax.jit(lambda ts, it: stepwise_trainer.run(ts, it, 1))


def run_sharded(trainer: Trainer, keys: jax.Array, num_logs: int | None = None):
    """``(final state, metrics [seeds, logs])`` of the seeds of ``keys`` on ``trainer.mesh``,
    interval by interval as the CLI runs them."""
    init, interval, _ = trainer.sharded(keys)
    state, chunks = init(keys), []
    for log in range(trainer.config.num_logs if num_logs is None else num_logs):
        state, metrics = interval(state, np.int32(log))
        chunks.append(jax.device_get(metrics))
    return state, {k: np.concatenate([c[k] for c in chunks], axis=1) for k in chunks[0]}


def assert_learned_the_maze(trainer: Trainer, params, metrics, min_success: float) -> None:
    """The greedy policy of ``params`` reaches the goal in at least ``min_success`` of 500 test
    episodes on near-shortest paths, the random agent rarely does, and the training curve
    rose."""
    from jaxnav.evaluate import evaluate, random_policy

    env, env_params = trainer.env, trainer.env_params
    key = jax.random.key(99)
    trained = evaluate(env, env_params, trainer.greedy_policy(params), key, 500)
    rand = evaluate(env, env_params, random_policy(env.num_actions), key, 500)
    assert trained["success_rate"] >= min_success, trained
    assert trained["mean_path_ratio"] <= 1.2, trained
    assert rand["success_rate"] <= 0.3, rand
    assert metrics["success_rate"][-1] > metrics["success_rate"][0] + 0.3


def random_rollout(step, env, params, key: jax.Array, num_envs: int, steps: int):
    """Per-step outputs of the batched ``step(keys, states, actions, params)``
    (``vmap(env.step)`` or ``env.step_batch``) over ``steps`` steps of uniformly random
    actions from ``num_envs`` fresh episodes. Traceable: jit it."""
    k_reset, k_run = jax.random.split(key)
    keys = jax.random.split(k_reset, num_envs)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

    def body(state, key):
        k_act, k_step = jax.random.split(key)
        action = jax.random.randint(k_act, (num_envs,), 0, env.num_actions)
        out = step(jax.random.split(k_step, num_envs), state, action, params)
        return out[1], out

    return jax.lax.scan(body, state, jax.random.split(k_run, steps))[1]


def bfs_distances(grid: np.ndarray, source: tuple[int, int]) -> np.ndarray:
    """The tests' oracle for the library's BFS (``maze_algorithms.distance_field``), in plain
    Python: 4-neighbour steps from ``source`` to every cell of ``grid`` (True = wall); -1 at
    walls and cells cut off, everywhere when ``source`` is a wall."""
    rows, cols = grid.shape
    dist = np.full(grid.shape, -1, np.int32)
    if grid[source]:
        return dist
    dist[source] = 0
    queue = collections.deque([source])
    while queue:
        r, c = queue.popleft()
        for nr, nc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= nr < rows and 0 <= nc < cols and not grid[nr, nc] and dist[nr, nc] < 0:
                dist[nr, nc] = dist[r, c] + 1
                queue.append((nr, nc))
    return dist
