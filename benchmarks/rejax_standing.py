"""Where the training speed-up over rejax stands, by every measure a reading of the goal may take.

    python -m benchmarks.rejax_standing RESULT.json [RESULT.json ...] [--target 3]
        [--out benchmarks/results/rejax_standing.json]

Each ``RESULT`` is a ``benchmarks.compare --sections train`` result (one process's or several
merged by ``--merge``). One row per result and network, computed from its runs, one a seed:

- speed: rejax / ours in train time, the mean over the seeds (as the comparison's summary
  gives it) with its standard error over the seeds and whether the mean is above ``--target``
  by more than twice it, the lowest seed's, and how many seeds fall below ``--target``;
- success of each side's final policy on the final evaluation's fresh episodes: the mean over
  the seeds with jaxnav's minus rejax's difference and its standard error over the seeds, the
  median and the interquartile mean; the final checks' and the last quarter's means; and on
  how many seeds ours reached the best check rejax reached in the run;
- which of those success measures ours is at least rejax's on (to the 3 places shown), and
  whether our final policies' mean is below rejax's by more than twice the larger of the
  difference's two standard errors, over the seeds and of the episodes alone.

The goal's open choices (which setups must reach the target, rejax as it ships or compiled
with our options, which success measure) are rows and columns here: the table answers each
reading and chooses none. Writes the JSON and a markdown table beside it (``.md``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import Any

from benchmarks.common import write_results
from benchmarks.compare import read_train_result
from benchmarks.train_vs_rejax import (
    final_difference_stats,
    pair_text,
    runs_by_network,
    side_stats,
    signed,
    standard_error,
)
from jaxnav.evaluate import iqm
from jaxnav.safe_io import check_output_file

DEFAULT_OUT = Path("benchmarks/results/rejax_standing.json")
REJAX_BUILDS = {False: "as it ships", True: "with our options"}


def _at_least(values: list[float] | None) -> bool:
    """Ours at least rejax's, to the 3 places the tables show (0.9996 against 0.9998 is
    equal success); False where the measure was not recorded."""
    return values is not None and round(values[0], 3) >= round(values[1], 3)


def _row(path: Path, runs: list[dict[str, Any]], target: float) -> dict[str, Any]:
    """The row of one network's runs (a seed each) of the result in ``path``."""
    config = runs[0]["config"]
    ratios = [r["wall_time_ratio"] for r in runs]
    success = {
        "final policy mean": side_stats(runs, "final_eval_success"),
        "median": side_stats(runs, "final_eval_success", statistics.median),
        "interquartile mean": side_stats(runs, "final_eval_success", iqm),
        "final check": side_stats(runs, "final_success"),
        "last quarter": side_stats(runs, "late_success"),
    }
    final = None
    if success["final policy mean"] is not None:
        ours, theirs = success["final policy mean"]
        stats = final_difference_stats(runs)  # None for one seed: no spread
        over_seeds, episodes = (None, None) if stats is None else stats[1:]
        # "equal or better" read as: not below rejax's by more than twice the noise, the larger
        # of the two standard errors (a few seeds can agree more closely than their episodes)
        below = None if stats is None else ours - theirs < -2 * max(over_seeds, episodes)
        final = {
            "episodes": runs[0].get("final_eval_episodes"),
            "difference": ours - theirs,
            "difference_se_over_seeds": over_seeds,
            "difference_se_of_the_episodes": episodes,
            "below_by_more_than_2_se": below,
        }
    ratio_mean, ratio_se = statistics.fmean(ratios), standard_error(ratios)  # se None: one seed
    return {
        "result": path.name,
        "env": config["env"],
        "algo": config["algo"],
        "network": runs[0]["hidden_sizes"],
        "compute_dtype": config.get("compute_dtype"),
        "num_envs": config.get("num_envs"),
        "rejax": REJAX_BUILDS[bool(runs[0].get("peer_compiler_options"))],
        "seeds": [r["seed"] for r in runs],
        "ratio_mean": ratio_mean,
        "ratio_se_over_seeds": ratio_se,
        "ratio_mean_above_target_by_more_than_2_se": (
            None if ratio_se is None else ratio_mean - 2 * ratio_se > target
        ),
        "ratio_lowest": min(ratios),
        "seeds_below_target": sum(r < target for r in ratios),
        "final_policy": final,
        "success": success,
        "ours_at_least_rejax_on": [m for m, v in success.items() if _at_least(v)],
        "peer_best_reached": sum(
            list(r["sides"].values())[0].get("time_to_peer_best_s") is not None for r in runs
        ),
    }


