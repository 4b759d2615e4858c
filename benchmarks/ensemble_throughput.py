"""Batched ensembles: what one batch-wide rebuild decision buys, and batch vs serial.

For B box piles (Lee & Herrmann 1993, the lee-herrmann law) falling in their box,
times the same steps three ways:

* `batch-wide`: `Ensemble` (the rebuild and history carry decided once for
  the batch with a `lax.pmax` over the vmap axis: real branches);
* `sequential`: `Ensemble(sequential=True)`, the members one after another
  inside the same compiled call, each with its own rebuilds (the pour's
  choice, on one CPU device: elsewhere side by side, and the JSON's
  `sequential_used` says which ran);
* `naive vmap`: `jax.vmap` of the single-pile step (jax-md's per-member cond
  becomes a select: every member rebuilds its list and carries its history at
  every step);
* `serial`: the B piles one after the other with `Simulator.run`.

Prints particle-steps per second for each and the ratios, and writes JSON.

With `--batch-only` only the batch-wide call is timed (large batches on a GPU,
where B serial piles would take longer than the batch is worth measuring).

    python benchmarks/ensemble_throughput.py [--members 8] [--n 100] [--steps 2000]
        [--precision float64] [--batch-only] [--out FILE]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
from jax import lax

import jaxpile
from jaxpile import io
from jaxpile.engine import ensemble
from jaxpile.protocols import box
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)

# as the commands run: float64 and XLA's settings, multi-output fusion included
# (jaxpile.config), unless JAXPILE_MULTI_OUTPUT_FUSION=0
jaxpile.configure()

LAW = "lee-herrmann"


def timed(fn, *args):
    jax.block_until_ready(fn(*args))  # compile and warm up
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t0


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--members", type=int, default=8)
    parser.add_argument("--n", type=int, default=100, help="disks per pile")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--precision", default="float64", choices=["float32", "float64"])
    parser.add_argument("--batch-only", action="store_true", help="time the batch-wide call alone")
    parser.add_argument("--out", default=None, help="JSON file for the figures")
    args = parser.parse_args(argv)

    width = (args.n / 409) ** 0.5 * 4.0  # the paper's 4 x 4 box scaled to n disks
    dtype = jnp.float32 if args.precision == "float32" else jnp.float64
    protocols = [box.SPEC.set_up(LAW, args.n, width=width, height=width, seed=s, dtype=dtype)
                 for s in range(args.members)]
    params = [box.law_and_params(LAW, {"mu": 0.1 + 0.05 * (s % 5)}, dtype=dtype)[2] for s in range(args.members)]
    sim = box.make_simulator(LAW, chunk_steps=args.steps)
    ens = ensemble.Ensemble(sim)
    state = ens.init(params, protocols)
    pb = ens.as_batch(params, args.members)
    n = jnp.int32(args.steps)
    frozen = jnp.zeros(args.members, bool)

    batch_wide = jax.jit(ens._advance)
    t0 = time.perf_counter()
    batch_wide.lower(pb, state, frozen, n).compile()
    compile_seconds = time.perf_counter() - t0
    t_batch = timed(batch_wide, pb, state, frozen, n)
    work = args.members * args.n * args.steps
    if args.batch_only:
        out = {"machine": describe(), "members": args.members, "disks_per_pile": args.n, "steps": args.steps,
               "precision": args.precision, "compile_seconds": compile_seconds,
               "batch_wide_particle_steps_per_s": work / t_batch}
        out["table"] = [{"case": f"{args.members} box piles x {args.n} disks ({LAW}, {args.precision}), one vmapped call",
                         "jaxpile": out["batch_wide_particle_steps_per_s"], "lammps": None, "ratio": None,
                         "note": f"compile {compile_seconds:.1f} s"}]
        print(f"{args.members} box piles x {args.n} disks x {args.steps} steps, {args.precision} ({out['machine']}): "
              f"{out['batch_wide_particle_steps_per_s']:.3g} particle-steps/s (compile {compile_seconds:.1f} s)")
        if args.out:
            io.write_json(args.out, out)
        return out

    @jax.jit
    def naive(params, state, n):
        return jax.vmap(lambda p, s: lax.fori_loop(0, n, lambda _, x: sim.step(p, x), s))(params, state)

    t_naive = timed(naive, pb, state, n)
    in_turn = ensemble.Ensemble(sim, sequential=True)
    t_sequential = timed(jax.jit(in_turn._advance), pb, state, frozen, n)

    singles = ensemble.members(state)
    single = jax.jit(sim._advance)
    jax.block_until_ready(single(params[0], singles[0], None, n))
    t0 = time.perf_counter()
    for p, s in zip(params, singles):
        jax.block_until_ready(single(p, s, None, n))
    t_serial = time.perf_counter() - t0

    out = {
        "machine": describe(),
        "members": args.members, "disks_per_pile": args.n, "steps": args.steps,
        "precision": args.precision, "compile_seconds": compile_seconds,
        "batch_wide_particle_steps_per_s": work / t_batch,
        "naive_vmap_particle_steps_per_s": work / t_naive,
        "sequential_particle_steps_per_s": work / t_sequential, "sequential_used": in_turn.sequential,
        "serial_particle_steps_per_s": work / t_serial,
        "batch_wide_over_naive": t_naive / t_batch,
        "batch_wide_over_serial": t_serial / t_batch,
    }
    case = f"{args.members} box piles x {args.n} disks ({LAW}), one vmapped call"
    out["table"] = [
        {"case": case + ": batch-wide rebuild vs naive vmap", "jaxpile": out["batch_wide_particle_steps_per_s"],
         "lammps": None, "ratio": None,
         "note": f"{out['batch_wide_over_naive']:.2f}x naive vmap ({out['naive_vmap_particle_steps_per_s']:.3g}); "
                 f"{out['batch_wide_over_serial']:.2f}x the same piles one after another in jaxpile; "
                 f"the members one after another in one call {out['sequential_particle_steps_per_s']:.3g}"},
    ]
    print(f"{args.members} box piles x {args.n} disks x {args.steps} steps ({out['machine']}):")
    for key in ("batch_wide", "sequential", "naive_vmap", "serial"):
        print(f"  {key:11s} {out[key + '_particle_steps_per_s']:.3g} particle-steps/s")
    print(f"  batch-wide decision vs naive vmap: {out['batch_wide_over_naive']:.2f}x; "
          f"vs serial: {out['batch_wide_over_serial']:.2f}x")
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
