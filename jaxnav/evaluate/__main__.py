"""``python -m jaxnav.evaluate``: a trained run (greedy) or the random agent on fresh episodes,
written to ``RUN/eval.json`` (the trained policy on the run's env; other policies, envs and
overrides each get their own file, see ``default_out_name``) with the table printed. Bad input
is one line on stderr, exit code 2; a write the machine refuses (a full disk), exit code 4.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from jaxnav import cli, run_dir
from jaxnav.evaluate import (
    SEED_STATISTICS,
    evaluate_seeds,
    mean_of,
    print_eval_table,
    print_seed_statistics,
    seed_statistics,
    shielded_policy,
)
from jaxnav.programs import enable_compilation_cache
from jaxnav.safe_io import WriteFault, check_output_file


def parser() -> argparse.ArgumentParser:
    p = cli.Parser(
        prog="python -m jaxnav.evaluate",
        description="Evaluate a trained run (greedy) or the random agent on fresh episodes.",
        formatter_class=cli.HelpFormatter,
    )
    cli.add_policy_source(
        p,
        "a policy shipped with jaxnav instead of a run (python -m jaxnav.pretrained "
        "lists them); --out is then optional",
    )
    p.add_argument("--env", help="evaluate on another env id (generalization); default: the run's")
    cli.add_env_args(p)
    p.add_argument("--episodes", type=int, default=1000, help="test episodes per seed")
    p.add_argument("--seed", type=int, default=0, help="seed of the test episodes")
    p.add_argument(
        "--policy",
        choices=("trained", "shielded", "random"),
        default="trained",
        help="shielded: the trained policy among the moves its lidar does not show blocked "
        "over the next step (robot envs, feed-forward policies)",
    )
    p.add_argument(
        "--out",
        type=Path,
        help="output JSON (default: RUN/eval.json for the trained policy on the run's env; "
        "RUN/eval-POLICY[-ENV][-MAZE][-KEY=VALUE...].json otherwise, one file each)",
    )
    return p


# at most this many layouts get a line each of their success rate (a bank of maze files)
MAX_NAMED_MAZES = 16


def default_out_name(policy: str, env: str | None, overrides: dict[str, Any]) -> str:
    """The file name of an evaluation in its run directory, one per policy, env, maze file and
    override set, so no evaluation overwrites another: ``eval.json`` for the trained policy on
    the run's own env, e.g. ``eval-random.json`` or ``eval-trained-RobotMaze-v0-rooms.json``."""
    overrides = dict(overrides)
    parts = ["eval"]
    maze = overrides.pop("maze_file", None)
    if policy == "trained" and env is None and maze is None and not overrides:
        return "eval.json"
    parts.append(policy)
    if env is not None:
        parts.append(env)
    if maze is not None:
        parts.append(Path(str(maze)).stem)
    parts += [f"{k}={json.dumps(v) if not isinstance(v, str) else v}" for k, v in overrides.items()]
    # a file name, whatever the values hold (a path, spaces, quotes)
    return re.sub(r"[^A-Za-z0-9_.=+,-]", "_", "-".join(parts))[:200] + ".json"


def main(argv: Sequence[str] | None = None) -> int:
    """Evaluate as the flags in ``argv`` (default: the command line's) say; the exit code."""
    prog = "jaxnav.evaluate"
    try:
        args = parser().parse_args(argv)
        if not 1 <= args.episodes <= 10**7:
            raise ValueError(f"--episodes {args.episodes}: must be in [1, 10000000]")
        cli.check_seed(args.seed)
        cli.check_policy_source(args)
        env, overrides = cli.env_from_args(args, args.env)
        if args.run is not None:
            config = run_dir.load_config(args.run)
        out = args.out or (
            None if args.run is None else args.run / default_out_name(args.policy, env, overrides)
        )
        if out is not None:
            check_output_file(out)  # a directory or a device is refused, not replaced
        if args.pretrained is not None:
            from jaxnav.export import load_pretrained

            config, trainer, params = load_pretrained(args.pretrained, env, overrides)
        else:
            on = run_dir.run_env(config, env, overrides)  # the run's sensors go with it
            config, trainer, params = run_dir.load_run_on(args.run, *on)
        if args.policy == "shielded":  # refused here, in one line, for a policy it cannot read
            shielded_policy(trainer.network, trainer.env, trainer.env_params)
    except (cli.UsageError, ValueError, FileNotFoundError) as e:
        return cli.fail(prog, str(e))
    enable_compilation_cache()
    rows = evaluate_seeds(trainer, params, args.episodes, args.seed, args.policy, per_maze=True)
    mazes = trainer.env.num_layouts(trainer.env_params)
    stats = {m: seed_statistics([r[m] for r in rows]) for m in SEED_STATISTICS}
    # each layout's name (a maze file's path) by index of maze_success; robot envs have them
    names = list(getattr(trainer.env, "layout_names", ()))
    result = {
        "run": str(args.run) if args.pretrained is None else f"pretrained:{args.pretrained}",
        "env": config.env,
        "env_kwargs": config.env_kwargs,
        "policy": args.policy,
        "episodes": args.episodes,
        "seed": args.seed,
        "episodes_per_maze": args.episodes / mazes,
        **mean_of(rows),
        "over_seeds": stats,
        "per_seed": rows,
        **({"maze_names": names} if names else {}),
    }
    if out is not None:
        try:
            run_dir.write_json(out, result)
        except WriteFault as e:
            return cli.write_failed(prog, e)
    print_eval_table(config.env, {args.policy: mean_of(rows)})
    if args.episodes % mazes:
        print(
            f"note: {args.episodes} episodes over {mazes} mazes: round-robin, "
            f"{args.episodes // mazes} or {args.episodes // mazes + 1} per maze"
        )
    if 1 < len(names) <= MAX_NAMED_MAZES:
        for i, name in enumerate(names):
            rates = [r["maze_success"][i] for r in rows if r["maze_success"][i] is not None]
            rate = f"{sum(rates) / len(rates):.3f}" if rates else "not played"
            print(f"  success on {name}: {rate}")
    if len(rows) > 1 and args.policy != "random":  # the random agent is the same for every seed
        print_seed_statistics(stats)
    if out is not None:
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
