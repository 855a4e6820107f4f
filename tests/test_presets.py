"""Training presets (``jaxnav.presets``): one per (algorithm, env id), applied by
``TrainConfig.for_env`` and the training CLI under the caller's own values."""

from __future__ import annotations

import pytest

from jaxnav.config import ALGOS, TrainConfig
from jaxnav.presets import (
    FAMILY_PRESETS,
    GENERALIST_PQN,
    GRID_RANDOM_PQN,
    ID_PRESETS,
    PRESETS,
    ROBOT_DQN,
    default_algo,
    train_defaults,
)
from jaxnav.registration import env_family, registered_envs
from jaxnav.train.__main__ import config_from_args
from jaxnav.train.__main__ import parser as train_parser

CORRIDOR = "#######\n.......\n#######\n"


@pytest.fixture(scope="module")
def maze_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("maze") / "corridor.txt"
    path.write_text(CORRIDOR)
    return str(path)


def env_kwargs(env_id: str, maze_file: str) -> dict:
    return {"maze_file": maze_file} if env_id == "RobotMaze-v0" else {}


def test_presets_cover_every_algorithm_and_env_id():
    assert set(PRESETS) == set(ALGOS)
    for algo in ALGOS:
        assert set(PRESETS[algo]) == set(registered_envs()), algo


def test_an_env_id_without_its_own_preset_trains_with_its_familys():
    # a new id of a registered env class needs no edit here: its class names the family
    families = {env_family(e) for e in registered_envs()}
    assert families == {"grid", "robot"}
    for algo in ALGOS:
        for env_id in registered_envs():
            own = ID_PRESETS.get(algo, {}).get(env_id)
            want = own if own is not None else FAMILY_PRESETS[algo][env_family(env_id)]
            assert PRESETS[algo][env_id] is want, (algo, env_id)
    assert PRESETS["dqn"]["RobotMaze-v0"] is ROBOT_DQN


@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("env_id", registered_envs())
def test_for_env_applies_the_preset_and_validates(env_id, algo, maze_file):
    config = TrainConfig.for_env(env_id, algo=algo, env_kwargs=env_kwargs(env_id, maze_file))
    config.validate()
    assert config.env == env_id and config.algo == algo
    preset = train_defaults(env_id, algo)
    for name, value in preset.items():
        assert getattr(config, name) == value, name
    # everything else is TrainConfig's default
    default = TrainConfig()
    for name in set(TrainConfig.__dataclass_fields__) - set(preset) - {"env", "algo", "env_kwargs"}:
        assert getattr(config, name) == getattr(default, name), name


def test_the_generalists_pqn_preset_and_the_robot_dqn_one():
    nav = TrainConfig.for_env("RobotNav-v0", algo="pqn")
    assert (nav.num_envs, nav.rollout_length, nav.num_minibatches, nav.num_epochs) == (
        8192,
        32,
        16,
        4,
    )
    assert nav.layer_norm and nav.total_timesteps == 838_860_800 and nav.gamma == 0.99
    assert nav.lr == 2e-3
    assert nav.hidden_sizes == (1024, 512, 256) and nav.compute_dtype == "bfloat16"
    assert train_defaults("RobotNav-v0", "pqn") == GENERALIST_PQN
    # the other robot envs keep the smaller PQN preset; DQN is the same on every robot env
    assert TrainConfig.for_env("RobotSimple-v0", algo="pqn").num_envs == 256
    assert train_defaults("RobotNav-v0") == train_defaults("RobotSimple-v0") == ROBOT_DQN
    assert train_defaults("GridMaze-v0") == {}  # the paper's grid: TrainConfig's defaults
    # a copy: changing it does not change the preset
    train_defaults("RobotNav-v0", "pqn")["num_envs"] = 1
    assert GENERALIST_PQN["num_envs"] == 8192


