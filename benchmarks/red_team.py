"""Red team: hostile inputs and faults against every command line (train, evaluate, render,
export, experiments, pretrained, deploy), the library's entry points (``jaxnav.make``, env
options, maze files, occupancy maps) and the deployment layer (``Policy``, ``LaserScan``,
``ScanObservation``).

    python -m benchmarks.red_team [--only TEXT] [--out benchmarks/results/red_team.json]

Each case states its documented outcome: exit 2 for bad input, 4 for a write the machine
refused, 130/143 for SIGINT/SIGTERM, 0 where a hostile-looking value is valid, or for the
library a ``ValueError``. A command case passes when it exits so, prints one line on stderr
(the last line for a signal, after the handler's notice) without "Traceback", and leaves no
half-written file (``*.partial*``, ``*.tmp``) and, when it fails, nothing new at all. Most
cases run in this process (a command's ``main(argv)``); a few signals need a process of their
own. Full and read-only disks are real tmpfs mounts, made where this runs as root (elsewhere
those cases are left out; the counts say how many ran).

Prints a table (case, expected, got, pass) and writes a JSON summary.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import errno
import io
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "red_team.json"
ROOT = Path(__file__).resolve().parents[1]
MAZES = ROOT / "examples" / "mazes"
ROOMS = (MAZES / "rooms.txt").read_bytes()
CASE_TIMEOUT_S = 300  # a case still running then is a hang: a failure

TINY = [
    "--env-arg", "size=5",
    "--hidden-sizes", "16",
    "--num-envs", "4",
    "--batch-size", "8",
    "--replay-ratio", "2",
    "--buffer-size", "64",
    "--learning-starts", "8",
    "--log-interval", "32",
    "--target-update-period", "10",
    "--eps-decay-steps", "64",
    "--quiet",
    "--total-timesteps", "64",
    "--eval-episodes", "2",
    "--checkpoint-every", "32",
]  # fmt: skip


class Accepted(BaseException):
    """Raised in place of training: the command accepted its input (exit 0 for the table)."""


class Hang(BaseException):
    """The case ran past ``CASE_TIMEOUT_S``."""


@dataclasses.dataclass
class Case:
    area: str
    name: str
    expect: tuple[Any, ...]  # exit codes, or "ValueError" / "ok" for library calls
    run: Callable[[Path], Any]  # in the case's own directory: (code, stdout, stderr) or a value
    train: bool = False  # really train (else a command that would train is stopped: Accepted)
    signal_case: bool = False  # judged by stderr's last line
    nothing_new: bool | None = None  # None: when it fails


@dataclasses.dataclass
class Result:
    area: str
    name: str
    expected: str
    got: str
    passed: bool
    why: str
    seconds: float
    line: str  # the last line on stderr (the error the user reads)


# ------------------------------------------------------------------ running one case
NEW_FILES: list[set[Path]] = []  # what each command wrote in its working directory
HALF_WRITTEN: list[Path] = []  # temporary files a command left there


def call(main: Callable[[list[str]], int], argv: list[str]) -> tuple[Any, str, str]:
    """``main(argv)`` in this process: (exit code or "crash", stdout, stderr); the files it
    left in the working directory (the case's) go to ``NEW_FILES`` and ``HALF_WRITTEN``."""
    before = files_under(Path.cwd())
    try:
        return _call(main, argv)
    finally:
        new = files_under(Path.cwd()) - before
        NEW_FILES.append(new)
        HALF_WRITTEN.extend(half_written(new))


def _call(main: Callable[[list[str]], int], argv: list[str]) -> tuple[Any, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code: Any = main(argv)
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        except Accepted:
            code = 0
        except Hang:
            raise
        except BaseException:  # noqa: BLE001 (what the red team looks for)
            traceback.print_exc(file=err)
            code = "crash"
    return code, out.getvalue(), err.getvalue()


def library(fn: Callable[[], Any]) -> tuple[Any, str, str]:
    """A library call: ("ValueError", "", message) when it refuses, ("ok", "", "") else."""
    try:
        fn()
    except ValueError as e:
        return "ValueError", "", str(e)
    except Hang:
        raise
    except BaseException:  # noqa: BLE001
        return "crash", "", traceback.format_exc()
    return "ok", "", ""


def files_under(root: Path) -> set[Path]:
    return {p for p in root.rglob("*")} if root.exists() else set()


def half_written(paths: set[Path]) -> list[Path]:
    return [
        p for p in paths if not p.is_dir() and (".partial" in p.name or p.name.endswith(".tmp"))
    ]  # a run's own .NAME.partial is a directory


@contextlib.contextmanager
def time_limit(seconds: int) -> Iterator[None]:
    def alarm(signum: int, frame: Any) -> None:
        raise Hang

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def run_case(case: Case, root: Path) -> Result:
    from jaxnav import runner

    where = root / f"case{abs(hash((case.area, case.name))) % 10**10}"
    where.mkdir()
    NEW_FILES.clear()
    HALF_WRITTEN.clear()
    cwd = os.getcwd()
    train_seeds = runner.train_seeds
    if not case.train:

        def accepted(*args: Any, **kwargs: Any) -> Any:
            raise Accepted

        runner.train_seeds = accepted
    t0 = time.perf_counter()
    try:
        os.chdir(where)
        with time_limit(CASE_TIMEOUT_S):
            outcome = case.run(where)
    except Hang:
        outcome = ("hang", "", f"still running after {CASE_TIMEOUT_S} s")
    except BaseException:  # noqa: BLE001 (the harness's own setup)
        outcome = ("crash", "", traceback.format_exc())
    finally:
        os.chdir(cwd)
        runner.train_seeds = train_seeds
    seconds = time.perf_counter() - t0
    code, _, err = outcome
    expected = "|".join(map(str, case.expect))
    why = judge(case, code, err, set().union(*NEW_FILES))
    last = (err.strip().splitlines() or [""])[-1][:300]
    scratch = str(root)  # this machine's scratch directory, not kept in the results
    last, why = (text.replace(scratch, "$TMP") for text in (last, why))
    return Result(case.area, case.name, expected, str(code), not why, why, round(seconds, 3), last)


def judge(case: Case, code: Any, err: str, new: set[Path]) -> str:
    """Why the case failed ('' when it passed); ``new``: the files its commands wrote."""
    if code not in case.expect:
        last = err.strip().splitlines()[-1:] or [""]
        return f"exit {code}: {last[0][:200]}"
    if "Traceback" in err:
        return "a traceback on stderr"
    lines = err.strip().splitlines()
    if case.signal_case:
        if not lines or "stopped by" not in lines[-1]:
            return f"last stderr line {lines[-1:]!r} does not say it stopped"
    elif code not in (0, "ok") and len(lines) != 1:
        return f"{len(lines)} lines on stderr: {err.strip()[:300]!r}"
    partial = [p for p in HALF_WRITTEN if os.path.lexists(p)]
    if partial:
        return f"half-written files left: {sorted(map(str, partial))[:3]}"
    nothing_new = case.nothing_new
    if nothing_new is None:
        nothing_new = code not in (0, "ok", "ValueError", 130, 143)
    if nothing_new and new:
        return f"left behind: {sorted(str(p.relative_to(p.parents[1])) for p in new)[:3]}"
    return ""


# ------------------------------------------------------------------ shared fixtures
@dataclasses.dataclass
class World:
    """What cases read: a trained run, its exported policies, a policy file, mounts."""

    root: Path
    run: Path
    npz: Path
    onnx: Path | None
    full: Path | None  # a full tmpfs (None: not root)
    read_only: Path | None
    mounts: list[Path]


def mount_tmpfs(where: Path, size: str = "512k") -> bool:
    where.mkdir(parents=True)
    cmd = ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)]
    return subprocess.run(cmd, capture_output=True).returncode == 0


