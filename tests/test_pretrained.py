"""The policies shipped in ``jaxnav/pretrained``: each loads (numpy, sha256 checked), is
small, and still meets the success its manifest states on fresh episodes."""

from __future__ import annotations

import json
import math

import pytest

from jaxnav import pretrained
from jaxnav.evaluate.__main__ import main as evaluate_main
from jaxnav.pretrained.check import measure
from jaxnav.render import main as render_main

FRESH_EPISODES = 200
FRESH_SEED = 31_337  # not the manifest's test episodes


@pytest.mark.slow
@pytest.mark.parametrize("name", pretrained.names())
def test_shipped_policy_meets_its_stated_success(name):
    entry = pretrained.entry(name)
    policy = pretrained.load(name)
    assert policy.metadata["env_id"] == entry["env_id"]
    assert policy.metadata["env_kwargs"] == entry["env_kwargs"]
    assert pretrained.path(name).stat().st_size < 5 * 2**20  # small enough to ship
    stated = entry["measured"]
    assert stated["episodes"] >= 1000 and entry["commands"]
    got = measure(policy, FRESH_EPISODES, FRESH_SEED)
    p = stated["success_rate"]
    # 3 standard errors of a success rate over the fresh episodes (at least that of one
    # failure in them, so a stated 1.000 allows a few)
    margin = 3 * math.sqrt(max(p * (1 - p), 1 / FRESH_EPISODES) / FRESH_EPISODES)
    assert got["success_rate"] >= p - margin, (got, stated)


def test_names_and_errors():
    assert "gridmaze-dqn" in pretrained.names()
    with pytest.raises(ValueError, match="--pretrained nope: no such policy; shipped: "):
        pretrained.load("nope")


def test_evaluate_and_render_run_a_pretrained_policy(tmp_path, capsys):
    out = tmp_path / "eval.json"
    argv = ["--pretrained", "gridmaze-dqn", "--episodes", "100", "--seed", "5", "--out", str(out)]
    assert evaluate_main(argv) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    result = json.loads(out.read_text())
    assert result["run"] == "pretrained:gridmaze-dqn" and result["env"] == "GridMaze-v0"
    assert result["success_rate"] >= 0.95
    # without --out nothing is written
    assert evaluate_main(["--pretrained", "gridmaze-dqn", "--episodes", "10"]) == 0
    assert "wrote" not in capsys.readouterr().out
    png = tmp_path / "traj.png"
    assert render_main(["--pretrained", "gridmaze-dqn", "--episodes", "2", "--out", str(png)]) == 0
    assert png.stat().st_size > 0
    assert "episode 1: success" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, message",
    [
        ([], "give a run directory or --pretrained NAME, one of them"),
        (["some/run", "--pretrained", "gridmaze-dqn"], "one of them"),
        (["--pretrained", "nope"], "--pretrained nope: no such policy; shipped: gridmaze-dqn"),
        (["--pretrained", "gridmaze-dqn", "--env-arg", "size=9"], "do not fit"),
    ],
)
def test_bad_pretrained_arguments_are_one_line_errors(argv, message, capsys):
    for main in (evaluate_main, render_main):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1


def test_add_refuses_a_damaged_file_or_a_shipped_name_and_copies_nothing(tmp_path, capsys):
    from jaxnav.pretrained.__main__ import main as pretrained_main

    def package() -> tuple[list[str], bytes]:
        npz = sorted(p.name for p in pretrained.HERE.glob("*.npz"))
        return npz, pretrained.MANIFEST.read_bytes()

    before = package()
    shipped = pretrained.path("gridmaze-dqn").read_bytes()
    cases = {
        "garbage": (bytes(range(256)) * 4, "not a jaxnav policy file (not an npz archive)"),
        "truncated": (shipped[: len(shipped) // 2], "truncated or damaged policy file"),
        "shipped": (shipped, "name 'gridmaze-dqn': a policy of that name is shipped; pass --force"),
    }
    for case, (content, named) in cases.items():
        file = tmp_path / f"{case}.npz"
        file.write_bytes(content)
        name = "gridmaze-dqn" if case == "shipped" else f"new-{case}"
        assert pretrained_main(["add", name, str(file), "--command", "python -m jaxnav.train"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and named in err, (case, err)
        assert case == "shipped" or str(file) in err
        assert package() == before, case  # nothing copied in, the manifest as it was


def test_add_with_force_replaces_a_shipped_policy(tmp_path, monkeypatch, capsys):
    """In a copy of the package folder: --force measures the file, copies it in and rewrites
    its entry."""
    import shutil

    from jaxnav.pretrained import __main__ as pretrained_cli
    from jaxnav.pretrained import check

    folder = tmp_path / "pretrained"
    folder.mkdir()
    shutil.copy(pretrained.MANIFEST, folder / "manifest.json")
    source = tmp_path / "policy.npz"
    shutil.copy(pretrained.path("gridmaze-dqn"), source)
    for module in (pretrained, check, pretrained_cli):
        monkeypatch.setattr(module, "HERE", folder, raising=False)
    for module in (pretrained, check):
        monkeypatch.setattr(module, "MANIFEST", folder / "manifest.json")
    (folder / "gridmaze-dqn.npz").write_bytes(b"the old file")
    argv = ["add", "gridmaze-dqn", str(source), "--command", "c", "--episodes", "20", "--force"]
    assert pretrained_cli.main(argv) == 0
    assert "added gridmaze-dqn: success" in capsys.readouterr().out
    entry = pretrained.entry("gridmaze-dqn")
    assert entry["measured"]["episodes"] == 20 and entry["commands"] == ["c"]
    assert (folder / "gridmaze-dqn.npz").read_bytes() == source.read_bytes()
    assert entry["sha256"] == pretrained.sha256(source)
