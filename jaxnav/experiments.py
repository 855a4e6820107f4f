"""The paper's experiments in one command: train the agents on several seeds, test them and
the random agent on the same fixed test episodes, write a results directory with figures.

    python -m jaxnav.experiments paper-grid  [--quick] [--seeds 5] [--out DIR]
    python -m jaxnav.experiments paper-robot [--quick] [--maze-file FILE]
    python -m jaxnav.experiments plot DIR    # redraw the figures of a results directory
    python -m jaxnav.experiments plot RUN    # a training run's curves: RUN/training_curves.png
    python -m jaxnav.experiments generalization RUN... [--family 'ENV_ID K=V ...'] [--out DIR]

Agents: ``dueling-double`` (the paper's model) and ``simple`` (plain DQN: dueling and double
off), each trained on all seeds at once (``vmap`` over seeds in one compiled program per agent
and training env, called once per logging interval for progress lines: ``runner.train_seeds``),
and ``random`` (a uniform action every step). Each test suite is a fixed
list of (start, goal, layout) drawn once from ``SUITE_SEED`` and replayed with
``env.reset_to``, so every agent and seed meets the same episodes.

A results directory holds ``results.json`` (every number, per seed, with mean and 95%
t-interval over seeds), ``results.md`` (the table), ``episodes.npz`` (per-episode outcomes
and recorded trajectories), the figures (``jaxnav.plots``) and ``runs/<study>-<agent>/``, run
directories as ``python -m jaxnav.train`` writes them (for ``jaxnav.evaluate`` and
``jaxnav.render``). It is written to a hidden sibling and renamed when complete.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxnav import run_dir
from jaxnav.agents.dqn import AGENT_LABELS, PAPER_AGENTS
from jaxnav.cli import (
    HelpFormatter,
    Parser,
    UsageError,
    check_seed,
    fail,
    one_line,
    parse_env_arg,
    write_failed,
)
from jaxnav.config import TrainConfig
from jaxnav.environment import Environment, EnvParams
from jaxnav.evaluate import (
    SEED_STATISTICS,
    evaluate_seeds,
    format_interval,
    format_value,
    mean_of,
    play,
    random_policy,
    seed_statistics,
    summarize,
    t_interval,
)
from jaxnav.programs import enable_compilation_cache
from jaxnav.registration import env_config, make, registered_envs
from jaxnav.runner import Progress, train_seeds
from jaxnav.safe_io import WriteFault, atomic_output, write_text
from jaxnav.train import Trainer

AGENTS = PAPER_AGENTS  # name -> the TrainConfig fields that make the agent
RANDOM = "random"
LABELS = AGENT_LABELS
SIZES = ("paper", "quick", "smoke")
SUITE_SEED = 20_240  # test episodes; independent of the training seeds
TRAJECTORY_EPISODES = 4  # recorded test episodes per suite (dueling-double, first seed)
# shipped with the package (examples/mazes links here), so an installed wheel has them
EXAMPLE_MAZE = Path(__file__).resolve().parent / "envs" / "robot" / "maze_files" / "rooms.txt"
METRICS = (
    "success_rate",
    "collision_rate",
    "timeout_rate",
    "mean_return",
    "mean_steps",
    "mean_episode_length",
    "mean_path_ratio",
    "spl",
)


# ------------------------------------------------------------------------------ presets
def grid_config(size: str) -> TrainConfig:
    """The grid experiment: jaxnav's defaults are the paper's grid setting (Sec. IV-A)."""
    paper = TrainConfig(env="GridMaze-v0")
    if size == "quick":  # a few minutes on a 2-core CPU
        return dataclasses.replace(
            paper, total_timesteps=96_000, eps_decay_steps=48_000, log_interval=8_000
        )
    if size == "smoke":  # seconds; checks the plumbing, learns little
        return _smoke(paper, {"size": 7})
    return paper


def robot_config(env_id: str, size: str, backend: str = "mjx") -> TrainConfig:
    """THE robot training settings, for every robot env of ``paper-robot``: the robot envs'
    tuned defaults (``TrainConfig.for_env``: 2M steps, 3-step returns, gamma 0.95) on
    ``backend``; ``quick`` and ``smoke`` only shrink the budget (too far for a robot to learn).
    """
    paper = TrainConfig.for_env(env_id, env_kwargs={"backend": backend})
    if size == "quick":
        return dataclasses.replace(
            paper, total_timesteps=48_000, eps_decay_steps=24_000, log_interval=8_000
        )
    if size == "smoke":
        return _smoke(paper, paper.env_kwargs)
    return paper


def _smoke(config: TrainConfig, env_kwargs: dict[str, Any]) -> TrainConfig:
    return dataclasses.replace(
        config,
        env_kwargs=env_kwargs,
        hidden_sizes=(32,),
        num_envs=8,
        total_timesteps=1_024,
        learning_starts=256,
        buffer_size=1_024,
        batch_size=32,
        replay_ratio=4.0,  # 32 sampled per step of the 8 envs: one gradient step an iteration
        log_interval=256,
        eps_decay_steps=512,
        target_update_period=128,
    )


@dataclasses.dataclass(frozen=True)
class Suite:
    """Fixed test episodes on one env. Layouts of the env's bank before ``first_layout`` are
    left out (a random-maze agent trained on layouts 0..N-1 is tested on unseen ones)."""

    name: str
    env: str
    env_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)
    first_layout: int = 0


@dataclasses.dataclass(frozen=True)
class Study:
    """One training env: the agents trained on it and the suites they are tested on."""

    name: str
    config: TrainConfig  # agent fields (dueling, double) are set per agent
    suites: tuple[Suite, ...]


def paper_grid(size: str) -> list[Study]:
    config = grid_config(size)
    return [Study("grid", config, (Suite(config.env, config.env, config.env_kwargs),))]


def paper_robot(size: str, maze_file: Path, backend: str = "mjx") -> list[Study]:
    studies = []
    for name, env_id in (("simple", "RobotSimple-v0"), ("complex", "RobotComplex-v0")):
        config = robot_config(env_id, size, backend)
        studies.append(Study(name, config, (Suite(env_id, env_id, config.env_kwargs),)))
    config = robot_config("RobotRandom-v0", size, backend)
    on = {"backend": backend}
    seen = env_config(config.env, **config.env_kwargs).num_layouts
    unseen = {**config.env_kwargs, "num_layouts": 2 * seen}  # layouts seen .. 2*seen-1
    generalization = (
        Suite(f"random mazes {seen}-{2 * seen - 1} (unseen)", config.env, unseen, seen),
        Suite("RobotSimple-v0 (unseen)", "RobotSimple-v0", on),
        Suite("RobotComplex-v0 (unseen)", "RobotComplex-v0", on),
        Suite(f"{maze_file.name} (unseen)", "RobotMaze-v0", {**on, "maze_file": str(maze_file)}),
    )
    studies.append(Study("random", config, generalization))
    return studies


# ---------------------------------------------------------------------------- test suites
def draw_suite(
    env: Environment, params: EnvParams, key: jax.Array, num: int
) -> dict[str, jax.Array]:
    """``num`` (start, goal, layout) triples, drawn once like fresh resets, in the env's terms
    (``env.reset_to_args``: e.g. a robot start is a pose (x, y, heading), a grid start a cell
    (row, col))."""
    _, states = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, num), params)
    start, goal, layout = jax.vmap(env.reset_to_args)(states)
    return {"start": start, "goal": goal, "layout": layout}


def start_suite(env: Environment, params: EnvParams, suite: dict[str, jax.Array]):
    """The suite's first observations and states, through ``env.reset_to``."""
    key = jax.random.key(0)  # reset_to is deterministic
    # vmapped, reset_to cannot check its arguments: a start in a wall is refused here
    env.check_reset_to(params, suite["start"], suite["goal"], suite["layout"])
    return jax.vmap(env.reset_to, in_axes=(None, None, 0, 0, 0))(
        key, params, suite["start"], suite["goal"], suite["layout"]
    )


