"""JaxNav's levels (``maze="jaxnav"``, ``RobotJaxNav-v0``), SFL's evaluation protocol
(``jaxnav.evaluate.levels``) and the benchmark that puts a policy beside SFL's figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import jaxnav
from benchmarks.jaxnav_levels import main as benchmark_main
from jaxnav import run_dir
from jaxnav.config import TrainConfig
from jaxnav.envs.maze_algorithms import fill_pockets, region_labels
from jaxnav.envs.robot import generators, jaxnav_levels
from jaxnav.evaluate.levels import (
    cvar_two_key,
    level_success,
    run_level_episodes,
    sfl_summary,
    worst_levels,
)
from jaxnav.experiments import HELD_OUT_MAZE_SEED
from jaxnav.train import Trainer
from jaxnav.train.__main__ import main as train_main

LEVELS = 16


@pytest.fixture(scope="module")
def jaxnav_env():
    return jaxnav.make("RobotJaxNav-v0", num_layouts=LEVELS, maze_seed=7)


# ------------------------------------------------------------------------------ levels
def test_a_level_is_the_nine_by_nine_interior_inside_the_boundary_walls():
    level = jaxnav_levels.jaxnav_level(0, 3)
    assert level.grid.shape == (9, 9) and level.cell_size == 1.0 and level.size_m == (9.0, 9.0)
    walls = level.walls(28)
    center, half = np.asarray(walls.center[:4]), np.asarray(walls.half_size[:4])
    # the 4 boundary boxes' inner faces: x = 0, x = 9, y = 0, y = 9 (the border ring)
    inner = [
        center[0, 0] + half[0, 0],
        center[1, 0] - half[1, 0],
        center[2, 1] + half[2, 1],
        center[3, 1] - half[3, 1],
    ]
    np.testing.assert_allclose(inner, [0.0, 9.0, 0.0, 9.0], atol=1e-6)


def test_obstacle_counts_are_uniform_below_48():
    counts = np.array([jaxnav_levels.level_draw(0, i).sum() for i in range(3000)])
    assert counts.min() >= 0 and counts.max() <= 47
    observed = np.bincount(counts, minlength=48)
    assert len(observed) == 48
    assert stats.chisquare(observed).pvalue > 1e-3


def test_a_level_is_its_draw_with_the_pockets_filled():
    for i in range(200):
        drawn = jaxnav_levels.level_draw(1, i)
        grid = jaxnav_levels.jaxnav_level(1, i).grid
        np.testing.assert_array_equal(grid, fill_pockets(drawn))
        free = region_labels(grid)
        assert free.max() == 1  # one connected free region, at least 2 cells
        assert (free == 1).sum() >= 2


def test_levels_depend_on_seed_and_index_only():
    small = jaxnav_levels.jaxnav_level_bank(20, seed=5)
    large = jaxnav_levels.jaxnav_level_bank(40, seed=5)
    for a, b in zip(small, large[:20], strict=True):
        np.testing.assert_array_equal(a.grid, b.grid)
    np.testing.assert_array_equal(jaxnav_levels.jaxnav_level(5, 7).grid, large[7].grid)
    other = jaxnav_levels.jaxnav_level_bank(40, seed=6)
    assert sum(np.array_equal(a.grid, b.grid) for a, b in zip(large, other, strict=True)) < 4


def test_held_out_levels_are_not_training_levels():
    # levels of few obstacles repeat by necessity (one empty level); from 10 on, C(81, 10)
    # layouts make a repeat of two independent draws all but impossible
    def busy(seed: int) -> set[bytes]:
        draws = (jaxnav_levels.jaxnav_level(seed, i).grid for i in range(1500))
        return {g.tobytes() for g in draws if g.sum() >= 10}

    training, held_out = busy(0), busy(HELD_OUT_MAZE_SEED)
    assert len(training) > 1000 and len(held_out) > 1000
    assert not training & held_out


def test_the_coarse_family_is_a_level_in_one_metre_cells_of_the_banks_shape():
    """``jaxnav_coarse`` in a bank of 20 x 20 cells of 0.5 m: a maze of 1 m cells, the level
    in the lower-left 10 x 10 (its boundary the arena's or a wall ring), walls elsewhere."""
    for i in range(40):
        maze = generators.family_maze(0, i, ("jaxnav_coarse",))
        assert maze.cell_size == 1.0 and maze.grid.shape == (20, 20)
        assert maze.grid[:10].all() and maze.grid[:, 10:].all()  # the padding
        free = np.argwhere(~maze.grid)
        assert np.ptp(free, axis=0).max() < jaxnav_levels.INTERIOR  # within a 9 x 9 level
        assert region_labels(maze.grid).max() == 1 and len(free) >= 2
    with pytest.raises(ValueError, match="jaxnav_coarse needs 18 x 18 cells or more"):
        generators.family_maze(0, 0, ("jaxnav_coarse",), rows=16, cols=16)


def test_a_level_needing_more_wall_slots_is_refused():
    with pytest.raises(ValueError, match="num_wall_slots=8: level jaxnav"):
        jaxnav.make("RobotJaxNav-v0", num_layouts=64, num_wall_slots=8)


# --------------------------------------------------------------------------------- env
def test_the_env_id_has_jaxnavs_protocol(jaxnav_env):
    env, params = jaxnav_env
    c = env.config
    assert (c.maze, c.radius, c.goal_radius, c.max_steps, c.dt) == ("jaxnav", 0.25, 0.3, 500, 0.1)
    assert c.backend == "kinematic" and c.waypoint_distance == 0.0 and c.num_goal_cells == 0
    assert env.num_layouts(params) == LEVELS
    # 8 frames of 32 lasers, D, bearing, the previous action and the radius
    assert env.observation_space(params).shape == (320,)


def cell_of(xy: np.ndarray) -> np.ndarray:
    """(row, col) of points (x, y) of a 9 x 9 level of 1 m cells."""
    return np.stack([8 - np.floor(xy[..., 1]), np.floor(xy[..., 0])], axis=-1).astype(int)


def test_start_and_goal_are_joined_by_a_path(jaxnav_env):
    env, params = jaxnav_env
    layouts = jnp.tile(jnp.arange(LEVELS), 32)
    keys = jax.random.split(jax.random.key(3), layouts.shape[0])
    _, state = jax.jit(jax.vmap(env.reset_layout, in_axes=(0, None, 0)))(keys, params, layouts)
    grids = np.asarray(params.bank.grid)
    start, goal = cell_of(np.asarray(state.pose[:, :2])), cell_of(np.asarray(state.goal))
    for layout, s, g in zip(np.asarray(layouts), start, goal, strict=True):
        labels = region_labels(grids[layout])
        assert labels[tuple(s)] > 0 and labels[tuple(s)] == labels[tuple(g)]
        assert tuple(s) != tuple(g)


def test_a_robot_at_any_free_cell_centre_touches_no_wall(jaxnav_env):
    env, params = jaxnav_env
    grids = np.asarray(params.bank.grid)
    layout, row, col = np.nonzero(~grids)
    pose = np.stack([col + 0.5, 8 - row + 0.5, np.zeros_like(col, float)], axis=-1)
    goal = np.asarray(params.bank.free_xy)[layout, 0]
    keys = jax.random.split(jax.random.key(0), len(layout))
    turn = jnp.full(len(layout), 2)  # turning in place: the collision test at the pose alone

    @jax.jit
    def spawn_and_turn(pose, goal, layout):
        _, state = jax.vmap(env.reset_to, in_axes=(0, None, 0, 0, 0))(
            keys, params, pose, goal, layout
        )
        return jax.vmap(env.step_no_reset, in_axes=(0, 0, 0, None))(keys, state, turn, params)

    obs, _, reward, *_, info = spawn_and_turn(
        jnp.asarray(pose), jnp.asarray(goal), jnp.asarray(layout)
    )
    assert obs.shape == (len(layout), 320) and np.isfinite(np.asarray(reward)).all()
    assert not np.asarray(info["collision"]).any()


# ---------------------------------------------------------------------------- protocol
def reference_cvar(select: list[float], measure: list[float], alpha: float) -> float:
    """Written out: the levels sorted by key A's rate (lower index first on a tie), the
    first ceil(alpha * L), their key B rates averaged."""
    order = sorted(range(len(select)), key=lambda i: (select[i], i))
    worst = order[: math.ceil(alpha * len(select))]
    return sum(measure[i] for i in worst) / len(worst)


def test_cvar_picks_the_worst_levels_on_one_key_and_measures_them_on_the_other():
    select = [1.0, 0.2, 0.5, 0.2, 0.9, 1.0, 0.0, 0.7, 0.3, 1.0]
    measure = [0.9, 0.6, 0.4, 1.0, 0.8, 0.1, 0.5, 0.7, 0.9, 1.0]
    # worst on A: level 6 (0.0), then 1 and 3 (0.2, 1 first), then 8 (0.3)
    assert cvar_two_key(select, measure, 0.1) == pytest.approx(0.5)
    assert cvar_two_key(select, measure, 0.3) == pytest.approx((0.5 + 0.6 + 1.0) / 3)
    assert cvar_two_key(select, measure, 0.25) == pytest.approx((0.5 + 0.6 + 1.0) / 3)
    assert cvar_two_key(select, measure, 1.0) == pytest.approx(np.mean(measure))
    # the same table on both keys: the biased figure, lower here
    assert cvar_two_key(measure, measure, 0.1) == pytest.approx(0.1)
    rng = np.random.default_rng(0)
    for _ in range(20):
        a = rng.integers(0, 11, 200) / 10
        b = rng.integers(0, 11, 200) / 10
        for alpha in (0.1, 0.01, 0.37):
            want = reference_cvar(a.tolist(), b.tolist(), alpha)
            assert cvar_two_key(a, b, alpha) == pytest.approx(want)
    assert worst_levels(np.array([0.5, 0.1, 0.1]), 0.5).tolist() == [1, 2]


def test_cvar_refuses_tables_of_other_levels():
    with pytest.raises(ValueError, match="need the same levels"):
        cvar_two_key(np.ones(3), np.ones(4), 0.1)
    with pytest.raises(ValueError, match="alpha=0"):
        cvar_two_key(np.ones(3), np.ones(3), 0)


def outcomes(layout: list[int], success: list[bool]) -> dict[str, np.ndarray]:
    success_arr = np.array(success, bool)
    return {
        "layout": np.array(layout),
        "success": success_arr,
        "collision": ~success_arr,
        "timeout": np.zeros(len(success), bool),
    }


def test_sfl_summary_of_hand_made_episodes():
    # 4 levels, 2 episodes each on each key; per-level success A: 1, 0.5, 0, 1; B: 0.5, 1, 1, 0
    a = outcomes([0, 1, 2, 3, 0, 1, 2, 3], [1, 1, 0, 1, 1, 0, 0, 1])
    b = outcomes([0, 1, 2, 3, 0, 1, 2, 3], [1, 1, 1, 0, 0, 1, 1, 0])
    np.testing.assert_allclose(level_success(a, 4), [1, 0.5, 0, 1])
    s = sfl_summary(a, b, 4)
    assert s["episodes"] == 16 and s["levels"] == 4
    assert s["success_rate"] == pytest.approx(10 / 16)
    assert s["success_rate_a"] == pytest.approx(5 / 8) and s["success_rate_b"] == 5 / 8
    assert s["collision_rate"] == pytest.approx(6 / 16)
    assert s["cvar_10"] == pytest.approx(1.0)  # level 2, worst on A, solved on B
    assert s["cvar_10_same_key"] == pytest.approx(0.0)  # level 3 on B
    with pytest.raises(ValueError, match="every one of the 5 levels"):
        sfl_summary(a, b, 5)


def _cautious(key, obs):
    """Forward unless the beam straight ahead reads under 0.3 (of 3.5 m), then turn left."""
    return jnp.where(obs[:, -35] < 0.3, 2, 0)


def test_level_episodes_do_not_depend_on_the_chunk(jaxnav_env):
    env, params = jaxnav_env
    run = jax.jit(run_level_episodes, static_argnums=(0, 2, 5, 6))
    key = jax.random.key(4)
    # levels 3, 4, 5 in two calls with other levels beside them, at other positions
    one = run(env, params, _cautious, key, jnp.array([0, 1, 2, 3, 4, 5]), 2, 40)
    other = run(env, params, _cautious, key, jnp.array([5, 3, 4, 9, 10, 11]), 2, 40)
    # round-robin: episode j of a call is in its level j % n
    np.testing.assert_array_equal(np.asarray(one["layout"]), np.tile(np.arange(6), 2))
    for name in ("success", "collision", "steps", "return"):
        a = np.asarray(one[name]).reshape(2, 6)[:, [3, 4, 5]]
        b = np.asarray(other[name]).reshape(2, 6)[:, [1, 2, 0]]
        np.testing.assert_array_equal(a, b)
    assert int(np.asarray(one["steps"]).max()) > 1  # the episodes moved
    assert not np.array_equal(np.asarray(one["steps"]), np.asarray(other["steps"]))


# --------------------------------------------------------------------------- benchmark
def test_benchmark_refuses_bad_flags_in_one_line(tmp_path, capsys):
    out = str(tmp_path / "r.json")
    assert benchmark_main(["--random", "--levels", "0", "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--levels 0" in err
    assert benchmark_main(["--random", "--maze-seed", "0", "--out", out]) == 2
    assert "--maze-seed 0" in capsys.readouterr().err
    assert benchmark_main(["--run", str(tmp_path / "none"), "--out", out]) == 2
    assert "not a run directory" in capsys.readouterr().err
    assert benchmark_main(["--random", "--policy", "shielded", "--out", out]) == 2
    assert "--policy shielded: shields a trained policy" in capsys.readouterr().err


@pytest.mark.slow
def test_benchmark_writes_the_table_for_the_random_agent(tmp_path, capsys):
    out = tmp_path / "jaxnav_levels.json"
    args = ["--random", "--levels", "5", "--episodes-per-level", "2", "--chunk-levels", "3"]
    assert benchmark_main([*args, "--out", str(out)]) == 0
    progress = [f"key {k}: {n}/5 levels" for k in "AB" for n in (3, 5)]
    assert capsys.readouterr().err.splitlines() == progress  # a line per chunk, on stderr
    result = json.loads(out.read_text())
    (row,) = result["rows"]
    assert row["levels"] == 5 and row["episodes"] == 20
    for name in ("success_rate", "cvar_10", "cvar_1", "collision_rate", "timeout_rate"):
        assert 0.0 <= row[name] <= 1.0
    assert row["collision_rate"] + row["timeout_rate"] + row["success_rate"] == pytest.approx(1)
    assert result["maze_seed"] == HELD_OUT_MAZE_SEED
    table = out.with_suffix(".md").read_text()
    assert "| random |" in table and "| SFL (published) | 0.980 | 0.80 |" in table


TINY_RUN = [
    "--env", "RobotRandom-v0",
    "--env-arg", "backend=kinematic",
    "--env-arg", "num_layouts=2",
    "--env-arg", "random_size=5",
    "--env-arg", "max_steps=20",
    "--hidden-sizes", "8",
    "--num-envs", "4",
    "--total-timesteps", "64",
    "--learning-starts", "16",
    "--buffer-size", "64",
    "--batch-size", "8",
    "--log-interval", "32",
    "--eval-episodes", "4",
    "--num-seeds", "2",
    "--quiet",
]  # fmt: skip


def waypoint_run(run: Path) -> None:
    """A run directory of an (untrained) network for RobotRandom-v0 with a planner's waypoint
    in its observation, as ``python -m jaxnav.train`` writes one."""
    env_kwargs = {"backend": "kinematic", "num_layouts": 2, "random_size": 5}
    config = TrainConfig.for_env(
        "RobotRandom-v0", env_kwargs={**env_kwargs, "waypoint_distance": 1.0}, hidden_sizes=(8,)
    )
    trainer = Trainer(config)
    init = lambda k: trainer.network.init(k, jnp.zeros((1, trainer.obs_size)))  # noqa: E731
    run_dir.create(run, trainer)
    run_dir.save_params(run, jax.vmap(init)(run_dir.seed_keys(config)))


@pytest.mark.slow
def test_benchmark_runs_a_policy_of_another_env_and_refuses_other_inputs(tmp_path, capsys):
    run, with_waypoint = tmp_path / "run", tmp_path / "waypoint"
    assert train_main([*TINY_RUN, "--out", str(run)]) == 0
    waypoint_run(with_waypoint)
    capsys.readouterr()
    out = tmp_path / "r.json"
    tiny = ["--levels", "3", "--episodes-per-level", "2", "--out", str(out)]
    assert benchmark_main(["--run", str(run), *tiny]) == 0
    result = json.loads(out.read_text())
    assert [r["name"] for r in result["rows"]] == ["seed 0", "seed 1", "mean of 2 seeds"]
    config = result["env_config"]  # the run's sensors on JaxNav's levels and robot
    assert (config["num_lasers"], config["laser_fov"], config["maze"]) == (7, 180.0, "jaxnav")
    assert config["radius"] == 0.25 and config["waypoint_distance"] == 0.0
    assert result["policy"] == f"run {run} (greedy)"
    # the same policy through the lidar collision monitor
    assert benchmark_main(["--run", str(run), *tiny, "--policy", "shielded"]) == 0
    assert json.loads(out.read_text())["policy"] == f"run {run} (greedy, shielded)"
    # a policy that reads a waypoint planned on the maze: not map-free, refused
    capsys.readouterr()
    assert benchmark_main(["--run", str(with_waypoint), *tiny]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the benchmark is map-free" in err


def test_benchmark_keeps_a_waypoint_from_the_robots_own_map(tmp_path, capsys):
    """An exported policy whose waypoint comes from its own lidar map is map-free: it runs on
    the levels with that map; the same network reading the maze's waypoint is refused."""
    from jaxnav import export

    kwargs = {"backend": "kinematic", "num_layouts": 2, "random_size": 5, "num_lasers": 32}
    kwargs |= {"laser_fov": 360.0, "waypoint_distance": 1.0}
    files = {}
    for name, own in (("own", {"lidar_map": 0.25}), ("maze", {})):
        config = TrainConfig.for_env("RobotRandom-v0", env_kwargs=kwargs | own, hidden_sizes=(8,))
        trainer = Trainer(config)
        params = trainer.network.init(jax.random.key(0), jnp.zeros((1, trainer.obs_size)))
        arrays = export.policy_arrays(trainer.network, params)
        files[name] = tmp_path / f"{name}.npz"
        export.write_policy(arrays, export.policy_metadata(trainer, {}), files[name], "npz")
    out = tmp_path / "r.json"
    tiny = ["--levels", "2", "--episodes-per-level", "1", "--out", str(out)]
    assert benchmark_main(["--pretrained", str(files["own"]), *tiny]) == 0
    config = json.loads(out.read_text())["env_config"]
    assert (config["lidar_map"], config["waypoint_distance"], config["maze"]) == (
        0.25, 1.0, "jaxnav"
    )  # fmt: skip
    capsys.readouterr()
    assert benchmark_main(["--pretrained", str(files["maze"]), *tiny]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the benchmark is map-free" in err
