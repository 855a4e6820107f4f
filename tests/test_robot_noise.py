"""The robot env's noise and randomization options: off (absent, zero, or a range of one
value) changes nothing bit for bit; on, their statistics are the configured ones; bad values
are refused in one line."""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_rollout

import jaxnav
from jaxnav.envs.robot.env import PAPER_SETUP, RANGE_FIELDS, STEP_NOISE_FIELDS
from jaxnav.registration import env_config, registered_envs

FORWARD, BACKWARD, LEFT, RIGHT = range(4)
# the std of a standard normal truncated at +-3 std, which the actuation noise draws
TRUNCATED_STD = math.sqrt(1 - 6 * math.exp(-4.5) / math.sqrt(2 * math.pi) / math.erf(3 / 2**0.5))


def rollout(env_id: str, steps: int = 60, num_envs: int = 16, **overrides):
    env, params = jaxnav.make(env_id, **overrides)
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    run = jax.jit(lambda key: random_rollout(step, env, params, key, num_envs, steps))
    obs, state, reward, terminated, truncated, info = run(jax.random.key(7))
    return obs, state.pose, reward, terminated, truncated


ZERO = {name: 0.0 for name in STEP_NOISE_FIELDS}


@pytest.mark.parametrize(
    "env_id, base",
    [
        ("RobotSimple-v0", {"backend": "kinematic", "clearance_reward": -1.0}),
        ("RobotNav-v0", {"num_layouts": 8}),
    ],
)
def test_options_off_are_bit_for_bit_the_env_without_them(env_id, base):
    c = env_config(env_id, **base)
    want = rollout(env_id, **base)
    chex.assert_trees_all_equal(rollout(env_id, **base, **ZERO), want)
    # a range of one value takes the per-episode path (values in the state): the same
    one_value = {
        "radius_range": (c.radius, c.radius),
        "speed_range": (c.speed, c.speed),
        "turn_speed_range": (c.turn_speed, c.turn_speed),
    }
    chex.assert_trees_all_equal(rollout(env_id, **base, **one_value), want)


def test_presets_have_every_option_off():
    for env_id in registered_envs():
        if not env_id.startswith("Robot"):
            continue
        overrides = {"maze_file": "examples/mazes/rooms.txt"} if env_id == "RobotMaze-v0" else {}
        c = env_config(env_id, **overrides)
        assert not c.has_step_noise, env_id
        # the map-free generalist's id is for robots of any size in its range, by definition
        sized = {"radius_range"} if env_id == "RobotNavMapfree-v0" else set()
        assert all(getattr(c, name) is None for name in set(RANGE_FIELDS) - sized), env_id
    assert not set(PAPER_SETUP) & {*STEP_NOISE_FIELDS, *RANGE_FIELDS}


# ------------------------------------------------------------------------- lasers
def laser_errors(num_states: int = 2048, **noise):
    """``(true ranges, sensed ranges)`` in metres of the first frame after a reset and after one
    turn, over ``num_states`` random episodes of RobotSimple-v0 (kinematic) with ``noise``."""
    env, params = jaxnav.make("RobotSimple-v0", backend="kinematic", **noise)
    c = env.config

    def one(key):
        obs, state = env.reset(key, params)
        obs2, state2, *_ = env.step_env(jax.random.fold_in(key, 9), state, LEFT, params)
        true = jnp.stack([env.lasers(s.pose, s.layout, params) for s in (state, state2)])
        frame = env.frame_size
        # the newest frame of each observation: lasers come first, divided by laser_range
        sensed = jnp.stack([o[-frame:][: c.num_lasers] for o in (obs, obs2)]) * c.laser_range
        return true, sensed

    keys = jax.random.split(jax.random.key(1), num_states)
    true, sensed = jax.jit(jax.vmap(one))(keys)
    return np.asarray(true).ravel(), np.asarray(sensed).ravel(), c


