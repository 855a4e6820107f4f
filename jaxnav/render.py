"""Trajectories as pictures: record episodes inside jit, draw them outside on numpy.

    python -m jaxnav.render RUN_DIR --episodes 4                  # animated, RUN_DIR/traj.gif
    python -m jaxnav.render RUN_DIR --episodes 4 --out traj.png   # paths and laser fans
    python -m jaxnav.render RUN_DIR --episodes 4 --out traj.pdf   # the same, vector

``record`` plays episodes with ``evaluate.play(record=True)`` (one compiled scan that returns
every state, and the env's ``sensor_ranges`` of every state, e.g. the robot's laser ranges) and
turns each episode into a dict of numpy arrays (the env's ``scene``: in metres, or cells of
side 1 with row 0 at the top): the path, headings, lasers, goal, outcome and the maze's wall
rectangles. ``draw_episode`` and ``save_gif`` only
read those arrays, so a recorded episode can be saved (``np.savez``) and drawn later.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxnav import run_dir
from jaxnav.agents import dqn
from jaxnav.cli import (
    HelpFormatter,
    Parser,
    UsageError,
    add_env_args,
    add_policy_source,
    check_policy_source,
    env_from_args,
    fail,
    write_failed,
)
from jaxnav.environment import Environment, EnvParams
from jaxnav.evaluate import Policy, play, random_policy
from jaxnav.programs import enable_compilation_cache
from jaxnav.safe_io import WriteFault, atomic_output, check_output_file
from jaxnav.train import Trainer

OUTCOMES = ("success", "collision", "timeout")
OUT_SUFFIXES = (".gif", ".png", ".svg", ".pdf")  # animated; raster; vector (papers)
Episode = dict[str, np.ndarray]


def record(
    env: Environment,
    env_params: EnvParams,
    policy: Policy,
    obs: jax.Array,
    state: Any,
    key: jax.Array | None = None,
) -> list[Episode]:
    """Play the batch of episodes starting at ``(obs, state)`` to their end; one ``Episode``
    (numpy arrays, see the module docstring) per episode."""
    max_steps = int(env_params.max_steps_in_episode)

    def rollout(obs, state, key):
        out = play(env, env_params, policy, key, obs, state, max_steps, record=True)
        # [T+1, N, R] sensor ranges, from the recorded states
        ranges = lambda s: env.sensor_ranges(s, env_params)  # noqa: E731
        out["ranges"] = jax.vmap(jax.vmap(ranges))(out["states"])
        return out

    key = jax.random.key(0) if key is None else key
    out = jax.tree.map(np.asarray, jax.jit(rollout)(obs, state, key))
    return [_episode(env, env_params, out, i) for i in range(obs.shape[0])]


def _episode(env: Environment, env_params: EnvParams, out: dict[str, Any], i: int) -> Episode:
    steps = int(out["steps"][i])
    states = jax.tree.map(lambda x: x[: steps + 1, i], out["states"])
    outcome = OUTCOMES.index(
        "success" if out["success"][i] else "collision" if out["collision"][i] else "timeout"
    )
    common = {
        "steps": np.int32(steps),
        "outcome": np.int32(outcome),
        "return": np.float32(out["return"][i]),
        # env.shortest_path_length: grid moves, robot metres (less the goal radius); -1 unknown
        "shortest_path": np.float32(out["shortest_path"][i]),
    }
    return common | env.scene(env_params, states, out["ranges"][: steps + 1, i])


def describe(ep: Episode) -> str:
    outcome = OUTCOMES[int(ep["outcome"])]
    text = f"{outcome} after {int(ep['steps'])} steps, return {float(ep['return']):.1f}"
    if float(ep["shortest_path"]) > 0:
        text += f" (shortest {float(ep['shortest_path']):.3g})"
    return text


# ------------------------------------------------------------------------------- drawing
def draw_episode(
    ax: Any,
    ep: Episode,
    upto: int | None = None,
    laser_steps: Sequence[int] | None = None,
    title: str | None = None,
) -> None:
    """Top-down view: walls, start (green), goal (red), the path up to step ``upto`` (default:
    the end), the robot there, and its laser rays at ``laser_steps`` (default: the current
    step while animating, 4 steps spread over the episode otherwise)."""
    from matplotlib.patches import Circle, Rectangle

    steps = int(ep["steps"])
    t = steps if upto is None else min(upto, steps)
    if laser_steps is None:
        laser_steps = [t] if upto is not None else np.linspace(0, steps, 4).round().astype(int)
    width, height = (float(v) for v in ep["arena"])
    robot = bool(ep["laser_angles"].size)
    ax.clear()
    ax.set_xlim(0, width)
    ax.set_ylim(0, height)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.add_patch(Rectangle((0, 0), width, height, fill=False, lw=2, color="black"))
    if robot:  # a metre scale: ticks in metres along the bottom and left edges
        step = metre_step(max(width, height))
        ax.set_xticks(np.arange(0, width + 1e-6, step))
        ax.set_yticks(np.arange(0, height + 1e-6, step))
        ax.tick_params(labelsize=7, length=2, pad=1)
        ax.set_xlabel("m", fontsize=7, labelpad=1)
    else:  # grid: show the cells
        ax.set_xticks(np.arange(width + 1), minor=True)
        ax.set_yticks(np.arange(height + 1), minor=True)
        ax.grid(which="minor", color="0.85", lw=0.5)
        ax.tick_params(which="minor", length=0)
    for x, y, w, h in ep["walls"]:
        ax.add_patch(Rectangle((x, y), w, h, color="0.35", lw=0))
    radius = float(ep["radius"])
    xy, heading = ep["xy"], ep["heading"]
    for s in laser_steps:  # rays from the robot's centre at each chosen step
        for angle, dist in zip(ep["laser_angles"], ep["lasers"][s], strict=True):
            a = heading[s] + angle
            end = xy[s] + dist * np.array([np.cos(a), np.sin(a)])
            ax.plot([xy[s, 0], end[0]], [xy[s, 1], end[1]], color="orange", lw=0.8, zorder=2)
    goal_r = float(ep["goal_radius"])
    ax.add_patch(Circle(ep["goal"], goal_r, color="tab:red", alpha=0.25, lw=0))
    ax.plot(*ep["goal"], marker="*", color="tab:red", ms=12, zorder=7, label="goal")
    ax.plot(*xy[0], marker="o", color="tab:green", ms=8, zorder=4, label="start")
    ax.plot(xy[: t + 1, 0], xy[: t + 1, 1], color="tab:blue", lw=1.5, zorder=3, label="path")
    ax.add_patch(Circle(xy[t], radius, color="tab:blue", alpha=0.8, zorder=5))
    if robot:  # drawn at least 2.5% of the arena wide (a 0.15 m disc is a dot in 10 m), with an
        # arrow for its heading; the true footprint stays inside it
        shown = max(radius, 0.025 * max(width, height))
        ax.add_patch(Circle(xy[t], shown, fill=False, ec="black", lw=1, zorder=6))
        d = 2.6 * shown * np.array([np.cos(heading[t]), np.sin(heading[t])])
        ax.annotate(
            "", xy[t] + d, xy[t], zorder=6, arrowprops={"arrowstyle": "-|>", "lw": 1.5}
        )
    text = title if title is not None else describe(ep)
    ax.set_title(textwrap.fill(text, 34), fontsize=8)  # two short lines, never into a neighbour


def metre_step(size: float) -> float:
    """Tick spacing in metres giving 3 to 6 ticks over ``size`` metres (1, 2 or 5 times a
    power of ten)."""
    for step in (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0):
        if size / step <= 6:
            return step
    return 10.0 ** math.ceil(math.log10(size / 5))


def _grid_shape(n: int) -> tuple[int, int]:
    cols = min(n, 4) if n != 4 else 2
    return math.ceil(n / cols), cols


def trajectories_figure(episodes: Sequence[Episode], title: str = "") -> Any:
    """Static figure: each episode's whole path with laser fans at 4 steps."""
    import matplotlib.pyplot as plt

    rows, cols = _grid_shape(len(episodes))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.8 * rows), squeeze=False)
    for ax, ep in zip(axes.ravel(), episodes, strict=False):
        draw_episode(ax, ep)
    for ax in axes.ravel()[len(episodes) :]:
        ax.axis("off")
    # one legend for all panels, below them: inside a panel it hides part of the maze
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8, frameon=False)
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