def suite_env(suite: Suite) -> tuple[Environment, EnvParams]:
    env, params = make(suite.env, **suite.env_kwargs)
    if suite.first_layout:
        params = env.layouts_from(params, suite.first_layout)
    return env, params


def test_agent(
    trainer: Trainer | None,
    params: Any,
    env: Environment,
    env_params: EnvParams,
    suite: dict[str, jax.Array],
    key: jax.Array,
    num_seeds: int,
) -> dict[str, np.ndarray]:
    """Per-episode outcomes [seeds, episodes] of each seed's greedy policy on the suite
    (``trainer=None``: the random agent, one policy key per "seed")."""
    obs, state = start_suite(env, env_params, suite)
    max_steps = int(env_params.max_steps_in_episode)

    def one(p, k):
        policy = random_policy(env.num_actions) if trainer is None else trainer.greedy_policy(p)
        return play(env, env_params, policy, k, obs, state, max_steps)

    keys = jax.random.split(key, num_seeds)
    out = jax.jit(jax.vmap(one, in_axes=(None if trainer is None else 0, 0)))(params, keys)
    return {k: np.asarray(v) for k, v in out.items()}


def summarize_seeds(episodes: dict[str, np.ndarray]) -> list[dict[str, float | None]]:
    """``evaluate.summarize`` per seed, plus the mean length over all episodes; the path ratio
    is None where no shortest path is known."""
    rows = []
    for i in range(episodes["success"].shape[0]):
        one = {k: v[i] for k, v in episodes.items()}
        row: dict[str, float | None] = dict(summarize(one))
        row["mean_episode_length"] = float(one["steps"].mean())
        if not one["success"].any():  # no successful episode: no steps to average
            row["mean_steps"] = row["mean_path_ratio"] = None
        if not (one["shortest_path"] > 0).any():
            row["mean_path_ratio"] = None
        rows.append(row)
    return rows


