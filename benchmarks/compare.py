"""jaxnav against its peers in one run: env throughput, DQN or PQN training time, CLI start-up.

    python -m benchmarks.compare [--num-envs 1,16,256,4096,16384] [--envs NAME,...]
        [--steps 200] [--target-s 0.5] [--rounds 3] [--train-config JSON]
        [--train-networks 512,256,128,64;64,64] [--train-seeds 0] [--eval-episodes 256]
        [--threshold 0.95] [--final-eval-episodes 2048] [--train-peer-options]
        [--sections env,train,compile] [--out benchmarks/results/compare.json]
    python -m benchmarks.compare --render --out RESULT.json
    python -m benchmarks.compare --merge RESULT.json... --out MERGED.json

Sections (each can be left out with ``--sections``):

- ``env``: env steps/s of random actions for our envs and the peers', each through its own
  ``make`` and auto-resetting ``step`` (``vmap`` of it; ours: ``step_batch``, the same results),
  jit + a loop of steps, rows of one num_envs timed in turn (``benchmarks.env_throughput``:
  compile time apart, XLA's peak memory per program). Ratios pair each of ours with the peer it
  is measured against: GridMaze-v0 / gymnax FourRooms-misc, GridMaze-Random-v0 / navix FourRooms
  (both draw a new layout per episode), and the robot (MJX and kinematic backends, a random maze
  per episode) / jaxmarl's JaxNav with one agent. A PNG plots steps/s against num_envs.
- ``train``: our DQN (or PQN, ``"algo": "pqn"`` in ``--train-config``) against rejax's with
  the same network, batch, replay ratio and steps (``benchmarks.train_vs_rejax``): wall time,
  the ratio, time to a greedy success threshold, compile time apart. The config is the CLI's
  default (the paper's grid experiment) with ``--train-config`` overrides, a JSON object of
  ``TrainConfig`` fields, applied after the preset of its ``env`` and ``algo`` as the CLI does. It
  runs once per network of ``--train-networks``: by default the config's (the paper's
  512-256-128-64) and rejax's default MLP (64, 64). With the large one both spend most of their
  time in the same gradient arithmetic; with the small one, in what surrounds it.
  ``--train-peer-options`` compiles rejax's programs with our XLA options too. Each side's
  final policy is evaluated once more on ``--final-eval-episodes`` other fresh episodes, which
  tells two final policies apart where one check of ``--eval-episodes`` cannot.
- ``compile``: every CLI entry point started twice, with an empty and then a filled persistent
  compilation cache (``benchmarks.compile_time``).

Writes the JSON, a markdown copy of the tables (same name, ``.md``) and the plot (``.png``).
``--render`` measures nothing: it writes the markdown of an earlier run's JSON (``--out``) again
with the tables of this version. ``--merge`` measures nothing either: it writes one result (JSON
and markdown, its summary with the means over seeds) of the train runs of several result files
of the same comparison, such as one seed a process; each file's command and machine stay in
``merged_from``.
Nothing here assumes a CPU: on a GPU pass larger sizes, e.g. ``--num-envs
1024,16384,262144``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import sys
from pathlib import Path
from typing import Any

import jax

from benchmarks import compile_time, env_throughput, train_vs_rejax
from benchmarks.common import (
    machine_info,
    machine_text,
    train_config,
    write_results,
    write_whole,
)
from jaxnav.config import TrainConfig
from jaxnav.host import package_version
from jaxnav.safe_io import check_output_file

DEFAULT_OUT = Path("benchmarks/results/compare.json")
SECTIONS = ("env", "train", "compile")
REJAX_DEFAULT_NETWORK = (64, 64)  # rejax 0.1.3's DQN MLP
NAVIX, JAXMARL = env_throughput.NAVIX, env_throughput.JAXMARL
DEFAULT_ENVS = (
    "GridMaze-v0",
    "GridMaze-Random-v0",
    "RobotRandom-v0 mjx",
    "RobotRandom-v0 kinematic",
    *env_throughput.PEER_ENVS,
)
# ours -> (peer, the target ratio on one GPU, measured in the same run; None: no target)
PAIRS = {
    "GridMaze-v0": ("FourRooms-misc", 1.0),
    env_throughput.ONEHOT: ("FourRooms-misc", None),
    "GridMaze-Random-v0": (NAVIX, 10.0),
    "RobotRandom-v0 mjx": (JAXMARL, 4.0),
    "RobotRandom-v0 kinematic": (JAXMARL, 300.0),
    "RobotSimple-v0 mjx": (JAXMARL, 4.0),
    "RobotSimple-v0 kinematic": (JAXMARL, 300.0),
}


def env_section(args: argparse.Namespace) -> dict[str, Any]:
    envs, skipped = env_throughput.usable(args.envs)
    rows, out_of_memory = [], {}
    for n in args.num_envs:
        for row in env_throughput.measure_interleaved(
            envs, n, args.steps, args.rounds, args.target_s, out_of_memory
        ):
            print(
                f"{row['env']:26s} {n:7d} envs: compile {row['compile_s']:6.2f} s, "
                f"{row['steps_per_s']:15,.0f} steps/s",
                file=sys.stderr,
            )
            rows.append(row)
    return {
        "skipped": skipped,
        "out_of_memory": out_of_memory,
        "rows": rows,
        "ratios": ratios(rows),
    }


def ratios(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Ours / paired peer at every num_envs where both were measured."""
    sps = {(r["env"], r["num_envs"]): r["steps_per_s"] for r in rows}
    out = []
    for (env, n), ours in sps.items():
        if env in PAIRS and (PAIRS[env][0], n) in sps:
            peer, target = PAIRS[env]
            out.append(
                {
                    "ours": env,
                    "peer": peer,
                    "num_envs": n,
                    "ratio": ours / sps[(peer, n)],
                    "gpu_target": target,
                }
            )
    return out


