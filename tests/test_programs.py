"""The traced-program cache (``jaxnav.programs``): a second run of the same config skips
tracing and computes the same; a damaged entry is traced again; another config misses."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import TINY_FLAGS

from jaxnav.train.__main__ import main as train_main

FLAGS = [*TINY_FLAGS, "--total-timesteps", "64", "--eval-episodes", "4"]


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("JAXNAV_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "programs"


def _run(out: Path, capsys: pytest.CaptureFixture, *extra: str) -> str:
    assert train_main([*FLAGS, *extra, "--out", str(out)]) == 0
    return capsys.readouterr().out


def test_second_run_skips_tracing_and_computes_the_same(tmp_path, cache, capsys):
    first = _run(tmp_path / "a", capsys)
    assert "compiled in" in first and "from the cache" not in first
    (entry,) = list(cache.iterdir())
    assert (entry / "programs.pkl").stat().st_size > 0
    second = _run(tmp_path / "b", capsys)
    assert "(traced programs from the cache)" in second
    assert (tmp_path / "a/metrics.csv").read_text() == (tmp_path / "b/metrics.csv").read_text()
    other = _run(tmp_path / "c", capsys, "--lr", "0.002")  # another config, another entry
    assert "from the cache" not in other and len(list(cache.iterdir())) == 2


def test_damaged_entry_is_traced_again_and_replaced(tmp_path, cache, capsys):
    _run(tmp_path / "a", capsys)
    (entry,) = list(cache.iterdir())
    (entry / "programs.pkl").write_bytes(b"not a pickle")
    again = _run(tmp_path / "b", capsys)
    assert "from the cache" not in again
    assert "(traced programs from the cache)" in _run(tmp_path / "c", capsys)
    assert (tmp_path / "a/metrics.csv").read_text() == (tmp_path / "c/metrics.csv").read_text()
