"""Fault injection: a run's directory, checkpoints and outputs under the faults a hostile user
or a failing machine brings (symlinks at ``--out``, files appearing, kills at every step of
finishing, damaged checkpoints, a second writer, a full disk). Each case ends in one line
naming the value and its exit code, nothing replaced, and a run that ``--resume`` completes.
Tiny configs: 4 logging intervals of 32 env steps."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import random
import shutil
import signal
import stat
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest
from conftest import TINY_FLAGS  # pytest puts tests/ on sys.path

from jaxnav import checkpoints, run_dir, runner
from jaxnav.train import Trainer
from jaxnav.train.__main__ import main as train_main

TINY = [*TINY_FLAGS, "--total-timesteps", "128", "--eval-episodes", "2", "--checkpoint-every", "32"]


class Killed(BaseException):
    """Stands for SIGKILL at a chosen moment: nothing after it runs, no handler sees it."""


def one_line_error(capsys, code: int, got: int) -> str:
    assert got == code
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


def tree(path: Path) -> list[Path]:
    return sorted(path.rglob("*"))


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory) -> Path:
    """The tiny run, uninterrupted."""
    out = tmp_path_factory.mktemp("ref") / "run"
    assert train_main([*TINY, "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def reference(reference_run) -> str:
    """metrics.csv of the tiny run, uninterrupted."""
    return (reference_run / "metrics.csv").read_text()


def assert_complete(out: Path, reference: str) -> None:
    assert (out / "summary.json").is_file() and (out / "params").is_dir()
    assert not (out / "checkpoints").exists() and not (out / run_dir.LOCK).exists()
    assert not run_dir.partial_dir(out).exists()
    assert (out / "metrics.csv").read_text() == reference


# ------------------------------------------------------------------ runs that must finish
@pytest.mark.parametrize("kind", ["dangling", "loop", "to_empty_dir", "empty_name", "dot"])
def test_out_that_a_run_can_never_be_renamed_to_is_refused_first(kind, tmp_path, capsys):
    out = tmp_path / "run"
    if kind == "dangling":
        out.symlink_to(tmp_path / "nowhere")
    elif kind == "loop":
        out.symlink_to(out)
    elif kind == "to_empty_dir":
        (tmp_path / "real").mkdir()
        out.symlink_to(tmp_path / "real")
    else:
        out = Path("" if kind == "empty_name" else ".")
    before = tree(tmp_path)
    err = one_line_error(capsys, 2, train_main([*TINY, "--out", str(out)]))
    assert err.startswith("jaxnav.train: error: ") and (
        "symbolic link" in err or "not a run directory name" in err
    )
    assert tree(tmp_path) == before


def test_file_appearing_in_out_during_training_then_resume_completes(
    tmp_path, capsys, monkeypatch, reference
):
    out = tmp_path / "run"
    out.mkdir()  # an empty --out is allowed
    write_trained = run_dir.write_trained

    def and_a_file_appears(*args, **kwargs):
        (out / "intruder.txt").write_text("hello")
        return write_trained(*args, **kwargs)

    monkeypatch.setattr(run_dir, "write_trained", and_a_file_appears)
    err = one_line_error(capsys, 2, train_main([*TINY, "--out", str(out)]))
    assert "cannot rename the finished run" in err and f"--resume {out}" in err
    assert (out / "intruder.txt").read_text() == "hello"  # not replaced
    monkeypatch.setattr(run_dir, "write_trained", write_trained)
    # resume refuses at once while the file is there, then completes without training
    err = one_line_error(capsys, 2, train_main(["--resume", str(out)]))
    assert "not an empty directory" in err
    (out / "intruder.txt").unlink()
    assert train_main(["--resume", str(out)]) == 0
    assert "run saved to" in capsys.readouterr().out
    assert_complete(out, reference)


@pytest.mark.parametrize(
    "moment", ["summary", "rmtree_checkpoints", "rename", "write_trained_twice"]
)
def test_kill_at_each_step_of_finishing_then_resume_completes(
    moment, tmp_path, capsys, monkeypatch, reference
):
    """Finishing is repeatable: a kill before summary.json retrains nothing (the final
    checkpoint) and rewrites params/; a kill after it only renames."""
    out = tmp_path / "run"
    target = {
        "summary": (run_dir, "write_json"),
        "rmtree_checkpoints": (run_dir.shutil, "rmtree"),
        "rename": (Path, "rename"),
        "write_trained_twice": (run_dir, "write_metrics_csv"),
    }[moment]
    original = getattr(*target)
    calls = []

    def killed(*args, **kwargs):
        calls.append(args)
        name = str(args[0]) if args else ""
        if moment == "summary" and not name.endswith("summary.json"):
            return original(*args, **kwargs)
        if moment == "rmtree_checkpoints" and not name.endswith("checkpoints"):
            return original(*args, **kwargs)
        if moment == "write_trained_twice" and not (
            name.endswith("timing.csv") and (Path(name).parent / "params").exists()
        ):
            return original(*args, **kwargs)
        if moment == "rmtree_checkpoints":
            original(*args, **kwargs)  # killed just after the checkpoints went
        raise Killed

    monkeypatch.setattr(*target, killed)
    with pytest.raises(Killed):
        train_main([*TINY, "--out", str(out)])
    monkeypatch.setattr(*target, original)
    assert run_dir.partial_dir(out).is_dir()
    assert train_main(["--resume", str(out)]) == 0
    capsys.readouterr()
    assert_complete(out, reference)
    assert train_main(["--resume", str(out)]) == 2  # complete: nothing to resume
    assert "is complete" in capsys.readouterr().err


@pytest.mark.parametrize(
    "signum, moment",
    [
        (signal.SIGTERM, "write_trained"),
        (signal.SIGINT, "write_trained"),
        (signal.SIGTERM, "summary"),
    ],
)
def test_signal_during_the_final_save_exits_128_plus_it_and_resume_is_bitwise(
    signum, moment, tmp_path, capsys, monkeypatch, reference_run
):
    """A signal while params/ or summary.json is being written was ignored until the run
    finished: it now stops after that step, and --resume completes the same run."""
    out = tmp_path / "run"
    target = (run_dir, "write_trained" if moment == "write_trained" else "write_json")
    original = getattr(*target)

    def signalled_while_saving(path, *args, **kwargs):
        if moment == "write_trained" or Path(path).name == "summary.json":
            os.kill(os.getpid(), signum)  # train's handler records it, the save goes on
        return original(path, *args, **kwargs)

    monkeypatch.setattr(*target, signalled_while_saving)
    capsys.readouterr()
    assert train_main([*TINY, "--out", str(out)]) == 128 + signum
    last = capsys.readouterr().err.strip().splitlines()[-1]
    name = signal.Signals(signum).name
    assert last == (
        f"jaxnav.train: stopped by {name} at env step 128 (checkpoint saved); "
        f"continue with: python -m jaxnav.train --resume {out}"
    ), last
    partial = run_dir.partial_dir(out)
    assert not out.exists() and (partial / "params").is_dir()
    assert (partial / "summary.json").exists() == (moment == "summary")
    monkeypatch.setattr(*target, original)
    assert train_main(["--resume", str(out)]) == 0
    capsys.readouterr()
    assert_complete(out, reference_run.joinpath("metrics.csv").read_text())
    trainer = Trainer(run_dir.load_config(out))
    mine, ref = (run_dir.load_trained_params(r, trainer) for r in (out, reference_run))
    for a, b in zip(jax.tree.leaves(mine), jax.tree.leaves(ref), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


# ------------------------------------------------------------------ one writer at a time
def test_second_writer_is_refused_and_a_dead_writers_lock_is_recovered(tmp_path, capsys, reference):
    out = tmp_path / "run"
    partial = run_dir.partial_dir(out)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from pathlib import Path; from jaxnav import run_dir; "
            f"run_dir.lock_run(Path({str(partial)!r}), new=True); print('locked', flush=True); "
            "time.sleep(600)",
        ],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        # a new run at the same --out while another starts one there
        err = one_line_error(capsys, 2, train_main([*TINY, "--out", str(out)]))
        assert "unfinished run is in" in err
        # the holder writes config.json as a real run would, then another --resume is refused
        config_doc = out.parent / "doc"
        assert train_main([*TINY, "--out", str(config_doc), "--total-timesteps", "32"]) == 0
        capsys.readouterr()
        (partial / "config.json").write_bytes((config_doc / "config.json").read_bytes())
        err = one_line_error(capsys, 2, train_main(["--resume", str(out)]))
        assert f"another process (pid {holder.pid}) is writing this run" in err
    finally:
        holder.kill()  # SIGKILL: the OS drops its flock
        holder.wait()
    # the lock of the dead process is no obstacle: the run (of 32 steps) resumes and completes
    assert train_main(["--resume", str(out)]) == 0
    assert (out / "summary.json").is_file() and not partial.exists()


def test_lock_is_held_while_training_and_released_when_done(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    seen = []
    train_seeds = runner.train_seeds

    def try_second_writer(*args, **kwargs):
        with pytest.raises(ValueError, match="another process .* is writing this run"):
            run_dir.lock_run(run_dir.partial_dir(out), new=False)
        seen.append(True)
        return train_seeds(*args, **kwargs)

    monkeypatch.setattr(runner, "train_seeds", try_second_writer)
    assert train_main([*TINY, "--out", str(out), "--total-timesteps", "32"]) == 0
    assert seen and not (out / run_dir.LOCK).exists()


# ------------------------------------------------------------------ disk full
def test_disk_full_is_one_line_exit_4_keeps_the_checkpoint_and_resume_completes(
    tmp_path, capsys, monkeypatch, reference
):
    out = tmp_path / "run"
    save = checkpoints.Checkpoints.save

    def full_at_third(self, logs_done, *args, **kwargs):
        if logs_done == 3:
            path = self.directory / str(logs_done)
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return save(self, logs_done, *args, **kwargs)

    monkeypatch.setattr(checkpoints.Checkpoints, "save", full_at_third)
    err = one_line_error(capsys, 4, train_main([*TINY, "--out", str(out)]))
    assert err.startswith("jaxnav.train: no space left on device while writing ")
    assert err.endswith(f"continue with: python -m jaxnav.train --resume {out}")
    names = os.listdir(run_dir.partial_dir(out) / "checkpoints")
    assert "2" in names and "3" not in names
    monkeypatch.setattr(checkpoints.Checkpoints, "save", save)
    assert train_main(["--resume", str(out)]) == 0
    capsys.readouterr()
    assert_complete(out, reference)


def test_disk_full_while_finishing_keeps_the_run_resumable(
    tmp_path, capsys, monkeypatch, reference
):
    out = tmp_path / "run"
    write_json = run_dir.write_json

    def full(path, obj):
        if path.name == "summary.json":
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return write_json(path, obj)

    monkeypatch.setattr(run_dir, "write_json", full)
    err = one_line_error(capsys, 4, train_main([*TINY, "--out", str(out)]))
    assert "summary.json" in err
    monkeypatch.setattr(run_dir, "write_json", write_json)
    assert train_main(["--resume", str(out)]) == 0
    capsys.readouterr()
    assert_complete(out, reference)


def test_resume_hint_is_shell_quoted(tmp_path, capsys):
    out = tmp_path / "a run; rm -rf x"
    assert train_main([*TINY, "--out", str(out), "--total-timesteps", "32"]) == 0
    assert f"--resume '{out}'" in capsys.readouterr().out


# ------------------------------------------------------------------ checkpoint checksums
def interrupted_after(out: Path, monkeypatch, last: int, flags: Sequence[str] = TINY) -> None:
    """Train the tiny run (or the run of ``flags``), killed just after saving checkpoint
    ``last``."""
    save = checkpoints.Checkpoints.save

    def then_killed(self, logs_done, *args, **kwargs):
        save(self, logs_done, *args, **kwargs)
        if logs_done == last:
            raise Killed

    monkeypatch.setattr(checkpoints.Checkpoints, "save", then_killed)
    with pytest.raises(Killed):
        train_main([*flags, "--out", str(out)])
    monkeypatch.setattr(checkpoints.Checkpoints, "save", save)


def flip_a_byte(step_dir: Path, rng: random.Random, only: bool = False) -> Path:
    """Flip one bit of a file chosen in ``step_dir`` (``only``: of ``step_dir``, a file)."""
    files = [step_dir] if only else [p for p in sorted(step_dir.rglob("*")) if p.is_file()]
    path = rng.choice(files)
    data = bytearray(path.read_bytes())
    if data:
        i = rng.randrange(len(data))
        data[i] ^= 1 << rng.randrange(8)
    else:
        data = bytearray(b"x")
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("trial", range(4))
def test_flipped_byte_in_the_newest_checkpoint_falls_back_to_the_previous_one(
    trial, tmp_path, capsys, monkeypatch, reference
):
    out = tmp_path / "run"
    interrupted_after(out, monkeypatch, 3)
    ckpts = run_dir.partial_dir(out) / "checkpoints"
    flipped = flip_a_byte(ckpts / "3", random.Random(trial))
    capsys.readouterr()
    assert train_main(["--resume", str(out)]) == 0
    warnings = [x for x in capsys.readouterr().err.splitlines() if x.startswith("warning:")]
    assert len(warnings) == 1, warnings
    assert "checkpoint 3 is damaged" in warnings[0] and "resuming from checkpoint 2" in warnings[0]
    assert flipped.name in warnings[0] or "checksums" in warnings[0]
    assert_complete(out, reference)  # bitwise the uninterrupted run's metrics


def test_a_run_of_rounded_step_counts_resumes_with_the_flags_it_was_started_with(
    tmp_path, capsys, monkeypatch, reference
):
    """Started with step counts that are not whole intervals, the run records the steps it
    trains; its own command line resumes it to the run of those steps, bit for bit."""
    out = tmp_path / "run"
    asked = ["--total-timesteps", "100", "--checkpoint-every", "40"]
    flags = [*TINY, *asked, "--out", str(out)]  # the later flags win: 100 steps, every 40
    save = checkpoints.Checkpoints.save

    def then_killed(self, logs_done, *args, **kwargs):
        save(self, logs_done, *args, **kwargs)
        if logs_done == 2:
            raise Killed

    monkeypatch.setattr(checkpoints.Checkpoints, "save", then_killed)
    with pytest.raises(Killed):
        train_main(flags)
    monkeypatch.setattr(checkpoints.Checkpoints, "save", save)
    doc = json.loads((run_dir.partial_dir(out) / "config.json").read_text())
    assert doc["config"]["total_timesteps"] == 128
    assert doc["checkpointing"]["checkpoint_every"] == 32
    capsys.readouterr()
    assert train_main(["--resume", str(out), *asked]) == 0
    assert "resumed from the checkpoint at env step 64" in capsys.readouterr().out
    assert_complete(out, reference)  # the uninterrupted run of 128 steps


def test_no_intact_checkpoint_is_refused_in_one_line(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    interrupted_after(out, monkeypatch, 3)
    ckpts = run_dir.partial_dir(out) / "checkpoints"
    for step in ("2", "3"):
        flip_a_byte(ckpts / step, random.Random(int(step)))
    capsys.readouterr()
    before = tree(tmp_path)
    err = one_line_error(capsys, 2, train_main(["--resume", str(out)]))
    assert "no intact checkpoint: checkpoint 3 is damaged" in err and "checkpoint 2" in err
    assert tree(tmp_path) == before  # the damaged ones are kept for a look


def test_config_or_maze_file_changed_since_the_checkpoint_is_refused(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    interrupted_after(out, monkeypatch, 2)
    config = run_dir.partial_dir(out) / "config.json"
    doc = json.loads(config.read_text())
    doc["environment"]["python"] = "edited"
    config.write_text(json.dumps(doc))
    capsys.readouterr()
    err = one_line_error(capsys, 2, train_main(["--resume", str(out)]))
    assert "config.json changed since checkpoint 2 was saved" in err
    # the maze file: the same check through the Checkpoints inputs
    state, metrics = {"x": np.zeros(3, np.float32)}, {"loss": np.zeros((1, 2), np.float32)}
    saving = checkpoints.Checkpoints(tmp_path / "c", 1, inputs={"maze file m.txt": "aa"})
    saving.save(1, state, metrics, {"seconds": {}})
    saving.close()
    edited = checkpoints.Checkpoints(tmp_path / "c", 1, inputs={"maze file m.txt": "bb"})
    with pytest.raises(ValueError, match="maze file m.txt changed since checkpoint 1"):
        edited.newest_intact(print)
    same = checkpoints.Checkpoints(tmp_path / "c", 1, inputs={"maze file m.txt": "aa"})
    assert same.newest_intact(print) == 1


# ------------------------------------------------------------------ outputs never replace
@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("trained") / "run"
    assert train_main([*TINY, "--out", str(out), "--total-timesteps", "32"]) == 0
    return out


def special_files(tmp_path: Path, suffix: str = ".json") -> dict[str, Path]:
    """A directory, a FIFO, a character device (where the container lets us make one), a
    symlink to a file (replacing would replace the link, not the file), a dangling symlink and
    a symlink loop, each named like an output file ending in ``suffix``."""
    made = {"dir": tmp_path / f"dir{suffix}", "fifo": tmp_path / f"fifo{suffix}"}
    made["dir"].mkdir()
    os.mkfifo(made["fifo"])
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "file").write_text("kept")
    made["link"] = tmp_path / f"link{suffix}"
    made["link"].symlink_to(tmp_path / "kept" / "file")
    made["dangling"] = tmp_path / f"dangling{suffix}"
    made["dangling"].symlink_to(tmp_path / "nowhere")
    made["loop"] = tmp_path / f"loop{suffix}"
    made["loop"].symlink_to(made["loop"])
    try:
        os.mknod(tmp_path / f"null{suffix}", 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        made["chardev"] = tmp_path / f"null{suffix}"
    except OSError:
        pass  # no CAP_MKNOD here; the FIFO covers a non-regular node
    return made


def nodes(root: Path) -> list[tuple]:
    """Each path under ``root`` with what replacing or writing it would change: its kind,
    inode, size and modification times (not the access time, which reading a link sets)."""
    return [
        (p, s.st_mode, s.st_ino, s.st_size, s.st_mtime_ns, s.st_ctime_ns)
        for p in tree(root)
        for s in [p.lstat()]
    ]


def test_evaluate_render_and_export_refuse_outputs_that_are_not_regular_files(
    trained, tmp_path, capsys
):
    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.export import main as export_main
    from jaxnav.render import main as render_main

    commands = {
        ".json": lambda out: evaluate_main([str(trained), "--out", out, "--episodes", "1"]),
        ".png": lambda out: render_main([str(trained), "--out", out, "--episodes", "1"]),
        ".npz": lambda out: export_main([str(trained), "--out", out]),
    }
    for ext, command in commands.items():
        (tmp_path / ext[1:]).mkdir()
        for kind, target in special_files(tmp_path / ext[1:], ext).items():
            before = nodes(tmp_path)
            err = one_line_error(capsys, 2, command(str(target)))
            assert f"--out {target}" in err, (kind, err)
            if kind in ("link", "dangling", "loop"):
                assert "symbolic link" in err, err
            assert nodes(tmp_path) == before, kind  # nothing replaced
        assert (tmp_path / ext[1:] / "kept" / "file").read_text() == "kept"
    assert not list(trained.glob("*.tmp")) and not list(tmp_path.glob(".*partial*"))


# ------------------------------------------------------------------ a finished run's params/
def test_a_flipped_byte_in_any_file_of_params_is_refused_naming_the_file(trained, tmp_path, capsys):
    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.export import main as export_main

    files = [p.relative_to(trained) for p in tree(trained / "params") if p.is_file()]
    assert f"params/{checkpoints.MANIFEST}" in map(str, files)
    for i, name in enumerate(files):
        run = tmp_path / f"run{i}"
        shutil.copytree(trained, run)
        flip_a_byte(run / name, random.Random(i), only=True)
        err = one_line_error(capsys, 2, export_main([str(run)]))
        assert f"{run / 'params'}: damaged" in err, err
        if name.name != checkpoints.MANIFEST:
            assert f"{name.relative_to('params')} differs from its checksum" in err, err
        assert not (run / "policy.npz").exists()
    err = one_line_error(capsys, 2, evaluate_main([str(run), "--episodes", "1"]))
    assert f"{run / 'params'}: damaged" in err and not (run / "eval.json").exists()


@pytest.mark.parametrize("damage", ["truncated", "not_json", "no_tree"])
def test_a_damaged_metadata_of_a_run_saved_without_checksums_is_one_line(
    damage, trained, tmp_path, capsys
):
    from jaxnav.export import main as export_main

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    (run / "params" / checkpoints.MANIFEST).unlink()  # as runs were saved before
    assert export_main([str(run), "--out", str(tmp_path / "old.npz")]) == 0  # still loads
    capsys.readouterr()
    metadata = run / "params" / "_METADATA"
    text = metadata.read_text()
    metadata.write_text(
        {"truncated": text[: len(text) // 2], "not_json": "\x00garbage", "no_tree": "{}"}[damage]
    )
    err = one_line_error(capsys, 2, export_main([str(run)]))
    assert f"{run / 'params'}: unreadable" in err and "config.json" not in err, err
    assert not (run / "policy.npz").exists()


# ------------------------------------------------------------------ a disk that refuses writes
@contextlib.contextmanager
def small_filesystem(
    where: Path, state: str, size: str = "256k", free: int = 0, before: Any = None
) -> Iterator[Path]:
    """A real tmpfs of ``size`` at ``where``: ``full`` (the file ``filler`` takes all but
    ``free`` bytes) or ``read-only`` (remounted so), after ``before(where)`` has put files
    there; root only, else the test is skipped."""
    where.mkdir()
    mount = ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)]
    if subprocess.run(mount, capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs needs root")
    try:
        if before is not None:
            before(where)
        if state == "full":
            fd = os.open(where / "filler", os.O_WRONLY | os.O_CREAT)
            try:
                while True:
                    os.write(fd, b"\0" * 4096)
            except OSError as e:
                assert e.errno == errno.ENOSPC
            finally:
                os.close(fd)
            os.truncate(where / "filler", (where / "filler").stat().st_size - free)
        else:
            remount = ["mount", "-o", "remount,ro", str(where)]
            subprocess.run(remount, check=True, capture_output=True)
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


@pytest.mark.parametrize("state", ["full", "read-only"])
def test_evaluate_render_and_export_on_a_disk_that_refuses_writes_are_one_line(
    state, trained, tmp_path, capsys
):
    from jaxnav.evaluate.__main__ import main as evaluate_main
    from jaxnav.export import main as export_main
    from jaxnav.render import main as render_main

    commands = {
        "eval.json": lambda out: evaluate_main([str(trained), "--out", out, "--episodes", "1"]),
        "traj.png": lambda out: render_main([str(trained), "--out", out, "--episodes", "1"]),
        "traj.gif": lambda out: render_main([str(trained), "--out", out, "--episodes", "1"]),
        "policy.npz": lambda out: export_main([str(trained), "--out", out]),
    }
    why = {"full": "no space left on device", "read-only": "read-only file system"}[state]
    with small_filesystem(tmp_path / "disk", state) as disk:
        before = nodes(disk)
        for name, command in commands.items():
            err = one_line_error(capsys, 4, command(str(disk / name)))
            assert err.startswith("jaxnav.") and f"cannot write {disk / name}: {why}" in err
            assert nodes(disk) == before, name  # nothing partial left behind


@pytest.mark.parametrize("state", ["full", "read-only"])
def test_experiments_plot_and_pretrained_add_on_a_disk_that_refuses_writes_are_one_line(
    state, trained, tmp_path, capsys, monkeypatch
):
    """The writers behind ``experiments plot`` and ``pretrained add`` (figures, the copied
    policy, the manifest) went around ``safe_io``: a raw OSError and a partial file left."""
    from jaxnav import pretrained
    from jaxnav.experiments import main as experiments_main
    from jaxnav.pretrained import __main__ as pretrained_cli
    from jaxnav.pretrained import check

    def put(where: Path) -> None:
        shutil.copytree(trained, where / "run")
        (where / "pretrained").mkdir()
        shutil.copy(pretrained.MANIFEST, where / "pretrained" / "manifest.json")

    policy = tmp_path / "policy.npz"
    shutil.copy(pretrained.path("gridmaze-dqn"), policy)
    why = {"full": "no space left on device", "read-only": "read-only file system"}[state]
    with small_filesystem(tmp_path / "disk", state, size="4m", before=put) as disk:
        folder = disk / "pretrained"
        for module in (pretrained, check, pretrained_cli):
            monkeypatch.setattr(module, "HERE", folder, raising=False)
        for module in (pretrained, check):
            monkeypatch.setattr(module, "MANIFEST", folder / "manifest.json")
        monkeypatch.setattr(check, "measure", lambda *args: {"success_rate": 1.0})
        files = lambda: [n for n in nodes(disk) if not stat.S_ISDIR(n[1])]  # noqa: E731
        before = files()
        err = one_line_error(capsys, 4, experiments_main(["plot", str(disk / "run")]))
        assert f"cannot write {disk / 'run' / 'training_curves.png'}: {why}" in err, err
        argv = ["add", "new-policy", str(policy), "--command", "c"]
        err = one_line_error(capsys, 4, pretrained_cli.main(argv))
        assert f"cannot write {folder}" in err and why in err, err
        assert files() == before  # nothing partial, nothing copied in


def test_no_writer_replaces_a_link_or_follows_one_planted_at_its_temporary_file(
    trained, tmp_path, capsys
):
    from jaxnav import safe_io
    from jaxnav.experiments import main as experiments_main

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    (tmp_path / "kept").write_text("kept")
    (run / "training_curves.png").symlink_to(tmp_path / "kept")
    err = one_line_error(capsys, 2, experiments_main(["plot", str(run)]))
    assert f"{run / 'training_curves.png'}: is a symbolic link" in err, err
    assert (run / "training_curves.png").is_symlink()
    # a link at the temporary file is removed, not written through
    (run / "training_curves.png").unlink()
    (run / ".training_curves.partial.png").symlink_to(tmp_path / "kept")
    assert experiments_main(["plot", str(run)]) == 0
    assert (tmp_path / "kept").read_text() == "kept"
    assert (run / "training_curves.png").read_bytes()[:4] == b"\x89PNG"
    assert not os.path.lexists(run / ".training_curves.partial.png")
    # a FIFO appearing at the path while the file is written is not replaced
    fifo = tmp_path / "out.json"
    with pytest.raises(ValueError, match="is a FIFO"):
        with safe_io.atomic_output(fifo) as tmp:
            tmp.write_text("{}")
            os.mkfifo(fifo)
    assert stat.S_ISFIFO(fifo.lstat().st_mode) and not list(tmp_path.glob(".out*"))


def test_a_signal_cutting_a_writer_is_not_hidden_by_the_error_its_cleanup_raises(tmp_path):
    """Ctrl-C inside np.savez: zipfile's close on the way out raised "seek of closed file",
    which export reported as bad input (exit 2) in place of the signal (exit 130)."""
    from jaxnav import Stopped, safe_io

    out = tmp_path / "policy.npz"
    with pytest.raises(Stopped):
        with safe_io.atomic_output(out) as tmp:
            try:
                tmp.write_bytes(b"half of it")
                raise Stopped(signal.SIGINT)  # as the handler raises it
            finally:
                raise ValueError("seek of closed file")  # as zipfile's close then does
    assert list(tmp_path.iterdir()) == []


def test_a_programs_cache_write_refused_leaves_no_temporary_file(tmp_path, monkeypatch):
    """The traced-programs cache is best effort (a refused write costs only start-up time),
    but a full disk left its half-written temporary file in the cache directory."""
    from jaxnav import programs

    def full(obj, f):
        f.write(b"half of it")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(programs.pickle, "dump", full)
    programs._save(tmp_path / "cache", {"entry": 1})
    assert list((tmp_path / "cache").iterdir()) == []


def test_a_new_run_or_results_on_a_read_only_disk_exit_4_naming_it(tmp_path, capsys):
    """A read-only --out was refused as bad input (exit 2, "not a writable directory"): the
    machine's refusal is exit 4, as for every other writer."""
    from jaxnav.experiments import main as experiments_main

    with small_filesystem(tmp_path / "disk", "read-only") as disk:
        err = one_line_error(capsys, 4, train_main([*TINY, "--out", str(disk / "run")]))
        assert err == f"jaxnav.train: error: cannot write {disk}: read-only file system; " + (
            "remount it writable or write elsewhere"
        ), err
        argv = ["paper-grid", "--smoke", "--out", str(disk / "results")]
        err = one_line_error(capsys, 4, experiments_main(argv))
        assert f"cannot write {disk}: read-only file system" in err, err