@pytest.mark.parametrize(
    "call, named",
    [
        (lambda: train_defaults("Nope-v0"), "unknown env id 'Nope-v0'; valid ids: GridMaze-v0"),
        (lambda: train_defaults("GridMaze-v0", "sac"), "algo='sac': must be one of dqn, pqn, ppo"),
        (lambda: TrainConfig.for_env("Nope-v0"), "unknown env id 'Nope-v0'"),
        (lambda: TrainConfig.for_env("RobotNav-v0", algo="sac"), "algo='sac'"),
    ],
)
def test_unknown_env_or_algorithm_is_a_one_line_error(call, named):
    with pytest.raises(ValueError) as e:
        call()
    assert named in str(e.value) and "\n" not in str(e.value)


def test_explicit_values_beat_the_preset():
    config = TrainConfig.for_env("RobotNav-v0", algo="pqn", num_envs=64, gamma=0.9)
    assert (config.num_envs, config.gamma) == (64, 0.9)
    assert config.rollout_length == GENERALIST_PQN["rollout_length"]  # the rest: the preset
    config.validate()
    dqn = TrainConfig.for_env("RobotSimple-v0", n_step=1, algo="dqn")
    assert dqn.n_step == 1 and dqn.gamma == ROBOT_DQN["gamma"]


def test_training_cli_lists_algo_and_applies_the_preset_under_its_flags():
    text = train_parser().format_help()
    assert "--algo" in text and "pqn" in text
    parse = lambda *argv: config_from_args(train_parser().parse_args(list(argv)))  # noqa: E731
    config = parse("--env", "RobotNav-v0", "--algo", "pqn", "--num-envs", "64")
    assert config.algo == "pqn" and config.num_envs == 64
    assert config.rollout_length == 32 and config.td_lambda == GENERALIST_PQN["td_lambda"]
    assert parse("--env", "RobotNav-v0").n_step == ROBOT_DQN["n_step"]  # dqn by default
    assert parse().algo == "dqn" and parse().env == "GridMaze-v0"


def test_grid_random_trains_with_its_pqn_preset_unless_the_dqn_is_asked_for():
    """GridMaze-Random-v0's default algorithm is PQN (``default_algo``), with its own preset;
    ``--algo dqn`` gives the paper's DQN settings; GridMaze-v0 keeps TrainConfig's defaults."""
    assert default_algo("GridMaze-Random-v0") == "pqn" and default_algo("GridMaze-v0") == "dqn"
    config = TrainConfig.for_env("GridMaze-Random-v0")
    assert config == TrainConfig.for_env("GridMaze-Random-v0", algo="pqn")
    assert config.algo == "pqn" and config.hidden_sizes == GRID_RANDOM_PQN["hidden_sizes"]
    assert train_defaults("GridMaze-Random-v0") == GRID_RANDOM_PQN
    config.validate()
    dqn = TrainConfig.for_env("GridMaze-Random-v0", algo="dqn")
    assert dqn == TrainConfig(env="GridMaze-Random-v0")
    assert TrainConfig.for_env("GridMaze-v0") == TrainConfig()  # the paper's grid, unchanged
    parse = lambda *argv: config_from_args(train_parser().parse_args(list(argv)))  # noqa: E731
    assert parse("--env", "GridMaze-Random-v0") == config
    assert parse("--env", "GridMaze-Random-v0", "--algo", "dqn") == dqn
    assert parse("--env", "GridMaze-Random-v0", "--total-timesteps", "5000").algo == "pqn"


# ------------------------------------------------------------------ replay ratio
@pytest.mark.parametrize("env_id", registered_envs())
def test_dqn_presets_take_the_updates_per_iteration_they_took_before_replay_ratio(
    env_id, maze_file
):
    """``replay_ratio`` replaced the field ``updates_per_iteration`` (1 in every preset and the
    experiments' configs): each derives the same gradient steps, so trains bit for bit the
    same."""
    config = TrainConfig.for_env(env_id, algo="dqn", env_kwargs=env_kwargs(env_id, maze_file))
    config.validate()
    assert config.updates_per_iteration == 1
    assert config.replay_ratio * config.num_envs == config.batch_size  # 16 x 8 = 128, 64 x 8 = 512


