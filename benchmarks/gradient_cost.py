"""Gradients through whole rollouts: cost against the forward run, memory
against the number of steps, and how the gradient norm behaves with the horizon.

The problem: a 10-layer 1992 lattice pile (55 disks, hooke law with friction
mu = 0.3 and rotation), started with random velocities and spins so that
contacts slide while it settles under gravity. The measured quantity is a base
force moment, sum_i N_i (x_i - x_c)^2 over the ground contacts (it changes
when the profile changes shape: the M or the hump).

1. Cost and memory: for each horizon T, the wall time of the forward rollout
   and of `jax.grad` with respect to (kn, kt, mu), with `checkpoint=False`
   (every step's intermediates stored) and `checkpoint=True` (blocks of
   sqrt(T) steps recomputed), and of the same gradient in forward mode (one
   jvp per parameter, batched: `fit.value_and_gradient(..., "forward")`), and
   the compiled temporary memory of each (`compiled.memory_analysis()`: XLA's
   own figure for the peak of live buffers). Derivative programs compile as
   jaxpile compiles them (`engine.compile.jit_derivative`).
2. Horizon: |dL/dmu| and |dL/dkn| (relative, d log L / d log theta) against T,
   full-horizon and differentiating only the final window of 200 steps (the state
   before it held fixed with `stop_gradient`), plus the spread of the
   full-horizon gradient over 8 random starts (ensemble averaging).

    python benchmarks/gradient_cost.py [--layers 10] [--horizons 250,1000,4000,16000] [--no-horizon] [--thunks]
                                       [--out FILE]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxpile  # noqa: F401  (float64)
from jaxpile import io
from jaxpile import fit
from jaxpile.boundaries import GROUND
from jaxpile.engine.compile import jit_derivative
from jaxpile.laws import hooke
from jaxpile.protocols import lattice
from jaxpile.simulate import Simulator
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)

NAMES = ("kn", "kt", "mu")


def setup(layers: int, seed: int):
    particles, boundaries = lattice.equilateral_pile(layers)
    rng = np.random.default_rng(seed)
    n = particles.count
    particles = particles.set(velocity=jnp.asarray(rng.normal(0, 0.2, (n, 2))),
                              angular_velocity=jnp.asarray(rng.normal(0, 1.0, n)))
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3, wall_mu=0.5)
    sim = Simulator(hooke.law(rotation=True), dt=5e-4, skin=0.1)
    state = sim.init(params, particles, boundaries)
    return sim, params, state


def moment(sim, params, state):
    cf = sim.contact_forces(params, state)
    normal = cf.wall.normal[:, GROUND] * cf.wall.in_contact[:, GROUND]
    x = state.particles.position[:, 0]
    centre = jnp.sum(normal * x) / jnp.maximum(jnp.sum(normal), 1e-12)
    return jnp.sum(normal * (x - centre) ** 2)


def loss_fn(sim, state, steps, checkpoint, window=None):
    def loss(params):
        s = state
        if window is not None and window < steps:
            s = jax.lax.stop_gradient(sim.rollout(params, s, steps - window))
            return moment(sim, params, sim.rollout(params, s, window, checkpoint=checkpoint))
        return moment(sim, params, sim.rollout(params, s, steps, checkpoint=checkpoint))
    return loss


def clock(fn, *args, compile_times: list | None = None):
    """Run time of `fn(*args)` after a first call (whose extra time, the trace and
    compile, is appended to `compile_times`)."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    run = time.perf_counter() - t0
    if compile_times is not None:
        compile_times.append(max(first - run, 0.0))
    return run


def temp_bytes(fn, *args) -> int:
    analysis = fn.lower(*args).compile().memory_analysis()
    return int(getattr(analysis, "temp_size_in_bytes", -1)) if analysis is not None else -1