def test_resume_of_a_run_whose_directory_is_read_only_is_one_line_then_completes(
    tmp_path, capsys, monkeypatch, reference
):
    """A read-only bind mount over the unfinished run's directory: what a directory of another
    user is to anyone but root."""
    out = tmp_path / "run"
    interrupted_after(out, monkeypatch, 2)
    partial = run_dir.partial_dir(out)
    bind = ["mount", "--bind", str(partial), str(partial)]
    if subprocess.run(bind, capture_output=True).returncode != 0:
        pytest.skip("a bind mount needs root")
    try:
        read_only = ["mount", "-o", "remount,ro,bind", str(partial)]
        subprocess.run(read_only, check=True, capture_output=True)
        before = nodes(partial)
        capsys.readouterr()
        err = one_line_error(capsys, 4, train_main(["--resume", str(out)]))
        assert err.startswith(f"jaxnav.train: error: cannot write {partial}: read-only"), err
        assert err.endswith(f"continue with: python -m jaxnav.train --resume {out}"), err
        assert nodes(partial) == before
    finally:
        subprocess.run(["umount", str(partial)], check=True)
    assert train_main(["--resume", str(out)]) == 0
    capsys.readouterr()
    assert_complete(out, reference)


def test_training_on_a_full_disk_is_one_line_without_orbax_tracebacks_and_resumes(
    tmp_path, reference
):
    """A real full disk under the whole command (orbax logs it, tensorstore's leftover writes
    print closed-event-loop tracebacks until the process ends): one line, exit 4, also on a
    --resume while the disk is still full; freed, the run resumes to the reference."""
    train = [sys.executable, "-m", "jaxnav.train"]
    with small_filesystem(tmp_path / "disk", "full", size="1m", free=32 * 1024) as disk:
        out = disk / "run"
        for argv in ([*TINY, "--out", str(out)], ["--resume", str(out)]):
            proc = subprocess.run([*train, *argv], capture_output=True, text=True, timeout=300)
            assert proc.returncode == 4, proc.stderr[-2000:]
            assert proc.stderr.count("\n") == 1, proc.stderr[-2000:]
            assert proc.stderr.startswith("jaxnav.train: no space left on device"), proc.stderr
        (disk / "filler").unlink()
        proc = subprocess.run([*train, "--resume", str(out)], capture_output=True, text=True)
        assert proc.returncode == 0 and proc.stderr == "", proc.stderr[-2000:]
        assert (out / "metrics.csv").read_text() == reference