@pytest.mark.parametrize("absolute, relative", [(0.05, 0.0), (0.0, 0.1), (0.03, 0.05)])
def test_laser_noise_has_the_configured_std(absolute, relative):
    true, sensed, c = laser_errors(laser_noise=absolute, laser_noise_rel=relative)
    std = absolute + relative * true
    # away from the clip at 0 and at the range, the error over its std is a standard normal
    inside = (true > 5 * std) & (true + 5 * std < c.laser_range)
    z = (sensed - true)[inside] / std[inside]
    assert inside.sum() > 10_000
    assert abs(z.mean()) < 0.03 and abs(z.std() - 1) < 0.03, (z.mean(), z.std())
    assert sensed.min() >= 0 and sensed.max() <= c.laser_range


def test_laser_dropout_reads_the_range_at_the_configured_rate():
    true, sensed, c = laser_errors(laser_dropout=0.2)
    hit = true < c.laser_range - 1e-3  # beams that do see a wall
    dropped = np.isclose(sensed[hit], c.laser_range, rtol=0, atol=1e-5)
    assert abs(dropped.mean() - 0.2) < 0.02, dropped.mean()
    np.testing.assert_allclose(sensed[hit][~dropped], true[hit][~dropped], atol=1e-5)


def test_laser_noise_stays_out_of_the_clearance_term():
    """The clearance term reads the true ranges: the same rewards with and without noise."""
    kw = {"backend": "kinematic", "clearance_reward": -1.0, "clearance": 2.0}
    actions = jax.random.randint(jax.random.key(3), (40, 64), 0, 4)

    def rewards(**noise):
        env, params = jaxnav.make("RobotSimple-v0", **kw, **noise)
        step = jax.vmap(env.step_env, in_axes=(0, 0, 0, None))

        def run(key):
            _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, 64), params)

            def body(state, a):  # no auto-reset: the same episodes whatever the keys
                _, state, reward, _, info = step(jax.random.split(key, 64), state, a, params)
                return state, (reward, info["reward_clearance"])

            return jax.lax.scan(body, state, actions)[1]

        return jax.jit(run)(jax.random.key(0))

    clean, noisy = rewards(), rewards(laser_noise=0.5, laser_dropout=0.5)
    assert np.asarray(clean[1]).min() < 0  # the term is at work
    chex.assert_trees_all_equal(noisy, clean)


# ---------------------------------------------------------------------- actuation
def motion(action: int, num: int = 4096, **options):
    """Per random start in RobotSimple-v0 (kinematic, free space ahead): the distance moved
    and the heading change of one ``action`` step, whether it collided, and the state."""
    env, params = jaxnav.make("RobotSimple-v0", backend="kinematic", **options)

    def one(key):
        _, s = env.reset(key, params)
        _, s2, _, _, info = env.step_env(jax.random.fold_in(key, 3), s, action, params)
        turn = jnp.angle(jnp.exp(1j * (s2.pose[2] - s.pose[2])))  # wrapped to (-pi, pi]
        return jnp.linalg.norm(s2.pose[:2] - s.pose[:2]), turn, info["collision"], s

    keys = jax.random.split(jax.random.key(2), num)
    moved, turn, collided, state = jax.jit(jax.vmap(one))(keys)
    return np.asarray(moved), np.asarray(turn), np.asarray(collided), state, env.config


def test_speed_noise_scales_the_executed_speed():
    moved, _, collided, _, c = motion(FORWARD, speed_noise=0.1)
    factor = moved[~collided] / (c.speed * c.dt)
    assert len(factor) > 1000
    assert abs(factor.mean() - 1) < 0.01
    assert abs(factor.std() - 0.1 * TRUNCATED_STD) < 0.005, factor.std()
    assert factor.min() >= 0.7 - 1e-5 and factor.max() <= 1.3 + 1e-5  # truncated at 3 std


