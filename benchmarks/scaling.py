"""Scaling: particle-steps per second and memory of one pile against its size,
in float32 and float64.

The problem: N disks of diameter 1 (sizes spread +-10%) start on a jittered
square grid with random velocities in a box (ground and two side walls) and
settle under gravity with the `hooke` law, friction and rotation on: contacts
form, slide and break, and the neighbour list is rebuilt as they fall. For each
N and precision it reports

* compile time (the first chunk's trace + XLA compile), apart from run time;
* particle-steps per second over `--steps` steps after that (`Simulator.run`,
  with its chunking, overflow checks and neighbour rebuilds: what a user gets);
* memory: the bytes of the simulation state (particles, contact history,
  neighbour list) and XLA's figure for the compiled chunk's temporary buffers
  (`compiled.memory_analysis()`), and on an accelerator the device's peak
  bytes in use. Both should grow linearly with N (flat per particle).

    python benchmarks/scaling.py [--sizes 1000,10000,100000] [--steps 500] [--precisions float32,float64] [--out FILE]
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
from jaxpile.engine.boundaries import make_boundaries
from jaxpile.engine import RunInfo, Simulator
from jaxpile.engine import make_particles
from jaxpile.laws import hooke
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)

# as the commands run: float64 and XLA's settings, multi-output fusion included
# (jaxpile.config), unless JAXPILE_MULTI_OUTPUT_FUSION=0
jaxpile.configure()

DT = 1e-3


def setup(n: int, dtype, seed: int = 0):
    """N disks on a jittered grid, 1.25 diameters apart, in a box as wide as a
    square of them; gaps are large enough that nothing overlaps at the start."""
    rng = np.random.default_rng(seed)
    columns = int(math.ceil(math.sqrt(n)))
    spacing = 1.25
    i = np.arange(n)
    position = np.stack([(i % columns + 0.5) * spacing, (i // columns + 0.5) * spacing + 0.1], axis=1)
    position += rng.uniform(-0.05, 0.05, position.shape)
    radius = 0.5 * rng.uniform(0.9, 1.1, n)
    particles = make_particles(position, radius, density=4.0 / math.pi, dtype=dtype,
                               velocity=rng.normal(0.0, 0.3, (n, 2)))
    boundaries = make_boundaries(left=0.0, right=columns * spacing, dtype=dtype)
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.5, dtype=dtype)
    return particles, boundaries, params


def state_bytes(state) -> int:
    return int(sum(x.nbytes for x in jax.tree_util.tree_leaves(state) if hasattr(x, "nbytes")))


def device_peak_bytes() -> int | None:
    stats = jax.devices()[0].memory_stats()
    return None if not stats or "peak_bytes_in_use" not in stats else int(stats["peak_bytes_in_use"])


def measure(n: int, precision: str, steps: int) -> dict:
    dtype = jnp.float32 if precision == "float32" else jnp.float64
    particles, boundaries, params = setup(n, dtype)
    sim = Simulator(hooke.law(rotation=True), DT, chunk_steps=min(steps, 500))
    state = sim.init(params, particles, boundaries)

    warm = RunInfo()
    state = sim.run(params, state, sim.chunk_steps, progress=False, info=warm)  # compile + one chunk
    compiled = sim._compiled_advance(params, state, None, RunInfo())  # the cached executable of the chunk
    temp = compiled.memory_analysis().temp_size_in_bytes if hasattr(compiled, "memory_analysis") else None

    info = RunInfo()
    t0 = time.perf_counter()
    state = sim.run(params, state, steps, progress=False, info=info)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - t0
    finite = bool(jnp.all(jnp.isfinite(state.particles.position)))
    return {
        "n": n, "precision": precision, "steps": steps,
        "compile_seconds": warm.compile_seconds,
        "run_seconds": seconds,
        "particle_steps_per_s": n * steps / seconds,
        "neighbor_slots": int(state.neighbors.idx.shape[1]),
        "reallocations": info.reallocations + warm.reallocations,
        "state_bytes": state_bytes(state),
        "state_bytes_per_particle": state_bytes(state) / n,
        "temp_bytes": temp,
        "temp_bytes_per_particle": None if temp is None else temp / n,
        "device_peak_bytes": device_peak_bytes(),
        "finite": finite,
    }


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000,10000,100000")
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--precisions", default="float32,float64")
    parser.add_argument("--out", default=None, help="JSON file for the figures")
    args = parser.parse_args(argv)

    machine = describe()
    print(f"scaling: settling box, hooke law with friction and rotation ({machine})")
    print(f"{'N':>8s} {'precision':>9s} {'compile s':>9s} {'p-steps/s':>10s} {'slots':>5s} "
          f"{'state B/p':>9s} {'temp B/p':>9s}")
    rows = []
    for precision in args.precisions.split(","):
        for n in (int(s) for s in args.sizes.split(",")):
            r = measure(n, precision, args.steps)
            rows.append(r)
            temp = "n/a" if r["temp_bytes_per_particle"] is None else f"{r['temp_bytes_per_particle']:.0f}"
            print(f"{n:8d} {precision:>9s} {r['compile_seconds']:9.2f} {r['particle_steps_per_s']:10.3g} "
                  f"{r['neighbor_slots']:5d} {r['state_bytes_per_particle']:9.0f} {temp:>9s}", flush=True)
    out = {"machine": machine, "jax_version": jax.__version__, "runs": rows,
           "table": [{"case": f"scaling: settling box, N = {r['n']}, {r['precision']}",
                      "jaxpile": r["particle_steps_per_s"], "lammps": None, "ratio": None,
                      "note": f"compile {r['compile_seconds']:.1f} s; {r['state_bytes_per_particle']:.0f} B/particle state"
                              + ("" if r["temp_bytes_per_particle"] is None
                                 else f" + {r['temp_bytes_per_particle']:.0f} B/particle XLA temp")}
                     for r in rows]}
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