def fill(where: Path) -> None:
    fd = os.open(where / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        while True:
            os.write(fd, b"\0" * 4096)
    except OSError as e:
        if e.errno != errno.ENOSPC:
            raise
    finally:
        os.close(fd)


def make_world(root: Path) -> World:
    from jaxnav.export import main as export_main
    from jaxnav.train.__main__ import main as train_main

    run = root / "run"
    code, _, err = call(train_main, [*TINY, "--out", str(run)])
    assert code == 0, err
    code, _, err = call(export_main, [str(run), "--out", str(root / "policy.npz")])
    assert code == 0, err
    onnx: Path | None = root / "policy.onnx"
    code, _, err = call(export_main, [str(run), "--format", "onnx", "--out", str(onnx)])
    if code != 0:
        onnx = None  # no onnx package: its cases are skipped
    mounts: list[Path] = []
    full = read_only = None
    if mount_tmpfs(root / "full"):
        mounts.append(root / "full")
        shutil.copytree(run, root / "full" / "run", ignore=shutil.ignore_patterns("params"))
        fill(root / "full")
        full = root / "full"
    if mount_tmpfs(root / "ro", "4m"):
        mounts.append(root / "ro")
        shutil.copytree(run, root / "ro" / "run")
        shutil.copy(root / "policy.npz", root / "ro" / "policy.npz")
        remount = ["mount", "-o", "remount,ro", str(root / "ro")]
        subprocess.run(remount, check=True, capture_output=True)
        read_only = root / "ro"
    return World(root, run, root / "policy.npz", onnx, full, read_only, mounts)


def special(where: Path, kind: str, suffix: str = "") -> Path:
    """A hostile path of ``kind`` in ``where`` (made there)."""
    path = where / f"{kind}{suffix}"
    if kind == "dir":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "link":
        (where / "target").write_text("kept")
        path.symlink_to(where / "target")
    elif kind == "dangling":
        path.symlink_to(where / "nowhere")
    elif kind == "loop":
        path.symlink_to(path)
    elif kind == "missing":
        pass
    elif kind == "through_file":
        (where / "afile").write_text("x")
        path = where / "afile" / f"x{suffix}"
    elif kind == "no_parent":
        path = where / "no" / "such" / f"x{suffix}"
    elif kind == "empty_file":
        path.write_bytes(b"")
    elif kind == "garbage":
        path.write_bytes(bytes(range(256)) * 8)
    elif kind == "unicode":
        path = where / f"ǅ☃ é{suffix}"
        path.write_bytes(b"\xff\xfe garbage")
    elif kind == "long_name":
        path = where / ("x" * 300 + suffix)
    else:
        raise ValueError(kind)
    return path


PATH_KINDS = ("dir", "fifo", "link", "dangling", "loop", "through_file", "no_parent")


# ------------------------------------------------------------------ the cases
def train_cases(world: World) -> list[Case]:
    from jaxnav.train.__main__ import main as train_main

    def train(argv: list[str], **kw: Any) -> Callable[[Path], Any]:
        return lambda where: call(train_main, [*TINY, "--out", str(where / "r"), *argv])

    cases: list[Case] = []
    bad_numbers = ["nan", "inf", "-inf", "1e999", "abc", "", "½", "0x10", "1" * 30]
    int_flags = [
        "--seed", "--num-seeds", "--total-timesteps", "--num-envs", "--buffer-size",
        "--batch-size", "--learning-starts", "--n-step", "--target-update-period",
        "--rollout-length", "--num-epochs", "--num-minibatches", "--eps-decay-steps",
        "--log-interval", "--eval-episodes", "--checkpoint-every", "--keep-checkpoints",
    ]  # fmt: skip
    float_flags = [
        "--replay-ratio", "--gamma", "--lr", "--lr-end", "--max-grad-norm", "--tau",
        "--eps-start", "--eps-end", "--td-lambda", "--clip-eps", "--vf-coef", "--ent-coef",
    ]  # fmt: skip
    for flag in int_flags:
        for value in ["nan", "1.5", "abc", "", "-1", "1" * 30]:
            cases.append(Case("train", f"{flag} {value!r}", (2,), train([flag, value])))
    for flag in float_flags:
        for value in bad_numbers[:6] + ["-1", "1e30"]:
            cases.append(Case("train", f"{flag} {value!r}", (2,), train([flag, value])))
    for flag in ["--dueling", "--double", "--layer-norm", "--fused-layer-norm", "--clip-value"]:
        for value in ["maybe", "", "2", "nan"]:
            cases.append(Case("train", f"{flag} {value!r}", (2,), train([flag, value])))
    for flag in ["--env", "--algo", "--compute-dtype", "--loss", "--optimizer"]:
        for value in ["", " ", "nope", "ǅ☃", "../../etc/passwd", "x" * 5000]:
            cases.append(Case("train", f"{flag} {value[:20]!r}", (2,), train([flag, value])))
    for value in ["", "0", "-1", "1,,2", "nan", "99999999", "1e9", "16;rm"]:
        cases.append(
            Case("train", f"--hidden-sizes {value!r}", (2,), train(["--hidden-sizes", value]))
        )
    for value in ["", "0", "-1", "abc", "99", "nan"]:
        cases.append(Case("train", f"--devices {value!r}", (2,), train(["--devices", value])))
    env_args = [
        "size", "=5", "size=", "size=nan", "size=1e999", "nosuch=1", "size=[", "size=5=6",
        "ǅ=1", "size=-3", "size=100000", "size=true", "size=\"7\"", "obstacle_density=2",
        "obstacle_density=nan", "num_layouts=-1", "num_layouts=10000000000",
        "max_steps=0", "max_steps=1e999", "max_steps=nan",
    ]  # fmt: skip
    for value in env_args:
        cases.append(Case("train", f"--env-arg {value!r}", (2,), train(["--env-arg", value])))
    cases.append(
        Case("train", "--env-arg size=5 twice", (2,), train(["--env-arg", "size=6"]))
    )  # TINY gives size=5: a repeated key is refused
    robot = ["--env", "RobotMaze-v0", "--env-arg", "backend=kinematic"]

    def maze(kind: str, content: bytes | None = None) -> Callable[[Path], Any]:
        def run(where: Path) -> Any:
            if content is not None:
                path = where / f"{kind}.txt"
                path.write_bytes(content)
            else:
                path = special(where, kind, ".txt")
            argv = [a for a in TINY if a not in ("--env-arg", "size=5")]
            return call(
                train_main, [*argv, *robot, "--maze-file", str(path), "--out", str(where / "r")]
            )

        return run

    for kind in ("dir", "fifo", "dangling", "loop", "missing", "through_file", "empty_file",
                 "garbage", "unicode"):  # fmt: skip
        cases.append(Case("maze file", f"--maze-file {kind}", (2,), maze(kind)))
    mazes = {
        "no free cell": ROOMS.replace(b".", b"#"),  # a maze large enough for the robot
        "one free cell": b"cell_size: 1.0\n" + b"#" * 10 + b"\n" + b"#" * 9 + b".\n",
        "two starts": b"cell_size: 0.5\nS..S\n...G\n",
        "ragged rows": b"cell_size: 0.5\nS...\n..\n...G\n",
        "unknown char": b"cell_size: 0.5\nS.x.\n...G\n",
        "cell_size nan": b"cell_size: nan\nS...\n...G\n",
        "cell_size -1": b"cell_size: -1\nS...\n...G\n",
        "cell_size 1e999": b"cell_size: 1e999\nS...\n...G\n",
        "200x200": b"cell_size: 0.5\n"
        + b"S"
        + b"." * 199
        + b"\n"
        + (b"." * 200 + b"\n") * 198
        + b"." * 199
        + b"G\n",
        "goal walled in": b"cell_size: 0.5\nS..#.\n...#G\n",
        "NUL bytes": b"cell_size: 0.5\nS.\x00.\n...G\n",
        "latin-1": b"cell_size: 0.5\n\xe9S...\n...G\n",
        "one huge line": b"cell_size: 0.5\nS" + b"." * 2_000_000 + b"G\n",
        "only a header": b"cell_size: 0.5\n",
    }
    for name, content in mazes.items():
        cases.append(Case("maze file", f"maze file: {name}", (2,), maze("m", content)))
    cases.append(
        Case("maze file", "maze file: UTF-8 BOM (read as without)", (0,),
             maze("bom", b"\xef\xbb\xbf" + ROOMS),
             nothing_new=False)
    )  # fmt: skip
    cases.append(Case("train", "control: the tiny run's flags are accepted", (0,),
                      train([]), nothing_new=False))  # fmt: skip
    for kind in PATH_KINDS + ("empty_name", "dot", "file", "nonempty_dir"):

        def out_case(where: Path, kind: str = kind) -> Any:
            if kind == "nonempty_dir":
                out = str(special(where, "dir"))
                (where / "dir" / "mine.txt").write_text("mine")
            elif kind == "empty_name":
                out = ""
            elif kind == "dot":
                out = "."
            elif kind == "file":
                out = str(where / "afile")
                (where / "afile").write_text("x")
            else:
                out = str(special(where, kind))
            return call(train_main, [*TINY, "--out", out])

        expect = (0,) if kind in ("no_parent", "dir") else (2,)  # an empty dir: documented
        cases.append(
            Case(
                "train",
                f"--out {kind}",
                expect,
                out_case,
                nothing_new=None if expect == (2,) else False,
            )
        )
    for kind in ("missing", "file", "empty_dir", "garbage_config", "empty_config", "complete",
                 "fifo", "loop"):  # fmt: skip

        def resume(where: Path, kind: str = kind) -> Any:
            if kind == "complete":
                target = world.run
            elif kind in ("fifo", "loop", "missing"):
                target = special(where, kind)
            elif kind == "file":
                target = where / "afile"
                target.write_text("x")
            else:
                target = where / "r"
                partial = where / ".r.partial"
                partial.mkdir()
                if kind == "garbage_config":
                    (partial / "config.json").write_bytes(b"\x00{garbage")
                elif kind == "empty_config":
                    (partial / "config.json").write_bytes(b"")
            return call(train_main, ["--resume", str(target)])

        cases.append(Case("train", f"--resume {kind}", (2,), resume))
    for coord in ["x", "host:99999", ":", "", "localhost:0", "[::1", "ǅ:1"]:
        argv = ["--coordinator", coord, "--num-processes", "2", "--process-id", "0"]
        cases.append(Case("train", f"--coordinator {coord!r}", (2,), train(argv)))
    for n, i in [("2", "2"), ("0", "0"), ("-1", "0"), ("2", "-1")]:
        argv = ["--coordinator", "localhost:1234", "--num-processes", n, "--process-id", i]
        cases.append(Case("train", f"--num-processes {n} --process-id {i}", (2,), train(argv)))
    cases.append(Case("train", "unknown flag", (2,), train(["--nope"])))
    cases.append(Case("train", "positional argument", (2,), train(["stray"])))
    return cases


def write_fault_cases(world: World) -> list[Case]:
    """Commands writing into a full or a read-only file system (real tmpfs mounts)."""
    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.experiments import main as experiments_main
    from jaxnav.export import main as export_main
    from jaxnav.render import main as render_main
    from jaxnav.train.__main__ import main as train_main

    cases: list[Case] = []
    run = str(world.run)
    for state, disk in (("full", world.full), ("read-only", world.read_only)):
        if disk is None:
            continue
        commands = {
            "evaluate --out": lambda w, d=disk: call(
                evaluate_main, [run, "--episodes", "1", "--out", str(d / "e.json")]
            ),
            "render --out png": lambda w, d=disk: call(
                render_main, [run, "--episodes", "1", "--quiet", "--out", str(d / "t.png")]
            ),
            "render --out gif": lambda w, d=disk: call(
                render_main, [run, "--episodes", "1", "--quiet", "--out", str(d / "t.gif")]
            ),
            "render --out svg": lambda w, d=disk: call(
                render_main, [run, "--episodes", "1", "--quiet", "--out", str(d / "t.svg")]
            ),
            "export npz": lambda w, d=disk: call(export_main, [run, "--out", str(d / "p.npz")]),
            "export onnx": lambda w, d=disk: call(
                export_main, [run, "--format", "onnx", "--out", str(d / "p.onnx")]
            ),
            "export into its run": lambda w, d=disk: call(export_main, [str(d / "run")]),
            "evaluate into its run": lambda w, d=disk: call(
                evaluate_main, [str(d / "run"), "--episodes", "1"]
            ),
            "experiments plot": lambda w, d=disk: call(experiments_main, ["plot", str(d / "run")]),
        }
        if state == "full":
            del commands["export into its run"], commands["evaluate into its run"]  # no params
            commands["experiments plot"] = commands["experiments plot"]
        for name, command in commands.items():
            if "onnx" in name and world.onnx is None:
                continue

            def fault(where: Path, command: Callable = command, disk: Path = disk) -> Any:
                before = files_under(disk)
                outcome = command(where)
                left = files_under(disk) - before
                if left:
                    return ("left", "", f"left on the disk: {sorted(map(str, left))[:3]}")
                return outcome

            cases.append(Case("write fault", f"{name} on a {state} disk", (4,), fault))
        train_argv = [*TINY, "--out", str(disk / f"run-{state}")]
        cases.append(
            Case("write fault", f"train --out on a {state} disk", (4,),
                 lambda w, a=train_argv: call(train_main, a), train=True)
        )  # fmt: skip
    return cases


def command_cases(world: World) -> list[Case]:
    """evaluate, render, export, experiments, pretrained and deploy.policy, hostile inputs."""
    from jaxnav.deploy.policy import main as describe_main
    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.experiments import main as experiments_main
    from jaxnav.export import main as export_main
    from jaxnav.pretrained.__main__ import main as pretrained_main
    from jaxnav.render import main as render_main

    run = str(world.run)
    cases: list[Case] = []
    commands = {
        "evaluate": (evaluate_main, ["--episodes", "1"], ".json"),
        "render": (render_main, ["--episodes", "1", "--quiet"], ".png"),
        "export": (export_main, [], ".npz"),
    }

    def damaged_run(where: Path, damage: str) -> Path:
        target = where / "run"
        shutil.copytree(world.run, target)
        if damage == "config garbage":
            (target / "config.json").write_bytes(b"\x00\xffgarbage")
        elif damage == "config empty":
            (target / "config.json").write_bytes(b"")
        elif damage == "config truncated":
            text = (target / "config.json").read_bytes()
            (target / "config.json").write_bytes(text[: len(text) // 2])
        elif damage == "config a list":
            (target / "config.json").write_text("[]")
        elif damage == "config unknown field":
            doc = json.loads((target / "config.json").read_text())
            doc["config"]["nope"] = 1
            (target / "config.json").write_text(json.dumps(doc))
        elif damage == "config nan lr":
            doc = json.loads((target / "config.json").read_text())
            doc["config"]["lr"] = float("nan")
            (target / "config.json").write_text(json.dumps(doc))
        elif damage == "no params":
            shutil.rmtree(target / "params")
        elif damage == "params flipped byte":
            files = sorted(p for p in (target / "params").rglob("*") if p.is_file())
            data = bytearray(files[-1].read_bytes())
            data[len(data) // 2] ^= 0x04
            files[-1].write_bytes(bytes(data))
        elif damage == "params truncated":
            files = sorted(p for p in (target / "params").rglob("*") if p.is_file())
            big = max(files, key=lambda p: p.stat().st_size)
            big.write_bytes(big.read_bytes()[:10])
        elif damage == "config a FIFO":
            (target / "config.json").unlink()
            os.mkfifo(target / "config.json")
        return target

    damages = ["config garbage", "config empty", "config truncated", "config a list",
               "config unknown field", "config nan lr", "no params", "params flipped byte",
               "params truncated", "config a FIFO"]  # fmt: skip
    for cmd, (main, extra, suffix) in commands.items():
        for kind in ("missing", "fifo", "loop", "dangling", "garbage", "empty_file", "unicode"):
            cases.append(
                Case(cmd, f"RUN is {kind}", (2,),
                     lambda w, m=main, e=extra, k=kind: call(m, [str(special(w, k)), *e]))
            )  # fmt: skip
        cases.append(Case(cmd, "RUN is ''", (2,), lambda w, m=main, e=extra: call(m, ["", *e])))
        for damage in damages:

            def damaged(where: Path, m=main, e=extra, d=damage, s=suffix) -> Any:
                target = damaged_run(where, d)
                before = files_under(where)
                outcome = call(m, [str(target), *e, "--out", str(where / f"o{s}")])
                if files_under(where) - before:
                    return ("wrote", "", "wrote from a damaged run")
                return outcome

            cases.append(Case(cmd, f"run with {damage}", (2,), damaged, nothing_new=False))
        for kind in PATH_KINDS + ("long_name",):
            cases.append(
                Case(cmd, f"--out {kind}", (2,),
                     lambda w, m=main, e=extra, k=kind, s=suffix:
                     call(m, [run, *e, "--out", str(special(w, k, s))]))
            )  # fmt: skip
        cases.append(
            Case(cmd, "--out ''", (2,), lambda w, m=main, e=extra: call(m, [run, *e, "--out", ""]))
        )
        for flag, value in [("--run-seed", "99"), ("--run-seed", "-1"), ("--run-seed", "nan")]:
            if cmd == "evaluate":
                continue
            cases.append(
                Case(cmd, f"{flag} {value}", (2,),
                     lambda w, m=main, e=extra, f=flag, v=value: call(m, [run, *e, f, v]))
            )  # fmt: skip
    for cmd, main in (("evaluate", evaluate_main), ("render", render_main)):
        extra = ["--quiet"] if cmd == "render" else []
        for flag, values in {
            "--episodes": ["0", "-1", "nan", "99999999999", ""],
            "--seed": ["-1", "nan", "1" * 30, ""],
            "--env": ["", "nope", "ǅ"],
            "--env-arg": ["size=nan", "nosuch=1", "size", "size=-1"],
            "--maze-file": ["", "/nonexistent/m.txt"],
            "--policy": ["best", ""],
            "--pretrained": ["nope", "", "../x"],
        }.items():
            for value in values:
                argv = [run, *extra, flag, value] if flag != "--pretrained" else [flag, value]
                cases.append(
                    Case(cmd, f"{flag} {value!r}", (2,), lambda w, m=main, a=argv: call(m, a))
                )
        cases.append(
            Case(
                cmd,
                "RUN and --pretrained",
                (2,),
                lambda w, m=main: call(m, [run, "--pretrained", "gridmaze-dqn"]),
            )
        )
    # fmt: skip
    for value in ["0", "101", "-5", "nan"]:
        cases.append(Case("render", f"--fps {value}", (2,),
                          lambda w, v=value:
                              call(render_main, [run, "--fps", v, "--quiet"])))  # fmt: skip
    for suffix in (".txt", ".jpg", ""):
        cases.append(
            Case(
                "render",
                f"--out suffix {suffix!r}",
                (2,),
                lambda w, s=suffix: call(render_main, [run, "--quiet", "--out", str(w / f"t{s}")]),
            )
        )
    for fmt, suffix in [("npz", ".onnx"), ("onnx", ".npz"), ("zip", ".zip"), ("", ".npz")]:
        cases.append(
            Case(
                "export",
                f"--format {fmt!r} --out *{suffix}",
                (2,),
                lambda w, f=fmt, s=suffix: call(
                    export_main, [run, "--format", f, "--out", str(w / f"p{s}")]
                ),
            )
        )
    # experiments
    for argv in (
        ["plot", ""], ["plot", "/nonexistent"], ["nope"], [], ["paper-grid", "--seeds", "1"],
        ["paper-grid", "--seeds", "nan"], ["paper-grid", "--seed", "-1"],
        ["paper-grid", "--test-episodes", "0"], ["paper-grid", "--total-timesteps", "-5"],
        ["paper-robot", "--maze-file", "/nonexistent.txt"], ["generalization"],
        ["generalization", "/nonexistent"], ["generalization", run, "--episodes", "0"],
        ["generalization", run, "--gifs", "99"], ["generalization", run, "--family", "nope"],
        ["generalization", run, "--seed", "-1"],
    ):  # fmt: skip
        name = " ".join(argv).replace(run, "RUN") or "(no arguments)"
        cases.append(Case("experiments", name, (2,),
                          lambda w, a=argv: call(experiments_main, a)))  # fmt: skip
    for kind in ("fifo", "garbage", "empty_file", "dir"):

        def plot(where: Path, kind: str = kind) -> Any:
            target = where / "results"
            target.mkdir()
            (target / "metrics.csv").write_text("seed,env_steps\n")
            if kind == "dir":
                (target / "results.json").mkdir()
            else:
                special(target, kind)
                (target / kind).rename(target / "results.json")
            return call(experiments_main, ["plot", str(target)])

        cases.append(Case("experiments", f"plot: results.json is {kind}", (2,), plot,
                          nothing_new=False))  # fmt: skip
    for kind in ("link", "fifo", "dir"):

        def plot_out(where: Path, kind: str = kind) -> Any:
            target = where / "run"
            shutil.copytree(world.run, target)
            special(target, kind, ".png")
            (target / f"{kind}.png").rename(target / "training_curves.png")
            return call(experiments_main, ["plot", str(target)])

        cases.append(Case("experiments", f"plot: training_curves.png is a {kind}", (2,),
                          plot_out, nothing_new=False))  # fmt: skip
    # pretrained (the package folder replaced by a copy: nothing here writes into jaxnav)
    for name, argv_of in {
        "garbage file": lambda w: [
            "add",
            "x",
            str(special(w, "garbage", ".npz")),
            "--command",
            "c",
        ],
        "missing file": lambda w: ["add", "x", str(w / "no.npz"), "--command", "c"],
        "fifo file": lambda w: ["add", "x", str(special(w, "fifo", ".npz")), "--command", "c"],
        "directory": lambda w: ["add", "x", str(special(w, "dir")), "--command", "c"],
        "bad name": lambda w: ["add", "../x", str(world.npz), "--command", "c"],
        "empty name": lambda w: ["add", "", str(world.npz), "--command", "c"],
        "unicode name": lambda w: ["add", "ǅ☃", str(world.npz), "--command", "c"],
        "no --command": lambda w: ["add", "x", str(world.npz)],
        "shipped name": lambda w: ["add", "gridmaze-dqn", str(world.npz), "--command", "c"],
        "--episodes 0": lambda w: ["add", "x", str(world.npz), "--command", "c", "--episodes", "0"],
        "--seed -1": lambda w: ["add", "x", str(world.npz), "--command", "c", "--seed", "-1"],
        "--episodes nan": lambda w: [
            "add",
            "x",
            str(world.npz),
            "--command",
            "c",
            "--episodes",
            "nan",
        ],
        "unknown verb": lambda w: ["remove", "x"],
    }.items():
        cases.append(
            Case(
                "pretrained",
                f"add: {name}",
                (2,),
                lambda w, f=argv_of: with_package_copy(w, lambda: call(pretrained_main, f(w))),
            )
        )
    # deploy.policy's description command
    for kind in ("missing", "fifo", "dir", "loop", "garbage", "empty_file", "unicode"):
        cases.append(Case("deploy", f"describe {kind}", (2,),
                          lambda w, k=kind:
                              call(describe_main, [str(special(w, k, ".npz"))])))  # fmt: skip
    cases.append(Case("deploy", "describe: two arguments", (2,),
                      lambda w: call(describe_main, ["a", "b"])))  # fmt: skip
    return cases


def with_package_copy(where: Path, fn: Callable[[], Any]) -> Any:
    """Run ``fn`` with jaxnav.pretrained's folder and manifest replaced by copies in ``where``."""
    from jaxnav import pretrained
    from jaxnav.pretrained import __main__ as cli
    from jaxnav.pretrained import check

    folder = where / "package"
    folder.mkdir()
    shutil.copy(pretrained.MANIFEST, folder / "manifest.json")
    saved = {
        (m, k): getattr(m, k)
        for m in (pretrained, check, cli)
        for k in ("HERE", "MANIFEST")
        if hasattr(m, k)
    }
    try:
        for m, k in saved:
            setattr(m, k, folder if k == "HERE" else folder / "manifest.json")
        outcome = fn()
    finally:
        for (m, k), v in saved.items():
            setattr(m, k, v)
    shutil.rmtree(folder)
    return outcome


def signal_cases(world: World) -> list[Case]:
    """SIGINT and SIGTERM at each moment of a run, in this process (train's handler records
    them); then ``--resume`` must complete the run with the uninterrupted one's metrics."""
    from jaxnav import checkpoints, run_dir, runner
    from jaxnav.train.__main__ import main as train_main

    reference = (world.run / "metrics.csv").read_text()
    moments: dict[str, tuple[Any, str, Callable[..., bool]]] = {
        "compiling": (runner.programs, "compile_training", lambda *a: True),
        "a checkpoint save": (checkpoints.Checkpoints, "save", lambda *a: True),
        "the final evaluation": (runner, "evaluate_seeds", lambda *a: True),
        "the final save of params": (run_dir, "write_trained", lambda *a: True),
        "writing timing.csv": (
            run_dir, "write_metrics_csv", lambda path, *a: Path(path).name == "timing.csv"
        ),
        "writing summary.json": (
            run_dir, "write_json", lambda path, *a: Path(path).name == "summary.json"
        ),
    }  # fmt: skip
    cases = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        for moment, (owner, attr, when) in moments.items():

            def signalled(where: Path, owner=owner, attr=attr, when=when, signum=signum) -> Any:
                original = getattr(owner, attr)
                sent: list[bool] = []

                def hooked(*args: Any, **kwargs: Any) -> Any:
                    check = args[1:] if owner is checkpoints.Checkpoints else args
                    if not sent and when(*check):
                        sent.append(True)
                        os.kill(os.getpid(), signum)
                    return original(*args, **kwargs)

                setattr(owner, attr, hooked)
                try:
                    out = where / "r"
                    code, stdout, err = call(train_main, [*TINY, "--out", str(out)])
                finally:
                    setattr(owner, attr, original)
                if code != 128 + signum:
                    return code, stdout, err
                again = call(train_main, ["--resume", str(out)])
                if again[0] != 0 or (out / "metrics.csv").read_text() != reference:
                    return ("resume", "", f"--resume: exit {again[0]}: {again[2][-300:]}")
                return code, stdout, err

            name = signal.Signals(signum).name
            cases.append(Case("signals", f"{name} during {moment}, then --resume", (128 + signum,),
                              signalled, train=True, signal_case=True))  # fmt: skip
    # evaluate and render while they compile and play, in processes of their own
    for cmd, argv, fraction in (
        ("evaluate", [str(world.run), "--episodes", "10000000", "--out", "e.json"], None),
        ("render", [str(world.run), "--episodes", "16", "--quiet", "--out", "t.gif"], 0.6),
        ("export", [str(world.run), "--out", "p.npz"], 0.6),
        ("experiments", ["plot", str(world.run)], 0.8),
    ):
        for signum in (signal.SIGINT, signal.SIGTERM):

            def stopped(
                where: Path, cmd: str = cmd, argv: list = argv, signum: int = signum,
                fraction: float | None = fraction,
            ) -> Any:  # fmt: skip
                # the signal while it works: a share of an uninterrupted run's time
                delay = 4.0 if fraction is None else fraction * duration(cmd, argv, where)
                outcome = in_process_of_its_own(f"jaxnav.{cmd}", argv, signum, delay)
                left = sorted(p.name for p in where.iterdir())
                return outcome if not left else ("left", "", f"left {left}")

            name = signal.Signals(signum).name
            when = "while it works" if fraction else "4 s in"
            cases.append(Case("signals", f"{name} {when}: python -m jaxnav.{cmd}",
                              (128 + signum,), stopped, signal_case=True))  # fmt: skip
    # the command starting up, in a process of its own (before train's handler is set)
    for signum, delay in ((signal.SIGINT, 1.0), (signal.SIGTERM, 1.0), (signal.SIGTERM, 3.0)):

        def starting(where: Path, signum: int = signum, delay: float = delay) -> Any:
            argv = [*TINY, "--total-timesteps", "3200", "--out", str(where / "r")]  # seconds
            return in_process_of_its_own("jaxnav.train", argv, signum, delay)

        name = signal.Signals(signum).name
        cases.append(Case("signals", f"{name} {delay:g} s into python -m jaxnav.train",
                          (128 + signum,), starting, train=True, signal_case=True))  # fmt: skip
    return cases


def checkout_env() -> dict[str, str]:
    """The environment of a command in another process: this checkout's jaxnav, whatever its
    working directory."""
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    return {**os.environ, "PYTHONPATH": path}


def duration(cmd: str, argv: list[str], where: Path) -> float:
    """Seconds ``python -m jaxnav.cmd argv`` takes uninterrupted (run in a directory of its
    own under ``where``, then removed)."""
    scratch = where / "timing"
    scratch.mkdir()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", f"jaxnav.{cmd}", *argv], cwd=scratch,
                   env=checkout_env(), capture_output=True, timeout=300)  # fmt: skip
    seconds = time.perf_counter() - t0
    shutil.rmtree(scratch)
    return seconds


def in_process_of_its_own(
    module: str, argv: list[str], signum: int, delay: float
) -> tuple[int, str, str]:
    """``python -m module argv`` sent ``signum`` after ``delay`` seconds: (exit code, where
    killed by a signal 128 + it as a shell reports it, stdout, stderr)."""
    cmd = [sys.executable, "-m", module, *argv]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=checkout_env()
    )
    time.sleep(delay)
    proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=120)
    code = proc.returncode if proc.returncode >= 0 else 128 - proc.returncode
    return code, stdout, stderr


def library_cases(world: World) -> list[Case]:
    import jaxnav
    from jaxnav import registration

    cases: list[Case] = []
    for env_id in [
        "",
        " ",
        "nope",
        "GridMaze-v0 ",
        "gridmaze-v0",
        "ǅ",
        None,
        3,
        ["GridMaze-v0"],
        b"GridMaze-v0",
    ]:
        cases.append(Case("library", f"jaxnav.make({env_id!r})", ("ValueError",),
                          lambda w, e=env_id: library(lambda: jaxnav.make(e))))  # fmt: skip
    hostile = [float("nan"), float("inf"), -1, 10**12, "abc", None, [], True, -1e-9, 1e30]
    for env_id in ("GridMaze-v0", "RobotSimple-v0"):
        fields = [f for f in dataclasses.fields(registration.env_config(env_id))
                  if f.name not in ("maze_file", "maze_files")]  # fmt: skip
        for i, f in enumerate(fields):
            for value in (hostile[i % len(hostile)], hostile[(i + 3) % len(hostile)]):

                def make(
                    where: Path, env_id: str = env_id, name: str = f.name, value: Any = value
                ) -> Any:
                    return library(lambda: jaxnav.make(env_id, **{name: value}))

                # refused, or a value the field takes (then the env builds)
                cases.append(Case("env options", f"{env_id} {f.name}={value!r}",
                                  ("ValueError", "ok"), make))  # fmt: skip
    cases.append(Case("env options", "GridMaze-v0 nosuch=1", ("ValueError",),
                      lambda w: library(lambda: jaxnav.make("GridMaze-v0", nosuch=1))))  # fmt: skip
    cases += occupancy_cases()
    return cases


def occupancy_cases() -> list[Case]:
    import jaxnav

    good_pgm = b"P5\n4 4\n255\n" + bytes([254] * 16)

    def map_case(yaml: str, image: bytes | None = good_pgm) -> Callable[[Path], Any]:
        def run(where: Path) -> Any:
            (where / "m.yaml").write_text(yaml)
            if image is not None:
                (where / "m.pgm").write_bytes(image)
            return library(
                lambda: jaxnav.make(
                    "RobotMaze-v0", maze_file=str(where / "m.yaml"), backend="kinematic"
                )
            )

        return run

    base = (
        "image: m.pgm\nresolution: 0.5\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
        "free_thresh: 0.196\n"
    )
    cases = []
    for name, yaml, image in [
        ("empty yaml", "", good_pgm),
        ("yaml garbage", "\x00\x01: [", good_pgm),
        ("yaml a list", "- 1\n- 2\n", good_pgm),
        ("no image", base.replace("image: m.pgm\n", ""), good_pgm),
        ("image missing", base, None),
        ("image garbage", base, b"garbage" * 10),
        ("image truncated", base, good_pgm[:14]),
        ("resolution nan", base.replace("0.5", "nan"), good_pgm),
        ("resolution -1", base.replace("0.5", "-1"), good_pgm),
        ("resolution 0", base.replace("0.5", "0"), good_pgm),
        ("origin yaw", base.replace("[0, 0, 0]", "[0, 0, 1]"), good_pgm),
        ("origin inf", base.replace("[0, 0, 0]", "[.inf, 0, 0]"), good_pgm),
        ("thresholds swapped", base.replace("0.65", "0.1"), good_pgm),
        ("image path escapes", base.replace("m.pgm", "/etc/passwd"), good_pgm),
        ("image is a directory", base.replace("m.pgm", "."), good_pgm),
        ("mode nope", base + "mode: nope\n", good_pgm),
        ("huge image header", base, b"P5\n100000 100000\n255\n" + bytes(16)),
        ("all occupied", base, b"P5\n4 4\n255\n" + bytes(16)),
    ]:
        cases.append(Case("occupancy map", name, ("ValueError",), map_case(yaml, image)))
    return cases


def deploy_cases(world: World) -> list[Case]:
    from jaxnav.deploy.policy import Policy
    from jaxnav.deploy.sensors import LaserScan, ScanObservation

    cases: list[Case] = []
    policy = Policy.load(world.npz)
    with np.load(world.npz) as f:
        stored = dict(f)

    def npz_with(**changes: Any) -> Callable[[Path], Any]:
        def run(where: Path) -> Any:
            arrays = {k: v for k, v in {**stored, **changes}.items() if v is not None}
            path = where / "p.npz"
            np.savez(path, **arrays)
            return library(lambda: Policy.load(path))

        return run

    meta = json.loads(str(stored["metadata"]))
    kernel = stored["dense0_kernel"].copy()
    kernel.flat[0] += 1
    for name, changes in {
        "a weight changed": {"dense0_kernel": kernel},
        "an array removed": {"dense0_bias": None},
        "checksum garbage": {"checksum": np.array("{")},
        "checksum an int": {"checksum": np.array(3)},
        "metadata not JSON": {"metadata": np.array("{"), "checksum": None},
        "metadata a list": {"metadata": np.array("[]"), "checksum": None},
        "format newer": {
            "metadata": np.array(json.dumps({**meta, "format_version": 99})),
            "checksum": None,
        },
        "format foreign": {
            "metadata": np.array(json.dumps({**meta, "format": "x"})),
            "checksum": None,
        },
        "obs_size wrong": {
            "metadata": np.array(
                json.dumps({**meta, "network": {**meta["network"], "obs_size": 3}})
            ),
            "checksum": None,
        },
        "kernel wrong shape": {"dense0_kernel": np.zeros((2, 2), np.float32), "checksum": None},
        "object array": {"evil": np.array([{}], dtype=object), "checksum": None},
        "no metadata": {"metadata": None, "checksum": None},
    }.items():
        cases.append(Case("deploy", f"Policy.load: {name}", ("ValueError",), npz_with(**changes)))
    data = world.npz.read_bytes()
    for name, content in {
        "truncated": data[: len(data) // 2],
        "one byte": data[:1],
        "zip header only": data[:30],
        "garbage": bytes(range(256)),
        "empty": b"",
        "a flipped byte mid-file": data[: len(data) // 2]
        + bytes([data[len(data) // 2] ^ 1])
        + data[len(data) // 2 + 1 :],
    }.items():

        def load_bytes(where: Path, content: bytes = content) -> Any:
            (where / "p.npz").write_bytes(content)
            return library(lambda: Policy.load(where / "p.npz"))

        cases.append(Case("deploy", f"Policy.load: {name}", ("ValueError",), load_bytes))
    for kind in ("dir", "fifo"):
        cases.append(Case("deploy", f"Policy.load: a {kind}", ("ValueError",),
                          lambda w, k=kind:
                              library(lambda: Policy.load(special(w, k, ".npz")))))  # fmt: skip
    n = policy.obs_size
    for name, obs in {
        "NaN": np.full(n, np.nan),
        "inf": np.full(n, np.inf),
        "one NaN in a batch": np.vstack([np.zeros(n), np.r_[np.zeros(n - 1), np.nan]]),
        "wrong size": np.zeros(n + 1),
        "empty": np.zeros(0),
        "0-d": np.float64(1.0),
        "strings": np.array(["a"] * n),
        "None": None,
        "a dict": {"a": 1},
        "1e39 (float32 overflow)": np.full(n, 1e39),
        "complex": np.zeros(n, complex) + 1j,
    }.items():
        cases.append(Case("deploy", f"Policy.act: {name}", ("ValueError",),
                          lambda w, o=obs: library(lambda: policy.act(o))))  # fmt: skip
    # a laser policy: a robot env's observation builder
    robot_meta = robot_metadata()
    good_scan = dict(angle_min=-math.pi, angle_increment=2 * math.pi / 360, range_min=0.1,
                     range_max=10.0, ranges=[1.0] * 360)  # fmt: skip
    for name, changes in {
        "range_max NaN": {"range_max": float("nan")},
        "range_min > range_max": {"range_min": 20.0},
        "range_min negative": {"range_min": -1.0},
        "angle_increment 0": {"angle_increment": 0.0},
        "angle_increment 1e20": {"angle_increment": 1e20},
        "angle_increment NaN": {"angle_increment": float("nan")},
        "angle_min inf": {"angle_min": float("inf")},
        "angle_min NaN": {"angle_min": float("nan")},
        "ranges empty": {"ranges": []},
        "ranges strings": {"ranges": ["a"] * 360},
        "ranges None": {"ranges": None},
        "range_max a word": {"range_max": "x"},
        "ranges 2-d": {"ranges": [[1.0] * 360]},
    }.items():

        def scan_case(where: Path, changes: dict = changes) -> Any:
            build = ScanObservation(robot_meta)
            scan = LaserScan(**{**good_scan, **changes})
            return library(lambda: build(scan, (1.0, 1.0, 0.0), (2.0, 2.0)))

        cases.append(Case("deploy", f"ScanObservation: {name}", ("ValueError",), scan_case))
    cases.append(
        Case("deploy", "ScanObservation: range_max inf (documented: every finite reading)",
             ("ok",), lambda w: library(lambda: ScanObservation(robot_meta)(
                 LaserScan(**{**good_scan, "range_max": math.inf}), (1.0, 1.0, 0.0), (2.0, 2.0))))
    )  # fmt: skip
    nan, inf = float("nan"), float("inf")
    for name, (pose, goal) in {
        "pose NaN": ((nan, 1.0, 0.0), (2.0, 2.0)),
        "yaw inf": ((1.0, 1.0, inf), (2.0, 2.0)),
        "goal inf": ((1.0, 1.0, 0.0), (inf, 2.0)),
        "goal NaN": ((1.0, 1.0, 0.0), (2.0, nan)),
        "pose too short": ((1.0, 1.0), (2.0, 2.0)),
        "goal too long": ((1.0, 1.0, 0.0), (2.0, 2.0, 3.0)),
        "pose strings": (("a", "b", "c"), (2.0, 2.0)),
        "pose None": (None, (2.0, 2.0)),
        "pose 1e300": ((1e300, 1.0, 0.0), (2.0, 2.0)),
        "goal -1e40": ((1.0, 1.0, 0.0), (-1e40, 2.0)),
    }.items():

        def pose_case(where: Path, pose: Any = pose, goal: Any = goal) -> Any:
            build = ScanObservation(robot_meta)
            return library(lambda: build(LaserScan(**good_scan), pose, goal))

        cases.append(Case("deploy", f"ScanObservation: {name}", ("ValueError",), pose_case))
    for name, kwargs in {
        "mount_yaw NaN": {"mount_yaw": nan},
        "mount_yaw inf": {"mount_yaw": inf},
        "beam_width NaN": {"beam_width": nan},
        "beam_width negative": {"beam_width": -0.1},
        "fill_uncovered NaN": {"fill_uncovered": nan},
        "fill_uncovered -1": {"fill_uncovered": -1.0},
        "mount_yaw a string": {"mount_yaw": "x"},
        "metadata without sensors": {"metadata": {**robot_meta, "sensors": None}},
        "metadata empty": {"metadata": {}},
    }.items():

        def builder_case(where: Path, kwargs: dict = kwargs) -> Any:
            def go() -> None:
                m = kwargs.get("metadata", robot_meta)
                build = ScanObservation(m, **{k: v for k, v in kwargs.items() if k != "metadata"})
                build(LaserScan(**good_scan), (1.0, 1.0, 0.0), (2.0, 2.0))

            return library(go)

        cases.append(Case("deploy", f"ScanObservation: {name}", ("ValueError",), builder_case))
    return cases


def robot_metadata() -> dict[str, Any]:
    """A laser policy's metadata (no weights needed): RobotSimple-v0's."""
    from jaxnav import export
    from jaxnav.config import TrainConfig
    from jaxnav.train import Trainer

    trainer = Trainer(
        TrainConfig(env="RobotSimple-v0", env_kwargs={"backend": "kinematic"}, hidden_sizes=(8,))
    )
    return export.policy_metadata(trainer)


# ------------------------------------------------------------------ the table
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", help="run the cases whose area or name contains this text")
    p.add_argument("--out", type=Path, default=RESULTS, help="JSON summary")
    args = p.parse_args(argv)
    os.environ.setdefault("JAXNAV_CACHE_DIR", tempfile.mkdtemp(prefix="red-team-cache-"))
    results = run_all(args.only)
    width = max(len(r.name) for r in results) if results else 10
    print(f"{'area':<14} {'case':<{width}} {'expected':<18} {'got':<10} pass")
    for r in results:
        mark = "pass" if r.passed else f"FAIL ({r.why})"
        print(f"{r.area:<14} {r.name:<{width}} {r.expected:<18} {r.got:<10} {mark}")
    passed = sum(r.passed for r in results)
    summary = {
        "cases": len(results),
        "passed": passed,
        "failed": [dataclasses.asdict(r) for r in results if not r.passed],
        "by_area": {
            area: {
                "cases": sum(r.area == area for r in results),
                "passed": sum(r.passed for r in results if r.area == area),
            }
            for area in dict.fromkeys(r.area for r in results)
        },
        "seconds": round(sum(r.seconds for r in results), 1),
        "results": [dataclasses.asdict(r) for r in results],
    }
    if args.only is None or args.out != RESULTS:  # one case a line
        rows = ",\n".join("  " + json.dumps(dataclasses.asdict(r)) for r in results)
        head = json.dumps({k: v for k, v in summary.items() if k != "results"}, indent=1)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(f'{head[:-2]},\n "results": [\n{rows}\n ]\n}}\n')
    print(f"\n{passed} of {len(results)} cases passed")
    return 0 if passed == len(results) else 1


def run_all(only: str | tuple[str, ...] | None = None) -> list[Result]:
    """Every case (or those whose area or name contains ``only``, or one of its texts) in a
    scratch directory."""
    root = Path(tempfile.mkdtemp(prefix="red-team-"))
    world = make_world(root / "world")
    try:
        groups = [train_cases, write_fault_cases, command_cases, signal_cases, library_cases,
                  deploy_cases]  # fmt: skip
        cases = [c for group in groups for c in group(world)]
        if only is not None:
            texts = (only,) if isinstance(only, str) else only
            cases = [c for c in cases if any(t in c.area or t in c.name for t in texts)]
        results = []
        for case in cases:
            results.append(run_case(case, root))
            r = results[-1]
            print(f"  {'ok  ' if r.passed else 'FAIL'} {r.area}: {r.name} ({r.seconds:.1f}s)"
                  + ("" if r.passed else f": {r.why}"), file=sys.stderr, flush=True)  # fmt: skip
        return results
    finally:
        for mount in world.mounts:
            subprocess.run(["umount", str(mount)], capture_output=True)
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
