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
   jvp per parameter, batched: `fit.value_and_gradient(..., "forward")`) over
   the three and over mu alone (a one-parameter pathwise fit's), timed side by side
   (`--rounds` rounds, every program once a round; the ratio to the forward
   is the median over rounds), and
   the compiled temporary memory of each (`compiled.memory_analysis()`: XLA's
   own figure for the peak of live buffers). Derivative programs compile as
   jaxpile compiles them (`engine.compile.jit_derivative`).
   With `--breakdown`, the checkpointed reverse program's kernel time per
   step is classed from a profile (`reverse_breakdown`): what to shrink next.
2. Horizon: |dL/dmu| and |dL/dkn| (relative, d log L / d log theta) against T,
   full-horizon and differentiating only the final window of 200 steps (the state
   before it held fixed with `stop_gradient`), plus the spread of the
   full-horizon gradient over 8 random starts (ensemble averaging).

    python benchmarks/gradient_cost.py [--layers 10] [--horizons 250,1000,4000,16000] [--no-horizon] [--thunks]
                                       [--rounds 7] [--breakdown] [--out FILE]
"""

from __future__ import annotations

import argparse
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxpile
from jaxpile import io
from jaxpile import fit
from jaxpile.engine.boundaries import GROUND
from jaxpile.engine import Simulator
from jaxpile.laws import hooke
from jaxpile.protocols import lattice
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)

# as the commands run: float64 and XLA's settings, multi-output fusion included
# (jaxpile.config), unless JAXPILE_MULTI_OUTPUT_FUSION=0
jaxpile.configure()

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


def side_by_side(programs: dict, rounds: int = 7) -> dict:
    """`{name: (fn, args)}` timed side by side: each compiled by a first call
    (its extra time over a run: `compile_NAME_s`), then `rounds` rounds in which
    every program runs once. `NAME_s`: the best run; `NAME_ratio`: the median
    over rounds of its time over the forward's in the same round, so a load
    that comes and goes on a shared machine moves both alike."""
    out, times = {}, {name: [] for name in programs}
    for name, (fn, args) in programs.items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        out[f"compile_{name}_s"] = max(first - (time.perf_counter() - t0), 0.0)
    for _ in range(rounds):
        for name, (fn, args) in programs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*args))
            times[name].append(time.perf_counter() - t0)
    for name, t in times.items():
        out[f"{name}_s"] = min(t)
        out[f"{name}_ratio"] = float(np.median(np.asarray(t) / np.asarray(times["forward"])))
    return out


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


def loop_kernels(fn, args) -> list:
    """The compiled program's loops, read from its HLO: for each `while`, its
    trip count and the kernels its body launches on a step that does not
    rebuild the neighbour list (fusions, copies, scatters...; of each
    `conditional` the smaller branch, plus one for the cond itself). A
    checkpointed reverse program holds three loops over steps: the forward
    that finds each block's start, the block's recomputation, and the
    transposed step. `[(trip count, kernels), ...]` in the order of the text."""
    import re

    comps, cur = {}, None
    for line in fn.lower(*args).compile().as_text().splitlines():
        head = re.match(r"^(?:ENTRY )?%?([\w.\-]+) .*\{$", line)
        if head and not line.startswith(" "):
            cur = comps.setdefault(head.group(1), [])
        elif line.startswith("}"):
            cur = None
        elif cur is not None:
            cur.append(line)
    free = ("get-tuple-element", "tuple", "parameter", "bitcast", "constant", "while")

    def kernels(name):
        n = 0
        for line in comps[name]:
            m = re.match(r"\s*(?:ROOT )?%[\w.\-]+ = \S.*? ([\w\-]+)\(", line)
            if not m or m.group(1) in free:
                continue
            branches = re.search(r"branch_computations=\{([^}]*)\}", line)
            n += 1 + (min(kernels(b.strip().lstrip("%")) for b in branches.group(1).split(",")) if branches else 0)
        return n

    loops = []
    for lines in comps.values():
        for line in lines:
            m = re.search(r" while\(.*body=%([\w.\-]+)", line)
            if m:
                trips = re.search(r'"known_trip_count":\{"n":"(\d+)"', line)
                loops.append((int(trips.group(1)) if trips else -1, kernels(m.group(1))))
    return loops


def reverse_breakdown(fn, args, steps: int) -> dict:
    """Where a compiled reverse-mode program's kernel time goes, per step, from
    a profile of one call: each XLA:CPU kernel classed by what its HLO came
    from (the instruction's op_name) and its kind: the reverse pass of the
    pair law, of the walls (their `cond`s), the stores and loads of the
    per-step residuals (dynamic-update-slice / dynamic-slice), copies, the
    scatter-adds (the reverse of the gathers), and the rest of the forward
    (the block's recomputation). Nested events (cond, while) are left out, so
    every kernel counts once. `{class: [kernels per step, us per step]}`."""
    import collections
    import glob
    import re
    import tempfile

    jax.block_until_ready(fn(*args))
    op_name = {}
    for line in fn.lower(*args).compile().as_text().splitlines():
        m = re.match(r"\s*(?:ROOT )?%([\w.\-]+) = .*?op_name=\"([^\"]*)\"", line)
        if m:
            op_name[m.group(1)] = m.group(2)
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder):
            jax.block_until_ready(fn(*args))
        planes = jax.profiler.ProfileData.from_file(sorted(glob.glob(f"{folder}/**/*.xplane.pb", recursive=True))[-1])
        events = [(ev.name, ev.duration_ns) for plane in planes.planes for line in plane.lines for ev in line.events]
    classes = collections.defaultdict(lambda: [0.0, 0.0])
    for name, ns in events:
        if name.startswith(("$", "end: ", "ThunkExecutor", "Threadpool", "Transpose", "PjitFunction")) or re.match(
                r"(cond|while|conditional)\.", name):
            continue
        op = op_name.get(name, "")
        reverse = "transpose(" in op
        if name.startswith("copy"):
            kind = "copies"
        elif "dynamic-update-slice" in name or "dynamic_update_slice" in op:
            kind = "residual stores"
        elif "dynamic-slice" in name or op.endswith("dynamic_slice"):
            kind = "residual loads"
        elif "scatter" in op:
            kind = "scatter-adds (reverse)" if reverse else "scatter-adds (forward)"
        elif reverse:
            kind = "reverse: walls" if "branch_1_fun" in op else "reverse: pairs, integrator, rest"
        else:
            kind = "forward and recomputation"
        classes[kind][0] += 1 / steps
        classes[kind][1] += ns / 1e3 / steps
    return {k: [round(c, 2), round(t, 1)] for k, (c, t) in sorted(classes.items(), key=lambda kv: -kv[1][1])}


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
                        help="also count the XLA:CPU kernels each program launches per step (from a profile), "
                             "and each loop's kernels in its compiled HLO")
    parser.add_argument("--rounds", type=int, default=7, help="side-by-side timing rounds (median ratio)")
    parser.add_argument("--breakdown", action="store_true",
                        help="also class the checkpointed reverse program's kernel time per step (from a profile)")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    horizons = [int(h) for h in args.horizons.split(",")]
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")

    sim, params, state = setup(args.layers, 0)
    rows = []
    print(f"{state.particles.count} disks, hooke with friction; times in s, memory = XLA temp buffers")
    print(f"{'T':>6} {'forward':>8} {'grad':>8} {'grad/fwd':>8} {'grad ckpt':>9} {'ckpt/fwd':>8} "
          f"{'jvp x3':>8} {'jvp/fwd':>8} {'jvp mu':>8} {'/fwd':>6} "
          f"{'mem fwd':>9} {'mem grad':>9} {'mem ckpt':>9}")
    for steps in horizons:
        # every derivative program compiled as jaxpile compiles them (engine.compile.jit_derivative)
        forward = jax.jit(loss_fn(sim, state, steps, False))
        # reverse mode over the three parameters alone (the others held: their cotangents are not computed)
        values = {k: getattr(params, k) for k in NAMES}
        grad_ckpt = fit.value_and_gradient(lambda v: loss_fn(sim, state, steps, True)(params.set(**v)), values,
                                           "reverse")
        # forward mode over the same three, as `fit.descend(mode="auto")` takes it for <= 4 values
        jvp = fit.value_and_gradient(lambda v: loss_fn(sim, state, steps, False)(params.set(**v)), values, "forward")
        # and over mu alone: what a pathwise fit of one parameter differentiates
        one = {"mu": params.mu}
        jvp_mu = fit.value_and_gradient(lambda v: loss_fn(sim, state, steps, False)(params.set(**v)), one, "forward")
        programs = {"forward": (forward, (params,)), "grad_checkpoint": (grad_ckpt, (values,)),
                    "grad_forward_mode": (jvp, (values,)), "grad_forward_mode_mu": (jvp_mu, (one,))}
        if steps <= args.no_store_limit:
            programs["grad"] = (fit.value_and_gradient(lambda v: loss_fn(sim, state, steps, False)(params.set(**v)),
                                                       values, "reverse"), (values,))
        row = {"steps": steps, **side_by_side(programs, args.rounds)}
        row.update({f"mem_{name}": temp_bytes(fn, *a) for name, (fn, a) in programs.items()})
        if args.thunks:  # why the derivatives cost what they do on a small pile: kernel launches per step
            row.update({f"kernels_{name}": kernels_per_step(fn, a, steps) for name, (fn, a) in programs.items()
                        if name != "grad"})
            print(f"  kernels per step: forward {row['kernels_forward']:.0f}, reverse checkpointed "
                  f"{row['kernels_grad_checkpoint']:.0f}, forward mode x3 {row['kernels_grad_forward_mode']:.0f}, "
                  f"x1 {row['kernels_grad_forward_mode_mu']:.0f}")
            row["loop_kernels"] = {name: loop_kernels(fn, a) for name, (fn, a) in programs.items() if name != "grad"}
            print("  loops in the compiled programs (trips, kernels a trip; conds at their lighter branch): " + "; ".join(
                f"{name} {loops}" for name, loops in row["loop_kernels"].items()))
        if args.breakdown:  # where the checkpointed reverse pass spends its kernel time
            row["reverse_breakdown"] = reverse_breakdown(grad_ckpt, (values,), steps)
            print("  checkpointed reverse, per step (kernels, us): " + "; ".join(
                f"{k} {c:.0f}, {t:.0f}" for k, (c, t) in row["reverse_breakdown"].items()))
        rows.append(row)
        mb = 1 / 2**20
        print(f"{steps:6d} {row['forward_s']:8.3f} {row.get('grad_s', math.nan):8.3f} "
              f"{row.get('grad_ratio', math.nan):8.2f} {row['grad_checkpoint_s']:9.3f} "
              f"{row['grad_checkpoint_ratio']:8.2f} {row['grad_forward_mode_s']:8.3f} "
              f"{row['grad_forward_mode_ratio']:8.2f} {row['grad_forward_mode_mu_s']:8.3f} "
              f"{row['grad_forward_mode_mu_ratio']:6.2f} {row['mem_forward'] * mb:8.2f}M "
              f"{row.get('mem_grad', -1) * mb:8.2f}M {row['mem_grad_checkpoint'] * mb:8.2f}M")

    n = state.particles.count
    table = [{"case": f"gradient: {n}-disk pile, {r['steps']} steps, d/d(kn, kt, mu) (checkpointed)",
              "jaxpile": n * r["steps"] / r["grad_checkpoint_s"], "lammps": None, "ratio": None,
              "note": f"{r['grad_checkpoint_ratio']:.1f}x the forward time; XLA temp "
                      f"{r['mem_grad_checkpoint'] / 2**20:.1f} MB"
                      + (f" (stored: {r['mem_grad'] / 2**20:.1f} MB)" if "mem_grad" in r else "")
                      + f"; compile {r['compile_grad_checkpoint_s']:.1f} s"} for r in rows]
    table += [{"case": f"gradient: {n}-disk pile, {r['steps']} steps, d/d(kn, kt, mu) (forward mode)",
               "jaxpile": n * r["steps"] / r["grad_forward_mode_s"], "lammps": None, "ratio": None,
               "note": f"{r['grad_forward_mode_ratio']:.1f}x the forward time (fit's default for "
                       f"<= 4 values); XLA temp {r['mem_grad_forward_mode'] / 2**20:.1f} MB, flat in T; "
                       f"compile {r['compile_grad_forward_mode_s']:.1f} s"} for r in rows]
    table += [{"case": f"gradient: {n}-disk pile, {r['steps']} steps, d/d mu (forward mode, one parameter)",
               "jaxpile": n * r["steps"] / r["grad_forward_mode_mu_s"], "lammps": None, "ratio": None,
               "note": f"{r['grad_forward_mode_mu_ratio']:.1f}x the forward time (a one-parameter "
                       f"pathwise fit's); XLA temp {r['mem_grad_forward_mode_mu'] / 2**20:.1f} MB, flat in T; "
                       f"compile {r['compile_grad_forward_mode_mu_s']:.1f} s"} for r in rows]
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
        from jaxpile.engine.ensemble import stack

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
