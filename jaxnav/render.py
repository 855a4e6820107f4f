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
import contextlib
import dataclasses
import math
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator, Sequence
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
    check_seed,
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
        if has_waypoint(env):  # [T+1, N, 2] the planner's point the policy reads
            point = lambda s: env.read_waypoint(  # noqa: E731
                s.pose, s.goal, s.layout, s.own_map, env_params
            )
            out["waypoints"] = jax.vmap(jax.vmap(point))(out["states"])
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
    scene = env.scene(env_params, states, out["ranges"][: steps + 1, i])
    if "waypoints" in out:
        scene["waypoint"] = out["waypoints"][: steps + 1, i]
    return common | scene


def has_waypoint(env: Environment) -> bool:
    """Whether ``env``'s observation holds a waypoint (``RobotNav``'s ``waypoint_distance``)."""
    return bool(getattr(env, "waypoint_steps", 0)) and hasattr(env, "read_waypoint")


def is_robot(ep: Episode) -> bool:
    """Whether ``ep`` is a robot's (metres, lasers, a heading) rather than a grid's (cells)."""
    return bool(ep["laser_angles"].size)


def describe(ep: Episode) -> str:
    outcome = OUTCOMES[int(ep["outcome"])]
    text = f"{outcome} after {int(ep['steps'])} steps, return {float(ep['return']):.1f}"
    if float(ep["shortest_path"]) > 0:
        unit = "m" if is_robot(ep) else "cells"  # robot: metres; grid: moves of one cell
        text += f" (shortest {float(ep['shortest_path']):.3g} {unit})"
    return text


# ------------------------------------------------------------------------------- progress
class Progress:
    """Progress lines on ``stream`` (stderr): a task's line once it has run ``after`` seconds,
    then a counter at most every ``every`` seconds; nothing when ``quiet``."""

    def __init__(
        self, quiet: bool = False, after: float = 5.0, every: float = 2.0, stream: Any = None
    ) -> None:
        self.quiet, self.after, self.every = quiet, after, every
        self.stream = sys.stderr if stream is None else stream
        self.start = self.last = time.perf_counter()

    def say(self, text: str) -> None:
        if not self.quiet:
            print(text, file=self.stream, flush=True)

    @contextlib.contextmanager
    def waiting(self, text: str) -> Iterator[None]:
        """Say ``text`` if the block is still running after ``after`` seconds (a compile)."""
        timer = threading.Timer(self.after, self.say, (text,))
        timer.daemon = True
        if not self.quiet:
            timer.start()
        try:
            yield
        finally:
            timer.cancel()

    def begin(self) -> None:
        self.start = self.last = time.perf_counter()

    def count(self, what: str, i: int, n: int) -> None:
        """``what i/n`` once the task has run ``after`` seconds, then every ``every`` seconds
        and at the end."""
        now = time.perf_counter()
        due = now - self.start >= self.after and (now - self.last >= self.every or i == n)
        if due and not self.quiet:
            self.last = now
            self.say(f"{what} {i}/{n}")


# ------------------------------------------------------------------------------- drawing
RAY_COLOR, PATH_COLOR, WAYPOINT_COLOR = "orange", "tab:blue", "tab:purple"


def _arena(ax: Any, ep: Episode) -> float:
    """Limits, ticks (metres, or the grid's cells), boundary and walls, drawn once; returns
    the robot's shown radius."""
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle, Rectangle

    width, height = (float(v) for v in ep["arena"])
    ax.clear()
    ax.set_xlim(0, width)
    ax.set_ylim(0, height)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.add_patch(Rectangle((0, 0), width, height, fill=False, lw=2, color="black"))
    if is_robot(ep):  # a metre scale: ticks in metres along the bottom and left edges
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
    # one collection, not a patch per wall: drawn in one call
    walls = [Rectangle((x, y), w, h) for x, y, w, h in ep["walls"]]
    ax.add_collection(PatchCollection(walls, facecolor="0.35", edgecolor="none", lw=0))
    ax.add_patch(Circle(ep["goal"], float(ep["goal_radius"]), color="tab:red", alpha=0.25, lw=0))
    ax.plot(*ep["goal"], marker="*", color="tab:red", ms=12, zorder=7, ls="", label="goal")
    ax.plot(*ep["xy"][0], marker="o", color="tab:green", ms=8, zorder=4, ls="", label="start")
    radius = float(ep["radius"])
    # a robot is drawn at least 2.5% of the arena wide (a 0.15 m disc is a dot in 10 m); its
    # true footprint stays inside
    return max(radius, 0.025 * max(width, height)) if is_robot(ep) else radius


