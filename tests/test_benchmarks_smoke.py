"""Smoke test of benchmarks/env_throughput.py at tiny sizes (our envs only)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = str(Path(__file__).resolve().parents[1])  # `benchmarks` is not installed; plain `pytest`
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def test_env_throughput_smoke(tmp_path: Path) -> None:
    from benchmarks import env_throughput

    out = tmp_path / "env_throughput.json"
    envs = ",".join(env_throughput.OUR_ENVS)
    result = env_throughput.main(
        ["--num-envs", "1,4", "--steps", "10", "--rounds", "2", "--envs", envs, "--out", str(out)]
    )
    data = json.loads(out.read_text())
    assert data == json.loads(json.dumps(result))
    machine = data["machine"]
    for field in ("platform", "cpu_count", "jax_version", "backend", "date"):
        assert machine[field], field
    rows = data["results"]
    assert {(r["env"], r["num_envs"]) for r in rows} == {
        (e, n) for e in env_throughput.OUR_ENVS for n in (1, 4)
    }
    for r in rows:
        assert r["steps"] == 10
        assert r["compile_s"] > 0 and r["steps_per_s"] > 0 and len(r["run_s"]) == 2
        assert r["baseline"] == "GridMaze-v0" and r["ratio"] > 0
    assert set(data["autoreset_cost"]) == {"1", "4"}
    assert out.with_suffix(".md").read_text().startswith("| env |")


def test_grid_sweep_smoke(tmp_path: Path) -> None:
    from benchmarks import grid_sweep

    out = tmp_path / "sweep.json"
    tiny = {
        "env_kwargs": {"size": 5},
        "hidden_sizes": [16],
        "total_timesteps": 2000,
        "learning_starts": 500,
        "log_interval": 500,
        "buffer_size": 1000,
        "batch_size": 16,
        "replay_ratio": 4.0,  # one gradient step an iteration
        "num_envs": 4,  # 500 / 4 iterations per log: exactly 4 logs
    }
    rows = grid_sweep.main(
        [
            "--seeds",
            "2",
            "--eval-episodes",
            "20",
            "--out",
            str(out),
            "--variant",
            "tiny",
            json.dumps(tiny),
        ]
    )
    data = json.loads(out.read_text())
    assert [r["name"] for r in data["rows"]] == ["tiny"] == [r["name"] for r in rows]
    row = data["rows"][0]
    assert len(row["per_seed"]) == 2 and 0.0 <= row["success_min"] <= row["success_mean"] <= 1.0
    assert len(row["train_success_curve"]) == 4
    assert data["meta"]["machine"]["jax_version"]
    assert out.with_suffix(".md").read_text().count("\n") == 3


def test_scaling_smoke(tmp_path: Path) -> None:
    """1 and 2 (CPU) devices: every row measured, the first count's ratio 1, JSON and table."""
    from benchmarks import scaling

    out = tmp_path / "scaling.json"
    flags = ["--devices", "1,2", "--envs", "GridMaze-v0", "--envs-per-device", "8"]
    flags += ["--steps", "5", "--train-envs-per-device", "4", "--batch-per-device", "8"]
    flags += ["--hidden-sizes", "16", "--iterations", "3", "--intervals", "2", "--rounds", "2"]
    assert scaling.main([*flags, "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    kinds = [
        "env GridMaze-v0",
        "train GridMaze-v0, envs split",
        "train GridMaze-v0, a seed per device",
    ]
    assert [(r["row"], r["devices"]) for r in rows] == [(k, d) for k in kinds for d in (1, 2)]
    for r in rows:
        assert r["steps_per_s"] > 0 and r["compile_s"] > 0 and len(r["run_s"]) == 2
    assert [r["num_envs"] for r in rows] == [8, 16, 4, 8, 4, 8]
    assert [r["ratio_vs_1"] for r in rows[::2]] == [1.0, 1.0, 1.0]
    assert "| train GridMaze-v0, envs split | 2 |" in out.with_suffix(".md").read_text()


def test_step_kernels_smoke(tmp_path: Path, capsys) -> None:
    from benchmarks import step_kernels

    flags = ["--num-envs", "4", "--steps", "2", "--envs", "GridMaze-v0", "--out", str(tmp_path)]
    assert step_kernels.main(flags) == 0
    row = capsys.readouterr().out.strip().splitlines()[-1].split("|")
    assert row[1].strip() == "GridMaze-v0"
    kernels, per_step, steps_per_s = int(row[2]), float(row[5]), float(row[6])
    assert kernels > 0 and per_step > 0 and steps_per_s > 0
    assert (tmp_path / "GridMaze-v0.hlo.txt").read_text().count("ENTRY") == 1


@pytest.mark.xdist_group("multihost")  # starts processes of its own
def test_multiprocess_smoke(tmp_path: Path) -> None:
    """On CPU, one process with 2 devices (run twice) and 2 processes with 1 device each write
    the same metrics.csv, and the benchmark says so in its JSON and table."""
    from conftest import TINY_FLAGS

    from benchmarks import multiprocess

    out = tmp_path / "multiprocess.json"
    train_args = " ".join([*TINY_FLAGS, "--eval-episodes", "4", "--total-timesteps", "128"])
    result = multiprocess.main(["--splits", "envs", "--train-args", train_args, "--out", str(out)])
    (row,) = json.loads(out.read_text())["rows"]
    assert row == result["rows"][0]
    assert row["one_process_twice_equal"] and row["one_vs_multi_process_equal"]
    assert "| envs | bitwise equal | bitwise equal |" in out.with_suffix(".md").read_text()


def test_profile_training_can_leave_loops_out_of_the_cuda_graphs() -> None:
    """By default the profiled program is compiled as training is; ``--loops-on-host`` drops
    only the loop and conditional command kinds, so the trace has every trip's kernels."""
    from benchmarks import profile_training as pt
    from jaxnav.train import COMPILER_OPTIONS

    assert pt.compiler_options(False) == COMPILER_OPTIONS
    host = pt.compiler_options(True)
    kinds = COMPILER_OPTIONS["xla_gpu_enable_command_buffer"].split(",")
    assert {"WHILE", "CONDITIONAL"} <= set(kinds)
    assert host["xla_gpu_enable_command_buffer"].split(",") == [
        k for k in kinds if k not in ("WHILE", "CONDITIONAL")
    ]
    assert {k: v for k, v in host.items() if k != "xla_gpu_enable_command_buffer"} == {
        k: v for k, v in COMPILER_OPTIONS.items() if k != "xla_gpu_enable_command_buffer"
    }


def test_profile_training_sums_device_kernels_by_kind(tmp_path: Path, capsys) -> None:
    from benchmarks import profile_training as pt

    device, host = (
        {"ph": "M", "name": "process_name", "pid": pid, "args": {"name": name}}
        for pid, name in ((1, "/device:GPU:0"), (2, "/host:CPU"))
    )
    kernels = [
        ("gemm_fusion_dot_general_3", 100, 30),
        ("input_add_reduce_fusion_3", 140, 50),
        ("input_add_reduce_fusion_3", 200, 50),
        ("loop_convert_fusion", 275, 10),
        ("void cub::detail::radix_sort::DeviceRadixSortOnesweepKernel", 290, 5),
        ("layer_norm_relu_backward__2", 300, 10),  # agents.layer_norm's Pallas kernel
    ]
    events = [device, host, {"ph": "X", "pid": 2, "name": "a host op", "ts": 0, "dur": 999}]
    events += [{"ph": "X", "pid": 1, "name": n, "ts": t, "dur": d} for n, t, d in kernels]
    s = pt.summarize(pt.device_kernels({"traceEvents": events}))
    assert (s["span_us"], s["busy_us"], s["kernels"]) == (210, 155, 6)
    assert s["by_kind_us"] == {
        "LayerNorm kernels (Pallas)": 10, "matrix products": 30, "reductions": 100,
        "conversions": 10, "sorts": 5, "gathers and scatters": 0, "copies": 0, "other": 0,
    }  # fmt: skip
    assert s["top"][0] == {
        "name": "input_add_reduce_fusion_3", "kind": "reductions", "calls": 2, "total_us": 100,
    }  # fmt: skip
    # idle: 10 us before each reduction, 25 before the conversion, 5 before the sort and the
    # LayerNorm kernel each, put on the kernel waited for
    assert s["idle_us"] == 55 and s["idle_before"][:2] == [
        {"name": "loop_convert_fusion", "kind": "conversions", "waits": 1, "total_us": 25},
        {"name": "input_add_reduce_fusion_3", "kind": "reductions", "waits": 2, "total_us": 20},
    ]  # fmt: skip
    # as 2 repeats: the longest wait is the host's between them, left out
    two = pt.summarize(pt.device_kernels({"traceEvents": events}), repeats=2)
    assert two["idle_us"] == 30 and two["idle_before"][0]["total_us"] == 20
    # this CPU runs no device kernels: one line, exit 2, nothing written
    out = tmp_path / "p.json"
    with pytest.raises(SystemExit) as exit_info:
        pt.main(["--env", "GridMaze-v0", "--iterations", "1", "--repeats", "1", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and err.count("\n") == 0 and "accelerator" in err, err
    assert not out.exists()
    # --config: TrainConfig fields after the preset; a bad one is named, exit 2
    for bad, named in (('{"num_envs": 0}', "num_envs"), ("[1]", "JSON object")):
        with pytest.raises(SystemExit) as exit_info:
            pt.main(["--env", "GridMaze-v0", "--config", bad, "--out", str(out)])
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert exit_info.value.code == 2 and "--config" in err and named in err, err
    assert not out.exists()


def test_layer_norm_blocks_times_each_block_against_the_jnp_form(monkeypatch) -> None:
    from benchmarks import layer_norm_blocks as lnb
    from jaxnav.agents import layer_norm
    from jaxnav.agents.layer_norm import Blocks

    chosen = Blocks(32, 4, 2, 1)
    monkeypatch.setitem(layer_norm.BACKWARD_BLOCKS, 128, chosen)
    before = dict(layer_norm.BACKWARD_BLOCKS)
    # blocks of 64 rows: more than the 32 there are, so not measured
    blocks = [Blocks(8, 4, 2, 2), Blocks(32, 4, 2, 1), Blocks(64, 4, 1, 1)]
    rows = lnb.measure(32, 128, blocks, chain=2)
    assert layer_norm.BACKWARD_BLOCKS == before  # the table is restored
    backward = [r for r in rows if r["direction"] == "backward"]
    assert [r["form"] for r in backward] == [
        "jnp (XLA)",
        "8 rows, 4 warps, 2 instances, 2 stages",
        "32 rows, 4 warps, 2 instances, 1 stages",
    ]
    assert [r["chosen"] for r in backward] == [False, False, True]
    forward = [r["form"] for r in rows if r["direction"] == "forward"]
    assert forward == [r["form"] for r in backward]
    assert backward[0]["jnp_over_this"] == 1.0
    assert all(r["us_per_call"] > 0 and r["compile_s"] > 0 for r in rows)
    assert "| backward | 128 | **32 rows, 4 warps, 2 instances, 1 stages** |" in lnb.markdown(
        {"machine": {"devices": ["cpu"], "jax_version": "x", "date": "2026-11-24"},
         "command": "c", "rows": 32, "chain": 2, "measurements": rows}
    )  # fmt: skip


def test_layer_norm_blocks_refuses_a_width_the_kernels_do_not_take(capsys) -> None:
    from benchmarks import layer_norm_blocks as lnb

    with pytest.raises(SystemExit) as exit_info:
        lnb.main(["--widths", "100"])
    assert exit_info.value.code == 2
    assert "--widths 100: the kernels take 64, 128, 256" in capsys.readouterr().err


# /proc/cpuinfo of a 2-core x86 host (two processor blocks) and of an ARM one (other fields)
CPUINFO_X86 = (
    "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 1\n"
    "model name\t: AMD EPYC\nflags\t\t: fpu sse2 avx2 fma\n\n"
    "processor\t: 1\nmodel name\t: another\nflags\t\t: avx2 avx512f\n"
)
CPUINFO_ARM = "processor\t: 0\nBogoMIPS\t: 50.00\nFeatures\t: fp asimd\nCPU part\t: 0xd0c\n"


def test_machine_text_names_the_cpu_and_its_vector_instructions() -> None:
    """A CPU result's head says which CPU (a run's speed differs between CPUs with and
    without AVX-512); what the system does not say is unknown, not absent."""
    from benchmarks.common import machine_text
    from jaxnav.host import cpu_info

    x86 = cpu_info(CPUINFO_X86)
    features = {"avx2": True, "avx512f": False, "avx512_bf16": False, "amx_tile": False}
    assert x86 == {"model": "AMD EPYC", "family": 25, "model_number": 1, "features": features}
    assert machine_text({"backend": "cpu", "cpu_count": 2, "cpu": x86}) == (
        "cpu (2 cores; AMD EPYC, family 25 model 1, AVX2, no AVX-512)"
    )
    arm = cpu_info(CPUINFO_ARM)
    assert arm == {"model": None, "family": None, "model_number": None, "features": None}
    assert machine_text({"backend": "cpu", "cpu_count": 4, "cpu": arm}) == "cpu (4 cores)"
    assert machine_text({"backend": "gpu", "cpu_count": 16}) == "gpu (16 cores)"  # older results


def test_benchmarks_and_runs_describe_the_host_alike() -> None:
    """A benchmark's ``machine`` and a run's ``environment`` record the same host fields with
    the same values, so results and runs from one machine can be matched."""
    from benchmarks.common import machine_info
    from jaxnav.host import host_info
    from jaxnav.run_dir import environment_info

    host, machine, environment = host_info(), machine_info(), environment_info()
    assert set(host) == {"python", "platform", "cpu_count", "cpu", "devices"}
    for record in (machine, environment):
        assert {k: record[k] for k in host} == host
    assert machine["backend"] == environment["jax_backend"]


def test_red_team_smoke() -> None:
    """A handful of the red team's cases (benchmarks/red_team.py, run by hand: hundreds of
    commands) pass: a damaged policy file, a NaN observation, a FIFO --out, a hostile flag."""
    from benchmarks import red_team

    picked = (
        "Policy.load: a weight changed",
        "Policy.act: NaN",
        "--out fifo",
        "--gamma 'nan'",
        "ScanObservation: range_max NaN",
    )
    results = red_team.run_all(only=picked)
    assert len(results) >= len(picked)
    failed = [(r.area, r.name, r.why) for r in results if not r.passed]
    assert not failed, failed


def test_memory_cost_times_both_networks_against_feed_forward(tmp_path: Path) -> None:
    from benchmarks import memory_cost

    out = tmp_path / "memory_cost.json"
    argv = ["--memory", "8", "--num-envs", "16", "--iterations", "2", "--out", str(out)]
    assert memory_cost.main(argv) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["memory"] for r in rows] == [0, 8]
    assert rows[0]["time_vs_feed_forward"] == 1.0 and rows[1]["time_vs_feed_forward"] > 0
    assert all(r["env_steps"] == 16 * memory_cost.ROLLOUT * 2 for r in rows)


def test_mapfree_gaps_splits_a_policy_by_narrowest_gap(tmp_path: Path, capsys) -> None:
    from benchmarks import mapfree_gaps
    from jaxnav import pretrained

    assert mapfree_gaps.main([]) == 2  # nothing asked
    policy = tmp_path / "robotnav-pqn.npz"
    policy.write_bytes(pretrained.path("robotnav-pqn").read_bytes())
    out = tmp_path / "gaps.jsonl"
    assert mapfree_gaps.main(["--policy", str(policy), "--episodes", "8", "--out", str(out)]) == 0
    row = json.loads(out.read_text())
    split = {k: v for k, v in row.items() if k.startswith("narrowest gap")}
    assert split and sum(v["episodes"] for v in split.values()) == 8
    assert 0.0 <= row["all"]["success"] <= 1.0


def test_mapfree_sweep_tests_an_exported_row_without_training(tmp_path: Path, monkeypatch) -> None:
    from benchmarks import mapfree_sweep
    from jaxnav import pretrained
    from jaxnav.experiments import Family

    # robotnav-sizes is row 17's policy; one small suite keeps the test short
    (tmp_path / "row17.npz").write_bytes(pretrained.path("robotnav-sizes").read_bytes())
    suite = Family("held-out", "own", {"maze_seed": 1_000_003, "num_layouts": 4})
    monkeypatch.setattr(mapfree_sweep, "families", lambda config: [suite])
    out = tmp_path / "sweep.jsonl"
    argv = ["--rows", "17", "--episodes", "4", "--trained", str(tmp_path), "--out", str(out)]
    # the shipped policy itself on row 19's env: its waypoint from its own lidar map
    own = ["--rows", "19", "--episodes", "4", "--pretrained", "robotnav-sizes", "--out", str(out)]
    assert mapfree_sweep.main(own) == 0
    assert mapfree_sweep.main(argv) == 0
    assert mapfree_sweep.main([*argv, "--shielded"]) == 0
    mapfree, greedy, shielded = (json.loads(line) for line in out.read_text().splitlines())
    assert greedy["row"] == 17 and greedy["train_s"] is None and greedy["tested"] == "exported npz"
    assert (greedy["policy"], shielded["policy"]) == ("greedy", "shielded")
    assert mapfree["tested"] == "pretrained robotnav-sizes" and mapfree["env_steps"] is None
    assert mapfree["env_kwargs"]["lidar_map"] > 0
    for row in (greedy, shielded, mapfree):
        assert set(row["tests"]) >= {"held-out"}
        assert 0.0 <= row["tests"]["held-out"]["success"] <= 1
    assert "| 17 | 0 | row 11 + odometry trail of 0.5 m cells, exported npz, shielded |" in (
        out.with_suffix(".md").read_text()
    )
    assert "| n/a |" in out.with_suffix(".md").read_text()


def test_mapfree_sweep_trains_seeds_together_and_reports_their_spread(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    from benchmarks import mapfree_sweep
    from jaxnav.config import TrainConfig
    from jaxnav.deploy.policy import Policy
    from jaxnav.experiments import Family

    assert mapfree_sweep.main(["--seeds", "1,1"]) == 2  # a seed twice
    assert mapfree_sweep.main(["--seeds", "-1"]) == 2
    # a start another row writes, and a folder for policies that cannot be one: refused at once
    monkeypatch.chdir(tmp_path)
    assert mapfree_sweep.main(["--rows", "22"]) == 2
    assert "--rows 20 --seeds 0,1 --policies runs/row20" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert mapfree_sweep.main(["--rows", "14", "--policies", "file/pol"]) == 2
    assert capsys.readouterr().err.startswith("--policies file/pol: ")
    _, env_id, env_kwargs, _ = mapfree_sweep.ROWS[14]
    tiny = TrainConfig.for_env(
        env_id,
        algo="pqn",
        env_kwargs={**env_kwargs, "num_layouts": 8, "backend": "kinematic"},
        eval_episodes=0,
        num_envs=8,
        rollout_length=4,
        num_minibatches=1,
        num_epochs=1,
        total_timesteps=64,
        hidden_sizes=(16,),
        compute_dtype="float32",
        fused_layer_norm=False,
        log_interval=32,
    )
    monkeypatch.setattr(mapfree_sweep, "row_config", lambda index: tiny)
    suite = Family("held-out", "own", {"maze_seed": 1_000_003, "num_layouts": 4})
    monkeypatch.setattr(mapfree_sweep, "families", lambda config: [suite])
    out, policies = tmp_path / "sweep.jsonl", tmp_path / "runs" / "pol"  # made by the sweep
    argv = ["--rows", "14", "--seeds", "0,3", "--episodes", "4", "--out", str(out)]
    assert mapfree_sweep.main([*argv, "--policies", str(policies)]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [(r["row"], r["seed"], r["seeds_trained_together"]) for r in rows] == [
        (14, 0, 2),
        (14, 3, 2),
    ]
    # each seed's own policy: the two runs differ
    a, b = (Policy.load(policies / n) for n in ("row14.npz", "row14_seed3.npz"))
    assert any(not np.array_equal(a.arrays[k], b.arrays[k]) for k in a.arrays)
    text = out.with_suffix(".md").read_text()
    assert "## Over seeds" in text and "| 14 | 0, 3 | " in text
