"""Each training setting is declared once, as a ``jaxnav.config.setting`` field of
``TrainConfig``: its validation, ``HParams`` and the training CLI's flag and ``--help`` line are
read off that declaration."""

from __future__ import annotations

import dataclasses

import jax
import pytest

from jaxnav.algos import ALGOS
from jaxnav.config import HPARAMS, TrainConfig, integer, number, setting
from jaxnav.presets import PRESETS
from jaxnav.train import HParams
from jaxnav.train.__main__ import config_from_args
from jaxnav.train.__main__ import parser as train_parser

# env_kwargs is the env's own config: set by --env-arg, validated by the env
SETTINGS = [f for f in dataclasses.fields(TrainConfig) if f.name != "env_kwargs"]
# the training CLI's flags that are not settings: where a run goes, how it is checkpointed and
# logged, the env overrides and the hosts
RUN_FLAGS = {
    "-h", "--help", "--env-arg", "--maze-file", "--out", "--quiet", "--tensorboard", "--wandb",
    "--resume", "--checkpoint-every", "--keep-checkpoints", "--coordinator", "--num-processes",
    "--process-id",
}  # fmt: skip


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def other_value(f: dataclasses.Field) -> tuple[str, object]:
    """A valid value of setting ``f`` other than its default: ``(as typed, as parsed)``."""
    d = f.default
    if isinstance(d, bool):
        return str(not d).lower(), not d
    if isinstance(d, tuple):
        return "8,4", (8, 4)
    if isinstance(d, int):
        return str(d + 1), d + 1
    if isinstance(d, float):
        return str(d / 2), d / 2
    choices = {
        "env": "RobotSimple-v0",
        "algo": "pqn",
        "compute_dtype": "bfloat16",
        "init_from": "gridmaze-dqn",
        "curriculum": "learnability",
    }
    value = choices.get(f.name) or {"huber": "mse", "adam": "sgd"}[d]
    return value, value


def test_every_setting_has_help_a_check_and_a_flag_and_every_flag_a_setting():
    actions = {opt: a for a in train_parser([])._actions for opt in a.option_strings}
    for f in SETTINGS:
        assert f.metadata["help"], f.name
        assert f.name == "env" or f.metadata["check"] is not None, f.name  # env: the registry's
        shown = actions[flag(f.name)].help
        assert shown.startswith(f"{f.metadata['help']} (default: "), (f.name, shown)
    assert set(actions) - RUN_FLAGS == {flag(f.name) for f in SETTINGS}
    # --algo's help is the registry's: each algorithm says what it is
    for name, algorithm in ALGOS.items():
        assert algorithm.summary and f"{name} ({algorithm.summary})" in actions["--algo"].help


@pytest.mark.parametrize("f", SETTINGS, ids=lambda f: f.name)
def test_every_setting_reaches_the_config_from_its_flag(f):
    typed, parsed = other_value(f)
    config = config_from_args(train_parser([]).parse_args([flag(f.name), typed]))
    assert getattr(config, f.name) == parsed != f.default


@pytest.mark.parametrize("f", SETTINGS[1:], ids=lambda f: f.name)  # env: unknown id, tested
def test_every_setting_is_validated_by_its_declared_check(f):
    with pytest.raises(ValueError) as info:
        dataclasses.replace(TrainConfig(), **{f.name: "junk"}).validate()
    assert str(info.value).startswith(f"{f.name}='junk': must be "), info.value


def test_a_new_setting_is_one_declaration_that_validation_reads():
    @dataclasses.dataclass(frozen=True)
    class Extended(TrainConfig):
        extra: int = setting(3, "a new setting", integer(0, 5))
        ratio: float = setting(0.5, "another", number(0.0, 1.0, positive=True))

    Extended().validate()
    for bad, message in [
        ({"extra": 9}, "extra=9: must be an integer in [0, 5]"),
        ({"ratio": 0.0}, "ratio=0.0: must be positive"),
        ({"ratio": float("nan")}, "ratio=nan: must be a number in [0.0, 1.0]"),
    ]:
        with pytest.raises(ValueError) as info:
            Extended(**bad).validate()
        assert str(info.value) == message


def test_hparams_are_the_settings_marked_hparam_in_the_saved_layout():
    assert tuple(HParams.__dataclass_fields__) == HPARAMS
    # checkpoints hold these leaves by name and in this order: old ones must still restore
    assert HPARAMS == (
        "gamma", "lr", "lr_end", "max_grad_norm", "tau", "eps_start", "eps_end",
        "eps_decay_steps", "td_lambda",
    )  # fmt: skip
    hp = HParams.from_config(TrainConfig(td_lambda=0.5, eps_decay_steps=7))
    paths, leaves = zip(*jax.tree_util.tree_flatten_with_path(hp)[0], strict=True)
    assert [p[0].name for p in paths] == list(HPARAMS)
    assert all(x.dtype == "float32" and x.shape == () for x in leaves)
    assert (float(hp.td_lambda), float(hp.eps_decay_steps)) == (0.5, 7.0)
    static = {f.name for f in SETTINGS} - set(HPARAMS)
    assert {"clip_eps", "num_envs", "hidden_sizes"} <= static  # compiled in, not vmapped


def test_presets_set_settings_only():
    names = {f.name for f in SETTINGS}
    for algo, by_env in PRESETS.items():
        for env_id, preset in by_env.items():
            assert set(preset) <= names, (algo, env_id, set(preset) - names)
