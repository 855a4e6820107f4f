"""Figures of an experiment's results directory (``jaxnav.experiments``), as PNG files, and of
one training run (``python -m jaxnav.experiments plot RUN``: ``RUN/training_curves.png``).

``draw_all`` reads only ``results.json``'s data and ``episodes.npz``'s arrays, so a results
directory can be redrawn (``python -m jaxnav.experiments plot DIR``) or loaded in a notebook:

- ``training_curves.png``: per training env, loss (log scale), return, episode length and
  success rate over env steps; mean and 95% t-band over seeds per agent.
- ``test_comparison.png``: per test suite, return and steps of each test episode (mean over
  seeds) per agent, as the paper's Fig. 4d/e and 7a/b.
- ``outcomes.png``: per test suite, success / collision / timeout rates per agent, with 95%
  intervals over seeds.
- ``trajectories.png``: recorded test episodes of the dueling double DQN (first seed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only; notebooks show the returned figures themselves
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from jaxnav import render  # noqa: E402
from jaxnav.agents.dqn import AGENT_LABELS as LABELS  # noqa: E402
from jaxnav.evaluate import t_interval  # noqa: E402
from jaxnav.safe_io import atomic_output  # noqa: E402

COLORS = {"dueling-double": "tab:blue", "simple": "tab:orange", "random": "tab:gray"}
CURVES = (
    ("loss", "TD loss (log scale)"),
    ("mean_return", "episode return"),
    ("mean_length", "episode length (steps)"),
    ("success_rate", "success rate"),
)
FIRST_EPISODES = 100  # test episodes shown one by one in the comparison


def steps_axis(ax: Any) -> None:
    """Env steps as 100k, 2M, ...: at most 5 ticks, so their labels never run together."""
    from matplotlib.ticker import EngFormatter, MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.xaxis.set_major_formatter(EngFormatter(sep=""))


def read_run_metrics(run: Path) -> dict[str, np.ndarray]:
    """A run directory's metrics.csv as ``{metric: float[seeds, logs]}`` (``env_steps`` too),
    seeds in the order they first appear."""
    import csv

    with (run / "metrics.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{run / 'metrics.csv'}: no rows")
    seeds = list(dict.fromkeys(r["seed"] for r in rows))
    by_seed = [[r for r in rows if r["seed"] == s] for s in seeds]
    names = [k for k in rows[0] if k != "seed"]
    return {k: np.array([[float(r[k]) for r in rs] for rs in by_seed]) for k in names}


def curve_axis(ax: Any, metric: str, title: str) -> None:
    """Scales, ticks, labels and grid of a training-curve panel of ``metric``."""
    if metric == "loss":
        ax.set_yscale("log")
    if metric == "success_rate":
        ax.set_ylim(-0.02, 1.02)
    steps_axis(ax)
    ax.set_xlabel("env steps per seed")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)


def run_curves(metrics: dict[str, np.ndarray], title: str) -> Any:
    """One run's training curves (``CURVES``): each seed thin, the mean over seeds thick with
    its 95% t-band when there are several."""
    steps = metrics["env_steps"][0]
    n_seeds = metrics["env_steps"].shape[0]
    fig, axes = plt.subplots(1, len(CURVES), figsize=(3.6 * len(CURVES), 3.2), squeeze=False)
    for ax, (metric, label) in zip(axes[0], CURVES, strict=True):
        values = np.asarray(metrics[metric], float)
        if metric == "loss":  # no updates yet during warm-up: nothing to plot
            values = np.where(values > 0, values, np.nan)
        for v in values:
            ax.plot(steps, v, color="tab:blue", lw=0.7, alpha=0.35 if n_seeds > 1 else 1.0)
        if n_seeds > 1:
            mean, half = t_interval(values)
            ax.plot(steps, mean, color="tab:blue", lw=2)
            ax.fill_between(steps, mean - half, mean + half, color="tab:blue", alpha=0.2)
        curve_axis(ax, metric, label)
    seeds = f"{n_seeds} seeds, mean and 95% CI" if n_seeds > 1 else "1 seed"
    fig.suptitle(f"{title}: training (epsilon-greedy episodes), {seeds}", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.92))
    return fig


def training_curves(results: dict[str, Any]) -> Any:
    studies = results["training"]
    n_seeds = len(results["seeds"])
    fig, axes = plt.subplots(
        len(studies), len(CURVES), figsize=(4 * len(CURVES), 3.2 * len(studies)), squeeze=False
    )
    for row, agents in zip(axes, studies.values(), strict=True):
        for ax, (metric, label) in zip(row, CURVES, strict=True):
            for agent, rec in agents.items():
                m = rec["metrics"]
                steps = np.asarray(m["env_steps"][0])
                values = np.asarray(m[metric], float)
                if metric == "loss":  # no updates yet during warm-up: nothing to plot
                    values = np.where(values > 0, values, np.nan)
                mean, half = t_interval(values)
                ax.plot(steps, mean, color=COLORS[agent], label=LABELS[agent])
                ax.fill_between(steps, mean - half, mean + half, color=COLORS[agent], alpha=0.25)
            curve_axis(ax, metric, f"{next(iter(agents.values()))['env']}: {label}")
        row[0].legend(fontsize=8)
    fig.suptitle(
        f"Training (epsilon-greedy episodes), mean and 95% CI over {n_seeds} seeds", fontsize=11
    )
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.06 / len(studies)))
    return fig


def test_comparison(results: dict[str, Any], arrays: dict[str, np.ndarray]) -> Any:
    suites = results["suites"]
    fig, axes = plt.subplots(len(suites), 2, figsize=(12, 3.2 * len(suites)), squeeze=False)
    for row, (name, suite) in zip(axes, suites.items(), strict=True):
        shown = min(FIRST_EPISODES, suite["test_episodes"])
        x = np.arange(1, shown + 1)
        for ax, key, label in zip(row, ("return", "steps"), ("return", "steps"), strict=True):
            for agent in suite["agents"]:
                per_episode = np.asarray(arrays[f"{name}/{agent}/{key}"], float).mean(axis=0)
                ax.plot(
                    x,
                    per_episode[:shown],
                    color=COLORS[agent],
                    lw=1,
                    marker=".",
                    ms=3,
                    label=f"{LABELS[agent]} (mean of all {suite['test_episodes']}: "
                    f"{per_episode.mean():.2f})",
                )
            ax.set_xlabel(f"test episode (first {shown} of {suite['test_episodes']})")
            ax.set_ylabel(f"{label} per episode (mean over seeds)")
            ax.set_title(f"{name}: {label} per test episode", fontsize=10)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def outcomes(results: dict[str, Any]) -> Any:
    suites = results["suites"]
    cols = min(3, len(suites))
    rows = -(-len(suites) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.6 * rows), squeeze=False)
    kinds = (
        ("success_rate", "success"),
        ("collision_rate", "collision"),
        ("timeout_rate", "timeout"),
    )
    for ax, (name, suite) in zip(axes.ravel(), suites.items(), strict=False):
        agents = list(suite["agents"])
        width = 0.8 / len(agents)
        for i, agent in enumerate(agents):
            row = suite["agents"][agent]
            means = [row[k]["mean"] for k, _ in kinds]
            half = [row[k]["ci95"] or 0.0 for k, _ in kinds]
            # the interval clipped to [0, 1]: rates cannot leave it
            errs = [np.minimum(half, means), np.minimum(half, 1 - np.asarray(means))]
            pos = np.arange(len(kinds)) + (i - (len(agents) - 1) / 2) * width
            bars = ax.bar(
                pos, means, width, yerr=errs, capsize=3, color=COLORS[agent], label=LABELS[agent]
            )
            ax.bar_label(bars, labels=[f"{m:.2f}" for m in means], fontsize=7, padding=2)
        ax.set_xticks(np.arange(len(kinds)), [label for _, label in kinds])
        ax.set_ylim(0, 1.12)
        ax.set_ylabel(f"rate over {suite['test_episodes']} test episodes")
        ax.set_title(name, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    for ax in axes.ravel()[len(suites) :]:
        ax.axis("off")
    fig.suptitle(f"Test outcomes, mean and 95% CI over {len(results['seeds'])} seeds", fontsize=11)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8)
    fig.tight_layout(rect=(0, 0.1 / rows, 1, 1 - 0.06 / rows))
    return fig


def trajectory_episodes(arrays: dict[str, np.ndarray], suite: str) -> list[render.Episode]:
    prefix = f"{suite}/trajectory/"
    episodes: dict[int, render.Episode] = {}
    for key, value in arrays.items():
        if key.startswith(prefix):
            index, field = key[len(prefix) :].split("/")
            episodes.setdefault(int(index), {})[field] = value
    return [episodes[i] for i in sorted(episodes)]


def trajectories(results: dict[str, Any], arrays: dict[str, np.ndarray]) -> Any:
    suites = [s for s in results["suites"] if trajectory_episodes(arrays, s)]
    cols = max(len(trajectory_episodes(arrays, s)) for s in suites)
    fig, axes = plt.subplots(
        len(suites), cols, figsize=(3.4 * cols, 3.6 * len(suites)), squeeze=False
    )
    for row, suite in zip(axes, suites, strict=True):
        episodes = trajectory_episodes(arrays, suite)
        for ax, ep in zip(row, episodes, strict=False):
            render.draw_episode(ax, ep)
        for ax in row[len(episodes) :]:
            ax.axis("off")
        row[0].set_ylabel(suite, fontsize=9)
    shown = [ep for suite in suites for ep in trajectory_episodes(arrays, suite)]
    render.legend(fig, shown)
    lasers = any(render.is_robot(ep) for ep in shown)
    fig.suptitle(
        "Dueling double DQN (first seed, greedy) on test episodes: path, start, goal"
        + (", laser rays at the last pose" if lasers else ""),
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0.05 / len(suites), 1, 1 - 0.06 / len(suites)))
    return fig


def draw_all(directory: Path, results: dict[str, Any], arrays: dict[str, np.ndarray]) -> list[Path]:
    """Write every figure into ``directory``; returns their paths."""
    figures = {
        "training_curves.png": training_curves(results),
        "test_comparison.png": test_comparison(results, arrays),
        "outcomes.png": outcomes(results),
        "trajectories.png": trajectories(results, arrays),
    }
    paths = []
    for name, fig in figures.items():
        path = Path(directory) / name
        save(fig, path)
        paths.append(path)
    return paths


def save(fig: Any, path: Path) -> None:
    """Write ``fig`` to ``path`` through ``safe_io.atomic_output`` and close it."""
    try:
        with atomic_output(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
