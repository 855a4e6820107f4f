"""The notebooks run top to bottom (with small sizes injected after their ``parameters`` cell)
and are committed without outputs."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
SMALL = {  # notebook -> code overriding its parameters cell, for CI speed
    "quickstart": "TOTAL_TIMESTEPS = 2_000\nNUM_SEEDS = 2\nHIDDEN_SIZES = (32,)\nSIZE = 7",
    "robot": "TOTAL_TIMESTEPS = 1_000\nNUM_SEEDS = 2\nHIDDEN_SIZES = (32,)\n"
    "EVAL_EPISODES = 10\nMJX_STEPS = 12",
    "experiments": "",  # reads the committed results directory
    "slam_to_policy": "EPISODES = 50\nFINE_TUNE_STEPS = 8_192\nDRIVE_EPISODES = 4",
}


def test_every_notebook_is_tested():
    assert sorted(p.stem for p in NOTEBOOKS.glob("*.ipynb")) == sorted(SMALL)


@pytest.mark.parametrize("name", sorted(SMALL))
def test_notebook_is_committed_without_outputs(name):
    book = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
    for cell in book.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SMALL))
def test_notebook_runs_top_to_bottom(name):
    book = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
    tagged = [i for i, c in enumerate(book.cells) if "parameters" in c.metadata.get("tags", [])]
    assert len(tagged) == 1, "one cell tagged 'parameters'"
    if SMALL[name]:
        book.cells.insert(tagged[0] + 1, nbformat.v4.new_code_cell(SMALL[name]))
    client = NotebookClient(
        book, timeout=300, kernel_name="python3", resources={"metadata": {"path": NOTEBOOKS}}
    )
    client.execute()  # raises CellExecutionError, with the cell and traceback, on failure
    images = [
        o
        for c in book.cells
        if c.cell_type == "code"
        for o in c.outputs
        if "image/png" in o.get("data", {}) or "image/gif" in o.get("data", {})
    ]
    assert images, "the notebook draws figures"