def save_gif(
    episodes: Sequence[Episode], path: Path, fps: int = 10, title: str = "", max_frames: int = 300
) -> int:
    """Animate the episodes side by side, one frame per step (every k-th step past
    ``max_frames``); written atomically. Returns the number of frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    longest = max(int(ep["steps"]) for ep in episodes)
    stride = max(1, math.ceil((longest + 1) / max_frames))
    frames = list(range(0, longest + 1, stride))
    if frames[-1] != longest:
        frames.append(longest)
    rows, cols = _grid_shape(len(episodes))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.ravel()[len(episodes) :]:
        ax.axis("off")
    fig.tight_layout(rect=(0, 0, 1, 0.94 if title else 1))

    def update(t):
        for ax, ep in zip(axes.ravel(), episodes, strict=False):
            end = min(t, int(ep["steps"]))
            status = describe(ep) if end == int(ep["steps"]) else f"step {end}"
            draw_episode(ax, ep, upto=t, title=status)
        if title:
            fig.suptitle(title, fontsize=10)

    try:
        with atomic_output(path) as tmp:
            FuncAnimation(fig, update, frames=frames).save(tmp, writer=PillowWriter(fps=fps))
    finally:
        plt.close(fig)
    return len(frames)


def save_figure(fig: Any, path: Path) -> None:
    """Save ``fig`` to ``path`` (.png; .svg and .pdf: vector, for papers), written atomically."""
    import matplotlib.pyplot as plt

    try:
        with atomic_output(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)


# ---------------------------------------------------------------------------- command line
def parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="python -m jaxnav.render",
        description="Draw episodes of a trained run: an animated GIF or a PNG of the paths.",
        formatter_class=HelpFormatter,
    )
    add_policy_source(
        p,
        "a policy shipped with jaxnav instead of a run (python -m jaxnav.pretrained)",
    )
    p.add_argument("--episodes", type=int, default=4, help="episodes drawn side by side (1-16)")
    p.add_argument(
        "--out",
        type=Path,
        help=".gif (animated), .png, or .svg/.pdf (vector) (default: RUN/traj.gif, in the run "
        "directory; NAME.gif with --pretrained)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the episodes' starts and goals")
    p.add_argument("--run-seed", type=int, help="which trained seed (default: the run's first)")
    p.add_argument("--policy", choices=("trained", "random"), default="trained")
    p.add_argument("--env", help="draw on another env id; default: the run's")
    add_env_args(p)
    p.add_argument("--fps", type=int, default=10, help="frames per second of a GIF (1-100)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Draw as the flags in ``argv`` (default: the command line's) say; the exit code."""
    prog = "jaxnav.render"
    try:
        args = parser().parse_args(argv)
        check_policy_source(args)
        if args.out is None:  # a run's pictures belong with the run, not in the cwd
            args.out = Path(f"{args.pretrained}.gif") if args.run is None else args.run / "traj.gif"
        if not 1 <= args.episodes <= 16:
            raise UsageError(f"--episodes {args.episodes}: must be in [1, 16]")
        if args.out.suffix not in OUT_SUFFIXES:
            raise UsageError(f"--out {args.out}: must end in {', '.join(OUT_SUFFIXES)}")
        check_output_file(args.out)  # a directory or a device is refused, not replaced
        if args.seed < 0 or not 1 <= args.fps <= 100:
            bad = f"--seed {args.seed}" if args.seed < 0 else f"--fps {args.fps}"
            raise UsageError(f"{bad}: out of range")
        if args.pretrained is not None:
            from jaxnav.export import load_pretrained

            env, overrides = env_from_args(args, args.env)
            config, trainer, params = load_pretrained(args.pretrained, env, overrides)
            env_trainer = trainer
        else:
            config = run_dir.load_config(args.run)
        seeds = run_dir.seeds_of(config)
        run_seed = seeds[0] if args.run_seed is None else args.run_seed
        if run_seed not in seeds:
            raise UsageError(f"--run-seed {run_seed}: the run has seeds {seeds}")
        if args.pretrained is None:
            trainer = Trainer(config)
            params = run_dir.load_trained_params(args.run, trainer)
            env_id, overrides = env_from_args(args, args.env)  # --maze-file: RobotMaze-v0
            if env_id is not None or overrides:
                env_id, kwargs = run_dir.run_env(config, env_id, overrides)  # sensors go along
                env_trainer = Trainer(dataclasses.replace(config, env=env_id, env_kwargs=kwargs))
                dqn.check_input_fits(
                    env_trainer.config.env, env_trainer.network_input, trainer.network_input
                )
            else:
                env_trainer = trainer
    except (UsageError, ValueError, FileNotFoundError) as e:
        return fail(prog, str(e))
    enable_compilation_cache()
    env, env_params = env_trainer.env, env_trainer.env_params
    if args.policy == "random":
        policy = random_policy(env.num_actions)
    else:
        policy = trainer.greedy_policy(jax.tree.map(lambda x: x[seeds.index(run_seed)], params))
    keys = jax.random.split(jax.random.key(args.seed), args.episodes)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, env_params)
    episodes = record(env, env_params, policy, obs, state)
    who = f"pretrained {args.pretrained}" if args.pretrained else f"seed {run_seed}"
    title = f"{env.name}: {args.policy} policy ({who})"
    try:
        if args.out.suffix == ".gif":
            frames = save_gif(episodes, args.out, fps=args.fps, title=title)
            print(f"wrote {args.out} ({frames} frames)")
        else:
            import matplotlib

            matplotlib.use("Agg")  # no display needed
            save_figure(trajectories_figure(episodes, title), args.out)
            print(f"wrote {args.out}")
    except WriteFault as e:
        return write_failed(prog, e)
    for i, ep in enumerate(episodes):
        print(f"  episode {i}: {describe(ep)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