def mean_ci(values: Sequence[float | None]) -> dict[str, float | None]:
    """Mean and the half-width of its 95% t-interval over seeds (None if undefined), and the
    number of seeds with a value (a seed without successes has no mean steps)."""
    x = np.asarray([v for v in values if v is not None], float)
    if len(x) == 0:
        return {"mean": None, "ci95": None, "seeds": 0}
    mean, half = t_interval(x)
    return {"mean": float(mean), "ci95": float(half) if len(x) > 1 else None, "seeds": len(x)}


# -------------------------------------------------------------------------------- running
def run_experiment(
    name: str,
    studies: list[Study],
    seeds: list[int],
    test_episodes: dict[str, int],
    out: Path,
    quiet: bool = False,
    command: str = "",
) -> dict[str, Any]:
    """Train, test and write ``out`` (see the module docstring); returns results.json's data."""
    from jaxnav import plots, render  # matplotlib only once there is something to draw

    t_start = time.perf_counter()
    partial = run_dir.partial_dir(out)
    shutil.rmtree(partial, ignore_errors=True)
    (partial / "runs").mkdir(parents=True)
    results: dict[str, Any] = {
        "experiment": name,
        "command": command,
        "seeds": seeds,
        "suite_seed": SUITE_SEED,
        "machine": run_dir.environment_info(),
        "training": {},
        "suites": {},
    }
    arrays: dict[str, np.ndarray] = {}
    num_jobs, job = len(studies) * len(AGENTS), 0
    for s_i, study in enumerate(studies):
        trained = {}
        for agent, fields in AGENTS.items():
            config = dataclasses.replace(
                study.config, num_seeds=len(seeds), seed=seeds[0], **fields
            )
            job += 1
            print(f"[{job}/{num_jobs}] {LABELS[agent]} on {config.env} ({study.name})", flush=True)
            trained[agent] = _train(config, partial / "runs" / f"{study.name}-{agent}", quiet)
            results["training"].setdefault(study.name, {})[agent] = trained[agent]["record"]
        for suite in study.suites:
            env, env_params = suite_env(suite)
            n = test_episodes[study.name]
            suite_key = jax.random.fold_in(jax.random.key(SUITE_SEED), s_i)
            episodes = draw_suite(env, env_params, suite_key, n)
            rows, t0 = {}, time.perf_counter()
            for agent in (*AGENTS, RANDOM):
                trainer = trained[agent]["trainer"] if agent != RANDOM else None
                params = trained[agent]["params"] if agent != RANDOM else None
                ep = test_agent(trainer, params, env, env_params, episodes, suite_key, len(seeds))
                per_seed = summarize_seeds(ep)
                rows[agent] = {
                    "per_seed": per_seed,
                    **{m: mean_ci([r[m] for r in per_seed]) for m in METRICS},
                }
                for k in ("return", "steps", "success", "collision", "timeout"):
                    arrays[f"{suite.name}/{agent}/{k}"] = ep[k]
            lead = trained["dueling-double"]
            policy = lead["trainer"].greedy_policy(jax.tree.map(lambda x: x[0], lead["params"]))
            first = jax.tree.map(lambda x: x[:TRAJECTORY_EPISODES], episodes)
            obs, state = start_suite(env, env_params, first)
            recorded = render.record(env, env_params, policy, obs, state)
            for i, ep_arrays in enumerate(recorded):
                for k, v in ep_arrays.items():
                    arrays[f"{suite.name}/trajectory/{i}/{k}"] = np.asarray(v)
            results["suites"][suite.name] = {
                "study": study.name,
                "env": suite.env,
                "env_kwargs": suite.env_kwargs,
                "first_layout": suite.first_layout,
                "test_episodes": n,
                "test_s": time.perf_counter() - t0,
                "agents": rows,
            }
            print_rows(suite.name, rows)
    results["wall_s_before_figures"] = time.perf_counter() - t_start
    with atomic_output(partial / "episodes.npz") as tmp:
        np.savez_compressed(tmp, **arrays)
    run_dir.write_json(partial / "results.json", results)
    write_text(partial / "results.md", results_markdown(results))
    plots.draw_all(partial, results, arrays)
    results["wall_s"] = time.perf_counter() - t_start
    run_dir.write_json(partial / "results.json", results)
    write_text(partial / "results.md", results_markdown(results))
    run_dir.complete(partial, out)
    print(f"\nwall time {results['wall_s']:.0f}s; results in {out}")
    return results


