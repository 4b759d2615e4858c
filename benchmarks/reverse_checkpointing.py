"""Where the checkpointed reverse pass spends its time: the same gradient with
the rematerialisation placed differently (issue 15, item 4).

The problem is `gradient_cost.py`'s (a 55-disk frictional pile, the base-force
moment after T steps, d/d(kn, kt, mu)); every program is timed side by side
(`gradient_cost.side_by_side`: the ratio to the forward is the median over
rounds) and all must give the same gradient.

- `blocks` (what `Simulator.rollout(checkpoint=True)` does): blocks of sqrt(T)
  steps under `jax.checkpoint`; the reverse pass recomputes a block, stacking
  every step's residuals, then runs the block's transpose.
- `blocks+step`: the same with each step under `jax.checkpoint` too, so a
  block's recomputation stacks only the state and the transpose recomputes
  each step.
- `step`: each step under `jax.checkpoint` and no blocks: the state is stored
  every step (memory linear in T), nothing else.
- `blocks,nothing_saveable`: the blocks with `policy=nothing_saveable`.

If the residuals' stacking were what costs, `blocks+step` and `step` would be
cheaper than `blocks`; if the transposed step itself is, they are not.

    python benchmarks/reverse_checkpointing.py [--steps 1000] [--rounds 7] [--out FILE]
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys

import jax
from jax import lax

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import gradient_cost as gc  # noqa: E402  (the problem and the side-by-side timing)
from machine import describe  # noqa: E402

from jaxpile import io  # noqa: E402
from jaxpile.engine.compile import jit_derivative  # noqa: E402

VARIANTS = ("blocks", "blocks+step", "step", "blocks,nothing_saveable")


def _scan(step, params, state, n: int):
    if n == 0:
        return state
    return lax.scan(lambda s, _: (step(params, s), None), state, None, length=n)[0]


def rollout(sim, params, state, steps: int, variant: str):
    """`sim.rollout(params, state, steps, checkpoint=True)` with the
    rematerialisation of `variant`."""
    state = sim.refresh_forces(params, state)
    step = sim.step
    if variant == "step":
        return _scan(jax.checkpoint(step, prevent_cse=False), params, state, steps)
    inner = jax.checkpoint(step, prevent_cse=False) if variant == "blocks+step" else step
    policy = jax.checkpoint_policies.nothing_saveable if variant == "blocks,nothing_saveable" else None
    block = max(1, round(math.sqrt(steps)))
    blocks, rest = divmod(steps, block)
    run_block = jax.checkpoint(lambda p, s: _scan(inner, p, s, block), prevent_cse=False, policy=policy)
    state = lax.scan(lambda s, _: (run_block(params, s), None), state, None, length=blocks)[0]
    return _scan(step, params, state, rest)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layers", type=int, default=10)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    sim, params, state = gc.setup(args.layers, 0)
    steps = args.steps
    programs = {"forward": (jax.jit(lambda p: gc.moment(sim, p, sim.rollout(p, state, steps))), (params,))}
    for v in VARIANTS:
        loss = (lambda v: lambda p: gc.moment(sim, p, rollout(sim, p, state, steps, v)))(v)
        programs[v] = (jit_derivative(jax.grad(loss)), (params,))
    grads = {v: programs[v][0](params) for v in VARIANTS}
    first = grads[VARIANTS[0]]
    agree = max(abs(float(getattr(g, k) - getattr(first, k))) / abs(float(getattr(first, k)))
                for g in grads.values() for k in gc.NAMES)
    if not agree < 1e-9:
        raise SystemExit(f"the variants' gradients differ (relative {agree:.2g}): not the same derivative")
    timing = gc.side_by_side(programs, args.rounds)
    rows = [{"program": name, "seconds": timing[f"{name}_s"], "ratio_to_forward": timing[f"{name}_ratio"],
             "temp_mb": gc.temp_bytes(fn, *a) / 2**20} for name, (fn, a) in programs.items()]
    print(f"{state.particles.count} disks, {steps} steps, d/d(kn, kt, mu); gradients agree to {agree:.1g}")
    for r in rows:
        print(f"  {r['program']:24s} {r['seconds'] * 1e3:7.1f} ms  {r['ratio_to_forward']:5.2f}x forward  "
              f"XLA temp {r['temp_mb']:6.1f} MB")
    out = {"machine": describe(), "disks": int(state.particles.count), "steps": steps, "rounds": args.rounds,
           "gradients_agree_to": agree, "rows": rows,
           "command": "python benchmarks/reverse_checkpointing.py " + " ".join(argv if argv is not None
                                                                              else sys.argv[1:])}
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
