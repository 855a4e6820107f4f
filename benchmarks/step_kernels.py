"""What one vectorized env step compiles to: top-level kernels, loops and time per step.

    python -m benchmarks.step_kernels [--num-envs 65536] [--envs "GridMaze-v0,FourRooms-misc"]
        [--steps 100] [--out DIR]

For each row of ``benchmarks.env_throughput`` (same ``build``): jit one auto-resetting batched
step (``Row.batch_step``) of ``--num-envs`` envs with random actions, count the top-level
operations of the compiled program that launch work (fusions, custom calls, gathers, scatters,
sorts, reduces, copies, while loops), and time it alone (one call: mostly dispatch on a GPU) and
as the body of a ``--steps`` loop (per step; median of 5). With ``--out`` the compiled HLO of
each row is written there.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from benchmarks.env_throughput import build

LAUNCHING = "fusion|custom-call|gather|scatter|sort|while|reduce|copy|dynamic-update-slice"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.step_kernels", description=__doc__)
    p.add_argument("--num-envs", type=int, default=65536)
    p.add_argument("--envs", default="GridMaze-v0,FourRooms-misc")
    p.add_argument("--steps", type=int, default=100, help="steps of the timed loop")
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    n = args.num_envs
    print(
        "| env | top-level kernels per step | while loops | ms per call of one step | "
        f"ms per step in a loop of {args.steps} ({n:,} envs) | steps/s in the loop |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for name in [e.strip() for e in args.envs.split(",") if e.strip()]:
        row = build(name)

        def one_step(key, state, step=row.batch_step, num_actions=row.num_actions):
            k_act, k_step = jax.random.split(key)
            actions = (jax.random.bits(k_act, (n,)) % num_actions).astype(jnp.int32)
            return step(jax.random.split(k_step, n), state, actions)

        def loop(key, state, one_step=one_step):
            body = lambda i, s: one_step(jax.random.fold_in(key, i), s)[1]  # noqa: E731
            return jax.lax.fori_loop(0, args.steps, body, state)

        _, state = jax.jit(jax.vmap(row.reset))(jax.random.split(jax.random.key(0), n))
        compiled = jax.jit(one_step).lower(jax.random.key(1), state).compile()
        looped = jax.jit(loop).lower(jax.random.key(1), state).compile()
        text = compiled.as_text()
        entry = text[text.index("\nENTRY") :]
        kernels = len(re.findall(rf"= \S+ ({LAUNCHING})\(", entry))
        loops = len(re.findall(r" while\(", text))
        per_call, per_step = [], []
        for _ in range(5):
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(jax.random.key(2), state))
            t1 = time.perf_counter()
            jax.block_until_ready(looped(jax.random.key(2), state))
            per_call.append(t1 - t0)
            per_step.append((time.perf_counter() - t1) / args.steps)
        call, dt = statistics.median(per_call), statistics.median(per_step)
        print(
            f"| {name} | {kernels} | {loops} | {call * 1e3:.3f} | {dt * 1e3:.4f} | {n / dt:.3g} |",
            flush=True,
        )
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / f"{name.replace(' ', '_')}.hlo.txt").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