def _train(config: TrainConfig, path: Path, quiet: bool) -> dict[str, Any]:
    """One agent on all seeds in one compiled program; its run directory written to ``path``."""
    trainer = Trainer(config)
    state, metrics, compile_s, train_s = train_seeds(
        trainer, run_dir.seed_keys(config), Progress(config, quiet)
    )
    run_dir.create(path, trainer)
    run_dir.write_trained(path, config, metrics, state.params)
    print(f"    compile {compile_s:.1f}s, train {train_s:.1f}s", flush=True)
    record = {
        "env": config.env,
        "config": run_dir.config_to_json(config),
        "compile_s": compile_s,
        "train_s": train_s,
        "metrics": {k: v.tolist() for k, v in metrics.items()},
    }
    return {"trainer": trainer, "params": state.params, "record": record}


# -------------------------------------------------------------------------------- tables
def _cell(stat: dict[str, float | None], digits: int = 3, n_seeds: int | None = None) -> str:
    """``mean ± ci95``; with the seeds behind it where they are fewer than ``n_seeds`` or the
    interval is wider than the mean (a few seeds, far apart: read the interval with care)."""
    if stat["mean"] is None:
        return "n/a"
    ci = "" if stat["ci95"] is None else f" ± {stat['ci95']:.{digits}f}"
    seeds = stat.get("seeds")
    wide = stat["ci95"] is not None and stat["ci95"] > abs(stat["mean"])
    if seeds is not None and (wide or (n_seeds is not None and seeds < n_seeds)):
        ci += f" (n={seeds})"
    return f"{stat['mean']:.{digits}f}{ci}"


def results_markdown(results: dict[str, Any]) -> str:
    """The results table: per suite and agent, mean ± 95% CI over seeds."""
    n_seeds = len(results["seeds"])
    head = (
        "| suite | agent | success | collision | timeout | mean return | mean steps "
        "(successes) | mean episode length (steps) | path ratio | SPL |\n" + "|---" * 10 + "|\n"
    )
    lines = [
        f"# {results['experiment']}\n",
        f"Mean ± 95% t-interval over {n_seeds} seeds (random agent: {n_seeds} policy keys); "
        "each agent meets the same fixed test episodes of a suite. Mean steps and path ratio "
        "(path travelled / shortest path: grid steps / BFS moves, robot metres / "
        "any-angle metres to the goal disc) are over successful episodes; SPL (success "
        "weighted by path length: the mean of success x shortest / max(travelled, shortest)) "
        "over the episodes whose shortest path is known.\n\n",
        head,
    ]
    for suite_name, suite in results["suites"].items():
        for agent, row in suite["agents"].items():
            cells = [
                _cell(row[m], 2 if "steps" in m or "length" in m else 3, n_seeds) for m in METRICS
            ]
            lines.append(f"| {suite_name} | {LABELS[agent]} | " + " | ".join(cells) + " |\n")
    trained = results["training"]
    lines.append("\nTraining (all seeds in one program per agent):\n\n")
    lines.append("| study | agent | env | env steps per seed | compile s | train s |\n")
    lines.append("|---|---|---|---|---|---|\n")
    for study, agents in trained.items():
        for agent, rec in agents.items():
            lines.append(
                f"| {study} | {LABELS[agent]} | {rec['env']} | "
                f"{rec['metrics']['env_steps'][0][-1]:,} | {rec['compile_s']:.1f} | "
                f"{rec['train_s']:.1f} |\n"
            )
    if "wall_s" in results:
        lines.append(f"\nWall time {results['wall_s']:.0f} s. Command: `{results['command']}`\n")
    return "".join(lines)