class EpisodeArtists:
    """The moving parts of one episode's panel: path, robot, heading, rays, waypoint, title;
    ``show(t)`` moves them to step ``t`` and returns them (to redraw on a saved background)."""

    def __init__(self, ax: Any, ep: Episode, animated: bool) -> None:
        from matplotlib.collections import LineCollection
        from matplotlib.patches import Circle

        self.ax, self.ep = ax, ep
        shown = _arena(ax, ep)
        kw = {"animated": animated}
        self.path = ax.plot([], [], color=PATH_COLOR, lw=1.5, zorder=3, label="path", **kw)[0]
        self.body = Circle((0, 0), float(ep["radius"]), color=PATH_COLOR, alpha=0.8, zorder=5, **kw)
        self.outline = Circle((0, 0), shown, fill=False, ec="black", lw=1, zorder=6, **kw)
        self.outline.set_label("robot")
        ax.add_patch(self.body)
        ax.add_patch(self.outline)
        self.shown = shown
        self.heading = self.rays = self.waypoint = None
        if is_robot(ep):
            self.heading = ax.annotate(
                "", (0, 0), (0, 0), zorder=6, arrowprops={"arrowstyle": "-|>", "lw": 1.5}, **kw
            )
            self.rays = LineCollection([], colors=RAY_COLOR, lw=0.8, zorder=2, **kw)
            self.rays.set_label("laser rays")
            ax.add_collection(self.rays)
        if "waypoint" in ep:
            self.waypoint = ax.plot(
                [], [], marker="X", color=WAYPOINT_COLOR, ms=7, ls="", zorder=6.5,
                label="waypoint", **kw,
            )[0]  # fmt: skip
        ax.title.set_animated(animated)

    def show(self, t: int, title: str | None = None) -> list[Any]:
        ep = self.ep
        t = min(t, int(ep["steps"]))
        xy, heading = ep["xy"], ep["heading"]
        self.path.set_data(xy[: t + 1, 0], xy[: t + 1, 1])
        self.body.set_center(xy[t])
        self.outline.set_center(xy[t])
        changed = [self.path, self.body, self.outline]
        if self.rays is not None:
            a = heading[t] + ep["laser_angles"]
            ends = xy[t] + ep["lasers"][t][:, None] * np.stack([np.cos(a), np.sin(a)], -1)
            self.rays.set_segments([[xy[t], end] for end in ends])
            direction = np.array([np.cos(heading[t]), np.sin(heading[t])])
            self.heading.xy = tuple(xy[t] + 2.6 * self.shown * direction)
            self.heading.set_position(tuple(xy[t]))
            changed += [self.rays, self.heading]
        if self.waypoint is not None:
            self.waypoint.set_data(ep["waypoint"][t, :1], ep["waypoint"][t, 1:])
            changed.append(self.waypoint)
        if title is None:
            title = describe(ep) if t == int(ep["steps"]) else f"step {t}"
        # two short lines, never into a neighbour
        self.ax.set_title(textwrap.fill(title, 34), fontsize=8)
        # redrawn by hand in this order, so in the order a full draw would use
        return [*sorted(changed, key=lambda a: a.get_zorder()), self.ax.title]


def legend(fig: Any, episodes: Sequence[Episode]) -> Any:
    """One legend for all panels, below them (inside a panel it hides part of the maze): robot,
    goal, waypoint (where an episode has one), laser rays (robots), path, start."""
    from matplotlib.lines import Line2D

    marker = {"ls": "", "markersize": 8}
    handles = {
        "robot": Line2D([], [], marker="o", mfc=PATH_COLOR, mec="black", **marker),
        "goal": Line2D([], [], marker="*", color="tab:red", **marker),
        "waypoint": Line2D([], [], marker="X", color=WAYPOINT_COLOR, **marker),
        "laser rays": Line2D([], [], color=RAY_COLOR, lw=1),
        "path": Line2D([], [], color=PATH_COLOR, lw=1.5),
        "start": Line2D([], [], marker="o", color="tab:green", **marker),
    }
    if not any("waypoint" in ep for ep in episodes):
        del handles["waypoint"]
    if not any(is_robot(ep) for ep in episodes):
        del handles["laser rays"]
    return fig.legend(
        list(handles.values()), list(handles), loc="lower center", ncol=len(handles),
        fontsize=8, frameon=False, handlelength=1.5, columnspacing=1.0,
    )  # fmt: skip


def draw_episode(ax: Any, ep: Episode, upto: int | None = None, title: str | None = None) -> None:
    """Top-down view: walls, start (green), goal (red), the path up to step ``upto`` (default:
    the end), the robot there with its heading, its laser rays and waypoint at that pose only
    (rays of many poses are clutter)."""
    t = int(ep["steps"]) if upto is None else upto
    EpisodeArtists(ax, ep, animated=False).show(t, describe(ep) if title is None else title)


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
    """Static figure: each episode's whole path, with the laser rays of its last pose."""
    import matplotlib.pyplot as plt

    rows, cols = _grid_shape(len(episodes))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.8 * rows), squeeze=False)
    for ax, ep in zip(axes.ravel(), episodes, strict=False):
        draw_episode(ax, ep)
    for ax in axes.ravel()[len(episodes) :]:
        ax.axis("off")
    legend(fig, episodes)
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


