"""A training iteration's time under sets of XLA options, each set in a process of its own.

    python -m benchmarks.xla_options [--config JSON] [--iterations 4] [--rounds 5]
        [--variant "NAME=FLAGS" ...] [--repeats 1] [--timeout 600]
        [--out benchmarks/results/xla_options.json]

XLA reads ``XLA_FLAGS`` once, when the backend starts, so every variant runs in a fresh
process (``python -m benchmarks.xla_options --child SPEC``) with its ``FLAGS`` added to the
environment's ``XLA_FLAGS``, on top of the options every training program is compiled with
(``jaxnav.train.COMPILER_OPTIONS``). Each process builds the training config of ``--config``
(a JSON object of ``TrainConfig`` fields over the preset of its env and algorithm, as
``benchmarks.compare`` takes it; default: RobotNav-v0's PQN preset) with a logging interval of
``--iterations`` iterations, compiles ``Trainer.run`` for one interval as the training CLI
does (compile seconds apart), calls it once untimed and ``--rounds`` times timed, each call
continuing from the last one's state. A variant's time is the median over its timed calls, and
over its ``--repeats`` processes, which run in turn (A, B, A, B, ...) so that a change of the
machine's load hits every variant alike; the speed-up is the first variant's time over each
variant's. A process that fails (an unknown flag, a compile or run-time error, the timeout)
is a row with its error, and its times are n/a.

Default variants: ``shipped`` (no flag added) and ``every command sequence a graph``
(``--xla_gpu_graph_min_graph_size=1``: XLA:GPU records runs of fewer than 5 commands as plain
launches, not command buffers, by default). Backends other than the GPU ignore XLA:GPU's
flags. An option that ``COMPILER_OPTIONS`` sets cannot be varied here: options given to the
compiler override ``XLA_FLAGS``, so such a variant is refused.

Writes the JSON and a markdown table beside it (``.md``).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

# jax and jaxnav are imported inside the functions: the parent process must set JAX_PLATFORMS
# before jax starts (``main``), and each child starts jax under its own XLA_FLAGS

DEFAULT_OUT = Path("benchmarks/results/xla_options.json")
DEFAULT_CONFIG = '{"env": "RobotNav-v0", "algo": "pqn"}'
DEFAULT_VARIANTS = (
    "shipped=",
    "every command sequence a graph=--xla_gpu_graph_min_graph_size=1",
)


def child(spec: dict[str, Any]) -> dict[str, Any]:
    """Time one variant in this process: compile, one untimed call, ``rounds`` timed ones."""
    import jax

    from benchmarks.common import machine_info, train_config
    from benchmarks.train_throughput import (
        Program,
        compile_donating,
        filled_state,
        first_timed_log,
        timed_config,
    )
    from jaxnav.train import Trainer

    rounds, iterations = spec["rounds"], spec["iterations"]
    trainer = Trainer(timed_config(train_config(spec["config"]), iterations, rounds))
    c = trainer.config
    key = jax.random.key(spec["seed"])
    ts = filled_state(trainer, key) if c.algo == "dqn" else jax.jit(trainer.init)(key)
    first = first_timed_log(c)
    logs = [jax.numpy.asarray(first + i, jax.numpy.int32) for i in range(rounds + 1)]
    compiled, compile_s = compile_donating(lambda ts, log: trainer.run(ts, log, 1), ts, logs[0])
    program = Program(compiled, ts, logs, compile_s)
    program.call(0, timed=False)
    for r in range(1, rounds + 1):
        program.call(r)
    ms = [t / iterations * 1e3 for t in program.run_s]
    return {
        "machine": machine_info(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "steps_per_iteration": c.steps_per_iteration,
        "updates_per_iteration": c.updates_per_learning_iteration,
        "ms_per_iteration": ms,
    } | program.record()


def run_variant(
    flags: str, spec: dict[str, Any], timeout: float, environ: dict[str, str]
) -> dict[str, Any]:
    """One process of a variant (``environ`` plus ``flags``): its record, or ``{"error":
    ...}`` where it failed."""
    env = dict(environ)
    env["XLA_FLAGS"] = " ".join(f for f in (env.get("XLA_FLAGS", ""), flags) if f)
    argv = [sys.executable, "-m", "benchmarks.xla_options", "--child", json.dumps(spec)]
    root = Path(__file__).resolve().parents[1]  # `benchmarks` is a folder of the repository
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(root), env.get("PYTHONPATH")) if p)
    try:
        done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"no result within --timeout {timeout:g} s"}
    lines = done.stdout.strip().splitlines()
    if done.returncode == 0 and lines:
        return json.loads(lines[-1])
    said = [line.strip() for line in done.stderr.splitlines() if line.strip()]
    last = said[-1] if said else "no output"
    return {"error": f"exit code {done.returncode}: {last[:300]}"}


def summarize(variants: list[tuple[str, str]], runs: dict[str, list[dict]]) -> list[dict]:
    """A row per variant: its processes, median time, speed-up over the first variant."""
    rows = []
    for name, flags in variants:
        per_process = [
            statistics.median(r["ms_per_iteration"]) if "error" not in r else None
            for r in runs[name]
        ]
        ok = [r for r in runs[name] if "error" not in r]
        ms = statistics.median(x for x in per_process if x is not None) if ok else None
        rows.append(
            {
                "variant": name,
                "flags": flags,
                "ms_per_iteration": ms,
                "ms_per_process": per_process,
                "compile_s": [r.get("compile_s") for r in runs[name]],
                "env_steps_per_s": ok[0]["steps_per_iteration"] / ms * 1e3 if ok else None,
                "errors": sorted({r["error"] for r in runs[name] if "error" in r}),
                "processes": runs[name],
            }
        )
    base = rows[0]["ms_per_iteration"]
    for row in rows:
        ms = row["ms_per_iteration"]
        row["speedup"] = base / ms if base is not None and ms is not None else None
    return rows


def markdown(result: dict[str, Any]) -> str:
    def num(x: float | None, fmt: str) -> str:
        return "n/a" if x is None else format(x, fmt)

    device = next(
        (p["machine"]["devices"][0] for r in result["rows"] for p in r["processes"]
         if "machine" in p),
        "n/a",
    )  # fmt: skip
    lines = [
        f"# A training iteration under XLA options: {result['config']}",
        "",
        f"`{result['command']}`; {device}. {result['iterations']} iterations a timed call, "
        f"the median of {result['rounds']} calls a process, {result['repeats']} process(es) "
        "a variant in turn.",
        "",
        f"| variant | XLA_FLAGS added | ms an iteration | per process | speed-up over "
        f"{result['rows'][0]['variant']} | env steps/s | compile s |",
        "|---|---|---:|---|---:|---:|---|",
    ]
    for r in result["rows"]:
        per = ", ".join(num(x, ".2f") for x in r["ms_per_process"])
        compile_s = ", ".join(num(x, ".1f") for x in r["compile_s"])
        flags = f"`{r['flags']}`" if r["flags"] else "(none)"
        lines.append(
            f"| {r['variant']} | {flags} | {num(r['ms_per_iteration'], '.2f')} | {per} | "
            f"{num(r['speedup'], '.3f')} | {num(r['env_steps_per_s'], ',.0f')} | {compile_s} |"
        )
    errors = [(r["variant"], e) for r in result["rows"] for e in r["errors"]]
    if errors:
        lines += ["", *(f"- {name}: {e}" for name, e in errors)]
    return "\n".join(lines)


def parse_variant(text: str) -> tuple[str, str]:
    name, sep, flags = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: expected NAME=FLAGS (FLAGS may be empty)")
    return name.strip(), flags.strip()


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    from benchmarks.common import train_config
    from benchmarks.train_throughput import Parser, timed_config  # one-line errors, exit 2

    p = Parser(prog="python -m benchmarks.xla_options", description=__doc__.splitlines()[0])
    p.add_argument("--config", default=DEFAULT_CONFIG, help="JSON object of TrainConfig fields")
    p.add_argument("--iterations", type=int, default=4, help="iterations a timed call")
    p.add_argument("--rounds", type=int, default=5, help="timed calls a process")
    p.add_argument("--repeats", type=int, default=1, help="processes a variant, in turn")
    p.add_argument("--variant", type=parse_variant, action="append", metavar="NAME=FLAGS",
                   help="repeatable; the first is the baseline (default: shipped, and every "
                   "command sequence a graph)")  # fmt: skip
    p.add_argument("--timeout", type=float, default=600.0, help="seconds a process, at most")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output path")
    args = p.parse_args(argv)
    for flag in ("iterations", "rounds", "repeats"):
        if getattr(args, flag) < 1:
            p.error(f"--{flag} {getattr(args, flag)}: must be >= 1")
    if args.timeout <= 0:
        p.error(f"--timeout {args.timeout:g}: must be > 0")
    args.variant = args.variant or [parse_variant(v) for v in DEFAULT_VARIANTS]
    names = [name for name, _ in args.variant]
    if len(set(names)) < len(names):
        p.error(f"--variant names {', '.join(names)}: each name once")
    from jaxnav.train import COMPILER_OPTIONS

    for name, flags in args.variant:
        for flag in shlex.split(flags):
            option = flag.lstrip("-").partition("=")[0]
            if option in COMPILER_OPTIONS:
                p.error(f"--variant {name}={flags}: {option} is set by jaxnav.train."
                        "COMPILER_OPTIONS, which overrides XLA_FLAGS; change it there")  # fmt: skip
    try:  # the config is checked here, before any process starts
        config = timed_config(train_config(args.config), args.iterations, args.rounds)
    except (ValueError, TypeError) as e:
        p.error(f"--config {args.config}: {e}")
    if config.devices != 1:
        p.error(f"--config devices={config.devices}: the benchmark times one device's program")
    return args


def main(argv: list[str] | None = None) -> dict[str, Any]:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        print(json.dumps(child(json.loads(argv[1]))))
        return {}
    # the processes get this environment; this one checks the config on the CPU, so that it
    # does not take the memory an accelerator's backend reserves when it starts
    environ = dict(os.environ)
    if "jax" not in sys.modules:
        os.environ["JAX_PLATFORMS"] = "cpu"
    args = parse_args(argv)
    spec = {
        "config": args.config,
        "iterations": args.iterations,
        "rounds": args.rounds,
        "seed": args.seed,
    }
    runs: dict[str, list[dict]] = {name: [] for name, _ in args.variant}
    for _ in range(args.repeats):
        for name, flags in args.variant:
            record = run_variant(flags, spec, args.timeout, environ)
            runs[name].append(record)
            said = record.get("error") or f"{statistics.median(record['ms_per_iteration']):.2f} ms"
            print(f"{name}: {said}", file=sys.stderr, flush=True)
    result = {
        "command": "python -m benchmarks.xla_options " + shlex.join(argv),
        "config": args.config,
        "iterations": args.iterations,
        "rounds": args.rounds,
        "repeats": args.repeats,
        "rows": summarize(args.variant, runs),
    }
    from benchmarks.common import write_results

    md = markdown(result)
    print(md)
    write_results(args.out, result, md)
    return result


if __name__ == "__main__":
    main()