def print_rows(suite: str, rows: dict[str, Any]) -> None:
    print(f"  {suite}:")
    for agent, row in rows.items():
        print(
            f"    {LABELS[agent]:<20} success {_cell(row['success_rate'])}  "
            f"return {_cell(row['mean_return'], 2)}  steps {_cell(row['mean_steps'], 1)}",
            flush=True,
        )


# ------------------------------------------------------------------------ generalization
# maze_seed (GridMaze: layout_seed, the same as grid_maze.HELD_OUT_LAYOUT_SEED) of the held-out
# mazes of the run's own env
HELD_OUT_MAZE_SEED = 1_000_003
EXAMPLE_MAZES = EXAMPLE_MAZE.parent
OWN = "own"  # a family's env: the run's own env id, with all its overrides
GENERALIZATION_METRICS = (
    "success_rate",
    "collision_rate",
    "timeout_rate",
    "worst10_success",
    "mean_path_ratio",
    "spl",
)


@dataclasses.dataclass(frozen=True)
class Family:
    """Mazes to test on: ``env`` (``OWN``: the run's env and all its overrides; another id:
    every setting of the run's env that differs from that id's, less the settings that choose
    the mazes, each env config's ``MAZE_FIELDS``) with ``env_kwargs`` on top."""

    name: str
    env: str
    env_kwargs: dict[str, Any] = dataclasses.field(default_factory=dict)

    def for_run(self, config: TrainConfig) -> tuple[str, dict[str, Any]]:
        """``(env id, env overrides)`` for a run trained with ``config``."""
        if self.env == OWN:
            return config.env, {**config.env_kwargs, **self.env_kwargs}
        # every setting of the run's env that differs from this env's (the run id's own
        # settings too, e.g. RobotNav-v0's sensors, observation, speed or backend), less the
        # maze-picking ones
        trained_config = env_config(config.env, **config.env_kwargs)
        target_config = env_config(self.env, **self.env_kwargs)
        mazes = trained_config.MAZE_FIELDS | target_config.MAZE_FIELDS
        trained = dataclasses.asdict(trained_config)
        target = dataclasses.asdict(target_config)
        carried = {
            k: v for k, v in trained.items() if k in target and k not in mazes and v != target[k]
        }
        return self.env, {**carried, **self.env_kwargs}


def default_families(config: TrainConfig, maze_seed: int = HELD_OUT_MAZE_SEED) -> list[Family]:
    """The run's own env on held-out mazes (``maze_seed``, where its env has that field; else
    its training mazes, named so), RobotSimple-v0, RobotComplex-v0 and every maze file of
    examples/mazes (RobotMaze-v0). A GridMaze run: its env on the layouts of ``layout_seed``
    ``maze_seed`` (the default shares none with the default training bank, see
    ``grid_maze.HELD_OUT_LAYOUT_SEED``) and on its training layouts; no robot family fits it."""
    fields = {f.name for f in dataclasses.fields(env_config(config.env, **config.env_kwargs))}
    if "layout_seed" in fields:
        return [
            Family(
                f"{config.env} layout_seed={maze_seed} (held out)",
                OWN,
                {"layout_seed": maze_seed},
            ),
            Family(f"{config.env} (training layouts)", OWN),
        ]
    if "maze_seed" in fields:
        own = Family(
            f"{config.env} maze_seed={maze_seed} (held out)", OWN, {"maze_seed": maze_seed}
        )
    else:
        own = Family(f"{config.env} (training mazes: no maze_seed to hold out)", OWN)
    files = [
        # slots to spare: an env uses as many as its maze needs
        Family(
            f"{f.name} (RobotMaze-v0)", "RobotMaze-v0", {"maze_file": str(f), "num_wall_slots": 64}
        )
        for f in sorted(EXAMPLE_MAZES.glob("*.txt"))
    ]
    robots = [Family(e, e) for e in ("RobotSimple-v0", "RobotComplex-v0")]
    return [own, *robots, *files]


def parse_family(text: str) -> Family:
    """``"ENV_ID KEY=VALUE ..."`` (``own`` for the run's env) as a ``Family`` named ``text``."""
    tokens = text.split()
    if not tokens:
        raise ValueError(f"--family {text!r}: give an env id, then KEY=VALUE overrides")
    env, *pairs = tokens
    if env != "own" and env not in registered_envs():  # a typo, not a family to skip
        raise ValueError(f"--family {text!r}: unknown env id {env!r} (or own)")
    kwargs = {}
    for pair in pairs:
        try:
            key, value = parse_env_arg(pair)
        except argparse.ArgumentTypeError as e:
            raise ValueError(f"--family {text!r}: {e}") from None
        kwargs[key] = value
    return Family(text, env, kwargs)


