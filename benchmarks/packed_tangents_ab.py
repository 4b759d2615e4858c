"""Packed tangents through the pair loop's gathers and scatters, side by side
with the pair loop as it is (issue 15, item 4).

A derivative of the step moves a tangent (forward mode) or a cotangent
(reverse mode) through every gather of a disk's fields onto its pairs
(`interactions.pair_ends`: position, velocity, spin, each end) and every
scatter of the pairs' forces onto their disks (`interactions.pair_sums`). In
reverse mode each gather becomes a scatter-add of its own. The variants
define those two functions' derivatives with `jax.custom_jvp`, the primal
left as it is (the forward is the same program):

  ends: the tangents of all the gathered fields packed into one `[n, m]`
        table and gathered by rows, once per end (reverse: one scatter-add
        of `[P, m]` rows per end instead of one per field);
  sums: the tangents of force and torque packed into one `[2P, m]` table
        and summed by one scatter (reverse: one gather of rows);
  both: the two.

Timed round by round with the forward, over d/d(kn, kt, mu) in reverse mode
(checkpointed) and forward mode, with the XLA:CPU kernels each launches per
step. The gradients must agree to round-off.

    python benchmarks/packed_tangents_ab.py [--layers 10] [--steps 1000] [--rounds 9] [--out FILE]
"""

from __future__ import annotations

import argparse
import functools

import jax
import jax.numpy as jnp

import gradient_cost as gc  # benchmarks/ (scripts run from there)
from jaxpile import fit, io
from jaxpile.engine import interactions
from machine import details

AS_IS = (interactions.pair_ends, interactions.pair_sums)


def _split(table, widths, axis: int) -> list:
    """`table` cut along `axis` into fields of the given numbers of components
    (None: one, the axis dropped)."""
    out, k = [], 0
    for c in widths:
        part = jax.lax.slice_in_dim(table, k, k + (c or 1), axis=axis)
        out.append(part if c else jnp.squeeze(part, axis))
        k += c or 1
    return out


@jax.custom_jvp
def packed_ends(fields, i, j):
    return AS_IS[0](fields, i, j)


@packed_ends.defjvp
def _packed_ends_jvp(primals, tangents):
    fields, i, j = primals
    table = jnp.concatenate([d.reshape(d.shape[0], -1) for d in tangents[0]], axis=1)  # [n, m]
    widths = [x.shape[1] if x.ndim > 1 else None for x in fields]
    ends = [_split(rows, widths, axis=0) for rows in (table[i].T, table[j].T)]  # rows: [m, P]
    return AS_IS[0](fields, i, j), tuple(zip(*ends))


@functools.partial(jax.custom_jvp, nondiff_argnums=(4,))
def packed_sums(at_i, at_j, i, j, n):
    return AS_IS[1](at_i, at_j, i, j, n)


@packed_sums.defjvp
def _packed_sums_jvp(n, primals, tangents):
    at_i, at_j, i, j = primals
    d_i, d_j = tangents[0], tangents[1]
    rows = [v if v.ndim > 1 else v[None] for v in d_i]  # [c, P] each
    rows_j = [-r if b is None else (d if d.ndim > 1 else d[None]) for r, b, d in zip(rows, at_j, d_j)]
    table = jax.ops.segment_sum(jnp.concatenate([jnp.concatenate(rows), jnp.concatenate(rows_j)], axis=1).T,
                                jnp.concatenate([i, j]), n)  # [n, m]
    widths = [v.shape[0] if v.ndim > 1 else None for v in at_i]
    return AS_IS[1](at_i, at_j, i, j, n), tuple(_split(table, widths, axis=1))


VARIANTS = {"as_is": AS_IS, "ends": (packed_ends, AS_IS[1]), "sums": (AS_IS[0], packed_sums),
            "both": (packed_ends, packed_sums)}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layers", type=int, default=10)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    sim, params, state = gc.setup(args.layers, 0)
    values = {k: getattr(params, k) for k in gc.NAMES}

    def loss(checkpoint):
        return lambda v: gc.loss_fn(sim, state, args.steps, checkpoint)(params.set(**v))

    programs = {"forward": (jax.jit(gc.loss_fn(sim, state, args.steps, False)).lower(params).compile(), (params,))}
    for name, (ends, sums) in VARIANTS.items():
        interactions.pair_ends, interactions.pair_sums = ends, sums  # read while jax traces
        for mode, checkpoint in (("reverse", True), ("forward_mode", False)):
            fn = fit.value_and_gradient(loss(checkpoint), values, mode.split("_")[0])
            programs[f"{mode}_{name}"] = (fn.lower(values).compile(), (values,))
    interactions.pair_ends, interactions.pair_sums = AS_IS

    out = {"machine": details(), "steps": args.steps, "disks": int(state.particles.count)}
    grads = {k: fn(*a)[1] for k, (fn, a) in programs.items() if k != "forward"}
    out["max_relative_difference"] = max(
        abs(float(g[p]) - float(grads["reverse_as_is"][p])) / abs(float(grads["reverse_as_is"][p]))
        for g in grads.values() for p in gc.NAMES)
    out.update(gc.side_by_side(programs, args.rounds))
    for k, (fn, a) in programs.items():
        out[f"kernels_per_step_{k}"] = gc.kernels_per_step(fn, a, args.steps)
        print(f"{k:22s} {1e3 * out[f'{k}_s']:7.1f} ms  {out[f'{k}_ratio']:5.2f}x the forward  "
              f"{out[f'kernels_per_step_{k}']:4.0f} kernels a step")
    print(f"gradients agree to {out['max_relative_difference']:.1e} (relative)")
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