def env_tables(section: dict[str, Any]) -> str:
    rows = section["rows"]
    sizes = sorted({r["num_envs"] for r in rows})
    envs = list(dict.fromkeys(r["env"] for r in rows))
    by = {(r["env"], r["num_envs"]): r for r in rows}
    head = "| env | " + " | ".join(f"{n} envs" for n in sizes)
    lines = [
        head + " | compile s | peak MB (largest) |",
        "|---|" + "---:|" * (len(sizes) + 2),
    ]
    for env in envs:
        cells = [by.get((env, n)) for n in sizes]
        sps = " | ".join("-" if c is None else f"{c['steps_per_s']:,.0f}" for c in cells)
        compiles = [c["compile_s"] for c in cells if c is not None]
        peak = [c for c in cells if c is not None][-1]["peak_bytes"]
        mb = "-" if peak is None else f"{peak / 2**20:,.1f}"
        lines.append(f"| {env} | {sps} | {min(compiles):.1f}-{max(compiles):.1f} | {mb} |")
    pairs = list(dict.fromkeys((r["ours"], r["peer"]) for r in section["ratios"]))
    if pairs:
        by_ratio = {(r["ours"], r["num_envs"]): r for r in section["ratios"]}
        lines += [
            "",
            "| ours / peer (steps/s) | "
            + " | ".join(f"{n} envs" for n in sizes)
            + " | target on one GPU |",
            "|---|" + "---:|" * (len(sizes) + 1),
        ]
        for ours, peer in pairs:
            cells = [by_ratio.get((ours, n)) for n in sizes]
            text = " | ".join("-" if c is None else f"{c['ratio']:.2f}" for c in cells)
            target = PAIRS[ours][1]
            goal = "-" if target is None else f">= {target:g}"
            lines.append(f"| {ours} / {peer} | {text} | {goal} |")
    if section["skipped"]:
        lines += ["", "Skipped: " + "; ".join(f"{k} ({v})" for k, v in section["skipped"].items())]
    if section["out_of_memory"]:
        lines += ["", "Out of memory, left out: " + "; ".join(section["out_of_memory"])]
    return "\n".join(lines)


