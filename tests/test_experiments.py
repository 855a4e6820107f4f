"""The experiment runner as a user runs it: a results directory with every number, table and
figure; fixed test suites; confidence intervals; bad flags refused cleanly."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from PIL import Image
from scipy import stats

import jaxnav
from jaxnav import experiments, render
from jaxnav.evaluate import play, random_policy
from jaxnav.experiments import EXAMPLE_MAZE, main

# One worker runs this module's tests (make test: --dist loadgroup) and the smoke experiment
# is session-scoped, so it is computed once even when other modules' tests run in between.
pytestmark = pytest.mark.xdist_group("experiments")
FIGURES = ("outcomes.png", "test_comparison.png", "training_curves.png", "trajectories.png")
AGENTS = ("dueling-double", "simple", "random")


@pytest.fixture(scope="session")
def smoke_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("experiments") / "grid"
    assert main(["paper-grid", "--smoke", "--seeds", "2", "--out", str(out), "--quiet"]) == 0
    return out


def test_results_directory_is_complete(smoke_dir):
    names = {p.name for p in smoke_dir.iterdir()}
    assert names == {"results.json", "results.md", "episodes.npz", "runs", *FIGURES}
    assert not list(smoke_dir.parent.glob(".*partial*"))  # written whole, then renamed
    assert {p.name for p in (smoke_dir / "runs").iterdir()} == {
        "grid-dueling-double",
        "grid-simple",
    }
    for name in FIGURES:
        with Image.open(smoke_dir / name) as img:
            assert img.format == "PNG" and min(img.size) > 300


def test_results_hold_every_agent_seed_and_interval(smoke_dir):
    results = json.loads((smoke_dir / "results.json").read_text())
    assert results["seeds"] == [0, 1] and results["wall_s"] > 0
    suite = results["suites"]["GridMaze-v0"]
    assert suite["test_episodes"] == 20 and set(suite["agents"]) == set(AGENTS)
    for agent in AGENTS:
        row = suite["agents"][agent]
        assert len(row["per_seed"]) == 2
        for seed_row in row["per_seed"]:  # every episode ends in exactly one way
            rates = [seed_row[k] for k in ("success_rate", "collision_rate", "timeout_rate")]
            assert sum(rates) == pytest.approx(1.0)
        values = [r["mean_return"] for r in row["per_seed"]]
        half = stats.t.ppf(0.975, 1) * np.std(values, ddof=1) / np.sqrt(2)
        assert row["mean_return"]["mean"] == pytest.approx(np.mean(values))
        assert row["mean_return"]["ci95"] == pytest.approx(half)
    for agent in ("dueling-double", "simple"):
        metrics = results["training"]["grid"][agent]["metrics"]
        assert np.asarray(metrics["success_rate"]).shape == (2, 4)  # seeds x logging intervals
    with np.load(smoke_dir / "episodes.npz") as f:
        for agent in AGENTS:
            assert f[f"GridMaze-v0/{agent}/return"].shape == (2, 20)
        assert f["GridMaze-v0/trajectory/0/xy"].shape[1] == 2
    table = (smoke_dir / "results.md").read_text()
    for label in ("dueling double DQN", "simple DQN", "random agent"):
        assert f"| GridMaze-v0 | {label} |" in table
    assert "Wall time" in table


def test_figures_are_redrawn_from_the_directory(smoke_dir):
    (smoke_dir / "outcomes.png").unlink()
    assert main(["plot", str(smoke_dir)]) == 0
    assert (smoke_dir / "outcomes.png").is_file()


def test_render_draws_an_experiment_run(smoke_dir, tmp_path):
    run = smoke_dir / "runs" / "grid-dueling-double"
    gif = tmp_path / "traj.gif"
    assert render.main([str(run), "--episodes", "2", "--out", str(gif)]) == 0
    with Image.open(gif) as img:
        assert img.format == "GIF" and img.n_frames >= 2
    png = tmp_path / "traj.png"
    assert render.main([str(run), "--episodes", "3", "--out", str(png), "--run-seed", "1"]) == 0
    assert png.is_file() and [p.name for p in tmp_path.iterdir()] == ["traj.gif", "traj.png"]


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["paper-grid", "--seeds", "1"], "--seeds 1"),
        (["paper-grid", "--quick", "--smoke"], "--smoke"),
        (["paper-grid", "--test-episodes", "0"], "--test-episodes 0"),
        (["paper-grid", "--total-timesteps", "-5"], "total_timesteps=-5"),
        (["paper-robot", "--maze-file", "no/such.txt"], "no/such.txt"),
        (["paper-maze"], "paper-maze"),
    ],
)
def test_bad_flags_are_one_line_exit_2_nothing_written(args, named, tmp_path, capsys):
    out = tmp_path / "out"
    assert main([*args, "--out", str(out)] if args != ["paper-maze"] else args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and named in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_malformed_maze_file_is_refused_with_its_position(tmp_path, capsys):
    maze = tmp_path / "bad.txt"
    maze.write_text("....\n..x.\n....\n")
    assert main(["paper-robot", "--smoke", "--maze-file", str(maze), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert f"{maze}:2:3" in err and err.count("\n") == 0
    assert [p.name for p in tmp_path.iterdir()] == ["bad.txt"]


def test_used_out_dir_is_refused(smoke_dir, capsys):
    assert main(["paper-grid", "--smoke", "--out", str(smoke_dir)]) == 2
    assert "already exists" in capsys.readouterr().err


# ------------------------------------------------------------------------------ pieces
def test_mean_ci_is_the_t_interval():
    ci = experiments.mean_ci([1.0, 2.0, 3.0])
    assert ci["mean"] == pytest.approx(2.0)
    assert ci["ci95"] == pytest.approx(
        4.302653 / np.sqrt(3), rel=1e-5
    )  # t(0.975, 2) * sd / sqrt(n)
    assert experiments.mean_ci([None, None]) == {"mean": None, "ci95": None, "seeds": 0}
    assert experiments.mean_ci([0.5, None]) == {"mean": 0.5, "ci95": None, "seeds": 1}


@pytest.mark.parametrize("env_id", ["GridMaze-v0", "RobotSimple-v0"])
def test_suite_replays_the_drawn_episodes(env_id):
    """reset_to from the suite gives the states fresh resets with the suite's keys give."""
    env, params = jaxnav.make(env_id)
    key = jax.random.key(3)
    suite = experiments.draw_suite(env, params, key, 16)
    obs, state = experiments.start_suite(env, params, suite)
    ref_obs, ref_state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, 16), params)
    np.testing.assert_allclose(obs, ref_obs, atol=1e-6)
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(ref_state), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)  # grid: BFS shortest path = bank's


