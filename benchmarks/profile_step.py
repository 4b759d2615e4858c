"""Where the time of one step goes: a profile of the compiled step, grouped by
what each XLA kernel computes.

Runs `--steps` steps of the 1992 lattice pile (hooke law, as the LAMMPS race)
under `jax.profiler`, reads the trace back, and sums the time of each XLA
kernel (fusion) per step, beside the step's time without the profiler (tracing
adds a fixed cost to every kernel, which small piles' many small kernels
magnify). Kernels are grouped by the jaxpile code they come
from (read from the HLO's stack-frame tables): the contact law, the geometry and force
sums around it, the neighbour list, the integrator. Also prints XLA's own cost analysis of one step (flops, bytes).

With `--case cone`, the same for cone_vs_lammps.py's cone of `--pour-n`
spheres (3D) at its half-way point.

With `--case pour` the step profiled is a pour's (hooke, vs_lammps.py's
pour of `--pour-n` disks at its half-way point, on the block of disks in
play, as `Simulator.run` runs it): where a small, changing pile spends its
step.

    python benchmarks/profile_step.py [--case lattice|pour|cone] [--layers 45] [--pour-n 1000] [--steps 500]
                                      [--precision float64] [--top 12] [--out FILE]
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import re
import tempfile
import time

import jax
import jax.numpy as jnp
from jax import lax

import jaxpile
from jaxpile import io
from jaxpile.engine import Simulator, gravity_ramp
from jaxpile.laws import hooke
from jaxpile.protocols import lattice, pour
from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)

# as the commands run: float64 and XLA's settings, multi-output fusion included
# (jaxpile.config), unless JAXPILE_MULTI_OUTPUT_FUSION=0
jaxpile.configure()


def _table(hlo_text: str, title: str) -> dict[int, str]:
    m = re.search(rf"^{title}\n(.*?)(?:\n\n|\n[A-Z]\w+\n)", hlo_text, re.S | re.M)
    return {} if m is None else dict(line.split(" ", 1) for line in m.group(1).splitlines() if line.strip())


def source_of_kernels(hlo_text: str) -> dict[str, str]:
    """Kernel name -> "file:function" of the innermost jaxpile (or jax-md) frame
    of the code it was traced from, read from the HLO's stack-frame tables."""
    files = {int(k): v.strip('"') for k, v in _table(hlo_text, "FileNames").items()}
    functions = {int(k): v.strip('"') for k, v in _table(hlo_text, "FunctionNames").items()}
    locations = {int(k): tuple(int(x) for x in re.findall(r"(?:file_name_id|function_name_id)=(\d+)", v))
                 for k, v in _table(hlo_text, "FileLocations").items()}
    frames = {int(k): tuple(int(x) for x in re.findall(r"(?:file_location_id|parent_frame_id)=(\d+)", v))
              for k, v in _table(hlo_text, "StackFrames").items()}

    def where(frame_id: int) -> str:
        seen = set()
        while frame_id in frames and frame_id not in seen:
            seen.add(frame_id)
            location, parent = frames[frame_id]
            file_id, function_id = locations.get(location, (0, 0))
            path = files.get(file_id, "")
            for package in ("jaxpile/", "jax_md/"):
                if package in path:
                    return f"{package}{path.split(package, 1)[1]}:{functions.get(function_id, '?')}"
            frame_id = parent
        return "other"

    out = {}
    for m in re.finditer(r"%([\w.-]+) = [^\n]*?(?:fusion|custom-call|gather|scatter)\([^\n]*?stack_frame_id=(\d+)", hlo_text):
        out[m.group(1)] = where(int(m.group(2)))
    return out


def group_of(source: str) -> str:
    """A coarse label for a kernel's source."""
    if source.startswith("jax_md/"):
        return "neighbour list (jax-md: check, rebuild)"
    if "jaxpile/laws/" in source:
        return "contact law kernel"
    if "interactions.py" in source:
        return "pair/wall geometry, masks, force sums"
    if "integrators.py" in source:
        return "integrator"
    if "neighbors.py" in source:
        return "neighbour check, pair list, history carry"
    return "step glue (" + source + ")"