def test_turn_noise_scales_the_executed_turn_rate():
    _, turn, _, _, c = motion(LEFT, turn_noise=0.2)
    factor = turn / (c.turn_speed * c.dt)
    assert abs(factor.mean() - 1) < 0.02
    assert abs(factor.std() - 0.2 * TRUNCATED_STD) < 0.01, factor.std()


def test_dt_jitter_stretches_the_step_uniformly():
    moved, turn, collided, _, c = motion(FORWARD, dt_jitter=0.2)
    factor = moved[~collided] / (c.speed * c.dt)
    assert factor.min() >= 0.8 - 1e-5 and factor.max() <= 1.2 + 1e-5
    assert factor.min() < 0.81 and factor.max() > 1.19
    assert abs(factor.std() - 0.2 / math.sqrt(3)) < 0.005, factor.std()


# ---------------------------------------------------------------------- per episode
def test_speed_ranges_are_drawn_per_episode_and_drive_the_robot():
    ranges = {"speed_range": (1.0, 2.0), "turn_speed_range": (1.0, 3.0)}
    moved, _, collided, state, c = motion(FORWARD, **ranges)
    speed = np.asarray(state.speed)
    assert speed.min() >= 1.0 and speed.max() <= 2.0 and abs(speed.mean() - 1.5) < 0.02
    np.testing.assert_allclose(moved[~collided], speed[~collided] * c.dt, rtol=1e-4)
    _, turn, _, state, _ = motion(LEFT, **ranges)
    turn_speed = np.asarray(state.turn_speed)
    assert turn_speed.min() >= 1.0 and turn_speed.max() <= 3.0
    np.testing.assert_allclose(turn, turn_speed * c.dt, rtol=1e-4)


def test_radius_range_is_drawn_per_episode_and_collides_at_that_radius():
    """Facing a wall, the robot drives until it touches it: it stops within one collision
    sub-step of the wall at its own episode's radius."""
    env, params = jaxnav.make("RobotSimple-v0", backend="kinematic", radius_range=(0.05, 0.3))
    c = env.config
    pose, goal = jnp.array([0.5, 1.5, math.pi]), jnp.array([8.5, 8.5])  # facing x = 0

    def drive(key):
        _, s = env.reset_to(key, params, pose, goal)

        def body(carry, _):
            s, ended = carry
            _, s2, _, done, _ = env.step_env(key, s, FORWARD, params)
            s = jax.tree.map(lambda a, b: jnp.where(ended, a, b), s, s2)  # frozen once ended
            return (s, ended | done), None

        (s, ended), _ = jax.lax.scan(body, (s, jnp.asarray(False)), None, length=4)
        return s.radius, s.pose[0], ended

    radius, x, hit = jax.jit(jax.vmap(drive))(jax.random.split(jax.random.key(4), 512))
    radius, x = np.asarray(radius), np.asarray(x)
    assert np.asarray(hit).all()
    assert radius.min() >= 0.05 and radius.max() <= 0.3 and abs(radius.mean() - 0.175) < 0.01
    sub_step = c.speed * c.dt / env.substeps
    gap = x - radius  # the wall's face is x = 0
    assert gap.min() >= 0 and gap.max() <= sub_step + 1e-5