def test_orbax_records_are_only_held_back_when_a_write_fault_ends_the_run(caplog):
    """Quieting a full disk hides no real error: other records pass at once, and the ones
    held back are shown when no write fault was reported."""
    import logging

    from jaxnav.train import __main__ as train_cli

    absl = logging.getLogger("absl")

    def drop_held_filters() -> None:  # an in-process run with a write fault keeps its own
        for held in [f for f in absl.filters if isinstance(f, train_cli.HoldWriteFaults)]:
            absl.removeFilter(held)

    drop_held_filters()
    hook = sys.unraisablehook
    with caplog.at_level(logging.WARNING, logger="absl"):
        with train_cli.quiet_write_faults():
            absl.error("a real error")
            absl.error("write failed: No space left on device")
            assert [r.getMessage() for r in caplog.records] == ["a real error"]
        assert [r.getMessage() for r in caplog.records][-1].endswith("No space left on device")
        assert sys.unraisablehook is hook
        caplog.clear()
        with train_cli.quiet_write_faults():
            absl.error("write failed: No space left on device")
            error = OSError(errno.ENOSPC, "No space left on device", "x")
            assert train_cli.write_refused("jaxnav.train", error, "resume") == 4
        absl.error("a leftover write: No space left on device")  # after the command's line
        assert caplog.records == [] and sys.unraisablehook is not hook
    sys.unraisablehook = hook
    drop_held_filters()