def pour_at_half_way(n: int, steps: int):
    """`(sim, params, state, title)`: vs_lammps.py's hooke pour of n disks run
    to half its pour steps, cut to the block of disks in play over the next
    `steps` steps (`jaxpile.engine.blocks`), as `Simulator.run` would run them."""
    import vs_lammps
    from jaxpile.engine import blocks

    protocol = vs_lammps.pour_setup(n, 0.15, 0)
    _, _, params = pour.law_and_params("hooke")
    sim = pour.make_simulator("hooke", dt=vs_lammps.DT, chunk_steps=vs_lammps.POUR_CHUNK,
                              integrator="velocity_verlet")
    state = sim.init(params, protocol.particles, protocol.boundaries, box=protocol.box,
                     protocol_state=protocol.protocol_state)
    state = sim.run(params, state, protocol.info["pour_steps"] // 2, progress=False)
    total = state.particles.count
    block = sim._block_for(state, steps, {})
    if block is not None:
        state = blocks.take_jit(state, *block)
    in_play = int(jnp.sum(state.particles.active))
    return sim, params, state, (f"pour of {n} disks (hooke) half-way: {in_play} disks in play, "
                                f"block of {state.particles.count} of {total}")


def cone_at_half_way(n: int, steps: int):
    """`(sim, params, state, title)`: cone_vs_lammps.py's cone of n spheres
    (hooke, the cone's own set-up) run to half its pour steps, cut to the
    block of spheres in play over the next `steps` steps, as `Simulator.run`
    would run them."""
    from jaxpile.engine import blocks
    from jaxpile.protocols import cone

    setup = cone.SPEC.set_up("hooke", n, seed=0)
    _, _, params = cone.law_and_params("hooke")
    sim = cone.simulator(cone.SPEC.make_options({"n": n}), law="hooke", dt=setup.info["dt"], chunk_steps=2000)
    state = sim.init(params, setup.particles, setup.boundaries, protocol_state=setup.protocol_state)
    state = sim.run(params, state, setup.info["pour_steps"] // 2, progress=False)
    total = state.particles.count
    block = sim._block_for(state, steps, {})
    if block is not None:
        state = blocks.take_jit(state, *block)
    in_play = int(jnp.sum(state.particles.active & ~state.particles.fixed))
    return sim, params, state, (f"cone of {n} spheres (hooke) half-way: {in_play} poured in play, "
                                f"block of {state.particles.count} of {total}")


def _timed(compiled, state) -> float:
    """Seconds for one call of the compiled loop, its result awaited."""
    start = time.perf_counter()
    jax.block_until_ready(compiled(state))
    return time.perf_counter() - start


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="lattice", choices=["lattice", "pour", "cone"])
    parser.add_argument("--layers", type=int, default=45)
    parser.add_argument("--pour-n", type=int, default=1000, help="pour: disks poured; cone: spheres poured")
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--precision", default="float64", choices=["float32", "float64"])
    parser.add_argument("--top", type=int, default=12)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    if args.case in ("pour", "cone") and args.precision != "float64":
        parser.error(f"--case {args.case} runs its race's set-up, in float64")

    dtype = jnp.float32 if args.precision == "float32" else jnp.float64
    if args.case == "pour":
        sim, params, state, title = pour_at_half_way(args.pour_n, args.steps)
    elif args.case == "cone":
        sim, params, state, title = cone_at_half_way(args.pour_n, args.steps)
    else:
        params = hooke.make_params(dtype=dtype, **lattice.PAPER_SETTING["params"]["hooke"])
        sim = Simulator(hooke.law(rotation=False), lattice.PAPER_SETTING["dt"], schedule=gravity_ramp(20_000))
        particles, boundaries = lattice.equilateral_pile(args.layers, dtype=dtype)
        state = sim.init(params, particles, boundaries)
        state = sim.run(params, state, 2000, progress=False)  # loaded and in contact
        title = f"{args.layers}-layer lattice pile ({particles.count} disks), hooke"

    run = jax.jit(lambda s: lax.fori_loop(0, args.steps, lambda i, s: sim.step(params, s), s))
    compiled = run.lower(state).compile()
    jax.block_until_ready(compiled(state))
    wall = min(_timed(compiled, state) for _ in range(3)) / args.steps * 1e6  # us a step, no profiler
    names = source_of_kernels(compiled.as_text())
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost

    with tempfile.TemporaryDirectory() as tmp:
        jax.profiler.start_trace(tmp, create_perfetto_trace=True)
        jax.block_until_ready(compiled(state))
        jax.profiler.stop_trace()
        files = glob.glob(f"{tmp}/**/*.trace.json.gz", recursive=True)
        events = json.load(gzip.open(files[0]))["traceEvents"] if files else []

    per_kernel = collections.Counter()
    for e in events:
        if e.get("ph") == "X" and e.get("name") in names:
            per_kernel[e["name"]] += e["dur"] / args.steps  # microseconds per step
    total = sum(per_kernel.values())
    groups = collections.Counter()
    for name, us in per_kernel.items():
        groups[group_of(names[name])] += us

    n = state.particles.count
    print(f"{title}, {args.precision}, {describe()}")
    print(f"kernel time per step: {total:.1f} us ({total / n * 1e3:.0f} ns per particle), "
          f"{len(per_kernel)} kernels, as traced; without the profiler a step takes {wall:.1f} us "
          f"(the trace adds ~{max(total - wall, 0.0) / max(len(per_kernel), 1):.2f} us a kernel)")
    for group, us in groups.most_common():
        print(f"  {group:42s} {us:8.1f} us  {100 * us / max(total, 1e-9):5.1f}%")
    print(f"top {args.top} kernels:")
    for name, us in per_kernel.most_common(args.top):
        print(f"  {us:8.1f} us  {name:30s} {names[name]}")
    flops = cost.get("flops") if cost else None
    print(f"XLA cost analysis of the compiled loop (both branches of each cond counted): "
          f"{flops:.3g} flops, {cost.get('bytes accessed', float('nan')):.3g} bytes per step" if flops else "")

    out = {"machine": describe(), "case": title,
           "disks": n, "precision": args.precision, "steps": args.steps,
           "kernel_us_per_step": total, "wall_us_per_step": wall, "kernels": len(per_kernel),
           "groups_us_per_step": dict(groups),
           "top_kernels": [{"name": k, "us_per_step": v, "op": names[k]} for k, v in per_kernel.most_common(args.top)],
           "xla_flops": flops, "xla_bytes_accessed": cost.get("bytes accessed") if cost else None}
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