def test_mjx_uses_the_episodes_radius():
    """On MJX the episode's radius is the sphere's: the config's radius as a one-value range
    steps bit for bit as without the range, and a larger robot touches a wall earlier."""
    env, params = jaxnav.make("RobotSimple-v0", radius_range=(0.13, 0.2))
    pose, goal = jnp.array([0.42, 1.5, math.pi]), jnp.array([8.5, 8.5])  # 0.42 m from x = 0
    _, s = env.reset_to(jax.random.key(0), params, pose, goal)
    step = jax.jit(env.step_env)
    actions = [LEFT, FORWARD, RIGHT, RIGHT, FORWARD, BACKWARD]
    fixed, ranged = s.replace(radius=None), s.replace(radius=jnp.float32(env.config.radius))
    for a in actions:
        *out_fixed, _ = step(jax.random.key(0), fixed, a, params)
        *out_ranged, _ = step(jax.random.key(0), ranged, a, params)
        chex.assert_trees_all_equal(out_ranged[0], out_fixed[0])  # observation
        chex.assert_trees_all_equal(out_ranged[1].pose, out_fixed[1].pose)
        chex.assert_trees_all_equal(out_ranged[2:], out_fixed[2:])  # reward, terminated
        fixed, ranged = out_fixed[1], out_ranged[1]
    first_hit = {}
    for radius in (0.13, 0.2):
        state = s.replace(radius=jnp.float32(radius))
        for t in range(4):
            _, state, _, _, info = step(jax.random.key(0), state, FORWARD, params)
            if bool(info["collision"]):
                first_hit[radius] = t
                break
    # substeps of 0.125 m: 0.17 m from the wall after the first step (within 0.2 m, not 0.13
    # m); the smaller robot touches in the second
    assert first_hit == {0.2: 0, 0.13: 1}


def test_noise_options_are_vmappable_in_step_batch():
    """``step_batch`` (fresh episodes scattered into the batch) equals ``vmap(step)`` with every
    option on, the per-episode values included."""
    options = {
        "backend": "kinematic",
        "max_steps": 12,
        "laser_noise": 0.02,
        "laser_dropout": 0.1,
        "speed_noise": 0.1,
        "turn_noise": 0.1,
        "dt_jitter": 0.1,
        "radius_range": (0.1, 0.2),
        "speed_range": (1.5, 2.5),
        "turn_speed_range": (2.0, 5.0),
    }
    env, params = jaxnav.make("RobotRandom-v0", num_layouts=4, **options)
    env.batch_reset_fraction = 1 / 8
    vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    run = jax.jit(
        lambda key: tuple(
            random_rollout(step, env, params, key, 32, 30) for step in (vstep, env.step_batch)
        )
    )
    want, got = run(jax.random.key(5))
    chex.assert_trees_all_equal(got, want)
    assert env.stochastic_step


# ---------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"laser_noise": -0.1}, r"laser_noise=-0.1: must be a number in \[0, inf\)"),
        ({"laser_noise_rel": float("nan")}, "laser_noise_rel=nan: must be a number"),
        ({"laser_dropout": 1.5}, r"laser_dropout=1.5: must be a number in \[0, 1\]"),
        ({"speed_noise": 0.4}, r"speed_noise=0.4: must be a number in \[0, 0.3333\)"),
        ({"turn_noise": True}, "turn_noise=True: must be a number"),
        ({"dt_jitter": 1.0}, r"dt_jitter=1.0: must be a number in \[0, 1\)"),
        ({"radius_range": (0.3, 0.1)}, r"radius_range=\(0.3, 0.1\): must be a pair"),
        ({"radius_range": (0.2, 0.6)}, r"radius_range=\(0.2, 0.6\): the robot must fit"),
        ({"speed_range": "fast"}, "speed_range='fast': must be a pair"),
        ({"turn_speed_range": (1.0,)}, r"turn_speed_range=\(1.0,\): must be a pair"),
        ({"speed_range": (1.0, -2.0)}, "speed_range=.*must be a pair"),
        # MJX sees contacts between substeps: the fastest noisy step must stay below the radius
        ({"speed_noise": 0.3}, "mjx_substeps=2: a physics substep would move the robot"),
        ({"radius_range": (0.05, 0.2)}, "its radius 0.05; use more substeps"),
    ],
)
def test_bad_noise_values_are_refused_in_one_line(overrides, message):
    with pytest.raises(ValueError, match=message) as e:
        jaxnav.make("RobotSimple-v0", **overrides)
    assert "\n" not in str(e.value)


def test_ranges_from_json_lists_become_tuples():
    c = env_config("RobotSimple-v0", backend="kinematic", radius_range=[0.1, 0.2])
    assert c.radius_range == (0.1, 0.2)
    hash(c)  # still hashable
