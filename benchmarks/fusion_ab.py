"""XLA:CPU multi-output fusion on and off, side by side: what it does to a step,
a pour, a batch and a gradient.

By default XLA:CPU copies a producer into each fusion that consumes it; a
contact law's arithmetic feeds the force, its scatters and the new history, so
the law ran several times a step. With multi-output fusion on
(`--xla_backend_extra_options=xla_cpu_use_multi_output_fusion`, which `import
jaxpile` sets with JAXPILE_MULTI_OUTPUT_FUSION=1, and `jaxpile pile` and `sweep`
set themselves) one fusion computes it once and writes every output. The flag
is read once per process, so each configuration runs in a child process of its
own, the two alternated for `--rounds` rounds on the same machine; each figure
is the best of its rounds.

Cases (all float64, one XLA thread, as jaxpile runs a pile):
  lattice:  the 45-layer 1992 pile (1035 disks, hooke), us per step (1000-step loop, best of 5)
  box:      a 1993 box pile (lee-herrmann, 3 walls), us per step
  pour:     200 disks poured and settled (hooke, vs_lammps's pour): run seconds, compile excluded
  ensemble: 16 box piles x 100 disks in one vmapped call, particle-steps/s
  gradient: the 55-disk frictional pile, 1000 steps (gradient_cost.py): forward,
            checkpointed reverse and forward mode x3, seconds (best of 3 rounds)
With the fusion on, derivative programs take XLA's newer emitters instead of
the older ones jaxpile gives them without it (`engine.compile`): with the older
ones the fusion makes a reverse gradient ~20x slower. Off is jaxpile's Python
default; `jaxpile pile`, `sweep` and `fit` run on. Also checks
that the two configurations agree to round-off (the lattice's positions after
1000 steps, the gradient).

    python benchmarks/fusion_ab.py [--rounds 2] [--cases lattice,box,pour,ensemble,gradient] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

CASES = ("lattice", "box", "pour", "ensemble", "gradient")


def _loop_us(sim, params, state, steps: int = 1000, repeats: int = 5) -> tuple:
    """`(compile s, best us per step, end state)` of a jitted `steps`-step loop."""
    import jax
    from jax import lax

    run = jax.jit(lambda s: lax.fori_loop(0, steps, lambda i, s: sim.step(params, s), s))
    t0 = time.perf_counter()
    compiled = run.lower(state).compile()
    compile_s = time.perf_counter() - t0
    out = jax.block_until_ready(compiled(state))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(state))
        best = min(best, time.perf_counter() - t0)
    return compile_s, best / steps * 1e6, out


def child(cases: list[str]) -> dict:
    """One configuration's figures (run in a child process)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import jaxpile  # noqa: F401  (float64, and the fusion setting of this child)
    from jaxpile.laws import hooke
    from jaxpile.protocols import box, lattice
    from jaxpile.simulate import Simulator, gravity_ramp

    out = {"xla_flags": os.environ.get("XLA_FLAGS", "")}
    if "lattice" in cases:
        params = hooke.make_params(**lattice.PAPER_SETTING["params"]["hooke"])
        sim = Simulator(hooke.law(rotation=False), lattice.PAPER_SETTING["dt"], schedule=gravity_ramp(20_000))
        particles, boundaries = lattice.equilateral_pile(45)
        state = sim.init(params, particles, boundaries)
        state = sim.run(params, state, 2000, progress=False)
        c, us, end = _loop_us(sim, params, state)
        out["lattice"] = {"compile_s": c, "us_per_step": us, "disks": particles.count,
                          "positions": np.asarray(end.particles.position).tolist()}
    if "box" in cases:
        protocol = box.protocol(400, law="lee-herrmann", seed=0)
        _, _, params = box.law_and_params("lee-herrmann", {})
        sim = box.make_simulator("lee-herrmann")
        state = sim.init(params, protocol.particles, protocol.boundaries, box=protocol.box,
                          protocol_state=protocol.protocol_state)
        state = sim.run(params, state, 2000, progress=False)
        c, us, _ = _loop_us(sim, params, state)
        out["box"] = {"compile_s": c, "us_per_step": us, "disks": protocol.particles.count}
    if "pour" in cases:
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        import vs_lammps

        protocol = vs_lammps.pour_setup(200, 0.15, 0)
        info = vs_lammps.jax_pour("hooke", protocol, 2000, None, vs_lammps.POUR_CHUNK)[-1]
        out["pour"] = {"run_s": info.wall_seconds, "compile_s": info.compile_seconds, "disks": 200}
    if "ensemble" in cases:
        from jaxpile import ensemble

        members, n, steps = 16, 100, 1000
        width = (n / 409) ** 0.5 * 4.0
        protocols = [box.protocol(n, law="lee-herrmann", width=width, height=width, seed=s) for s in range(members)]
        params = [box.law_and_params("lee-herrmann", {"mu": 0.1 + 0.05 * (s % 5)})[2] for s in range(members)]
        ens = ensemble.Ensemble(box.make_simulator("lee-herrmann", chunk_steps=steps))
        state = ens.init(params, protocols)
        pb = ens._as_batch(params, members)
        advance = jax.jit(ens._advance)
        args = (pb, state, jnp.zeros(members, bool), jnp.int32(steps))
        t0 = time.perf_counter()
        compiled = advance.lower(*args).compile()
        c = time.perf_counter() - t0
        jax.block_until_ready(compiled(*args))
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(*args))
            best = min(best, time.perf_counter() - t0)
        out["ensemble"] = {"compile_s": c, "particle_steps_per_s": members * n * steps / best,
                           "members": members, "disks": n}
    if "gradient" in cases:
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        import gradient_cost as gc
        from jaxpile import fit

        sim, params, state = gc.setup(10, 0)
        steps = 1000
        values = {k: getattr(params, k) for k in gc.NAMES}
        forward = jax.jit(gc.loss_fn(sim, state, steps, False))
        ckpt = fit.value_and_gradient(lambda v: gc.loss_fn(sim, state, steps, True)(params.set(**v)), values,
                                      "reverse")
        jvp = fit.value_and_gradient(lambda v: gc.loss_fn(sim, state, steps, False)(params.set(**v)), values,
                                     "forward")
        row = gc.side_by_side({"forward": (forward, (params,)), "grad_checkpoint": (ckpt, (values,)),
                               "grad_forward_mode": (jvp, (values,))}, rounds=3)
        _, grad = ckpt(values)
        row["gradient"] = {k: float(v) for k, v in grad.items()}
        out["gradient"] = row
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--out", default=None)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    cases = [c for c in args.cases.split(",") if c]
    unknown = set(cases) - set(CASES)
    if unknown:
        parser.error(f"unknown case(s) {sorted(unknown)}; known: {', '.join(CASES)}")
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    if args.child:
        print(json.dumps(child(cases)))
        return {}

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from machine import describe

    runs = {"off": [], "on": []}
    for r in range(args.rounds):
        for name, flag in (("off", "0"), ("on", "1")):
            env = {**os.environ, "JAXPILE_MULTI_OUTPUT_FUSION": flag}
            done = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", "--cases", ",".join(cases)],
                                  capture_output=True, text=True, env=env)
            if done.returncode != 0:
                raise SystemExit(f"the {name} child failed:\n{done.stderr[-3000:]}")
            runs[name].append(json.loads(done.stdout.strip().splitlines()[-1]))
            print(f"round {r + 1}, multi-output fusion {name}: done", flush=True)

    def best(name, case, key, larger=False):
        values = [run[case][key] for run in runs[name]]
        return max(values) if larger else min(values)

    summary = {"machine": describe(), "rounds": args.rounds,
               "command": " ".join(["python benchmarks/fusion_ab.py", *(sys.argv[1:] if argv is None else argv)])}
    lines = []
    for case, key, larger, unit in (("lattice", "us_per_step", False, "us/step"),
                                    ("lattice", "compile_s", False, "s compile"),
                                    ("box", "us_per_step", False, "us/step"),
                                    ("box", "compile_s", False, "s compile"),
                                    ("pour", "run_s", False, "s run"),
                                    ("pour", "compile_s", False, "s compile"),
                                    ("ensemble", "particle_steps_per_s", True, "particle-steps/s"),
                                    ("ensemble", "compile_s", False, "s compile"),
                                    ("gradient", "forward_s", False, "s forward"),
                                    ("gradient", "grad_checkpoint_s", False, "s reverse (checkpointed)"),
                                    ("gradient", "grad_forward_mode_s", False, "s forward mode x3"),
                                    ("gradient", "grad_checkpoint_ratio", False, "x forward (reverse)"),
                                    ("gradient", "grad_forward_mode_ratio", False, "x forward (forward mode)")):
        if case not in cases:
            continue
        off, on = best("off", case, key, larger), best("on", case, key, larger)
        summary[f"{case}_{key}"] = {"off": off, "on": on, "all_off": [r[case][key] for r in runs["off"]],
                                    "all_on": [r[case][key] for r in runs["on"]]}
        lines.append(f"  {case:9s} {unit:28s} off {off:10.4g}   on {on:10.4g}   on/off {on / off:6.3f}")
    if "lattice" in cases:
        import numpy as np

        a = np.asarray(runs["off"][0]["lattice"]["positions"])
        b = np.asarray(runs["on"][0]["lattice"]["positions"])
        summary["lattice_max_position_difference"] = float(np.max(np.abs(a - b)))
        lines.append(f"  lattice positions after 1000 steps: max |off - on| = {summary['lattice_max_position_difference']:.2e} sigma")
    if "gradient" in cases:
        g_off, g_on = runs["off"][0]["gradient"]["gradient"], runs["on"][0]["gradient"]["gradient"]
        summary["gradient_relative_difference"] = {k: abs(g_on[k] - g_off[k]) / max(abs(g_off[k]), 1e-300)
                                                   for k in g_off}
        lines.append("  reverse gradient d/d(" + ", ".join(g_off) + "): relative |off - on| "
                     + ", ".join(f"{v:.1e}" for v in summary["gradient_relative_difference"].values()))
    print(f"multi-output fusion off/on, best of {args.rounds} alternated rounds ({summary['machine']}):")
    print("\n".join(lines))
    if args.out:
        from jaxpile import io

        io.write_json(args.out, summary)
    return summary


if __name__ == "__main__":
    main()