def plot(rows: list[dict[str, Any]], out: Path, title: str) -> None:
    """steps/s against num_envs, log-log, one line per env (ours solid, peers dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 5))
    for env in dict.fromkeys(r["env"] for r in rows):
        pts = sorted((r["num_envs"], r["steps_per_s"]) for r in rows if r["env"] == env)
        peer = env in env_throughput.PEER_ENVS
        label = f"{env} (peer)" if peer else env
        xs, ys = zip(*pts, strict=True)
        ax.plot(xs, ys, marker="o", linestyle="--" if peer else "-", label=label)
    ax.set(xscale="log", yscale="log", xlabel="parallel envs", ylabel="env steps / s")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def train_networks(spec: str | None, config: TrainConfig) -> list[tuple[int, ...]]:
    """Hidden sizes of each network to train: ``spec`` as ``"512,256,128,64;64,64"``, or by
    default the config's network and rejax's default one."""
    if spec is None:
        return list(dict.fromkeys([tuple(config.hidden_sizes), REJAX_DEFAULT_NETWORK]))
    networks = []
    for part in spec.split(";"):
        try:
            sizes = tuple(int(n) for n in part.split(","))
        except ValueError:
            sizes = ()
        if not sizes or min(sizes) < 1:
            raise ValueError(f"{part!r} is not a list of positive layer widths")
        networks.append(sizes)
    return networks


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--num-envs", default="1,16,256,4096,16384", help="comma-separated")
    p.add_argument(
        "--envs",
        default=",".join(DEFAULT_ENVS),
        help=f"comma-separated of {env_throughput.ALL_ENVS}",
    )
    p.add_argument("--steps", type=int, default=200, help="env steps per timed run, at most")
    p.add_argument("--target-s", type=float, default=0.5, help="seconds per timed run, about")
    p.add_argument("--rounds", type=int, default=3, help="timed runs per row, interleaved")
    p.add_argument(
        "--train-config",
        default="{}",
        help="JSON TrainConfig overrides, e.g. '{\"total_timesteps\": 80000}'",
    )
    p.add_argument(
        "--train-networks",
        default=None,
        help="hidden sizes per trained network, ';'-separated, e.g. '512,256,128,64;64,64' "
        f"(default: the config's and rejax's default {','.join(map(str, REJAX_DEFAULT_NETWORK))})",
    )
    p.add_argument("--train-seeds", default="0", help="comma-separated seeds, a run each")
    p.add_argument("--eval-episodes", type=int, default=256, help="greedy episodes per check")
    p.add_argument("--threshold", type=float, default=0.95, help="greedy success to reach")
    p.add_argument(
        "--final-eval-episodes",
        type=int,
        default=2048,
        help="greedy episodes each side's final policy is evaluated on, 0 for none",
    )
    p.add_argument(
        "--train-peer-options",
        action="store_true",
        help="compile rejax's programs with jaxnav.train.COMPILER_OPTIONS too (ours always)",
    )
    p.add_argument("--compile-timesteps", type=int, default=16_000, help="steps per CLI run")
    p.add_argument("--sections", default=",".join(SECTIONS), help=f"comma-separated {SECTIONS}")
    p.add_argument("--out", type=Path, default=None, help=f"JSON output path ({DEFAULT_OUT})")
    only = p.add_mutually_exclusive_group()
    only.add_argument(
        "--render", action="store_true", help="rewrite --out's markdown, measure nothing"
    )
    only.add_argument(
        "--merge",
        nargs="+",
        type=Path,
        metavar="RESULT",
        help="write the train runs of these result files as one result to --out, measure nothing",
    )
    args = p.parse_args(argv)
    if args.merge:
        if args.out is None:  # never the default: a merge would replace the full comparison
            p.error("--merge: give --out, the path of the merged result")
        return args
    args.out = DEFAULT_OUT if args.out is None else args.out
    if args.render:
        if not args.out.is_file():
            p.error(f"--render --out {args.out}: no such result file")
        return args
    try:
        args.num_envs = [int(n) for n in args.num_envs.split(",") if n.strip()]
    except ValueError:
        p.error(f"--num-envs {args.num_envs!r}: comma-separated integers")
    args.envs = [e.strip() for e in args.envs.split(",") if e.strip()]
    args.sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    bad = [e for e in args.envs if e not in env_throughput.ALL_ENVS]
    bad += [s for s in args.sections if s not in SECTIONS]
    if bad:
        p.error(f"unknown envs or sections: {', '.join(bad)}")
    if not args.num_envs or min(args.num_envs) < 1 or min(args.steps, args.rounds) < 1:
        p.error("--num-envs, --steps and --rounds must be >= 1")
    if args.eval_episodes < 1 or not 0 < args.threshold <= 1:
        p.error("--eval-episodes must be >= 1, --threshold in (0, 1]")
    if args.final_eval_episodes < 0:
        p.error(f"--final-eval-episodes {args.final_eval_episodes}: must be >= 0")
    try:
        args.train_seeds = [int(s) for s in args.train_seeds.split(",") if s.strip()]
    except ValueError:
        args.train_seeds = []
    if not args.train_seeds or min(args.train_seeds) < 0:
        p.error(f"--train-seeds {args.train_seeds!r}: comma-separated integers >= 0")
    try:
        args.train_config = train_config(args.train_config)
    except (ValueError, TypeError) as e:  # bad JSON, unknown field, invalid value
        p.error(f"--train-config {args.train_config!r}: {e}")
    try:
        args.train_networks = train_networks(args.train_networks, args.train_config)
    except ValueError as e:
        p.error(f"--train-networks {args.train_networks!r}: {e}")
    return args


def markdown(result: dict[str, Any]) -> str:
    """The tables of a run's result: each section it has."""
    parts = []
    if "env" in result:
        parts.append("### Env steps/s\n\n" + env_tables(result["env"]))
    if "train" in result:
        for run in result["train"]:
            config = run["config"]
            parts.append(
                f"### {config['algo'].upper()} training, {config['env']}, "
                f"{config['total_timesteps']:,} env steps, network "
                f"{'-'.join(map(str, run['hidden_sizes']))}, seed {run['seed']}\n\n"
                + train_vs_rejax.table(run)
            )
        algo = result["train"][0]["config"]["algo"].upper()
        parts.append(
            f"### {algo} training, each network\n\n" + train_vs_rejax.summary(result["train"])
        )
    if "compile" in result:
        parts.append("### CLI start-up\n\n" + compile_time.table(result["compile"]))
    return "\n\n".join(parts)