# ------------------------------------------------------------------ hostile inputs
def test_hostile_env_inputs_are_one_line(tmp_path, capsys):
    import jaxnav

    fifo = tmp_path / "maze.txt"
    os.mkfifo(fifo)  # reading it would block forever
    cases = {
        "FIFO maze file": ["--maze-file", str(fifo)],
        "obs_heading=False": ["--env", "RobotSimple-v0", "--env-arg", "obs_heading=False"],
        "deep nesting": ["--env-arg", "size=" + "[" * 50_000],
    }
    base = [a for a in TINY if a not in ("--env-arg", "size=5")]  # robot envs have no size
    for name, argv in cases.items():
        err = one_line_error(capsys, 2, train_main([*base, "--out", str(tmp_path / "r"), *argv]))
        want = {"FIFO maze file": str(fifo), "obs_heading=False": "obs_heading='False'"}
        assert want.get(name, "nested too deeply") in err, (name, err)
    assert not (tmp_path / "r").exists() and not (tmp_path / ".r.partial").exists()
    with pytest.raises(ValueError, match=r"unknown env id \['GridMaze-v0'\]"):
        jaxnav.make(["GridMaze-v0"])


@pytest.mark.parametrize("port", ["99999999", "0", "65536"])
def test_coordinator_port_out_of_range_is_refused(port, capsys):
    argv = [*TINY, "--coordinator", f"localhost:{port}", "--num-processes", "2"]
    err = one_line_error(capsys, 2, train_main([*argv, "--process-id", "0", "--out", "x"]))
    assert f"--coordinator 'localhost:{port}'" in err and "[1, 65535]" in err


