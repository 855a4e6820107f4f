"""``init_from`` (``--init-from``): a run that starts from a shipped or exported policy's weights
acts as that policy does before it learns anything; a policy whose network, observation or
actions are not the run's is refused in one line naming it."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from jaxnav import pretrained
from jaxnav.config import TrainConfig
from jaxnav.export import env_for
from jaxnav.train import Trainer
from jaxnav.train.__main__ import main as train_main

FLOOR = "examples/maps/floor.yaml"


def generalist_config(env_overrides=None, **overrides) -> TrainConfig:
    """PQN on the floor plan with the generalist's sensors (``env_overrides`` on them) and
    network."""
    policy = pretrained.load("robotnav-pqn")
    _, kwargs = env_for(policy, "RobotMaze-v0", {"maze_file": FLOOR})
    kwargs.update(env_overrides or {})
    values = {"env_kwargs": kwargs, "hidden_sizes": (1024, 512, 256), "num_envs": 8}
    return TrainConfig.for_env("RobotMaze-v0", algo="pqn", **{**values, **overrides})


@pytest.mark.slow  # compiles training of the shipped 1024-512-256 network
@pytest.mark.parametrize("source", ["name", "npz file"])
def test_a_run_from_a_shipped_policy_starts_with_its_weights(source):
    init = "robotnav-pqn" if source == "name" else str(pretrained.path("robotnav-pqn"))
    trainer = Trainer(generalist_config(init_from=init))
    state = trainer.init(jax.random.key(0))
    policy = pretrained.load("robotnav-pqn")
    kernel = np.asarray(state.params["params"]["Dense_0"]["kernel"])
    np.testing.assert_array_equal(kernel, policy.arrays["dense0_kernel"])
    obs = np.asarray(state.obs)  # the run's first observations, 8 envs
    q = np.asarray(trainer.network.apply(state.params, state.obs))
    np.testing.assert_allclose(q, policy.q_values(obs), rtol=1e-4, atol=1e-4)
    assert np.asarray(q.argmax(-1)).tolist() == [policy.act(o) for o in obs]
    fresh = Trainer(generalist_config()).init(jax.random.key(0))
    assert not np.array_equal(np.asarray(fresh.params["params"]["Dense_0"]["kernel"]), kernel)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            {"init_from": "robotnav-pqn", "hidden_sizes": (64,)},
            "init_from='robotnav-pqn': its network has hidden_sizes=(1024, 512, 256), this "
            "run's hidden_sizes=(64,)",
        ),
        (
            {"init_from": "robotnav-pqn", "layer_norm": False},
            "init_from='robotnav-pqn': its network has layer_norm=True, this run's "
            "layer_norm=False",
        ),
        (
            {"init_from": "robotnav-pqn", "env_overrides": {"num_lasers": 16}},
            "init_from='robotnav-pqn': --env RobotMaze-v0: observations (88,) do not fit the "
            "run's network (152,)",
        ),
        ({"init_from": "missing/policy.npz"}, "init_from='missing/policy.npz': no such policy"),
    ],
)
def test_a_policy_that_does_not_fit_the_run_is_refused(overrides, message):
    trainer = Trainer(generalist_config(**overrides))  # a trained run's evaluation reads none
    with pytest.raises(ValueError) as e:
        trainer.init(jax.random.key(0))
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def test_an_unknown_policy_name_is_refused_with_the_config():
    with pytest.raises(ValueError) as e:
        generalist_config(init_from="no-such-policy").validate()
    assert str(e.value).startswith("init_from='no-such-policy': must be a shipped policy (")


def test_the_command_line_refuses_it_in_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    assert (
        train_main(["--init-from", "robotnav-pqn", "--hidden-sizes", "16", "--out", str(out)]) == 2
    )
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "init_from='robotnav-pqn'" in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.slow  # compiles and runs a training program
def test_the_command_line_fine_tunes_a_shipped_policy(tmp_path, capsys):
    """320 env steps at a negligible learning rate from the shipped grid agent: the run's own
    evaluation is the agent's (from random weights it would be the random agent's); the run's
    config records where it started."""
    out = tmp_path / "run"
    flags = ["--total-timesteps", "320", "--learning-starts", "64", "--buffer-size", "256"]
    flags += ["--log-interval", "160", "--eval-episodes", "200", "--lr", "1e-7", "--lr-end", "1e-7"]
    assert train_main(["--init-from", "gridmaze-dqn", *flags, "--quiet", "--out", str(out)]) == 0
    trained = json.loads((out / "summary.json").read_text())["trained"]
    assert trained["success_rate"] >= 0.95, trained
    assert json.loads((out / "config.json").read_text())["config"]["init_from"] == "gridmaze-dqn"
