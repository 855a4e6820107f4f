"""Where a training iteration's GPU time goes: device kernels of one logging interval, by kind.

    python -m benchmarks.profile_training [--env RobotNav-v0] [--algo pqn] [--config JSON]
        [--iterations 2] [--repeats 2] [--loops-on-host]
        [--out benchmarks/results/profile_training.json]

The env's preset for the algorithm (``TrainConfig.for_env``), then ``--config``'s ``TrainConfig``
fields, with a logging interval of ``--iterations`` iterations; ``Trainer.run(state, log, 1)``
for the first interval in which the algorithm learns (a DQN waits for ``learning_starts``) is
compiled once, run twice untimed, then ``--repeats`` times under ``jax.profiler.trace`` (a
Perfetto trace). Every device kernel of
the trace is put in one kind by its name (``KINDS``: the Pallas LayerNorm kernels, matrix
products, reductions, dtype conversions, sorts, gathers and scatters, copies, the rest) and its
time summed. Reported: the span from the first kernel's start to the last one's end, the
kernels' total time (so the fraction of the span the device was busy), each kind's time and
share, the kernels that took longest, and where the device sat idle within the intervals
(the time between a kernel's start and the end of all before it, put on that kernel: the
kernels the device waited for; the ``repeats - 1`` longest waits, the host's between
intervals, left out). Needs an accelerator: a CPU run's trace has no
device kernels and the script says so in one line (exit 2).

The program is compiled with ``COMPILER_OPTIONS``, as training compiles it, so its loops and
conditionals run as CUDA graph nodes; the trace then shows few of the kernels inside them (the
grid's DQN at 4,096 envs: 194 kernels an iteration where its 32 gradient steps run some 2,000,
and the device "idle" for 87% of the span). ``--loops-on-host`` leaves loops and conditionals
out of the command buffers, so that every trip's kernels are in the trace: a slower program
than training's (the host launches each trip), whose kernels are the same.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import gzip
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from benchmarks.common import machine_info, train_config, write_results
from jaxnav.config import TrainConfig
from jaxnav.train import COMPILER_OPTIONS, Trainer

# command-buffer kinds that make a loop or conditional one CUDA graph node
LOOP_COMMANDS = ("WHILE", "CONDITIONAL")


def compiler_options(loops_on_host: bool) -> dict[str, Any]:
    """Training's ``COMPILER_OPTIONS``; with ``loops_on_host``, without ``LOOP_COMMANDS``."""
    if not loops_on_host:
        return dict(COMPILER_OPTIONS)
    kinds = COMPILER_OPTIONS["xla_gpu_enable_command_buffer"].split(",")
    kept = ",".join(k for k in kinds if k not in LOOP_COMMANDS)
    return {**COMPILER_OPTIONS, "xla_gpu_enable_command_buffer": kept}


# kind -> substrings of a kernel's name (first match wins, in this order)
KINDS: dict[str, tuple[str, ...]] = {
    "LayerNorm kernels (Pallas)": ("layer_norm_relu",),  # agents.layer_norm, named so
    "matrix products": ("gemm", "nvjet", "cublas", "cutlass", "dot"),
    "reductions": ("reduce",),
    "conversions": ("convert",),
    "sorts": ("sort",),
    "gathers and scatters": ("gather", "scatter", "dynamic"),
    "copies": ("copy", "memcpy", "memset", "transpose"),
}
OTHER = "other"
TOP = 15


def kind_of(name: str) -> str:
    low = name.lower()
    return next((k for k, keys in KINDS.items() if any(s in low for s in keys)), OTHER)


def device_kernels(trace: dict[str, Any]) -> list[dict[str, Any]]:
    """The complete events (``ph == "X"``) of the trace's device processes (named
    ``/device:...``), i.e. the kernels and copies the accelerator ran."""
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    devices = {
        e["pid"]
        for e in events
        if e.get("ph") == "M"
        and e.get("name") == "process_name"
        and str(e.get("args", {}).get("name", "")).startswith("/device:")
    }
    return [e for e in events if e.get("ph") == "X" and e.get("pid") in devices]