# ------------------------------------------------------------------ out-of-range actions
@pytest.mark.parametrize("env_id", ["GridMaze-v0", "RobotSimple-v0"])
def test_out_of_range_actions_are_clipped_on_every_env_or_raise_when_checked(env_id):
    import jax
    import jax.numpy as jnp

    import jaxnav

    env, params = jaxnav.make(env_id)
    key = jax.random.key(0)
    _, state = env.reset(key, params)
    n = env.num_actions

    def step(action):
        return env.step_no_reset(key, state, action, params)[1]

    clipped = jax.jit(step)  # one compile for every action (eager robot steps are slow)
    for bad, same_as in ((-1, 0), (-5, 0), (n, n - 1), (n + 4, n - 1), (2**31 - 1, n - 1)):
        got, want = clipped(jnp.int32(bad)), clipped(jnp.int32(same_as))
        assert all(
            bool(jnp.array_equal(a, b))
            for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True)
        ), (env_id, bad)
    env.check_actions = True
    checked = jax.jit(lambda a: step(a))  # a new function: jit caches traces per function
    with pytest.raises(Exception, match=rf"action {n}: outside \[0, {n}\)"):
        jax.block_until_ready(checked(jnp.int32(n)))
    jax.block_until_ready(checked(jnp.int32(n - 1)))  # in range: fine


