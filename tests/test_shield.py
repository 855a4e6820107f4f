"""The lidar collision monitor (``jaxnav.deploy.shield``): which moves it blocks, numpy and JAX
alike, and what it changes in the simulator and at deployment."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxnav
from jaxnav import pretrained
from jaxnav.deploy.shield import Shield
from jaxnav.evaluate import run_episodes
from jaxnav.evaluate.__main__ import main as evaluate_main

SMALL = {"num_layouts": 8, "backend": "kinematic"}


@pytest.fixture(scope="module")
def robot():
    env, params = jaxnav.make("RobotNav-v0", **SMALL)
    shield = Shield.from_layouts(
        env.observation_layout(params), env.action_layout(), env.sensor_layout()
    )
    return env, params, shield


def scan(env, params, shield: Shield, walls: dict[int, float]) -> np.ndarray:
    """An observation whose newest frame reads the laser range on every beam but those in
    ``walls`` (beam -> metres)."""
    obs = np.zeros(env.observation_layout(params)["size"], np.float32)
    for beam, (i, metres) in enumerate(zip(shield.laser_index, shield.laser_metres, strict=True)):
        obs[i] = walls.get(beam, metres) / metres
    return obs


def test_a_wall_ahead_blocks_forward_one_behind_backward_and_turns_never(robot):
    env, params, shield = robot
    names = [a["name"] for a in env.action_layout()]
    angles = np.asarray(shield.angles)
    ahead, behind = np.argmin(np.abs(angles)), np.argmax(np.abs(angles))
    left = np.argmin(np.abs(angles - math.pi / 2))
    assert abs(angles[behind]) == pytest.approx(math.pi) and angles[ahead] == pytest.approx(0)
    near = shield.radius + max(shield.reach) - 0.01  # the disc's front after one step, less 1 cm
    cases = {
        "open": ({}, set()),
        "ahead": ({ahead: near}, {"forward"}),
        "ahead, out of reach": ({ahead: near + 0.06}, set()),
        "behind": ({behind: near}, {"backward"}),
        "beside, parallel": ({left: shield.radius + 0.02}, set()),
    }
    for case, (walls, blocked) in cases.items():
        got = shield.blocked(scan(env, params, shield, walls))
        assert {n for n, b in zip(names, got, strict=True) if b} == blocked, case


def test_a_corner_between_two_beams_blocks_forward_a_straight_wall_as_near_does_not(robot):
    """A right-angled corner 0.29 m ahead, pointing at the robot between the beams at 0 and
    11.25 degrees, whose returns both lie out of the step's reach (0.30 m): blocked. A straight
    wall 0.32 m ahead, read by five beams: not blocked."""
    env, params, shield = robot
    angles = np.degrees(np.asarray(shield.angles))
    beam = {round(float(a), 2): i for i, a in enumerate(angles)}
    assert shield.radius + max(shield.reach) == pytest.approx(0.30)
    # faces (1, -1) and (1, 1) from the corner (0.29, 0.03): the beams' hits on them
    corner = {beam[0.0]: 0.32, beam[11.25]: math.hypot(0.29 + 0.0346, 0.03 + 0.0346)}
    wall = {beam[a]: 0.32 / math.cos(math.radians(a)) for a in (-22.5, -11.25, 0.0, 11.25, 22.5)}
    assert shield.blocked(scan(env, params, shield, corner))[0]
    assert not shield.blocked(scan(env, params, shield, wall))[0]


@pytest.mark.slow  # rolls out whole episodes to collect observations
def test_numpy_and_jax_block_the_same_moves_on_the_envs_observations(robot):
    env, params, shield = robot
    keys = jax.random.split(jax.random.key(0), 64)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    seen = []
    for t in range(40):  # forward mostly: many walls come near
        actions = jnp.where(jax.random.uniform(jax.random.key(t), (64,)) < 0.7, 0, 2)
        obs, state, *_ = step(jax.random.split(jax.random.key(100 + t), 64), state, actions, params)
        seen.append(np.asarray(obs))
    seen = np.concatenate(seen)
    blocked_np = shield.blocked(seen)
    np.testing.assert_array_equal(blocked_np, np.asarray(shield.blocked(jnp.asarray(seen), jnp)))
    assert 0 < blocked_np[:, 0].mean() < 1  # some forward moves blocked, not all


def test_a_shielded_policy_that_wants_forward_crashes_far_less(robot):
    env, params, shield = robot
    q = jnp.array([1.0, 0.0, 0.5, 0.4])  # forward first, then turn left
    plain = lambda key, obs: jnp.argmax(jnp.broadcast_to(q, obs.shape[:1] + q.shape), -1)  # noqa: E731

    def shielded(key, obs):
        return shield.act(jnp.broadcast_to(q, obs.shape[:1] + q.shape), obs, jnp)

    key, steps = jax.random.key(3), 200
    crashes = {
        name: float(np.mean(run_episodes(env, params, pol, key, 64, steps)["collision"]))
        for name, pol in (("plain", plain), ("shielded", shielded))
    }
    # the rest touch wall corners that lie between two beams
    assert crashes["plain"] > 0.9 and crashes["shielded"] < 0.35, crashes


def test_the_deployed_policy_acts_as_the_evaluated_one():
    """``Policy.act(obs, policy.shield)`` (numpy) picks what the JAX monitor picks from the
    same Q-values, on observations whose lasers read anything up to the range."""
    policy = pretrained.load("robotnav-sizes")
    shield = policy.shield
    rng = np.random.default_rng(0)
    obs = rng.uniform(0.0, 1.0, (256, policy.obs_size)).astype(np.float32)
    obs[:, shield.radius_index] = rng.uniform(0.1, 0.245, 256)
    q = policy.q_values(obs)
    acted = policy.act(obs, shield)
    np.testing.assert_array_equal(acted, shield.act(q, obs))
    np.testing.assert_array_equal(
        acted, np.asarray(shield.act(jnp.asarray(q), jnp.asarray(obs), jnp))
    )
    blocked = shield.blocked(obs)
    assert 0 < blocked[:, 0].mean() < 1 and not blocked[np.arange(256), acted].any()
    assert (acted != np.argmax(q, axis=-1)).any()  # the monitor changed some actions


def test_evaluate_refuses_a_shield_for_a_policy_without_lidar_in_one_line(capsys):
    assert evaluate_main(["--pretrained", "gridmaze-dqn", "--policy", "shielded"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--policy shielded" in err and "lidar" in err


def test_a_shielded_env_stands_where_its_lidar_shows_the_move_blocked():
    """``shielded=True``: the robot facing a wall 0.11 m from its disc does not drive into it
    (it stands, paying a step); without the monitor the same command crashes."""
    key = jax.random.key(0)
    outcomes = {}
    for shielded in (False, True):
        env, params = jaxnav.make("RobotSimple-v0", backend="kinematic", shielded=shielded)
        pose, goal = jnp.array([1.5, 0.26, -math.pi / 2]), jnp.array([8.5, 5.5])
        _, s = env.reset_to(key, params, pose, goal)
        _, s1, reward, _, info = jax.jit(env.step_env)(key, s, 0, params)  # forward
        outcomes[shielded] = (bool(info["collision"]), np.asarray(s1.pose), float(reward))
        _, s2, _, _, info = jax.jit(env.step_env)(key, s, 2, params)  # a turn is never blocked
        assert not bool(info["collision"]) and float(s2.pose[2]) != float(s.pose[2])
    assert outcomes[False][0] and not outcomes[True][0]
    np.testing.assert_allclose(outcomes[True][1], [1.5, 0.26, -math.pi / 2], atol=1e-6)
    assert outcomes[True][2] == pytest.approx(env.config.step_reward_start)
    with pytest.raises(ValueError, match=r"^shielded=True: .*obs_radius=True"):
        jaxnav.make("RobotNav-v0", shielded=True, radius_range=(0.1, 0.2), num_layouts=4)
    with pytest.raises(ValueError, match=r"^shielded='yes': must be true or false"):
        jaxnav.make("RobotSimple-v0", shielded="yes")