def kernels_per_step(fn, args, steps: int) -> float:
    """XLA:CPU kernels (thunks) launched per step by the compiled `fn(*args)`,
    counted in a profile of one call (`jax.profiler`): the host-side cost of a
    small pile, where each kernel's launch outweighs its arithmetic."""
    import glob
    import tempfile

    jax.block_until_ready(fn(*args))
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder):
            jax.block_until_ready(fn(*args))
        planes = jax.profiler.ProfileData.from_file(sorted(glob.glob(f"{folder}/**/*.xplane.pb", recursive=True))[-1])
        names = [ev.name for plane in planes.planes for line in plane.lines for ev in line.events]
    # a kernel's events: its own name (its "end: " twin and the executor's and Python's own events left out)
    kernels = [n for n in names if not n.startswith(("$", "end: ", "ThunkExecutor", "Threadpool", "Transpose"))]
    return len(kernels) / steps


def relative_gradient(grad, params, value):
    return {k: float(getattr(grad, k)) * float(getattr(params, k)) / float(value) for k in NAMES}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layers", type=int, default=10)
    parser.add_argument("--horizons", default="250,1000,4000,16000")
    parser.add_argument("--no-store-limit", type=int, default=4000,
                        help="largest horizon to try without checkpointing (its memory grows with T)")
    parser.add_argument("--window", type=int, default=200)
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--no-horizon", action="store_true", help="cost and memory only (skip part 2)")
    parser.add_argument("--thunks", action="store_true",
                        help="also count the XLA:CPU kernels each program launches per step (from a profile)")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    horizons = [int(h) for h in args.horizons.split(",")]

    sim, params, state = setup(args.layers, 0)
    rows = []
    print(f"{state.particles.count} disks, hooke with friction; times in s, memory = XLA temp buffers")
    print(f"{'T':>6} {'forward':>8} {'grad':>8} {'grad/fwd':>8} {'grad ckpt':>9} {'ckpt/fwd':>8} "
          f"{'jvp x3':>8} {'jvp/fwd':>8} "
          f"{'mem fwd':>9} {'mem grad':>9} {'mem ckpt':>9}")
    for steps in horizons:
        # every derivative program compiled as jaxpile compiles them (engine.compile.jit_derivative)
        forward = jax.jit(loss_fn(sim, state, steps, False))
        grad_ckpt = jit_derivative(jax.grad(loss_fn(sim, state, steps, True)))
        # forward mode over the three parameters, as `fit.fit(mode="auto")` takes it for <= 4 values
        values = {k: getattr(params, k) for k in NAMES}
        jvp = fit.value_and_gradient(lambda v: loss_fn(sim, state, steps, False)(params.set(**v)), values, "forward")
        compiles = []
        row = {"steps": steps, "forward_s": clock(forward, params, compile_times=compiles),
               "grad_checkpoint_s": clock(grad_ckpt, params, compile_times=compiles),
               "grad_forward_mode_s": clock(jvp, values, compile_times=compiles),
               "mem_forward": temp_bytes(forward, params), "mem_grad_checkpoint": temp_bytes(grad_ckpt, params),
               "mem_grad_forward_mode": temp_bytes(jvp, values)}
        row.update(compile_forward_s=compiles[0], compile_grad_checkpoint_s=compiles[1],
                   compile_grad_forward_mode_s=compiles[2])
        if args.thunks:  # why the derivatives cost what they do on a small pile: kernel launches per step
            row.update(kernels_forward=kernels_per_step(forward, (params,), steps),
                       kernels_grad_checkpoint=kernels_per_step(grad_ckpt, (params,), steps),
                       kernels_grad_forward_mode=kernels_per_step(jvp, (values,), steps))
            print(f"  kernels per step: forward {row['kernels_forward']:.0f}, reverse checkpointed "
                  f"{row['kernels_grad_checkpoint']:.0f}, forward mode x3 {row['kernels_grad_forward_mode']:.0f}")
        if steps <= args.no_store_limit:
            grad = jit_derivative(jax.grad(loss_fn(sim, state, steps, False)))
            row.update(grad_s=clock(grad, params, compile_times=compiles), mem_grad=temp_bytes(grad, params))
            row.update(compile_grad_s=compiles[3])
        rows.append(row)
        mb = 1 / 2**20
        g = row.get("grad_s", float("nan"))
        print(f"{steps:6d} {row['forward_s']:8.3f} {g:8.3f} {g / row['forward_s']:8.2f} "
              f"{row['grad_checkpoint_s']:9.3f} {row['grad_checkpoint_s'] / row['forward_s']:8.2f} "
              f"{row['grad_forward_mode_s']:8.3f} {row['grad_forward_mode_s'] / row['forward_s']:8.2f} "
              f"{row['mem_forward'] * mb:8.2f}M {row.get('mem_grad', -1) * mb:8.2f}M "
              f"{row['mem_grad_checkpoint'] * mb:8.2f}M")

    n = state.particles.count
    table = [{"case": f"gradient: {n}-disk pile, {r['steps']} steps, d/d(kn, kt, mu) (checkpointed)",
              "jaxpile": n * r["steps"] / r["grad_checkpoint_s"], "lammps": None, "ratio": None,
              "note": f"{r['grad_checkpoint_s'] / r['forward_s']:.1f}x the forward time; XLA temp "
                      f"{r['mem_grad_checkpoint'] / 2**20:.1f} MB"
                      + (f" (stored: {r['mem_grad'] / 2**20:.1f} MB)" if "mem_grad" in r else "")
                      + f"; compile {r['compile_grad_checkpoint_s']:.1f} s"} for r in rows]
    table += [{"case": f"gradient: {n}-disk pile, {r['steps']} steps, d/d(kn, kt, mu) (forward mode)",
               "jaxpile": n * r["steps"] / r["grad_forward_mode_s"], "lammps": None, "ratio": None,
               "note": f"{r['grad_forward_mode_s'] / r['forward_s']:.1f}x the forward time (fit's default for "
                       f"<= 4 values); XLA temp {r['mem_grad_forward_mode'] / 2**20:.1f} MB, flat in T; "
                       f"compile {r['compile_grad_forward_mode_s']:.1f} s"} for r in rows]
    if args.no_horizon:
        out = {"machine": describe(),
               "disks": n, "cost": rows, "table": table}
        if args.out:
            io.write_json(args.out, out)
        return out

    print(f"\nrelative gradients d log L / d log theta against the horizon "
          f"(full; last {args.window} steps only; spread over {args.seeds} random starts)")
    horizon_rows = []
    starts = [setup(args.layers, s)[2] for s in range(args.seeds)]
    for steps in horizons:
        full = jax.jit(jax.value_and_grad(loss_fn(sim, state, steps, True)))
        win = jax.jit(jax.value_and_grad(loss_fn(sim, state, steps, True, window=args.window)))
        v, g = full(params)
        vw, gw = win(params)
        rel, rel_w = relative_gradient(g, params, v), relative_gradient(gw, params, vw)
        batch = jax.jit(jax.vmap(lambda s: jax.value_and_grad(loss_fn(sim, s, steps, True))(params)))
        from jaxpile.ensemble import stack

        vs, gs = batch(stack(starts))
        per = np.array([[float(getattr(gs, k)[i]) * float(getattr(params, k)) / float(vs[i]) for k in NAMES]
                        for i in range(args.seeds)])
        row = {"steps": steps, "loss": float(v), "relative_grad": rel, "relative_grad_window": rel_w,
               "ensemble_mean": dict(zip(NAMES, per.mean(0).tolist())),
               "ensemble_std": dict(zip(NAMES, per.std(0, ddof=1).tolist()))}
        horizon_rows.append(row)
        print(f"  T = {steps:6d}: " + ", ".join(
            f"{k}: {rel[k]:+.3g} (window {rel_w[k]:+.3g}; starts {row['ensemble_mean'][k]:+.3g} "
            f"+- {row['ensemble_std'][k]:.2g})" for k in NAMES))

    out = {"machine": describe(),
           "disks": n, "cost": rows, "horizon": horizon_rows, "table": table}
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
