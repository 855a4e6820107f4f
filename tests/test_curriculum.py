"""The curriculum over layouts by learnability (``--curriculum learnability``,
``jaxnav.train.curriculum``): how resets draw layouts from the statistics, how the statistics
follow the episodes that ended, and that they travel with the training state (devices,
checkpoints, ``--resume``)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_FLAGS, TINY_TRAIN, run_sharded  # pytest puts tests/ on sys.path
from test_faults import assert_complete, interrupted_after, one_line_error
from test_reliability import final_params

import jaxnav
from jaxnav import checkpoints, run_dir
from jaxnav.train import METRIC_NAMES, Trainer, curriculum
from jaxnav.train.__main__ import main as train_main
from jaxnav.train.__main__ import parser as train_parser

# a bank of 8 grid layouts with short episodes: many end within a tiny run
BANK = {"size": 5, "num_layouts": 8, "goals_per_layout": 4, "max_steps": 12}
TINY_CURRICULUM = dataclasses.replace(
    TINY_TRAIN, env="GridMaze-Random-v0", env_kwargs=BANK, curriculum="learnability"
)
# the algorithms' own sizes on top of TINY_TRAIN: a rollout of 2 steps in 2 minibatches
ROLLOUT = {"rollout_length": 2, "num_minibatches": 2}
ALGO_SIZES = {"dqn": {}, "pqn": ROLLOUT, "ppo": ROLLOUT}


def stats_of(success: list[float]) -> curriculum.LayoutStats:
    return curriculum.LayoutStats(
        success=jnp.asarray(success, jnp.float32), episodes=jnp.ones(len(success), jnp.int32)
    )


# ------------------------------------------------------------------ the draw
def test_probabilities_mix_learnability_with_a_uniform_share():
    share = curriculum.UNIFORM_SHARE
    got = np.asarray(curriculum.layout_probabilities(stats_of([0.0, 0.5, 1.0, 0.5])))
    np.testing.assert_allclose(got, share / 4 + (1 - share) * np.array([0, 0.5, 0, 0.5]))
    # nothing learnable (every layout always or never solved): uniform
    flat = curriculum.layout_probabilities(stats_of([0.0, 1.0, 1.0]))
    np.testing.assert_allclose(np.asarray(flat), np.full(3, 1 / 3))
    cdf = np.asarray(curriculum.layout_cdf(stats_of([0.2, 0.5, 0.9])))
    assert cdf[-1] == 1.0 and np.all(np.diff(cdf) > 0)
    # before any episode every layout is at the prior, the most learnable: uniform
    fresh = curriculum.layout_probabilities(curriculum.init(5))
    np.testing.assert_allclose(np.asarray(fresh), np.full(5, 0.2), rtol=1e-6)


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("GridMaze-Random-v0", {"size": 5, "num_layouts": 3, "goals_per_layout": 4}),
        ("RobotRandom-v0", {"num_layouts": 3, "random_size": 4}),
    ],
)
def test_resets_draw_a_layout_solved_half_the_time_more_often_at_the_stated_share(env_id, kwargs):
    env, params = jaxnav.make(env_id, **kwargs)
    assert env.weighted_layouts and params.layout_cdf is None
    stats = stats_of([0.0, 0.5, 1.0])  # never, half the time, always solved
    params = params.replace(layout_cdf=curriculum.layout_cdf(stats))
    n = 30_000
    _, state = jax.jit(jax.vmap(env.reset_env, in_axes=(0, None)))(
        jax.random.split(jax.random.key(7), n), params
    )
    counts = np.bincount(np.asarray(env.layout_index(state)), minlength=3)
    share = curriculum.UNIFORM_SHARE
    expected = n * np.array([share / 3, share / 3 + 1 - share, share / 3])
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert chi2 < 13.8, (counts, expected)  # chi-square, 2 degrees of freedom, p = 0.001
    assert counts[1] > 3 * max(counts[0], counts[2])


# ------------------------------------------------------------------ the statistics
def test_update_moves_each_layouts_success_by_its_ended_episodes():
    stats = curriculum.LayoutStats(
        success=jnp.asarray([0.5, 0.2, 0.9, 0.5], jnp.float32),
        episodes=jnp.asarray([0, 3, 1, 0], jnp.int32),
    )
    # [time 3, env 4]: layout 0 ends twice (one success), layout 1 once (a failure), layout 2
    # steps without ending, layout 3 is not played; steps that do not end count for nothing
    layout = jnp.asarray([[0, 1, 2, 0], [0, 1, 2, 0], [0, 1, 2, 0]])
    ended = jnp.asarray([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]], bool)
    reached = jnp.asarray([[1, 1, 1, 1], [0, 0, 1, 0], [1, 1, 1, 0]], bool)
    got = curriculum.update(stats, layout, ended, reached)
    step = curriculum.SUCCESS_STEP
    k2, k1 = (1 - step) ** 2, 1 - step
    want = [k2 * 0.5 + (1 - k2) * 0.5, k1 * 0.2 + (1 - k1) * 0.0, 0.9, 0.5]
    np.testing.assert_allclose(np.asarray(got.success), want, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(got.episodes), [2, 4, 1, 0])
    assert float(got.success[2]) == float(stats.success[2])  # untouched bit for bit


def test_an_ended_episode_counts_for_the_layout_it_ran_in_not_the_one_reset_drew():
    trainer = Trainer(dataclasses.replace(TINY_CURRICULUM, num_envs=64))
    ts = jax.jit(trainer.init)(jax.random.key(1))
    # every episode at its last step: the next step ends all of them and auto-reset draws anew
    last = trainer.env_params.max_steps_in_episode - 1
    ts = ts.replace(env_state=ts.env_state.replace(time=jnp.full_like(ts.env_state.time, last)))
    keys = tuple(jax.random.split(jax.random.key(2), 3))
    after, (_, _, stats) = jax.jit(trainer.env_step)(ts, keys, 1.0, ts.params)
    before_layout = np.asarray(ts.env_state.layout)
    assert np.asarray(stats["episodes"]).all()
    np.testing.assert_array_equal(np.asarray(stats["layout"]), before_layout)
    assert (np.asarray(after.env_state.layout) != before_layout).any()  # the test can tell


@pytest.mark.parametrize("algo", sorted(ALGO_SIZES))
def test_the_statistics_count_every_episode_that_ended_in_each_layout(algo):
    """One iteration per logging interval, stepped here: the episodes an iteration ended are
    the envs whose episode length went back to 0, in the layout they were in before it."""
    config = dataclasses.replace(
        TINY_CURRICULUM, algo=algo, **ALGO_SIZES[algo], num_envs=8, buffer_size=128
    )
    config = dataclasses.replace(config, log_interval=config.steps_per_iteration)
    trainer = Trainer(config)
    run = jax.jit(lambda ts, it: trainer.run(ts, it, 1))
    ts = jax.jit(trainer.init)(jax.random.key(4))
    counted = np.zeros(8, np.int64)
    episodes = 0
    for it in range(config.num_logs):
        if config.rollout_length == 1:  # the env steps of the iteration, as the loop takes them
            layout = np.asarray(ts.env_state.layout)
            ts, metrics = run(ts, it)
            ended = np.asarray(ts.episode_length) == 0
            np.add.at(counted, layout[ended], 1)
        else:
            ts, metrics = run(ts, it)
        episodes += int(metrics["episodes"][0])
    stats = jax.device_get(ts.curriculum)
    assert stats.episodes.sum() == episodes > 8
    if config.rollout_length == 1:
        np.testing.assert_array_equal(stats.episodes, counted)
    played = stats.episodes > 0
    assert (stats.success[~played] == curriculum.PRIOR).all()
    assert ((stats.success >= 0) & (stats.success <= 1)).all()
    assert (stats.success[played] != curriculum.PRIOR).any()


def test_seeds_keep_their_own_statistics_and_devices_share_them():
    """Vmapped seeds differ; two devices splitting a seed's envs hold the same statistics as
    one device (integer counts: exact whatever the order of the sums)."""
    warm_up = dataclasses.replace(TINY_CURRICULUM, learning_starts=64, num_seeds=2)
    keys = jax.random.split(jax.random.key(3), 2)
    one_state, _ = run_sharded(Trainer(warm_up), keys, num_logs=2)
    stats = jax.device_get(one_state.curriculum)
    assert not np.array_equal(stats.episodes[0], stats.episodes[1])
    key = keys[:1]
    one_state, _ = run_sharded(Trainer(dataclasses.replace(warm_up, num_seeds=1)), key, 2)
    two = Trainer(dataclasses.replace(warm_up, num_seeds=1, devices=2))
    two_state, _ = run_sharded(two, key, num_logs=2)
    for leaf in jax.tree.leaves(two_state.curriculum):
        copies = [np.asarray(s.data) for s in leaf.addressable_shards]
        assert len(copies) == 2
        np.testing.assert_array_equal(copies[0], copies[1])
    jax.tree.map(
        np.testing.assert_array_equal,
        jax.device_get(one_state.curriculum),
        jax.device_get(two_state.curriculum),
    )


# ------------------------------------------------------------------ checkpoints and the CLI
CURRICULUM_FLAGS = [
    *TINY_FLAGS,
    "--env", "GridMaze-Random-v0",
    "--algo", "dqn",
    "--env-arg", "num_layouts=8",
    "--env-arg", "goals_per_layout=4",
    "--env-arg", "max_steps=12",
    "--curriculum", "learnability",
    "--total-timesteps", "128",
    "--eval-episodes", "2",
    "--checkpoint-every", "32",
]  # fmt: skip


def test_resume_with_the_curriculum_is_bitwise_the_uninterrupted_run(tmp_path, monkeypatch, capsys):
    reference = tmp_path / "reference"
    assert train_main([*CURRICULUM_FLAGS, "--out", str(reference)]) == 0
    out = tmp_path / "run"
    interrupted_after(out, monkeypatch, 2, CURRICULUM_FLAGS)
    # the checkpoint holds the statistics of the episodes so far
    partial = run_dir.partial_dir(out)
    trainer = Trainer(run_dir.load_config(partial))
    like = jax.eval_shape(jax.vmap(trainer.init), jax.random.split(jax.random.key(0), 1))
    one = jax.eval_shape(lambda ts: trainer.run(jax.tree.map(lambda x: x[0], ts), 0, 1)[1], like)
    logs = trainer.config.num_logs
    metrics_like = {k: np.zeros((1, logs), one[k].dtype) for k in METRIC_NAMES}
    saved = checkpoints.Checkpoints(partial / "checkpoints", keep=2)
    _, state, _, _ = saved.restore(like, metrics_like, step=2)
    saved.close()
    assert state.curriculum.episodes.sum() > 0
    capsys.readouterr()
    assert train_main(["--resume", str(out)]) == 0
    assert "resumed from the checkpoint at env step 64" in capsys.readouterr().out
    assert_complete(out, (reference / "metrics.csv").read_text())
    mine, ref = final_params(out), final_params(reference)
    for a, b in zip(jax.tree.leaves(mine), jax.tree.leaves(ref), strict=True):
        np.testing.assert_array_equal(a, b)


def test_the_flag_is_in_help_and_bad_values_are_one_line_exit_2(tmp_path, capsys):
    assert "--curriculum" in train_parser([]).format_help()
    err = one_line_error(
        capsys, 2, train_main([*TINY_FLAGS, "--curriculum", "junk", "--out", str(tmp_path / "a")])
    )
    assert "curriculum='junk': must be one of none, learnability" in err
    # GridMaze-v0 has one layout: nothing for a curriculum to choose
    err = one_line_error(
        capsys,
        2,
        train_main([*TINY_FLAGS, "--curriculum", "learnability", "--out", str(tmp_path / "b")]),
    )
    assert "curriculum=learnability: GridMaze-v0 has one layout" in err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_off_the_env_params_and_the_state_are_as_before():
    trainer = Trainer(TINY_TRAIN)
    assert TINY_TRAIN.curriculum == "none" and trainer.env_params.layout_cdf is None
    assert trainer.rollout_env_params(None) is trainer.env_params
    state = jax.eval_shape(trainer.init, jax.random.key(0))
    assert state.curriculum is None