def standing(path: Path, result: dict[str, Any], target: float) -> list[dict[str, Any]]:
    """The rows of one result: one per network it ran."""
    return [_row(path, runs, target) for runs in runs_by_network(result["train"])]


def _yes_no(value: bool | None) -> str:
    return "n/a" if value is None else ("yes" if value else "no")


def markdown(rows: list[dict[str, Any]], target: float) -> str:
    lines = [
        f"| result | setup | rejax | seeds | rejax / ours, mean (s.e. over the seeds) "
        f"| mean above {target:g}x by more than 2 s.e. | lowest seed | seeds below {target:g}x "
        f"| final policy, mean, jaxnav / rejax (difference, s.e. over the seeds) | median "
        f"| interquartile mean | final check | last quarter "
        f"| final policy mean below rejax's by more than 2 s.e. (the larger of the two) "
        f"| rejax's best check reached by ours | ours at least rejax's on |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        final, success = r["final_policy"], r["success"]
        mean = pair_text(success["final policy mean"])
        if final is not None:
            se = final["difference_se_over_seeds"]
            mean += f" ({signed(final['difference'])}, {'n/a' if se is None else f'{se:.3f}'})"
        setup = (
            f"{r['env']} {r['algo'].upper()}, {'-'.join(map(str, r['network']))}, "
            f"{r['compute_dtype'] or 'n/a'}, "
            f"{'n/a' if r['num_envs'] is None else format(r['num_envs'], ',')} envs"
        )
        n, ratio_se = len(r["seeds"]), r["ratio_se_over_seeds"]
        lines.append(
            f"| `{r['result']}` | {setup} | {r['rejax']} | {n} | {r['ratio_mean']:.2f}x "
            f"({'n/a' if ratio_se is None else f'{ratio_se:.3f}'}) "
            f"| {_yes_no(r['ratio_mean_above_target_by_more_than_2_se'])} "
            f"| {r['ratio_lowest']:.2f}x | {r['seeds_below_target']} | {mean} "
            f"| {pair_text(success['median'])} | {pair_text(success['interquartile mean'])} "
            f"| {pair_text(success['final check'])} | {pair_text(success['last quarter'])} "
            f"| {_yes_no(final and final['below_by_more_than_2_se'])} "
            f"| {r['peer_best_reached']} of {n} "
            f"| {', '.join(r['ours_at_least_rejax_on']) or 'none'} |"
        )
    episodes = {r["final_policy"]["episodes"] for r in rows if r["final_policy"]}
    counts = " or ".join(f"{e:,}" for e in sorted(episodes)) or "n/a"
    lines.append(
        f"\nFinal policies on {counts} fresh episodes a seed; final checks and the last "
        f"quarter's checks on the comparison's check episodes. Means of the per-seed ratios."
    )
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.rejax_standing", description=__doc__.split("\n")[0]
    )
    p.add_argument("results", nargs="+", type=Path, metavar="RESULT")
    p.add_argument("--target", type=float, default=3.0, help="speed-up asked for (default 3)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"JSON output ({DEFAULT_OUT})")
    args = p.parse_args(argv)
    if not args.target > 0:
        p.error(f"--target {args.target}: must be > 0")
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    command = " ".join(
        ["python -m benchmarks.rejax_standing", *(sys.argv[1:] if argv is None else argv)]
    )
    try:
        check_output_file(args.out)
        rows = []
        for path in args.results:
            rows += standing(path, read_train_result(path, "result")[0], args.target)
    except ValueError as e:
        print(e, file=sys.stderr)
        raise SystemExit(2) from None
    except (KeyError, TypeError) as e:
        print(f"result {path}: a train run lacks {e!r}", file=sys.stderr)
        raise SystemExit(2) from None
    result = {"command": command, "target": args.target, "rows": rows}
    md = markdown(rows, args.target)
    print(md)
    write_results(args.out, result, md)
    return result


if __name__ == "__main__":
    main()