def evaluate_family(
    runs: Sequence[Path], family: Family, episodes: int, seed: int
) -> dict[str, Any]:
    """Every seed of every run on ``family`` (``evaluate.evaluate_seeds``, the same episodes
    for all): means over seeds, IQM and bootstrap 95% intervals of the success rates
    (``evaluate.seed_statistics``), per-seed rows; ``skipped`` lists runs the family does not
    fit (a bad override, observations of another size), with the reason."""
    rows: list[dict[str, Any]] = []
    skipped: list[str] = []
    env_kwargs: dict[str, Any] = {}
    env = family.env
    mazes = None
    for run in runs:
        try:
            env, env_kwargs = family.for_run(run_dir.load_config(run))
            _, trainer, params = run_dir.load_run_on(run, env, env_kwargs)
        except (ValueError, FileNotFoundError) as e:
            skipped.append(f"{run}: {one_line(str(e))}")
            continue
        mazes = trainer.env.num_layouts(trainer.env_params)
        for row in evaluate_seeds(trainer, params, episodes, seed):
            rows.append({"run": str(run), **row})
    out: dict[str, Any] = {
        "env": env,
        "env_kwargs": env_kwargs,
        "mazes": mazes,
        "episodes": episodes,
        "seeds": len(rows),
        "skipped": skipped,
    }
    if rows:
        means = mean_of([{k: v for k, v in r.items() if k != "run"} for r in rows])
        out["mean"] = {m: means[m] for m in GENERALIZATION_METRICS}
        out["over_seeds"] = {m: seed_statistics([r[m] for r in rows]) for m in SEED_STATISTICS}
    out["per_seed"] = rows
    return out


def generalization_markdown(results: dict[str, Any]) -> str:
    """One row per family: means over seeds, success IQM with its 95% bootstrap interval."""
    lines = [
        "# Generalization\n\n",
        f"Runs: {', '.join(results['runs'])}. {results['episodes']} episodes per family and "
        "seed, round-robin over the family's mazes. Success, collision, timeout, worst-10% "
        "success (the mean success of the ceil(10%) of mazes with the lowest success) and path "
        "ratio (path travelled / shortest path, successful episodes; n/a where no shortest "
        "path is known) and SPL (success weighted by path length, over the episodes whose "
        "shortest path is known) are means over seeds; IQM of the per-seed success with a 95% "
        "percentile bootstrap interval over seeds.\n\n",
        "| family | seeds | mazes | success | collision | timeout | worst-10% success | "
        "success IQM [95% CI] | path ratio | SPL |\n",
        "|---" * 10 + "|\n",
    ]
    for name, fam in results["families"].items():
        if not fam["seeds"]:
            lines.append(f"| {name} | 0 | | | | | | | | |\n")
            continue
        m = fam["mean"]
        cells = [format_value(m[k]) for k in GENERALIZATION_METRICS[:4]]
        iqm_cell = format_interval(fam["over_seeds"]["success_rate"], "iqm")
        lines.append(
            f"| {name} | {fam['seeds']} | {fam['mazes']} | "
            + " | ".join(cells)
            + f" | {iqm_cell} | {format_value(m['mean_path_ratio'])} | {format_value(m['spl'])} |\n"
        )
    notes = [
        f"- {name}: skipped {s}\n" for name, f in results["families"].items() for s in f["skipped"]
    ]
    if notes:
        lines += ["\nNot evaluated:\n\n", *notes]
    return "".join(lines)


def trajectories_gif(run: Path, family: Family, episodes: int, seed: int, path: Path) -> str:
    """Record ``episodes`` greedy episodes of the run's first seed on ``family`` (test key
    ``seed``) into the GIF ``path``; returns one line per episode's outcome."""
    from jaxnav import render  # matplotlib only once there is something to draw

    env_id, kwargs = family.for_run(run_dir.load_config(run))
    config, trainer, params = run_dir.load_run_on(run, env_id, kwargs)
    policy = trainer.greedy_policy(jax.tree.map(lambda x: x[0], params))
    env, env_params = trainer.env, trainer.env_params
    keys = jax.random.split(jax.random.key(seed), episodes)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, env_params)
    recorded = render.record(env, env_params, policy, obs, state)
    title = f"{family.name}: greedy policy of {run.name} (seed {config.seed})"
    render.save_gif(recorded, path, title=title)
    return "; ".join(render.describe(ep) for ep in recorded)


