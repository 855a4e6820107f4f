"""Drive an exported robot policy from recorded lidar scans, as a robot would run it.

    python -m jaxnav.export RUN --format npz --out policy.npz
    python examples/drive_from_scans.py policy.npz --episodes 3 --scan-beams 360

1. ``record``: plays episodes in the simulator (JAX), the trained network acting on the env's
   own observations, and logs what a robot would have each control step: a 360-degree lidar
   scan of ``--scan-beams`` readings (cast by the simulator's ray caster, +inf where nothing
   is within the scanner's ``range_max``), the pose, the goal, the robot's radius and the
   maze's map, with the simulator's action and waypoint, to an npz scan log.
2. ``drive``: reads the log with numpy alone (``jaxnav.deploy``, no JAX) and runs the robot's
   loop in one object, ``Navigator``: map, goal (``reset`` at each episode's start), then scan
   and pose -> its own planner's waypoint, the observation (frames stacked) -> the action;
   prints each action beside the simulator's and how often actions and waypoints agree. With
   ``--scan-beams`` a multiple of the policy's beams (and ``--angle-min`` on one), the scan
   holds the policy's exact beam directions and every action agrees; other resolutions read
   the nearest reading, a fraction of a degree off.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from jaxnav.deploy.navigator import Navigator
from jaxnav.deploy.planner import GridMap
from jaxnav.deploy.policy import Policy
from jaxnav.deploy.sensors import LaserScan


def record(
    policy_path: Path,
    log: Path,
    episodes: int,
    scan_beams: int,
    angle_min: float,
    range_max: float,
    seed: int,
) -> None:
    """Play ``episodes`` episodes in the simulator with the trained network and write the
    scan log ``log``."""
    import jax
    import jax.numpy as jnp

    import jaxnav
    from jaxnav.agents.dqn import QNetwork
    from jaxnav.envs.robot import geometry
    from jaxnav.export import flax_params

    policy = Policy.load(policy_path)
    meta, net = policy.metadata, policy.network
    if meta["sensors"] is None:
        raise SystemExit(f"{policy_path}: a {meta['env_id']} policy has no lidar to drive from")
    env, params = jaxnav.make(meta["env_id"], **meta["env_kwargs"])
    network = QNetwork(
        num_actions=net["num_actions"],
        hidden_sizes=tuple(net["hidden_sizes"]),
        dueling=net["dueling"],
        onehot_sizes=None,
        layer_norm=net["layer_norm"],
    )
    weights = flax_params(policy.arrays, net)
    increment = 2 * math.pi / scan_beams
    scan_angles = jnp.asarray(angle_min + increment * np.arange(scan_beams), jnp.float32)

    @jax.jit
    def sense_and_act(obs, state):
        """The simulator's greedy action and what the robot's sensors and planner give."""
        w = jax.tree.map(lambda x: x[state.layout], params.bank.walls)
        lo, hi = geometry.box_bounds(w.center, w.half_size, w.active)
        ranges = geometry.lasers(state.pose, lo, hi, scan_angles, 1e6)
        ranges = jnp.where(ranges > range_max, jnp.inf, ranges)  # no return within range
        waypoint = env.waypoint(state.pose, state.goal, state.layout, params)
        action = jnp.argmax(network.apply(weights, obs[None])[0])
        return action, ranges, waypoint

    reset, step = jax.jit(env.reset), jax.jit(env.step_env)
    names = ("ranges", "pose", "goal", "waypoint", "start", "layout", "radius")
    rows: dict[str, list] = {k: [] for k in names}
    rows["sim_action"], outcomes = [], []
    for e in range(episodes):
        key = jax.random.key(seed + e)
        obs, state = reset(key, params)
        for t in range(int(params.max_steps_in_episode)):
            action, ranges, waypoint = sense_and_act(obs, state)
            for name, value in (
                ("ranges", ranges), ("pose", state.pose), ("goal", state.goal),
                ("waypoint", waypoint), ("start", t == 0), ("sim_action", action),
                ("layout", state.layout),
                ("radius", env.config.radius if state.radius is None else state.radius),
            ):  # fmt: skip
                rows[name].append(np.asarray(value))
            key, k_step = jax.random.split(key)
            obs, state, _, done, info = step(k_step, state, action, params)
            if bool(done):
                break
        outcomes.append(
            "goal" if bool(info["goal_reached"]) else "collision" if bool(done) else "timeout"
        )
    np.savez_compressed(
        log,
        **{k: np.stack(v) for k, v in rows.items()},
        angle_min=angle_min,
        angle_increment=increment,
        range_max=range_max,
        grids=np.asarray(params.bank.grid),  # the maps: every maze of the bank
        cell_size=np.asarray(params.bank.cell_size),  # each maze's
        origins=np.asarray(env.layout_origins, np.float64),
    )
    steps = len(rows["start"])
    print(
        f"recorded {episodes} episodes ({steps} control steps) of {meta['env_id']} to {log}: "
        f"{', '.join(outcomes)}"
    )


def drive(policy_path: Path, log: Path, quiet: bool = False) -> float:
    """The robot's loop over the scan log with numpy alone; returns the fraction of steps
    whose action is the simulator's."""
    policy = Policy.load(policy_path)
    period = policy.metadata["sensors"]["control_period_s"]
    with np.load(log) as f:
        data = {k: f[k] for k in f.files}
    agree = same_waypoint = 0
    steps = len(data["start"])
    episode = np.cumsum(data["start"]) - 1
    for t in range(steps):
        layout = int(data["layout"][t])
        origin = data["origins"][layout]
        if data["start"][t]:  # a new maze, robot and goal; the map frame is env + origin
            cell = float(data["cell_size"][layout])
            grid_map = GridMap(data["grids"][layout], cell, tuple(origin))
            nav = Navigator(policy, map=grid_map, radius=float(data["radius"][t]))
            nav.reset(goal=data["goal"][t] + origin)
        scan = LaserScan(
            ranges=data["ranges"][t],
            angle_min=float(data["angle_min"]),
            angle_increment=float(data["angle_increment"]),
            range_max=float(data["range_max"]),
        )
        pose = data["pose"][t] + [*origin, 0.0]
        action = nav.act(scan=scan, pose=pose)
        sim = int(data["sim_action"][t])
        agree += action == sim
        if nav.waypoint is not None:
            same_waypoint += np.allclose(nav.waypoint, data["waypoint"][t] + origin, atol=1e-4)
        if not quiet:
            name = policy.action_names[action]
            v, omega = nav.speeds(action)
            differs = "" if action == sim else f"   simulator: {policy.action_names[sim]}"
            print(
                f"episode {episode[t]} step {t:4d}: {name:<10} (v {v:+.2f} m/s, "
                f"omega {omega:+.2f} rad/s){differs}"
            )
    planned = f"; {same_waypoint}/{steps} waypoints the simulator's" if nav.waypoint else ""
    print(
        f"{steps} control steps ({steps * period:.1f} s) of {episode[-1] + 1} episodes driven "
        "from the log: "
        f"{agree}/{steps} actions ({agree / steps:.1%}) the simulator's{planned}"
    )
    return agree / steps


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policy", type=Path, help="an exported robot policy (.npz)")
    p.add_argument("--episodes", type=int, default=3)
    p.add_argument("--scan-beams", type=int, default=360, help="readings of a 360-degree scan")
    p.add_argument("--angle-min", type=float, default=-180.0, help="first reading, degrees")
    p.add_argument("--range-max", type=float, default=12.0, help="the scanner's range, metres")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode")
    p.add_argument("--log", type=Path, default=Path("scans.npz"), help="scan log to write")
    p.add_argument("--quiet", action="store_true", help="print only the summaries")
    args = p.parse_args(argv)
    record(
        args.policy,
        args.log,
        args.episodes,
        args.scan_beams,
        math.radians(args.angle_min),
        args.range_max,
        args.seed,
    )
    drive(args.policy, args.log, args.quiet)
    return 0


if __name__ == "__main__":
    sys.exit(main())
