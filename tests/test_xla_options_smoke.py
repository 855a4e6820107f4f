"""benchmarks/xla_options.py: every variant timed in a process of its own, failures as rows."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = str(Path(__file__).resolve().parents[1])  # `benchmarks` is not installed; plain `pytest`
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

TINY = '{"num_envs": 4, "algo": "pqn", "hidden_sizes": [16], "env_kwargs": {"size": 5}, ' \
    '"rollout_length": 2, "num_minibatches": 2}'  # fmt: skip


def test_variants_are_timed_apart_and_a_failing_one_is_a_row(tmp_path: Path) -> None:
    from benchmarks import xla_options

    out = tmp_path / "xla.json"
    argv = ["--config", TINY, "--iterations", "2", "--rounds", "2", "--out", str(out)]
    argv += ["--variant", "shipped=", "--variant", "unknown flag=--xla_no_such_flag=1"]
    result = xla_options.main(argv)
    data = json.loads(out.read_text())
    assert data == json.loads(json.dumps(result))
    shipped, unknown = data["rows"]
    assert (shipped["variant"], shipped["flags"]) == ("shipped", "")
    (process,) = shipped["processes"]
    assert len(process["ms_per_iteration"]) == 2 and min(process["ms_per_iteration"]) > 0
    assert process["steps_per_iteration"] == 8 and process["compile_s"] > 0
    assert shipped["speedup"] == 1.0 and shipped["errors"] == []
    assert shipped["env_steps_per_s"] == pytest.approx(8e3 / shipped["ms_per_iteration"])
    # XLA refuses an unknown flag when its backend starts: the row says so, times are n/a
    assert unknown["ms_per_iteration"] is None and unknown["speedup"] is None
    assert "--xla_no_such_flag" in unknown["errors"][0]
    md = out.with_suffix(".md").read_text()
    assert "| unknown flag | `--xla_no_such_flag=1` | n/a | n/a | n/a | n/a | n/a |" in md
    assert data["command"].startswith("python -m benchmarks.xla_options --config '{")


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--variant", "no flags"], "'no flags': expected NAME=FLAGS"),
        (["--variant", "a=", "--variant", "a=--x"], "each name once"),
        (["--rounds", "0"], "--rounds 0: must be >= 1"),
        (["--config", '{"num_envs": 0}'], '--config {"num_envs": 0}: '),
        (
            ["--variant", "graphs=--xla_gpu_enable_command_buffer=FUSION"],
            "xla_gpu_enable_command_buffer is set by jaxnav.train.COMPILER_OPTIONS",
        ),
    ],
)
def test_bad_arguments_are_one_line_errors(argv, named, capsys) -> None:
    from benchmarks import xla_options

    with pytest.raises(SystemExit) as e:
        xla_options.main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and named in err