def generalization_main(args: argparse.Namespace, command: str) -> int:
    """``generalization``: evaluate the runs on each family and write results.json/.md."""
    prog = "jaxnav.experiments"
    try:
        if not 1 <= args.episodes <= 10**7:
            raise ValueError(f"--episodes {args.episodes}: must be in [1, 10000000]")
        check_seed(args.seed)
        if not 0 <= args.gifs <= 16:
            raise ValueError(f"--gifs {args.gifs}: must be in [0, 16]")
        configs = [run_dir.load_config(run) for run in args.runs]
        if args.family:
            families = [parse_family(f) for f in args.family]
        else:
            families = default_families(configs[0], args.maze_seed)
        out = args.out or Path("runs") / f"generalization-{time.strftime('%Y%m%d-%H%M%S')}"
        run_dir.check_writable(out)
    except (UsageError, ValueError, FileNotFoundError) as e:
        return fail(prog, str(e))
    enable_compilation_cache()
    results: dict[str, Any] = {
        "experiment": "generalization",
        "command": command,
        "runs": [str(r) for r in args.runs],
        "episodes": args.episodes,
        "seed": args.seed,
        "families": {},
    }
    for fam in families:
        res = evaluate_family(args.runs, fam, args.episodes, args.seed)
        results["families"][fam.name] = res
        done = f"{res['seeds']} seeds" if res["seeds"] else "skipped"
        print(f"  {fam.name}: {done}", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    run_dir.write_json(out / "results.json", results)
    table = generalization_markdown(results)
    write_text(out / "results.md", table)
    print(table)
    for fam in families:  # trajectories on each hand-drawn maze, where the run fits it
        maze_file = fam.env_kwargs.get("maze_file")
        if args.gifs and maze_file and results["families"][fam.name]["seeds"]:
            path = out / f"trajectories-{Path(maze_file).stem}.gif"
            outcomes = trajectories_gif(args.runs[0], fam, args.gifs, args.seed, path)
            print(f"wrote {path}: {outcomes}")
    print(f"results in {out}")
    return 0


# ---------------------------------------------------------------------------- command line
def parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    size = common.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="a few minutes on a laptop CPU")
    size.add_argument("--smoke", action="store_true", help="seconds; for tests (learns little)")
    common.add_argument("--seeds", type=int, default=5, help="training seeds per agent (>= 2)")
    common.add_argument("--seed", type=int, default=0, help="first seed")
    common.add_argument("--total-timesteps", type=int, help="env steps per seed (overrides)")
    common.add_argument("--test-episodes", type=int, help="episodes per test suite")
    common.add_argument("--out", type=Path, help="results directory (default: runs/<name>-<time>)")
    common.add_argument("--quiet", action="store_true", help="no per-interval progress lines")
    p = Parser(prog="python -m jaxnav.experiments", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="experiment", required=True, parser_class=Parser)
    sub.add_parser(
        "paper-grid",
        parents=[common],
        help="Fig. 4: grid, 1000 test episodes",
        formatter_class=HelpFormatter,
    )
    robot = sub.add_parser(
        "paper-robot",
        parents=[common],
        help="Fig. 7: robot mazes and generalization, 100 test episodes",
        formatter_class=HelpFormatter,
    )
    robot.add_argument(
        "--maze-file",
        type=Path,
        default=EXAMPLE_MAZE,
        help="a maze never trained on, for the generalization rows",
    )
    robot.add_argument(
        "--backend",
        choices=("mjx", "kinematic"),
        default="mjx",
        help="robot physics: MuJoCo MJX or the exact pure-JAX unicycle (faster on CPU)",
    )
    gen = sub.add_parser(
        "generalization",
        help="evaluate trained runs on maze families never trained on",
        formatter_class=HelpFormatter,
    )
    gen.add_argument("runs", type=Path, nargs="+", metavar="RUN", help="run directories")
    gen.add_argument(
        "--family",
        action="append",
        metavar="'ENV_ID [KEY=VALUE ...]'",
        help="a family to test on, repeatable; 'own' as ENV_ID is the run's env with all its "
        "overrides, another id gets the run's overrides but the maze-picking ones (default: "
        "own env with a held-out maze_seed, RobotSimple-v0, RobotComplex-v0, each maze file of "
        "examples/mazes)",
    )
    gen.add_argument(
        "--maze-seed",
        type=int,
        default=HELD_OUT_MAZE_SEED,
        help="maze_seed (GridMaze: layout_seed) of the own env's held-out mazes",
    )
    gen.add_argument("--episodes", type=int, default=1000, help="episodes per family and seed")
    gen.add_argument("--seed", type=int, default=0, help="seed of the test episodes")
    gen.add_argument(
        "--gifs",
        type=int,
        default=4,
        help="episodes in a trajectory GIF per maze-file family (first run, first seed; 0: none)",
    )
    gen.add_argument("--out", type=Path, help="results directory (default: runs/<name>-<time>)")
    plot = sub.add_parser(
        "plot",
        help="redraw the figures of a results directory, or draw a training run's curves "
        "(RUN/training_curves.png from its metrics.csv)",
    )
    plot.add_argument("dir", type=Path, help="a results directory or a run directory")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the experiment ``argv`` (default: the command line's) names; the exit code."""
    try:
        return _main(argv)
    except WriteFault as e:  # a full disk, a read-only directory: one line, nothing partial
        return write_failed("jaxnav.experiments", e)
    except ValueError as e:  # an output that is a link or a device, found when writing it
        return fail("jaxnav.experiments", str(e))


def _main(argv: Sequence[str] | None) -> int:
    prog = "jaxnav.experiments"
    try:
        args = parser().parse_args(argv)
        if args.experiment == "plot":
            return _replot(args.dir)
        if args.experiment == "generalization":
            command = "python -m jaxnav.experiments " + " ".join(
                sys.argv[1:] if argv is None else list(argv)
            )
            return generalization_main(args, command)
        size = "quick" if args.quick else "smoke" if args.smoke else "paper"
        if not 2 <= args.seeds <= 4096:
            raise UsageError(f"--seeds {args.seeds}: must be in [2, 4096] (a CI needs 2)")
        check_seed(args.seed)
        if args.test_episodes is not None and not 1 <= args.test_episodes <= 10**6:
            raise UsageError(f"--test-episodes {args.test_episodes}: must be in [1, 1000000]")
        if args.experiment == "paper-grid":
            studies = paper_grid(size)
        else:
            if not args.maze_file.is_file():
                raise UsageError(f"--maze-file {args.maze_file}: no such file")
            studies = paper_robot(size, args.maze_file.resolve(), args.backend)
        if args.total_timesteps is not None:
            studies = [
                dataclasses.replace(
                    s, config=dataclasses.replace(s.config, total_timesteps=args.total_timesteps)
                )
                for s in studies
            ]
        for study in studies:  # every value checked before anything is trained or written
            study.config.validate()
        rounded = [s.config.whole_intervals() for s in studies]  # the steps a run trains
        studies = [
            dataclasses.replace(s, config=c) for s, (c, _) in zip(studies, rounded, strict=True)
        ]
        for study in studies:
            for suite in study.suites:
                cfg = env_config(suite.env, **suite.env_kwargs)
                if suite.first_layout and cfg.num_layouts <= suite.first_layout:
                    raise UsageError(f"suite {suite.name}: no layouts after {suite.first_layout}")
        default_episodes = 1000 if args.experiment == "paper-grid" else 100
        if size == "smoke":
            default_episodes = 20
        episodes = {s.name: args.test_episodes or default_episodes for s in studies}
        out = args.out or Path("runs") / f"{args.experiment}-{time.strftime('%Y%m%d-%H%M%S')}"
        run_dir.check_writable(out)
    except (UsageError, ValueError) as e:
        return fail(prog, str(e))
    for note in dict.fromkeys(note for _, note in rounded if note):
        print(note)
    enable_compilation_cache()
    seeds = [args.seed + i for i in range(args.seeds)]
    command = "python -m jaxnav.experiments " + " ".join(
        sys.argv[1:] if argv is None else list(argv)
    )
    run_experiment(args.experiment, studies, seeds, episodes, out, args.quiet, command)
    return 0


def _replot(directory: Path) -> int:
    from jaxnav import plots

    if (directory / "metrics.csv").is_file() and not (directory / "results.json").is_file():
        try:  # one training run
            config = run_dir.load_config(directory)
            metrics = plots.read_run_metrics(directory)
            fig = plots.run_curves(metrics, f"{config.env} ({config.algo})")
        except (OSError, ValueError, KeyError) as e:
            return fail("jaxnav.experiments", f"{directory}: unreadable run ({e})")
        path = directory / "training_curves.png"
        plots.save(fig, path)
        print(f"wrote {path}")
        return 0
    try:
        results = json.loads((directory / "results.json").read_text())
        with np.load(directory / "episodes.npz") as f:
            arrays = dict(f)
    except (OSError, ValueError, KeyError) as e:
        return fail("jaxnav.experiments", f"{directory}: not a results directory ({e})")
    plots.draw_all(directory, results, arrays)
    print(f"figures redrawn in {directory}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
