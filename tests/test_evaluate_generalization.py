"""Evaluation over a bank of mazes: per-maze success, worst-10%, path ratio, statistics over
seeds, and the ``generalization`` experiment on a tiny trained robot run."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav
from jaxnav.evaluate import (
    MIN_EPISODES_PER_MAZE,
    bootstrap_ci,
    iqm,
    layout_assignment,
    maze_success,
    play,
    run_episodes,
    seed_statistics,
    summarize,
    worst_fraction_mean,
)
from jaxnav.evaluate.__main__ import main as evaluate_main
from jaxnav.experiments import main as experiments_main
from jaxnav.train.__main__ import main as train_main

ROBOT = {"backend": "kinematic", "num_layouts": 4, "random_size": 5}


# --------------------------------------------------------------------- per-maze numbers
def test_worst_ten_percent_of_hand_made_maze_success():
    ten = np.array([1.0] * 9 + [0.2])  # M = 10: the single worst maze
    assert worst_fraction_mean(ten) == pytest.approx(0.2)
    eleven = np.array([0.9] * 9 + [0.1, 0.3])  # M = 11: ceil(1.1) = 2 worst mazes
    assert worst_fraction_mean(eleven) == pytest.approx(0.2)
    thousand = np.concatenate([np.zeros(100), np.full(900, 1.0)])[::-1]  # order does not matter
    assert worst_fraction_mean(thousand) == 0.0
    # 1001 mazes: ceil(100.1) = 101 worst, the 101 zeros
    assert worst_fraction_mean(np.concatenate([thousand, [0.0]])) == 0.0
    assert worst_fraction_mean(np.array([0.5, np.nan])) == 0.5  # a maze without episodes: out
    assert math.isnan(worst_fraction_mean(np.array([np.nan])))
    assert worst_fraction_mean(np.array([0.0, 0.5, 1.0]), fraction=1.0) == pytest.approx(0.5)


def test_maze_success_groups_episodes_by_layout():
    episodes = {"layout": np.array([0, 1, 2, 0, 1, 2]), "success": np.array([1, 0, 1, 1, 1, 0])}
    rates, counts = maze_success(episodes)
    np.testing.assert_allclose(rates, [1.0, 0.5, 0.5])
    np.testing.assert_array_equal(counts, [2, 2, 2])


def episodes_of(layout, success) -> dict[str, np.ndarray]:
    """Hand-made episodes (as ``play`` returns them) in ``layout`` with ``success``."""
    success = np.asarray(success, bool)
    n = len(success)
    return {
        "return": np.where(success, 10.0, -5.0),
        "steps": np.full(n, 20),
        "success": success,
        "collision": ~success,
        "timeout": np.zeros(n, bool),
        "shortest_path": np.full(n, 4.0),
        "path_length": np.full(n, 5.0),
        "layout": np.asarray(layout, np.int32),
    }


def test_worst_ten_percent_needs_five_episodes_of_every_maze_played():
    k = MIN_EPISODES_PER_MAZE
    assert k == 5
    # mazes 0, 1, 2 with success 1.0, 0.6, 0.2 over 5 episodes each: the worst maze's 0.2
    layout = np.repeat([0, 1, 2], k)
    success = [1, 1, 1, 1, 1] + [1, 1, 1, 0, 0] + [1, 0, 0, 0, 0]
    row = summarize(episodes_of(layout, success))
    assert row["mazes"] == 3 and row["worst10_success"] == pytest.approx(0.2)
    # one maze a single episode short: not a number, whatever the others
    short = summarize(episodes_of(layout[1:], success[1:]))
    assert short["worst10_success"] is None and short["success_rate"] == pytest.approx(8 / 14)
    # one episode per maze (rate 0 or 1, the worst 10% is 0 by construction): None
    assert summarize(episodes_of(np.arange(20), [1] * 19 + [0]))["worst10_success"] is None
    # a maze not played (layout 1 of 0..2) does not count
    skipped = layout != 1
    row = summarize(episodes_of(layout[skipped], np.asarray(success)[skipped]))
    assert row["mazes"] == 2 and row["worst10_success"] == pytest.approx(0.2)
    # one maze, many episodes: n/a, not the success rate again
    one = summarize(episodes_of(np.zeros(8), [1] * 6 + [0] * 2))
    assert one["worst10_success"] is None and one["success_rate"] == 0.75
    no_layout = episodes_of(np.zeros(8), [1] * 6 + [0] * 2)
    del no_layout["layout"]
    assert summarize(no_layout)["worst10_success"] is None


@pytest.mark.parametrize("episodes, mazes", [(12, 4), (13, 4), (3, 1)])
def test_layout_assignment_is_round_robin(episodes, mazes):
    counts = np.bincount(layout_assignment(episodes, mazes), minlength=mazes)
    assert counts.sum() == episodes and counts.max() - counts.min() <= (episodes % mazes > 0)


def _random(key, obs):
    return jax.random.randint(key, obs.shape[:1], 0, 4)


@pytest.mark.parametrize(
    "env_id, kwargs",
    [
        ("RobotRandom-v0", ROBOT),
        ("GridMaze-Random-v0", {"size": 7, "num_layouts": 5, "goals_per_layout": 4}),
    ],
)
def test_run_episodes_gives_every_maze_the_same_number_of_episodes(env_id, kwargs):
    env, params = jaxnav.make(env_id, **kwargs)
    mazes = env.num_layouts(params)
    run = jax.jit(run_episodes, static_argnums=(0, 2, 4, 5))
    per_maze = MIN_EPISODES_PER_MAZE  # the fewest with which worst-10% is a number
    out = run(env, params, _random, jax.random.key(0), per_maze * mazes, 20)
    _, counts = maze_success(out)
    np.testing.assert_array_equal(counts, [per_maze] * mazes)
    row = summarize(out)
    assert row["mazes"] == mazes
    assert 0.0 <= row["worst10_success"] <= row["success_rate"] <= 1.0


def test_reset_layout_keeps_the_draws_of_reset():
    """``reset_env`` is ``reset_layout`` in the layout it draws: same start, goal and heading."""
    env, params = jaxnav.make("RobotRandom-v0", **ROBOT)
    for i in range(4):
        key = jax.random.key(i)
        _, state = env.reset(key, params)
        _, again = env.reset_layout(key, params, state.layout)
        np.testing.assert_array_equal(state.pose, again.pose)
        np.testing.assert_array_equal(state.goal, again.goal)


# ------------------------------------------------------------------------- path ratio
CORRIDOR = "#######\n.......\n#######\n"


def test_robot_path_ratio_of_a_straight_run_is_at_least_one(tmp_path):
    maze = tmp_path / "corridor.txt"
    maze.write_text(CORRIDOR)
    env, params = jaxnav.make("RobotMaze-v0", maze_file=str(maze), backend="kinematic")
    # facing the goal 5 m east along the corridor's cell centres; always forward
    pose = jnp.array([[0.5, 1.5, 0.0], [1.5, 1.5, 0.0]])
    goal = jnp.array([[5.5, 1.5], [4.5, 1.5]])
    obs, state = jax.vmap(env.reset_to, in_axes=(None, None, 0, 0, None))(
        jax.random.key(0), params, pose, goal, 0
    )
    forward = lambda key, obs: jnp.zeros(obs.shape[:1], jnp.int32)  # noqa: E731
    out = play(env, params, forward, jax.random.key(1), obs, state, 40)
    assert out["success"].all()
    np.testing.assert_allclose(out["shortest_path"], [4.5, 2.5])  # to the goal disc
    np.testing.assert_allclose(out["path_length"], 0.25 * np.asarray(out["steps"]), rtol=1e-5)
    ratio = summarize(out)["mean_path_ratio"]
    assert ratio is not None and 1.0 <= ratio < 1.2


def test_path_ratio_is_none_where_not_measured():
    ep = {
        "return": np.zeros(3),
        "steps": np.array([5, 6, 7]),
        "success": np.array([True, True, False]),
        "collision": np.zeros(3, bool),
        "timeout": np.array([False, False, True]),
        "shortest_path": np.full(3, -1.0),  # no shortest path known
        "path_length": np.array([2.0, 3.0, 4.0]),
        "layout": np.zeros(3, np.int32),
    }
    assert summarize(ep)["mean_path_ratio"] is None
    known = {**ep, "shortest_path": np.array([1.0, 3.0, 1.0])}
    assert summarize(known)["mean_path_ratio"] == pytest.approx(1.5)  # (2/1 + 3/3) / 2
    no_success = {**known, "success": np.zeros(3, bool)}
    assert summarize(no_success)["mean_path_ratio"] is None


# ---------------------------------------------------------------------- over seeds
def test_iqm_and_bootstrap_interval():
    assert iqm([1.0, 2.0, 3.0]) == 2.0  # fewer than 4: the mean
    assert iqm([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 100.0]) == pytest.approx(3.5)
    assert iqm([0.0, 1.0, 2.0, 3.0, 100.0]) == 2.0  # 5 // 4 = 1 cut at each end
    values = [float(v) for v in range(16)] + [1e6]  # 17 // 4 = 4 cut at each end
    assert iqm(values) == pytest.approx(sum(range(4, 13)) / 9)
    values = [0.6, 0.7, 0.8, 0.9, 1.0]
    lo, hi = bootstrap_ci(values)
    assert lo <= np.mean(values) <= hi and (lo, hi) == bootstrap_ci(values)  # fixed resamples
    assert bootstrap_ci([0.5]) is None
    st = seed_statistics([0.5, None, 0.7])
    assert st["seeds"] == 2 and st["mean"] == pytest.approx(0.6)
    assert seed_statistics([None])["mean"] is None


# ------------------------------------------------------------- a tiny trained robot run
TINY_ROBOT = [
    "--env", "RobotRandom-v0",
    "--env-arg", "backend=kinematic",
    "--env-arg", "num_layouts=4",
    "--env-arg", "random_size=5",
    "--env-arg", "max_steps=30",
    "--hidden-sizes", "16",
    "--num-envs", "8",
    "--total-timesteps", "128",
    "--learning-starts", "32",
    "--buffer-size", "128",
    "--batch-size", "16",
    "--replay-ratio", "2",
    "--log-interval", "64",
    "--eps-decay-steps", "64",
    "--target-update-period", "16",
    "--eval-episodes", "8",
    "--num-seeds", "2",
    "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def robot_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "robot"
    assert train_main([*TINY_ROBOT, "--out", str(out)]) == 0
    return out


def test_evaluate_cli_prints_worst_ten_percent_per_maze(robot_run, tmp_path, capsys):
    out = tmp_path / "eval.json"
    args = [str(robot_run), "--env-arg", "num_layouts=6", "--episodes", "12", "--out", str(out)]
    assert evaluate_main(args) == 0
    printed = capsys.readouterr().out
    assert "worst10_success" in printed and "over 6 mazes" in printed
    assert "success_rate over 2 seeds" in printed and "IQM" in printed
    result = json.loads(out.read_text())
    assert result["episodes_per_maze"] == 2
    assert all(len(r["maze_success"]) == 6 for r in result["per_seed"])
    assert result["over_seeds"]["success_rate"]["seeds"] == 2
    assert result["mean_path_ratio"] is None or result["mean_path_ratio"] > 0


@pytest.mark.slow
def test_generalization_writes_a_table_per_family(robot_run, tmp_path, capsys):
    out = tmp_path / "gen"
    rooms = Path(__file__).parents[1] / "examples" / "mazes" / "rooms.txt"
    maze = f"RobotMaze-v0 maze_file={rooms} num_wall_slots=64"
    # the grid does not fit
    families = ["own num_layouts=3", "RobotSimple-v0", "GridMaze-v0", maze]
    args = ["generalization", str(robot_run), "--episodes", "6", "--gifs", "2", "--out", str(out)]
    args += [a for f in families for a in ("--family", f)]
    assert experiments_main(args) == 0
    results = json.loads((out / "results.json").read_text())
    own = results["families"]["own num_layouts=3"]
    assert own["seeds"] == 2 and own["mazes"] == 3
    assert own["env_kwargs"]["backend"] == "kinematic" and own["env_kwargs"]["max_steps"] == 30
    simple = results["families"]["RobotSimple-v0"]
    assert simple["env_kwargs"] == {"backend": "kinematic", "max_steps": 30}  # no maze keys
    assert simple["mean"]["worst10_success"] is None  # one maze: n/a, not its success again
    assert len(simple["over_seeds"]["success_rate"]["iqm_ci95"]) == 2
    grid = results["families"]["GridMaze-v0"]
    assert grid["seeds"] == 0 and grid["skipped"]
    table = (out / "results.md").read_text()
    assert "worst-10% success" in table and "| RobotSimple-v0 | 2 | 1 |" in table
    printed = capsys.readouterr().out
    assert "success IQM" in printed
    # a trajectory GIF on the hand-drawn maze (only there), two episodes with their outcomes
    gifs = sorted(p.name for p in out.glob("*.gif"))
    assert gifs == ["trajectories-rooms.gif"]
    assert (out / gifs[0]).read_bytes()[:6] == b"GIF89a"
    line = next(x for x in printed.splitlines() if "trajectories-rooms.gif" in x)
    assert line.count(";") == 1  # two episodes described


def test_the_statistics_over_seeds_are_scipys_and_match_the_hand_formulas():
    """iqm is ``scipy.stats.trim_mean(x, 0.25)`` and the comparisons' standard error
    ``scipy.stats.sem``: both equal the formulas they replaced."""
    import math

    from benchmarks.train_vs_rejax import standard_error

    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 4, 5, 8, 11):
        x = rng.random(n)
        s = np.sort(x)
        assert iqm(x) == pytest.approx(float(s[n // 4 : n - n // 4].mean()), abs=1e-15)
        if n < 2:
            assert standard_error(list(x)) is None
            continue
        mean = sum(x) / n
        hand = math.sqrt(sum((v - mean) ** 2 for v in x) / (n - 1) / n)
        assert standard_error(list(x)) == pytest.approx(hand, rel=1e-12)
