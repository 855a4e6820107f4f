"""Start-up time of each CLI entry point: a first run (empty persistent compilation cache)
against a second run of the same command (cache filled by the first).

    python -m benchmarks.compile_time [--entries grid,robot-kinematic,robot-mjx,evaluate]
        [--total-timesteps 16000] [--out benchmarks/results/compile_time.json]

Every entry point runs as a fresh ``python -m ...`` process with its own empty
``JAXNAV_CACHE_DIR``, twice. For training: "first step s" is the wall time from starting the
process to the CLI's ``compiled in`` line (imports, env construction, tracing, and XLA
compilation or cache loading: everything before the first training step), and "compile s" the
compile time the CLI itself reports in ``summary.json``. The runs are shortened to
``--total-timesteps``, rounded up to whole logging intervals (one by default); the compiled programs
are the same as a full run's, since the CLI compiles one logging interval and calls it repeatedly.
For ``jaxnav.evaluate`` (one compiled program that plays all episodes), "first step s" is the wall
time of the whole command. ``import`` is ``python -c "import jaxnav.train.__main__"`` (the training
command line and all it imports): the floor under every start-up time.

Each run also records where JAX spent its compile time (``jax.monitoring`` durations, summed
over every program of the process, evaluation included): tracing to a jaxpr, lowering to
StableHLO (both happen on every run: the persistent cache is keyed by the lowered program),
and XLA compilation or loading from the cache; plus the number of persistent-cache hits.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import machine_info, write_results

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = Path("benchmarks/results/compile_time.json")
PHASES = {
    "trace_s": "/jax/core/compile/jaxpr_trace_duration",
    "lower_s": "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "compile_or_load_s": "/jax/core/compile/backend_compile_duration",
}
CACHE_HIT = "/jax/compilation_cache/cache_hits"
RECORD = "--record-phases"  # internal: run a CLI entry point in-process, recording PHASES
TRAIN_ENTRIES = {
    "grid": ["--env", "GridMaze-v0"],
    "robot-kinematic": ["--env", "RobotSimple-v0", "--env-arg", "backend=kinematic"],
    "robot-mjx": ["--env", "RobotSimple-v0", "--env-arg", "backend=mjx"],
}
ENTRIES = (*TRAIN_ENTRIES, "evaluate")
TARGETS = {"grid": 10.0, "robot-kinematic": 30.0, "robot-mjx": 30.0}  # first-run compile s
SECOND_RUN_TARGET_S = 3.0


def run_recording_phases(out: Path, entry: str, argv: list[str]) -> int:
    """Run the command line ``entry`` (train or evaluate) in this process; write JAX's compile
    phase durations and the persistent-cache hits to ``out`` (JSON)."""
    import jax

    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.train.__main__ import main as train_main

    totals = dict.fromkeys([*PHASES, "cache_hits"], 0.0)
    names = {event: key for key, event in PHASES.items()}

    def on_duration(event: str, secs: float, **_: Any) -> None:
        if event in names:
            totals[names[event]] += secs

    def on_event(event: str, **_: Any) -> None:
        totals["cache_hits"] += event == CACHE_HIT

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    jax.monitoring.register_event_listener(on_event)
    try:
        return {"train": train_main, "evaluate": evaluate_main}[entry](argv)
    finally:
        out.write_text(json.dumps(totals))


def timed_command(argv: list[str], cache_dir: Path, marker: str | None) -> dict[str, Any]:
    """Run ``python argv``; wall seconds until a stdout line starts with ``marker`` (or until
    exit when None) and in total. Raises with the output if the command fails."""
    env = {**os.environ, "JAXNAV_CACHE_DIR": str(cache_dir)}
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        cwd=ROOT,  # where `python -m benchmarks...` finds the package
    )
    marked, lines = None, []
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append(line)
        if marked is None and marker is not None and line.startswith(marker):
            marked = time.perf_counter() - t0
    total = time.perf_counter() - t0
    if proc.wait() != 0:
        raise RuntimeError(f"{' '.join(argv)} failed:\n{''.join(lines[-20:])}")
    return {"first_step_s": total if marker is None else marked, "total_s": total}


def measure_train(name: str, flags: list[str], work: Path) -> dict[str, Any]:
    """``python -m jaxnav.train FLAGS`` twice with one fresh cache directory."""
    cache = work / f"cache-{name}"
    runs = []
    for i in (1, 2):
        out, phases = work / f"{name}-{i}", work / f"{name}-{i}-phases.json"
        argv = ["-m", "benchmarks.compile_time", RECORD, str(phases), "train"]
        run = timed_command([*argv, *flags, "--out", str(out)], cache, "compiled in")
        run["compile_s"] = json.loads((out / "summary.json").read_text())["compile_s"]
        run["phases"] = json.loads(phases.read_text())
        runs.append(run)
    return {"entry": name, "command": "python -m jaxnav.train " + " ".join(flags)} | _runs(runs)


def measure_evaluate(run_dir: Path, work: Path) -> dict[str, Any]:
    cache, phases = work / "cache-evaluate", work / "evaluate-phases.json"
    argv = ["-m", "benchmarks.compile_time", RECORD, str(phases), "evaluate", str(run_dir)]
    runs = []
    for _ in (1, 2):
        runs.append(timed_command([*argv, "--episodes", "1000"], cache, None))
        runs[-1]["phases"] = json.loads(phases.read_text())
    return {"entry": "evaluate", "command": "python -m jaxnav.evaluate RUN"} | _runs(runs)


def _runs(runs: list[dict[str, Any]]) -> dict[str, Any]:
    return {"first_run": runs[0], "second_run": runs[1]}


def measure_import(work: Path) -> dict[str, Any]:
    command = "import jaxnav.train.__main__"
    run = timed_command(["-c", command], work / "cache-import", None)
    return {"entry": "import", "command": f'python -c "{command}"', "first_run": run}


def phases(run: dict[str, Any] | None) -> str:
    """``trace + lower + compile-or-load`` seconds and cache hits of one run, for the table."""
    if run is None or "phases" not in run:
        return "-"
    p = run["phases"]
    return (
        f"{p['trace_s']:.1f} + {p['lower_s']:.1f} + {p['compile_or_load_s']:.1f} "
        f"({p['cache_hits']:.0f} hits)"
    )


def table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| entry point | first run: first step s | compile s | second run: first step s "
        "| compile s | JAX trace + lower + compile/load s, first / second run | target |",
        "|---|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        one, two = r["first_run"], r.get("second_run")
        cell = lambda run, k: "-" if run is None or k not in run else f"{run[k]:.1f}"  # noqa: E731
        target = (
            f"compile <= {TARGETS[r['entry']]:g} s, second <= {SECOND_RUN_TARGET_S:g} s"
            if r["entry"] in TARGETS
            else "-"
        )
        lines.append(
            f"| `{r['command']}` | {cell(one, 'first_step_s')} | {cell(one, 'compile_s')} | "
            f"{cell(two, 'first_step_s')} | {cell(two, 'compile_s')} | "
            f"{phases(one)} / {phases(two)} | {target} |"
        )
    return "\n".join(lines)


def short(name: str, total_timesteps: int) -> list[str]:
    """Flags of a short run of train entry ``name``: ``total_timesteps`` rounded up to whole
    logging intervals of the entry's preset (the CLI trains whole intervals only)."""
    from jaxnav.config import TrainConfig

    per_log = TrainConfig.for_env(TRAIN_ENTRIES[name][1]).steps_per_log
    steps = -(-total_timesteps // per_log) * per_log
    return ["--quiet", "--total-timesteps", str(steps), "--eval-episodes", "100"]


def measure(entries: list[str], total_timesteps: int) -> list[dict[str, Any]]:
    """The import floor, then each entry point twice (evaluate reads the grid run)."""
    with tempfile.TemporaryDirectory(prefix="jaxnav-compile-") as tmp:
        work = Path(tmp)
        rows = [measure_import(work)]
        for name in entries:
            if name in TRAIN_ENTRIES:
                flags = TRAIN_ENTRIES[name] + short(name, total_timesteps)
                rows.append(measure_train(name, flags, work))
            else:
                if not (work / "grid-1").exists():
                    flags = TRAIN_ENTRIES["grid"] + short("grid", total_timesteps)
                    measure_train("grid", flags, work)
                rows.append(measure_evaluate(work / "grid-1", work))
            print(table(rows[-1:]).splitlines()[-1], file=sys.stderr)
    return rows


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--entries", default=",".join(ENTRIES), help=f"comma-separated of {ENTRIES}")
    p.add_argument("--total-timesteps", type=int, default=16_000, help="steps of each train run")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output path")
    args = p.parse_args(argv)
    args.entries = [e.strip() for e in args.entries.split(",") if e.strip()]
    unknown = [e for e in args.entries if e not in ENTRIES]
    if unknown or args.total_timesteps < 1:
        p.error(f"unknown entries {unknown} (valid: {ENTRIES}), or total timesteps < 1")
    return args


def main(argv: list[str] | None = None) -> dict[str, Any] | int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == [RECORD]:
        return run_recording_phases(Path(argv[1]), argv[2], argv[3:])
    args = parse_args(argv)
    info = machine_info()
    rows = measure(args.entries, args.total_timesteps)
    md = table(rows)
    print(md)
    result = {"machine": info, "total_timesteps": args.total_timesteps, "results": rows}
    write_results(args.out, result, md)
    return result


if __name__ == "__main__":
    result = main()
    sys.exit(result if isinstance(result, int) else 0)
