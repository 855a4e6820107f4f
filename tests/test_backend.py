"""The backend-dependent choices (``jaxnav.backend``): one module asks which backend it runs
on, and each choice is the one its docstring names on a CPU and on a GPU."""

from __future__ import annotations

from pathlib import Path

import jax

from jaxnav import backend

PACKAGE = Path(__file__).resolve().parents[1] / "jaxnav"


def test_only_the_backend_module_asks_which_backend_it_runs_on():
    """``jax.default_backend`` appears in ``jaxnav.backend`` and in the run metadata that
    records it, nowhere else in the package."""
    found: dict[str, list[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        for line in path.read_text().splitlines():
            if "default_backend" in line:
                found.setdefault(str(path.relative_to(PACKAGE)), []).append(line.strip())
    assert sorted(found) == ["backend.py", "run_dir.py"]
    assert found["run_dir.py"] == ['"jax_backend": jax.default_backend(),']


def test_each_choice_on_a_cpu_and_a_gpu():
    """What each choice is on a CPU, a GPU and a TPU, and JAX's default backend (a CPU in the
    tests) where no platform is given."""
    choices = {  # name -> (cpu, gpu, tpu)
        "returns_unrolled": (False, True, False),
        "target_update_select": (False, True, True),
        "optimizer_barrier": (False, True, False),
        "masked_taken_values": (False, True, False),
        "layer_norm_kernels": (False, True, False),
        "pallas_interpret": (True, False, True),
        "ray_cast_unrolled": (False, True, True),
    }
    assert jax.default_backend() == "cpu"
    for name, values in choices.items():
        choice = getattr(backend, name)
        assert tuple(choice(p) for p in ("cpu", "gpu", "tpu")) == values, name
        assert choice() == values[0], name
    assert [backend.updates_unroll(16, p) for p in ("cpu", "gpu", "tpu")] == [1, 16, 1]
    assert backend.updates_unroll(16) == 1
    small, large = backend.ACCELERATOR_MIN_BATCH - 1, backend.ACCELERATOR_MIN_BATCH
    assert [backend.step_batch_as_vmap(n, "gpu") for n in (small, large)] == [True, False]
    assert [backend.step_batch_as_vmap(n, "tpu") for n in (small, large)] == [True, False]
    assert [backend.step_batch_as_vmap(n, "cpu") for n in (1, small)] == [False, False]
    assert backend.step_batch_as_vmap(1) is False