# what makes two train runs one comparison, beside their config less its network
SAME_COMPARISON = ("threshold", "eval_episodes", "final_eval_episodes", "peer_compiler_options")


def read_train_result(path: Path, flag: str) -> tuple[dict[str, Any], list[tuple[Any, Any]]]:
    """The result in ``path`` with train runs and each run's (``comparison``, (network,
    seed)); ``ValueError`` (one line, starting with ``flag`` and the path) otherwise."""
    try:
        result = json.loads(path.read_text())
        runs = result["train"]
        identities = [(comparison(run), (tuple(run["hidden_sizes"]), run["seed"])) for run in runs]
    except FileNotFoundError:
        raise ValueError(f"{flag} {path}: no such result file") from None
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"{flag} {path}: not a train result of this benchmark ({e!r})") from None
    if not runs:
        raise ValueError(f"{flag} {path}: holds no train runs")
    return result, identities


def merged(paths: list[Path], command: str) -> dict[str, Any]:
    """One result of the train runs of ``paths``, results of the same comparison, ordered by
    network and seed. ``ValueError`` (one line) naming a file that is not such a result, is of
    another comparison, or repeats a network and seed."""
    runs: list[dict[str, Any]] = []
    sources: list[dict[str, Any]] = []
    seen: dict[tuple[tuple[int, ...], int], Path] = {}
    first: dict[str, Any] | None = None
    for path in paths:
        result, identities = read_train_result(path, "--merge")
        file_runs = result["train"]
        for identity, key in identities:
            first = identity if first is None else first
            keys = first.keys() | identity.keys()
            differ = sorted(k for k in keys if first.get(k) != identity.get(k))
            if differ:
                raise ValueError(
                    f"--merge {path}: another comparison than {paths[0]} (differs in "
                    f"{', '.join(differ)})"
                )
            if key in seen:
                raise ValueError(
                    f"--merge {path}: network {'-'.join(map(str, key[0]))} seed {key[1]} is "
                    f"already in {seen[key]}"
                )
            seen[key] = path
        runs += file_runs
        sources.append(
            {"file": str(path), "command": result.get("command"), "machine": result.get("machine")}
        )
    networks = list(dict.fromkeys(tuple(run["hidden_sizes"]) for run in runs))
    runs.sort(key=lambda run: (networks.index(tuple(run["hidden_sizes"])), run["seed"]))
    return {
        "machine": sources[0]["machine"],
        "command": command,
        "merged_from": sources,
        "train": runs,
    }