def idle_before(kernels: list[dict[str, Any]], between: int = 0) -> list[tuple[str, float]]:
    """(kernel name, idle us) for each wait: the device's idle time before a kernel started
    (after every earlier kernel had ended), without the ``between`` longest waits."""
    ordered = sorted(kernels, key=lambda e: e["ts"])
    waits, end = [], ordered[0]["ts"]
    for e in ordered:
        if e["ts"] > end:
            waits.append((e["ts"] - end, e["name"]))
        end = max(end, e["ts"] + e.get("dur", 0))
    return [(name, us) for us, name in sorted(waits, reverse=True)[between:]]


def longest_by_name(times: list[tuple[str, float]], count: str) -> list[dict[str, Any]]:
    """The ``TOP`` kernel names of most time in ``times`` ((name, us) pairs), each with its
    kind, its number of pairs (under the key ``count``) and its total us."""
    by_name: dict[str, list[float]] = collections.defaultdict(lambda: [0, 0.0])
    for name, us in times:
        by_name[name][0] += 1
        by_name[name][1] += us
    top = sorted(by_name.items(), key=lambda kv: -kv[1][1])[:TOP]
    return [{"name": n, "kind": kind_of(n), count: int(c), "total_us": t} for n, (c, t) in top]


def summarize(kernels: list[dict[str, Any]], repeats: int = 1) -> dict[str, Any]:
    """Span, busy time, time per kind, the longest kernels and the idle time within the
    ``repeats`` intervals, by the kernel waited for (microseconds)."""
    if not kernels:
        raise ValueError("the trace has no device kernels (profiling needs an accelerator)")
    start = min(e["ts"] for e in kernels)
    end = max(e["ts"] + e.get("dur", 0) for e in kernels)
    by_kind: dict[str, float] = dict.fromkeys([*KINDS, OTHER], 0.0)
    durations = [(e["name"], e.get("dur", 0)) for e in kernels]
    for name, us in durations:
        by_kind[kind_of(name)] += us
    idle = idle_before(kernels, repeats - 1)
    return {
        "span_us": end - start,
        "busy_us": sum(by_kind.values()),
        "kernels": len(kernels),
        "by_kind_us": by_kind,
        "top": longest_by_name(durations, "calls"),
        "idle_us": sum(us for _, us in idle),
        "idle_before": longest_by_name(idle, "waits"),
    }