def animation_figure(
    episodes: Sequence[Episode], title: str = ""
) -> tuple[Any, Callable[[int], list[Any]]]:
    """The GIF's figure, and ``show(t)``: moves every panel to step ``t`` and returns the
    artists that moved (the rest, walls, ticks and legend, never change)."""
    import matplotlib.pyplot as plt

    rows, cols = _grid_shape(len(episodes))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.4 * rows + 0.3), squeeze=False)
    try:
        panels = [
            EpisodeArtists(ax, ep, animated=True)
            for ax, ep in zip(axes.ravel(), episodes, strict=False)
        ]
        for ax in axes.ravel()[len(episodes) :]:
            ax.axis("off")
        for p in panels:  # the longest titles, so that the layout leaves room for them
            p.show(int(p.ep["steps"]))
        legend(fig, episodes)
        if title:
            fig.suptitle(title, fontsize=10)
        bottom = 0.3 / fig.get_figheight()
        fig.tight_layout(rect=(0, bottom, 1, 0.94 if title else 1))
    except BaseException:  # no half-built figure left open in pyplot
        plt.close(fig)
        raise

    def show(t: int) -> list[Any]:
        return [a for p in panels for a in p.show(t)]

    return fig, show


def save_gif(
    episodes: Sequence[Episode],
    path: Path,
    fps: int = 10,
    title: str = "",
    max_frames: int = 300,
    progress: Progress | None = None,
) -> int:
    """Animate the episodes side by side, one frame per step (every k-th step past
    ``max_frames``); written atomically. Returns the number of frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    progress = Progress(quiet=True) if progress is None else progress
    longest = max(int(ep["steps"]) for ep in episodes)
    stride = max(1, math.ceil((longest + 1) / max_frames))
    frames = list(range(0, longest + 1, stride))
    if frames[-1] != longest:
        frames.append(longest)
    fig, show = animation_figure(episodes, title)
    progress.begin()
    try:
        # the still parts drawn once; each frame redraws only the moving artists over them
        fig.canvas.draw()
        background = fig.canvas.copy_from_bbox(fig.bbox)
        images = []
        for i, t in enumerate(frames, 1):
            fig.canvas.restore_region(background)
            for artist in show(t):
                fig.draw_artist(artist)
            images.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
            progress.count("frame", i, len(frames))
    finally:
        plt.close(fig)
    # one palette, from the first and last frames (every colour is on one of them), for all
    palette = Image.fromarray(np.concatenate([images[0], images[-1]])).quantize(255)
    gif = [Image.fromarray(im).quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
    with atomic_output(path) as tmp:
        gif[0].save(
            tmp, format="GIF", save_all=True, append_images=gif[1:], duration=1000 / fps, loop=0
        )
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
    p.add_argument(
        "--quiet", action="store_true", help="no progress lines on stderr (compiling, frames)"
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Draw as the flags in ``argv`` (default: the command line's) say; the exit code."""
    prog = "jaxnav.render"
    try:
        args = parser().parse_args(argv)
        check_policy_source(args)
        defaulted = args.out is None
        if args.out is None:  # a run's pictures belong with the run, not in the cwd
            args.out = Path(f"{args.pretrained}.gif") if args.run is None else args.run / "traj.gif"
        if not 1 <= args.episodes <= 16:
            raise UsageError(f"--episodes {args.episodes}: must be in [1, 16]")
        if args.out.suffix not in OUT_SUFFIXES:
            raise UsageError(f"--out {args.out}: must end in {', '.join(OUT_SUFFIXES)}")
        try:
            check_output_file(args.out)  # a directory or a device is refused, not replaced
        except ValueError:
            if defaulted and args.run is not None:  # RUN/traj.gif: name the run, not its path
                run_dir.load_config(args.run)
            raise
        check_seed(args.seed)
        if not 1 <= args.fps <= 100:
            raise UsageError(f"--fps {args.fps}: out of range")
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
    progress = Progress(quiet=args.quiet)
    with progress.waiting("compiling and playing the episodes..."):
        # one compiled program, not one small compile per operation of the reset
        obs, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, env_params)
        episodes = record(env, env_params, policy, obs, state)
    who = f"pretrained {args.pretrained}" if args.pretrained else f"seed {run_seed}"
    title = f"{env.name}: {args.policy} policy ({who})"
    try:
        if args.out.suffix == ".gif":
            frames = save_gif(episodes, args.out, fps=args.fps, title=title, progress=progress)
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
