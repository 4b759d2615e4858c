"""The `jaxpile` command.

  jaxpile pile --protocol lattice --layers 45 --law hooke --out DIR [--set NAME=VALUE ...]
  jaxpile compare DIR [DIR ...]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np


def _parse_set(items, known) -> dict:
    from jaxpile.errors import InputError

    values = {}
    for item in items or []:
        if "=" not in item:
            raise InputError(f"--set takes NAME=VALUE; got {item!r}.")
        name, value = item.split("=", 1)
        name = name.strip()
        if name not in known:
            raise InputError(f"unknown parameter {name!r} in --set; known: {', '.join(known)}.")
        try:
            values[name] = float(value)
        except ValueError:
            raise InputError(f"--set {name}= needs a number; got {value!r}.") from None
    return values


def _on_off(text: str) -> bool:
    if text.lower() in ("on", "true", "yes", "1"):
        return True
    if text.lower() in ("off", "false", "no", "0"):
        return False
    raise argparse.ArgumentTypeError(f"expected on or off, got {text!r}")


def _parse_hard_collisions(text):
    from jaxpile.collisions import HardCollisions
    from jaxpile.errors import InputError

    if text is None:
        return None
    try:
        eps, mu = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--hard-collisions takes EPS,MU (e.g. 0.5,0.3); got {text!r}.") from None
    hard = HardCollisions(restitution=eps, mu=mu)
    hard.check()
    return hard


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxpile", description="Differentiable 2D granular piles in JAX.")
    sub = parser.add_subparsers(dest="command", required=True)

    pile = sub.add_parser("pile", help="build a pile, relax it, measure its base forces and draw it")
    pile.add_argument("--protocol", default="lattice", choices=["lattice"],
                      help="how the pile is built (lattice: the 1992 equilateral pile)")
    pile.add_argument("--layers", type=int, default=None, help="layers of the lattice pile (default 45: 1035 disks)")
    pile.add_argument("--law", default="hooke", help="contact law: hooke, liffman, lee-herrmann, baxter")
    pile.add_argument("--set", action="append", metavar="NAME=VALUE", help="override a law parameter (repeatable)")
    pile.add_argument("--rotation", type=_on_off, default=None, metavar="on|off",
                      help="integrate spins (lattice default: off, as the 1992 static analysis)")
    pile.add_argument("--dt", type=float, default=None, help="time step (default: the protocol's)")
    pile.add_argument("--integrator", default="velocity_verlet",
                      choices=["velocity_verlet", "leapfrog", "gear", "implicit_midpoint"],
                      help="time integrator (leapfrog: Baxter et al. 1997 eqs. 9-12; gear: fifth-order "
                           "predictor-corrector, Lee & Herrmann 1993; implicit_midpoint: Liffman et al. 1992 eq. 24)")
    pile.add_argument("--hard-collisions", metavar="EPS,MU", default=None,
                      help="fast approaches collide impulsively with restitution EPS and friction MU "
                           "(Liffman et al. 1992 eqs. 1-22); default off")
    pile.add_argument("--seed", type=int, default=0, help="random seed (the lattice pile is deterministic)")
    pile.add_argument("--max-steps", type=int, default=None, help="step budget for loading and relaxing")
    pile.add_argument("--ramp-steps", type=int, default=None, help="steps over which gravity is switched on")
    pile.add_argument("--speed-tol", type=float, default=None, help="max disk speed that counts as at rest")
    pile.add_argument("--precision", choices=["float64", "float32"], default="float64")
    pile.add_argument("--no-progress", action="store_true", help="no progress bar")
    pile.add_argument("--out", required=True, help="output folder")

    compare = sub.add_parser("compare", help="print the summaries of finished runs side by side")
    compare.add_argument("dirs", nargs="+")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from jaxpile.errors import InputError, SimulationError

    try:
        if args.command == "pile":
            run_pile(args)
        elif args.command == "compare":
            print(compare_table(args.dirs))
    except (InputError, SimulationError) as err:
        print(f"jaxpile: error: {err}", file=sys.stderr)
        return 2
    return 0


def run_pile(args) -> dict:
    import jax.numpy as jnp

    from jaxpile.errors import InputError

    import jaxpile  # noqa: F401  (turns on float64)
    from jaxpile import analysis, io, plot, theory
    from jaxpile.laws import get_law_module
    from jaxpile.protocols import lattice
    from jaxpile.simulate import Simulator, gravity_ramp

    setting = lattice.PAPER_SETTING
    lawmod = get_law_module(args.law)
    layers = setting["layers"] if args.layers is None else args.layers
    rotation = setting["rotation"] if args.rotation is None else args.rotation
    dt = setting["dt"] if args.dt is None else args.dt
    ramp = setting["ramp_steps"] if args.ramp_steps is None else args.ramp_steps
    tol = setting["speed_tolerance"] if args.speed_tol is None else args.speed_tol
    max_steps = setting["max_steps"] if args.max_steps is None else args.max_steps
    dtype = jnp.float64 if args.precision == "float64" else jnp.float32

    overrides = _parse_set(args.set, lawmod.PARAM_NAMES)
    values = {**setting["params"].get(lawmod.NAME, {}), **overrides}
    params = lawmod.make_params(dtype=dtype, **values)
    law = lawmod.law(rotation=rotation)
    particles, boundaries = lattice.equilateral_pile(layers, dtype=dtype)
    progress = None if not args.no_progress else False

    if layers < 1:
        raise InputError(f"--layers must be >= 1; got {layers}.")
    if max_steps < 1:
        raise InputError(f"--max-steps must be >= 1; got {max_steps}.")
    print(f"jaxpile: {args.protocol} pile, {layers} layers = {particles.count} disks, law {law.name} "
          f"(rotation {'on' if rotation else 'off'}), dt = {dt:g}, {args.precision}", flush=True)
    hard = _parse_hard_collisions(args.hard_collisions)
    if hard is not None:
        print(f"jaxpile: hard collisions on (restitution {hard.restitution:g}, mu {hard.mu:g}); "
              "contacts switch to the soft law by eq. 22", flush=True)
    sim = Simulator(law, dt, schedule=gravity_ramp(ramp), integrator=args.integrator, hard_collisions=hard)
    state = sim.init(params, particles, boundaries)
    t0 = time.perf_counter()
    state, info = lattice.relax(sim, params, state, ramp_steps=ramp, speed_tolerance=tol,
                                max_steps=max_steps, progress=progress)
    total = time.perf_counter() - t0

    base = analysis.base_forces(sim, params, state)
    network = analysis.contact_network(sim, params, state)
    check = lattice.compare_with_theory(base, layers)
    summary = {
        "protocol": args.protocol,
        "law": law.name,
        "rotation": rotation,
        "layers": layers,
        "n_particles": int(particles.count),
        "params": {k: float(v) for k, v in vars(params).items() if v is not None},
        "dt": dt,
        "integrator": args.integrator,
        "hard_collisions": None if hard is None else hard._asdict(),
        "precision": args.precision,
        "seed": args.seed,
        "steps": int(info.steps),
        "wall_seconds": info.wall_seconds,
        "compile_seconds": info.compile_seconds,
        "total_seconds": total,
        "particle_steps_per_second": info.particle_steps_per_second,
        "neighbor_reallocations": info.reallocations,
        "final_max_speed": info.max_speed,
        "at_rest": info.at_rest,
        "speed_tolerance": tol,
        "base_contacts": check["base_contacts"],
        "pile_intact": check["pile_intact"],
        "theory_normal_mg": check["theory_normal"],
        "max_rel_dev_normal": check["max_rel_dev_normal"],
        "max_rel_dev_horizontal": check["max_rel_dev_horizontal"],
        "ground_friction_needed": theory.lattice_ground_friction_needed(layers),
    }
    out = args.out
    os.makedirs(out, exist_ok=True)
    io.write_json(os.path.join(out, "summary.json"), summary)
    io.write_csv(os.path.join(out, "base_forces.csv"), {"x": base.x, "normal": base.normal, "horizontal": base.horizontal})
    io.save_state(os.path.join(out, "state.npz"), state, law=law.name, params=summary["params"], dt=dt,
                  rotation=rotation, precision=args.precision)
    mu = summary["params"].get("mu")
    title = f"{layers}-layer lattice pile, {law.name} law" + ("" if mu is None else f", mu = {mu:g}")
    plot.pile_figure(state.particles.position, state.particles.radius, network, title=title,
                     path=os.path.join(out, "pile.png"))
    h_theory = check["theory_horizontal"] if check["pile_intact"] else None
    n_theory = np.full(len(base.x), check["theory_normal"]) if check["pile_intact"] else None
    plot.base_profile_figure(base.x, base.normal, base.horizontal, theory_normal=n_theory, theory_horizontal=h_theory,
                             title=title + " vs Liffman et al. 1992 eqs. 42, 44",
                             path=os.path.join(out, "profile.png"))
    print(_summary_lines(summary), flush=True)
    print(f"jaxpile: wrote {out}/summary.json, base_forces.csv, state.npz, pile.png, profile.png")
    return summary


def _summary_lines(s: dict) -> str:
    return (
        f"  steps {s['steps']}, run {s['wall_seconds']:.1f} s, compile {s['compile_seconds']:.1f} s, "
        f"{s['particle_steps_per_second']:.3g} particle-steps/s, at rest: {s['at_rest']} "
        f"(max speed {s['final_max_speed']:.2e})\n"
        f"  ground contacts {s['base_contacts']} (pile intact: {s['pile_intact']}); "
        f"max |N - N_eq42| / N_eq42 = {s['max_rel_dev_normal']:.3%}, "
        f"max |H - H_eq44| / max|H| = {s['max_rel_dev_horizontal']:.3%}"
    )


def compare_table(dirs) -> str:
    from jaxpile.errors import InputError

    rows = []
    for d in dirs:
        path = os.path.join(d, "summary.json")
        if not os.path.isfile(path):
            raise InputError(f"{path} not found: give folders written by 'jaxpile pile --out DIR'.")
        with open(path) as f:
            s = json.load(f)
        rows.append((d, s))
    head = (f"{'run':32s} {'law':>12s} {'disks':>6s} {'mu':>5s} {'rot':>4s} {'steps':>8s} {'p-steps/s':>10s} "
            f"{'dev N':>8s} {'dev H':>8s}")
    lines = [head, "-" * len(head)]
    for d, s in rows:
        lines.append(
            f"{d:32s} {s['law']:>12s} {s['n_particles']:6d} "
            f"{('%5.2f' % s['params']['mu']) if 'mu' in s['params'] else '    -'} "
            f"{'on' if s['rotation'] else 'off':>4s} {s['steps']:8d} {s['particle_steps_per_second']:10.3g} "
            f"{s['max_rel_dev_normal']:8.2%} {s['max_rel_dev_horizontal']:8.2%}"
        )
    lines.append(
        "dev N, dev H: largest deviation of the ground forces from Liffman et al. 1992 eqs. 42 and 44.\n"
        "The analytic forces assume frictionless disks at rest; with disk-disk friction the base forces\n"
        "depend on how the pile was loaded (tangential springs lock in shear), so mu > 0 departs from them."
    )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