@pytest.mark.parametrize("size", ["full", "quick", "smoke"])
def test_experiment_configs_take_one_update_per_iteration(size):
    from jaxnav import experiments

    for config in (experiments.grid_config(size), experiments.robot_config("RobotSimple-v0", size)):
        config.validate()
        assert config.updates_per_iteration == 1, (size, config.env)


@pytest.mark.parametrize("num_envs, updates", [(16, 1), (64, 4), (256, 16), (1024, 64)])
def test_the_default_replay_ratio_holds_across_env_counts(num_envs, updates):
    config = TrainConfig(num_envs=num_envs)
    config.validate()
    assert config.updates_per_iteration == updates  # 8 sampled transitions per env step
    assert config.updates_per_iteration * config.batch_size == 8 * num_envs


@pytest.mark.parametrize(
    "fields, suggestion",
    [
        ({"replay_ratio": 3.0}, "e.g. batch_size=48 (1 per iteration)"),
        ({"num_envs": 1000}, "e.g. batch_size=125 (64 per iteration)"),
        ({"num_envs": 4, "batch_size": 64}, "e.g. batch_size=32 (1 per iteration)"),
        ({"num_envs": 7, "replay_ratio": 0.3}, "no batch size divides replay_ratio * num_envs"),
    ],
)
def test_a_replay_ratio_giving_no_whole_updates_is_refused_with_a_batch_size(fields, suggestion):
    config = TrainConfig(**fields)
    with pytest.raises(ValueError) as info:
        config.validate()
    message = str(info.value)
    assert "\n" not in message and suggestion in message, message
    for name in ("replay_ratio", "num_envs", "batch_size"):
        assert f"{name}={getattr(config, name)!r}" in message, message
    fixed = message.split("e.g. ")[1].split(" ")[0].split("=")
    TrainConfig(**{**fields, fixed[0]: type(getattr(config, fixed[0]))(fixed[1])}).validate()


def test_replay_ratio_is_dqn_only():
    pqn = TrainConfig.for_env("GridMaze-v0", algo="pqn", batch_size=1000)
    pqn.validate()  # 8 * 64 / 1000: no whole number, but PQN samples no replay


def test_help_shows_each_default_once_the_named_presets():
    """``--help`` gives one default a flag: the preset of the ``--env`` and ``--algo`` beside
    it, named in the description; without them the paper's grid DQN's."""
    plain = " ".join(train_parser([]).format_help().split())
    assert "Defaults shown: GridMaze-v0 with --algo dqn" in plain
    assert "steps per seed (default: 240000)" in plain and "; --algo" not in plain
    argv = ["--env", "RobotNav-v0", "--algo", "pqn", "--help"]
    text = " ".join(train_parser(argv).format_help().split())
    assert "Defaults shown: RobotNav-v0 with --algo pqn" in text
    assert f"steps per seed (default: {GENERALIST_PQN['total_timesteps']})" in text
    assert f"(default: {GENERALIST_PQN['num_envs']})" in text and "; robot envs" not in text
    # a bad id in argv leaves the grid's defaults; parsing the flags then names it
    for argv in (["--env", "x"], ["--env", "--"], ["--algo"]):
        bad = train_parser(argv).format_help()
        assert "Defaults shown: GridMaze-v0" in " ".join(bad.split())


def test_the_map_free_generalist_id_is_the_measured_sweep_row():
    """``RobotNavMapfree-v0`` is row 14 of benchmarks/mapfree_sweep.py (the best map-free row,
    docs/mapfree.md), env and training preset alike, and needs no waypoint."""
    from benchmarks import mapfree_sweep
    from jaxnav.registration import env_config

    _, env_id, env_kwargs, train = mapfree_sweep.ROWS[14]
    assert "trail" in mapfree_sweep.ROWS[14][0] and train == {}
    config = env_config("RobotNavMapfree-v0")
    assert config == env_config(env_id, **env_kwargs)
    assert config.waypoint_distance == 0 and not config.obs_absolute and config.trail_cell > 0
    for algo in ("pqn", "ppo"):
        assert train_defaults("RobotNavMapfree-v0", algo) == train_defaults(env_id, algo)
