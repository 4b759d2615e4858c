"""Where the reverse pass's layout copies come from, and one way tried to
remove them (issue 15, item 4), side by side in one process.

In the compiled checkpointed gradient of `gradient_cost.py`'s 55-disk pile,
112 of the HLO's layout copies sit in `laws.base.contact_result`: its
`jnp.where(in_contact, force, 0)` on the stacked `[2]` force and history,
which `vmap` over a component-major batch turns into transposes. Variant A is
the law as it is; variant B masks each component before stacking them (the
same numbers: the forward is bit-identical). Both are timed round by round,
with the XLA:CPU kernels each launches per step.

    python benchmarks/contact_mask_ab.py [--steps 1000] [--rounds 7] [--out FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

import gradient_cost as gc  # benchmarks/ (scripts run from there)
from jaxpile import fit, io
from jaxpile.engine.compile import jit_derivative
from jaxpile.laws import base, hooke
from jaxpile.simulate import Simulator
from machine import details

_VARIANT = {"now": "A"}
_AS_IS = base.contact_result


def _per_component(in_contact, force, torque, history, normal, torque_j):
    def masked(v):
        return jnp.stack([jnp.where(in_contact, v[k], 0.0) for k in range(v.shape[0])])
    return base.PairForce(force=masked(force), torque=jnp.where(in_contact, torque, 0.0), history=masked(history),
                          normal=jnp.where(in_contact, normal, 0.0), in_contact=in_contact,
                          torque_j=jnp.where(in_contact, torque_j, 0.0))


def _law(variant: str):
    """hooke with rotation, its kernel a new function that picks the variant while jax traces it."""
    def pair_force(*args):
        _VARIANT["now"] = variant
        return hooke.pair_force(*args)
    return dataclasses.replace(hooke.law(rotation=True), pair_force=pair_force)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    hooke.contact_result = lambda *a: (_AS_IS if _VARIANT["now"] == "A" else _per_component)(*a)
    _, params, start = gc.setup(10, 0)
    programs = {}
    for v in ("A", "B"):
        sim = Simulator(_law(v), dt=5e-4, skin=0.1)
        state = sim.init(params, start.particles, start.boundaries)
        loss = gc.loss_fn(sim, state, args.steps, False)
        programs[f"forward_{v}"] = (jax.jit(loss), (params,))
        programs[f"reverse_{v}"] = (jit_derivative(jax.grad(gc.loss_fn(sim, state, args.steps, True))), (params,))
        programs[f"jvp_mu_{v}"] = (fit.value_and_gradient(lambda u, loss=loss: loss(params.set(mu=u)), params.mu,
                                                          "forward"), (params.mu,))
    leaves = {k: [np.asarray(x) for x in jax.tree.leaves(fn(*a))] for k, (fn, a) in programs.items()}
    out = {"machine": details(), "steps": args.steps, "disks": int(start.particles.count)}
    for k in ("forward", "reverse", "jvp_mu"):
        a, b = leaves[f"{k}_A"], leaves[f"{k}_B"]
        out[f"{k}_bit_identical"] = all(np.array_equal(x, y) for x, y in zip(a, b))
        out[f"{k}_max_relative_difference"] = max(float(np.max(np.abs(x - y) / np.maximum(np.abs(x), 1e-300)))
                                                  for x, y in zip(a, b))
    for k, (fn, a) in programs.items():
        out[f"kernels_per_step_{k}"] = gc.kernels_per_step(fn, a, args.steps)
    times = {k: [] for k in programs}
    for _ in range(args.rounds):
        for k, (fn, a) in programs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*a))
            times[k].append(time.perf_counter() - t0)
    t = {k: np.asarray(v) for k, v in times.items()}
    for v in ("A", "B"):
        for k in ("forward", "reverse", "jvp_mu"):
            out[f"{k}_{v}_s"] = float(t[f"{k}_{v}"].min())
        for k in ("reverse", "jvp_mu"):
            out[f"{k}_{v}_ratio"] = float(np.median(t[f"{k}_{v}"] / t[f"forward_{v}"]))
        print(f"{v}: forward {1e3 * out[f'forward_{v}_s']:.1f} ms, reverse {1e3 * out[f'reverse_{v}_s']:.1f} ms "
              f"({out[f'reverse_{v}_ratio']:.2f}x, {out[f'kernels_per_step_reverse_{v}']:.0f} kernels a step), "
              f"forward mode d/d mu {1e3 * out[f'jvp_mu_{v}_s']:.1f} ms ({out[f'jvp_mu_{v}_ratio']:.2f}x)")
    print(f"forward bit-identical: {out['forward_bit_identical']}; reverse differs by at most "
          f"{out['reverse_max_relative_difference']:.1e} (relative)")
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