def comparison(run: dict[str, Any]) -> dict[str, Any]:
    """What a train run compares, less its network: equal for runs ``--merge`` may join."""
    config = {f"config {k}": v for k, v in run["config"].items() if k != "hidden_sizes"}
    return config | {k: run.get(k) for k in SAME_COMPARISON}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the chosen sections, print the tables, write JSON, markdown and the plot."""
    args = parse_args(argv)
    command = " ".join(["python -m benchmarks.compare", *(sys.argv[1:] if argv is None else argv)])
    if args.merge:
        try:
            check_output_file(args.out)
            result = merged(args.merge, command)
        except ValueError as e:
            print(e, file=sys.stderr)
            raise SystemExit(2) from None
        md = markdown(result)
        print(md)
        write_results(args.out, result, md)
        return result
    if args.render:
        try:
            result = json.loads(args.out.read_text())
            md = markdown(result)
        except (ValueError, KeyError, TypeError) as e:
            print(
                f"--render --out {args.out}: not a result of this benchmark ({e!r})",
                file=sys.stderr,
            )
            raise SystemExit(2) from None
        write_whole(args.out.with_suffix(".md"), md + "\n")
        return result
    info = machine_info() | {
        "versions": {
            d: package_version(d) for d in ("navix", "jaxmarl", "rejax", "mujoco-mjx", "flax")
        }
    }
    result: dict[str, Any] = {"machine": info, "command": command}
    if "env" in args.sections:
        result["env"] = env_section(args)
    if "train" in args.sections:
        result["train"] = []
        for hidden_sizes in args.train_networks:
            config = dataclasses.replace(args.train_config, hidden_sizes=hidden_sizes)
            for seed in args.train_seeds:
                run = train_vs_rejax.measure(
                    config,
                    args.eval_episodes,
                    args.threshold,
                    seed,
                    args.train_peer_options,
                    args.final_eval_episodes,
                )
                result["train"].append(run | {"config": dataclasses.asdict(config)})
    if "compile" in args.sections:
        entries = list(compile_time.ENTRIES)
        result["compile"] = compile_time.measure(entries, args.compile_timesteps)
    info["loadavg_1m_at_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    info["max_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    info["device_memory"] = [
        d.memory_stats() for d in jax.local_devices() if d.memory_stats() is not None
    ]
    md = markdown(result)
    print(md)
    write_results(args.out, result, md)
    if "env" in result:
        title = f"{machine_text(info)}, {info['date'][:10]}"
        plot(result["env"]["rows"], args.out.with_suffix(".png"), title)
    return result


if __name__ == "__main__":
    main()