# ------------------------------------------------------------------ --env-arg fuzz by type
def json_values():
    from hypothesis import strategies as st

    scalars = st.one_of(
        st.none(),
        st.booleans(),
        st.integers(min_value=-(2**70), max_value=2**70),
        st.floats(allow_nan=True, allow_infinity=True),
        st.text(max_size=8),
    )
    return st.recursive(scalars, lambda x: st.lists(x, max_size=3), max_leaves=6)


FUZZ_TRIED = {"cases": 0, "accepted": 0, "refused": 0}


def test_env_arg_values_of_every_type_are_accepted_or_one_valueerror():
    """Every env field given a value of every JSON type: ``env_config`` returns a config or
    raises ValueError (the one line the commands print), never another exception."""
    import dataclasses

    from hypothesis import given, settings
    from hypothesis import strategies as st

    from jaxnav import registration

    fields = [
        (env_id, f.name)
        for env_id in ("GridMaze-v0", "RobotSimple-v0")
        for f in dataclasses.fields(registration.env_config(env_id))
        if f.name not in ("maze_file",)  # a path: the maze file fuzz is test_hostile_input's
    ]

    @settings(max_examples=300, deadline=None, database=None)
    @given(field=st.sampled_from(fields), value=json_values())
    def check(field, value):
        env_id, name = field
        FUZZ_TRIED["cases"] += 1
        try:
            registration.env_config(env_id, **{name: value})
            registration.make(env_id, **{name: value})  # accepted: it must build
        except ValueError as e:
            assert "\n" not in str(e)
            FUZZ_TRIED["refused"] += 1
        else:
            FUZZ_TRIED["accepted"] += 1

    check()
    print(FUZZ_TRIED)


