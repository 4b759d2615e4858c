"""What `jaxpile pile` writes: summary.json, base_forces.csv, contacts.csv,
state.npz, final.xyz, the trajectory it records while running, pile.png and
profile.png, and the protocol's own figures; and the headline it prints (which
`jaxpile compare` prints too)."""

from __future__ import annotations

import os

import numpy as np

from jaxpile import config
from jaxpile.errors import InputError
from jaxpile.io import plain
from jaxpile.cli.parsing import hard_collisions_of
from jaxpile.cli.presentation import presentation


def trajectory(args, resumed_from: int):
    """The context that records OUT/trajectory.xyz with --trajectory-every (a
    resumed run drops the frames written after its checkpoint and goes on)."""
    import contextlib

    from jaxpile import export

    if args.trajectory_every is None:
        return contextlib.nullcontext()
    if args.trajectory_every < 1:
        raise InputError(f"--trajectory-every must be >= 1 step; got {args.trajectory_every}.")
    os.makedirs(args.out, exist_ok=True)
    return export.trajectory(os.path.join(args.out, _trajectory_name(args)), args.trajectory_every,
                             resume_step=resumed_from if args.resume is not None else None)


def _trajectory_name(args) -> str:
    return "trajectory.lammpstrj" if args.trajectory_format == "lammps" else "trajectory.xyz"


def write_outputs(args, spec, state, m, contact_law, params, options: dict, total: float,
                  resumed_from: int) -> dict:
    """Measures the finished pile (base forces, contact network), writes every
    file of the run to OUT, prints its headline, and returns its summary."""
    from jaxpile import export, io
    from jaxpile.engine.simulate import Simulator
    from jaxpile.laws import granular
    from jaxpile.measure import analysis

    name = args.protocol
    dt = args.dt if args.dt is not None else _protocol_dt(spec, m, contact_law.name)
    sim = Simulator(contact_law, dt)
    registered = presentation(spec.name)
    base = (analysis.base_forces(sim, params, state) if registered.base_forces is None
            else registered.base_forces(sim, params, state, m))  # e.g. the fixed row a heap stands on
    network = analysis.contact_network(sim, params, state)
    active = np.asarray(state.particles.active)
    hard = hard_collisions_of(getattr(args, "hard_collisions", None))
    steps, wall = int(m.get("steps_run", 0)), float(m.get("wall_seconds", 0.0))  # this call's steps and time
    summary = {
        "protocol": name,
        "law": contact_law.name,
        "rotation": bool(contact_law.rotation),
        "law_options": dict(contact_law.options),  # its readings beyond rotation (rolling, lever arm, ...)
        "params": {k: float(v) for k, v in vars(params).items() if v is not None},
        "dt": dt,
        "integrator": args.integrator,
        "hard_collisions": None if hard is None else hard._asdict(),  # --hard-collisions EPS,MU
        "precision": args.precision,
        "settings": config.settings(),  # float64 and XLA's, which decide the numbers at round-off (jaxpile.config)
        "seed": args.seed,
        "options": options,
        "n_particles": int(active.sum()),
        "particle_steps_per_second": steps * int(active.sum()) / wall if wall > 0 else None,
        "cli_total_seconds": total,
        "resumed_from_step": resumed_from,
        # a protocol may give its own plain-number summary (pour: the rest are maps and arrays)
        **(plain(m) if registered.summary is None else registered.summary(m)),
    }
    summary["protocol"], summary["law"] = name, contact_law.name
    line = granular.line_at(contact_law.name, summary["params"])
    if line is not None:  # the line at the values run, to take back to LAMMPS
        summary["lammps_pair_coeff"] = line
    out = args.out
    os.makedirs(out, exist_ok=True)
    io.write_json(os.path.join(out, "summary.json"), summary)
    io.write_csv(os.path.join(out, "base_forces.csv"),
                 {"x": np.asarray(base.x), "normal": np.asarray(base.normal), "horizontal": np.asarray(base.horizontal)})
    io.save_state(os.path.join(out, "state.npz"), state, law=contact_law.name, params=summary["params"], dt=dt,
                  rotation=summary["rotation"], precision=args.precision, protocol=name)
    export.write_contacts(os.path.join(out, "contacts.csv"), sim, params, state)
    export.write_xyz(os.path.join(out, "final.xyz"), state, time=int(state.step) * dt)
    written = ["summary.json", "base_forces.csv", "contacts.csv", "state.npz", "final.xyz"]
    written += [_trajectory_name(args)] if args.trajectory_every else []
    written += _protocol_figures(name, m, state, base, network, contact_law.name, out)
    print(headline(name, summary), flush=True)
    print(f"jaxpile: wrote {out}/" + ", ".join(written))
    return summary


def _protocol_dt(spec, m, law_name: str) -> float:
    """The time step the protocol ran with: its measurements' `info`, else its default for the law."""
    info = m.get("info") or {}
    return float(info["dt"]) if "dt" in info else float(spec.default_dt(law_name))


def headline(name: str, summary: dict) -> str:
    """The protocol's headline numbers from a run's summary (its registry entry's
    `headline` keys; dotted keys reach into nested dicts) and the run's rate."""
    parts = []
    for key in presentation(name).headline:
        v = summary
        for part in key.split("."):
            v = v.get(part) if isinstance(v, dict) else None
        if v is not None:
            parts.append(f"{key} = {v:.4g}" if isinstance(v, float) else f"{key} = {v}")
    rate = summary.get("particle_steps_per_second")
    timing = f"{rate:.3g} particle-steps/s" if rate else ""
    # why a measurement is NaN (the surface could not be read: `repose_error`), where summary.json says it
    reasons = [f"  {key}: {value}" for key, value in summary.items() if key.endswith("_error") and value]
    return "\n".join(["  " + ", ".join(parts), *reasons] + ([f"  {timing}"] if timing else []))


def _protocol_figures(name, m, state, base, network, law_name, out) -> list:
    """pile.png and profile.png for every protocol, and the protocol's own
    figures (its registry entry's `figures`, `profile_theory`, `length_unit`)."""
    from jaxpile import plot

    registered = presentation(name)
    p = state.particles
    title = f"{name} pile, {law_name} law, {int(np.asarray(p.active).sum())} {'spheres' if p.dim == 3 else 'disks'}"
    plot.pile_figure(p.position, p.radius, network, active=np.asarray(p.active), title=title,
                     length_unit="diameters" if registered.length_unit is None else registered.length_unit(law_name),
                     path=os.path.join(out, "pile.png"))
    theory_lines = None if registered.profile_theory is None else registered.profile_theory(m, base)
    th_n, th_h, label = theory_lines or (None, None, None)
    plot.base_profile_figure(base.x, base.normal, base.horizontal, theory_normal=th_n, theory_horizontal=th_h,
                             title=title + (f" vs {label}" if label else ""), path=os.path.join(out, "profile.png"))
    written = ["pile.png", "profile.png"]
    for figure in registered.figures:
        written += figure(m, title, out)
    return written