def profile(
    config: TrainConfig, iterations: int, repeats: int, loops_on_host: bool = False
) -> dict[str, Any]:
    steps = iterations * config.steps_per_iteration
    log = max(1, -(-config.first_learning_iteration // iterations))
    config = dataclasses.replace(config, log_interval=steps, total_timesteps=steps * (log + 1))
    trainer = Trainer(config)
    state = jax.jit(trainer.init)(jax.random.key(0))
    # with the interval's metrics, as training computes them (without, XLA drops their work)
    interval = jax.jit(
        lambda ts: trainer.run(ts, jnp.int32(log), 1),
        compiler_options=compiler_options(loops_on_host),
    )
    interval = interval.lower(state).compile()
    for _ in range(2):
        jax.block_until_ready(interval(state))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            for _ in range(repeats):
                jax.block_until_ready(interval(state))
        path = next(Path(tmp).rglob("perfetto_trace.json.gz"))
        trace = json.loads(gzip.decompress(path.read_bytes()))
    return {
        "env": config.env,
        "algo": config.algo,
        "iterations": iterations,
        "repeats": repeats,
        "loops_on_host": loops_on_host,
        "env_steps_per_repeat": steps,
        "config": {
            "num_envs": config.num_envs,
            "minibatch_size": config.minibatch_size,
            "updates_per_iteration": config.updates_per_learning_iteration,
            "hidden_sizes": list(config.hidden_sizes),
            "compute_dtype": config.compute_dtype,
        },
        **summarize(device_kernels(trace), repeats),
    }


def markdown(result: dict[str, Any]) -> str:
    m, c = result["machine"], result["config"]
    span, busy = result["span_us"], result["busy_us"]
    lines = [
        f"# Device time of training, by kernel kind: {result['env']}, {result['algo']}\n",
        f"`{result['command']}`; {m['devices'][0]}, jax {m['jax_version']}, {m['date'][:10]}.",
        f"{result['repeats']} logging intervals of {result['iterations']} iterations "
        f"({result['env_steps_per_repeat']:,} env steps each; {c['num_envs']:,} envs, "
        f"{c['updates_per_iteration']} gradient steps of {c['minibatch_size']:,} an iteration, "
        f"network {'-'.join(map(str, c['hidden_sizes']))} in {c['compute_dtype']}).\n",
        (
            "Loops and conditionals launched by the host (`--loops-on-host`): every trip's "
            "kernels are in the trace, in a slower program than training's.\n"
            if result.get("loops_on_host")
            else "Loops and conditionals as CUDA graph nodes, as training compiles them: the "
            "trace shows few of the kernels inside them (`--loops-on-host` shows them all).\n"
        ),
        f"Span {span / 1e3:.1f} ms, kernels busy {busy / 1e3:.1f} ms ({busy / span:.0%} of the "
        f"span), {result['kernels']:,} kernels "
        f"({result['kernels'] / (result['repeats'] * result['iterations']):,.0f} an iteration).\n",
        "| kind | ms | share of kernel time |",
        "|---|---:|---:|",
    ]
    for kind, us in sorted(result["by_kind_us"].items(), key=lambda kv: -kv[1]):
        lines.append(f"| {kind} | {us / 1e3:.1f} | {us / busy:.0%} |")
    idle = result["idle_us"]
    tables = (
        ("", "longest kernels", "calls", result["top"]),
        (
            f"Idle within the intervals: {idle / 1e3:.1f} ms ({idle / span:.0%} of the span), "
            "by the kernel the device waited for:\n",
            "idle before", "waits", result["idle_before"],
        ),
    )  # fmt: skip
    for intro, heading, count, entries in tables:
        lines += ["", *([intro] if intro else []), f"| {heading} | kind | {count} | ms |"]
        lines.append("|---|---|---:|---:|")
        for t in entries:
            lines.append(
                f"| `{t['name'][:70]}` | {t['kind']} | {t[count]} | {t['total_us'] / 1e3:.1f} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.profile_training", description=__doc__.splitlines()[0]
    )
    p.add_argument("--env", default="RobotNav-v0")
    p.add_argument("--algo", default="pqn")
    p.add_argument("--config", default="{}", help="JSON TrainConfig fields after the preset")
    p.add_argument("--iterations", type=int, default=2, help="iterations per logging interval")
    p.add_argument("--repeats", type=int, default=2, help="intervals traced")
    p.add_argument(
        "--loops-on-host",
        action="store_true",
        help="loops and conditionals outside the CUDA graphs, so that the trace has every "
        "trip's kernels (a slower program than training's)",
    )
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/profile_training.json"))
    args = p.parse_args(argv)
    if min(args.iterations, args.repeats) < 1:
        p.error("--iterations and --repeats must be >= 1")
    try:
        config = train_config(args.config, env=args.env, algo=args.algo, eval_episodes=0)
    except (ValueError, TypeError) as e:  # JSONDecodeError is a ValueError
        p.error(f"--config {args.config!r}: {e}")
    try:
        result = profile(config, args.iterations, args.repeats, args.loops_on_host)
    except ValueError as e:
        print(f"benchmarks.profile_training: error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    given = sys.argv[1:] if argv is None else argv
    result = {
        "machine": machine_info(),
        "command": " ".join(["python -m benchmarks.profile_training", *given]),
        **result,
    }
    write_results(args.out, result, markdown(result))
    print(markdown(result))
    return result


if __name__ == "__main__":
    main()