def test_an_unfinished_run_saved_with_updates_per_iteration_resumes_bitwise(
    tmp_path, capsys, monkeypatch, reference
):
    """A run cut after its second checkpoint whose config.json names the older field
    ``updates_per_iteration`` (1 here: 2 sampled transitions per step of 4 envs, batch 8) in
    place of ``replay_ratio`` resumes to the uninterrupted run's metrics, bit for bit."""
    out = tmp_path / "run"
    interrupted_after(out, monkeypatch, 2)
    saved = run_dir.partial_dir(out) / "config.json"
    document = json.loads(saved.read_text())
    assert document["config"].pop("replay_ratio") == 2.0
    document["config"]["updates_per_iteration"] = 1
    saved.write_text(json.dumps(document))
    # as such a run was saved: its checkpoints carry the checksum of that config.json
    manifests = sorted(saved.parent.glob(f"checkpoints/*/{checkpoints.MANIFEST}"))
    assert len(manifests) == 2  # the run resumes from checkpoint 2, not from the start
    for manifest in manifests:
        sums = json.loads(manifest.read_text())
        sums["inputs"]["config.json"] = checkpoints.sha256_of(saved)
        manifest.write_text(json.dumps(sums))
    capsys.readouterr()
    assert train_main(["--resume", str(out)]) == 0
    assert "run saved to" in capsys.readouterr().out
    assert_complete(out, reference)