def test_generalization_suites_are_unseen_mazes():
    studies = {s.name: s for s in experiments.paper_robot("smoke", EXAMPLE_MAZE)}
    assert set(studies) == {"simple", "complex", "random"}
    random_study = studies["random"]
    _, train_params = jaxnav.make(random_study.config.env, **random_study.config.env_kwargs)
    unseen, *others = random_study.suites
    _, test_params = experiments.suite_env(unseen)
    seen = np.asarray(train_params.bank.grid)
    new = np.asarray(test_params.bank.grid)
    assert new.shape == seen.shape  # as many unseen layouts as training ones
    assert not (new[:, None] == seen[None]).all(axis=(2, 3)).any()  # none of them trained on
    assert [s.env for s in others] == ["RobotSimple-v0", "RobotComplex-v0", "RobotMaze-v0"]
    assert others[-1].env_kwargs["maze_file"] == str(EXAMPLE_MAZE)


def test_play_matches_stepping_with_auto_reset(open_maze):
    """evaluate.play (no auto-reset, frozen after the end) scores episodes as a plain loop
    over env.step does, and records the start state first."""
    env, params = open_maze
    n, steps = 32, int(params.max_steps_in_episode)
    policy = random_policy(env.num_actions)
    key = jax.random.key(7)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, n), params)
    out = jax.jit(play, static_argnums=(0, 2, 6, 7))(
        env, params, policy, key, obs, state, steps, True
    )
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    ended, ret, length = np.zeros(n, bool), np.zeros(n), np.zeros(n)
    success, o, s = np.zeros(n, bool), obs, state
    for k in jax.random.split(key, steps):
        k_pol, k_env = jax.random.split(k)
        o, s, r, term, trunc, info = step(jax.random.split(k_env, n), s, policy(k_pol, o), params)
        ret += np.where(ended, 0.0, r)
        length += ~ended
        success |= ~ended & np.asarray(info["goal_reached"])
        ended |= np.asarray(term | trunc)
    np.testing.assert_allclose(out["return"], ret, atol=1e-6)
    np.testing.assert_array_equal(out["steps"], length)
    np.testing.assert_array_equal(out["success"], success)
    np.testing.assert_array_equal(out["states"].pos[0], state.pos)
