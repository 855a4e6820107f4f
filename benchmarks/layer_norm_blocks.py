"""The fused LayerNorm's Pallas kernels by block size, against XLA's fusion of the same math.

    python -m benchmarks.layer_norm_blocks [--rows 16384] [--widths 1024,512,256]
        [--rows-per-block 2,4,8,16,32] [--warps 4,8] [--instances 256,512,1024]
        [--stages 1,2] [--chain 20] [--out benchmarks/results/layer_norm_blocks.json]

For each row width, ``agents.layer_norm``'s forward and backward (``z``'s gradient and the
three parameter gradients' column sums) in bfloat16, as a GPU training step runs them, with
every ``layer_norm.Blocks`` of the options (rows a block, warps an instance, at most so many
instances looping over the blocks, loads pipelined so many stages deep), and the jnp form
(``pallas=False``: what XLA fuses of the same functions) as the baseline. One program
chains ``--chain`` calls (each call's output the next one's input) so launches overlap as in
training; reported: the time per call, the baseline's time over it, and compile time apart.
The blocks ``layer_norm`` uses (``FORWARD_BLOCKS``, ``BACKWARD_BLOCKS``) are marked. Triton
kernels need a GPU: a run elsewhere says so in one line (exit 2).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from benchmarks.common import compile_timed, machine_info, write_results
from jaxnav.agents import layer_norm

REPEATS = 5


def chained(op: Callable[[jax.Array], tuple], chain: int) -> Callable[[jax.Array], tuple]:
    """``chain`` calls of ``op(x) -> (x', other outputs)``, each on the last one's ``x'``;
    the other outputs are summed so that none is left out of the program."""

    def run(x: jax.Array) -> tuple:
        kept = None
        for _ in range(chain):  # straight-line: no while loop's per-trip synchronization
            x, other = op(x)
            kept = other if kept is None else jax.tree.map(jnp.add, kept, other)
        return x, kept

    return run


def seconds_per_call(op: Callable[[jax.Array], tuple], x: jax.Array, chain: int):
    """(seconds per call, best of ``REPEATS``; compile seconds)."""
    program, compile_s = compile_timed(chained(op, chain), x)
    return min(program() for _ in range(REPEATS)) / chain, compile_s


def measure(rows: int, width: int, blocks: list[layer_norm.Blocks], chain: int) -> list[dict]:
    """One width: the jnp form, then the kernels with each of ``blocks`` whose rows divide
    ``rows``, forward and backward."""
    k_z, k_g = jax.random.split(jax.random.key(width))
    z = jax.random.normal(k_z, (rows, width), jnp.bfloat16)
    grad = jax.random.normal(k_g, (rows, width), jnp.bfloat16)
    params = (jnp.zeros(width), jnp.ones(width), jnp.zeros(width))

    def forward(pallas: bool):
        # a gradient step's forward: a call without a gradient is the jnp form either way
        def op(v):
            fn = lambda x: layer_norm.layer_norm_relu(x, *params, pallas=pallas)  # noqa: E731
            return jax.vjp(fn, v)[0], ()

        return op

    def backward(pallas: bool):
        def op(v):
            # z's gradient chained; the parameters' gradients (the column sums) kept
            _, vjp = jax.vjp(lambda *a: layer_norm.layer_norm_relu(*a, pallas=pallas), z, *params)
            dz, *param_grads = vjp(v)
            return dz, param_grads

        return op

    directions = {
        "forward": (forward, layer_norm.FORWARD_BLOCKS, z),
        "backward": (backward, layer_norm.BACKWARD_BLOCKS, grad),
    }
    out = []
    for direction, (op, table, x) in directions.items():
        chosen = table[width]
        base_s, base_compile = seconds_per_call(op(False), x, chain)
        out.append(row(direction, width, "jnp (XLA)", base_s, base_s, base_compile, False))
        for entry in blocks:
            if rows % entry.rows:
                continue
            table[width] = entry  # read when the kernels are traced
            try:
                s, compile_s = seconds_per_call(op(True), x, chain)
            finally:
                table[width] = chosen
            label = (
                f"{entry.rows} rows, {entry.warps} warps, {entry.instances} instances, "
                f"{entry.stages} stages"
            )
            out.append(row(direction, width, label, s, base_s, compile_s, entry == chosen))
    return out


def row(direction, width, form, s, base_s, compile_s, chosen) -> dict[str, Any]:
    return {
        "direction": direction,
        "width": width,
        "form": form,
        "us_per_call": s * 1e6,
        "jnp_over_this": base_s / s,
        "compile_s": compile_s,
        "chosen": chosen,
    }


def markdown(result: dict[str, Any]) -> str:
    m = result["machine"]
    lines = [
        "# The fused LayerNorm's Pallas kernels by block size\n",
        f"`{result['command']}`; {m['devices'][0]}, jax {m['jax_version']}, {m['date'][:10]}.",
        f"{result['rows']:,} rows in bfloat16; time per call in a chain of {result['chain']} "
        f"(best of {REPEATS}); baseline: the jnp form, XLA's fusion of the same math; "
        "**bold**: the block `agents.layer_norm` uses. The jnp forward is row-local from input "
        "to output, so XLA fuses chained calls into fewer kernels: its time per call is a lower "
        "bound, not one call's.\n",
        "| direction | width | form | us per call | jnp / this | compile s |",
        "|---|---:|---|---:|---:|---:|",
    ]
    for r in result["measurements"]:
        form = f"**{r['form']}**" if r["chosen"] else r["form"]
        lines.append(
            f"| {r['direction']} | {r['width']} | {form} | {r['us_per_call']:.1f} | "
            f"{r['jnp_over_this']:.2f}x | {r['compile_s']:.1f} |"
        )
    return "\n".join(lines)


def int_list(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated integers") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected positive integers")
    return values


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, default=16384)
    p.add_argument("--widths", type=int_list, default=[1024, 512, 256])
    p.add_argument("--rows-per-block", type=int_list, default=[2, 4, 8, 16, 32])
    p.add_argument("--warps", type=int_list, default=[4, 8])
    p.add_argument("--instances", type=int_list, default=[256, 512, 1024], help="at most")
    p.add_argument("--stages", type=int_list, default=[1, 2], help="Triton's pipeline depth")
    p.add_argument("--chain", type=int, default=20, help="calls chained in one program")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/layer_norm_blocks.json"))
    args = p.parse_args(argv)
    bad = [w for w in args.widths if w not in layer_norm.KERNEL_WIDTHS]
    if bad:
        p.error(
            f"--widths {bad[0]}: the kernels take {', '.join(map(str, layer_norm.KERNEL_WIDTHS))}"
        )
    if args.rows < 1 or args.chain < 1:
        p.error(f"--rows {args.rows} --chain {args.chain}: both must be positive")
    if jax.default_backend() != "gpu":
        print("layer_norm_blocks: the Triton kernels need a GPU; this machine has none",
              file=sys.stderr)  # fmt: skip
        raise SystemExit(2)
    blocks = [
        layer_norm.Blocks(*b)
        for b in itertools.product(args.rows_per_block, args.warps, args.instances, args.stages)
    ]
    result = {
        "machine": machine_info(),
        "command": "python -m benchmarks.layer_norm_blocks " + " ".join(argv or sys.argv[1:]),
        "rows": args.rows,
        "chain": args.chain,
        "measurements": [
            r
            for w in args.widths
            for r in measure(args.rows, w, blocks, args.chain)
        ],
    }
    write_results(args.out, result, markdown(result))
    print(markdown(result))
    return result


if __name__ == "__main__":
    main()
