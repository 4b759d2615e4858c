"""jaxpile against LAMMPS on identical problems: do they agree, and how many
particle-steps per second does each manage?

Both codes run the `hooke` law, which is LAMMPS's `gran/hooke/history` (pair
and `fix wall/gran`), with velocity Verlet (`fix nve/sphere disc`, or plain
`fix nve` with rotation off) in float64; `benchmarks/lammps_peer.py` writes the
LAMMPS inputs. Three cases (`--cases`, default all):

1. `lattice`: the 1992 equilateral pile (45 layers, 1035 disks; hooke with
   `lattice.PAPER_SETTING`: kn = 1e4, gamma_n = 100, mu = 0, ground mu = 1,
   rotation off, dt = 1e-3), gravity ramped in over R steps (`gravity_ramp`;
   in LAMMPS a smoothstep of min(step / R, 1), in the same `run` as the hold)
   and held for H more (default 20000 + 20000). jaxpile against LAMMPS serial
   and `mpirun -np 2`. Agreement: per bottom disk (matched by x), |N_jax -
   N_lmp| / max N and |H_jax - H_lmp| / max |H| must both stay under 1%. The
   loaded pile amplifies round-off (measured: about x70 per 1000 steps at full
   load), so a round-off control runs too: jaxpile against itself with one
   disk moved by 1e-12 sigma. Its deviations are the floor of any comparison
   (measured: 5000 + 5000 steps ~3% in N and ~5% in H, 20000 + 20000 ~0.4%), and
   `within_round_off_spread` says whether LAMMPS stays within twice it. The
   loaded pile ends in one of at least two static piles ~5% apart in base N,
   and round-off picks which (see `OUTCOME_NUDGES`): two more nudged runs map
   them, and `agree_with_an_outcome` says whether LAMMPS is within 1% of one
   of the piles jaxpile ends in. The
   positions at the ramp's end, before the growth, are compared as well.
2. `pour`: the 1997 poured heap (`protocols.pour`, ~1000 disks onto a row of
   fixed disks), hooke with the pour's own parameters (kn = 500, rotation on)
   and velocity Verlet (the protocol's default is leapfrog; LAMMPS has Verlet).
   The disks appear at their release height moving at the free-fall speed from
   100 sigma (`insert_height`, the protocol's exact shortcut) one every
   `--pour-interval` time units, then the heap settles for `--pour-settle`
   steps. LAMMPS replays the protocol: each disk is created with `create_atoms`
   at the same step, position and velocity (a `run` segment per disk). Two
   things keep the replay from being exact: every `run` re-evaluates the forces
   at its set-up with the full-step velocities (a step of velocity Verlet uses
   the half-step ones), and fast impacts turn round-off into O(v dt) changes
   wherever a contact's first step is a near thing. (Checked by hand: jaxpile
   re-evaluating its forces at each release as LAMMPS does matches LAMMPS to
   1e-16 over the first 7 disks; the 8th interval already differs by 7e-5.)
   A pour is chaotic after that, so the check is statistical: the disks on
   the row, the heap's centroid height and its rms width must agree within 10%
   (the apex height and the width in columns, which move a disk at a time, are
   reported beside them). The segments are run with `pre yes` (LAMMPS asks
   for a set-up after atoms were added) and again with `pre no`; what the
   segments cost beyond their loop time and the process start-up is reported.
   jaxpile also pours the same heap with each paper's own law
   (liffman, lee-herrmann, baxter; the protocol's leapfrog integrator), jaxpile
   alone. The work counted for both codes is (substrate + poured disks) x
   steps: LAMMPS carries only the disks created so far (its step-weighted mean
   count is reported), jaxpile runs each chunk of 2000 steps on the smallest
   power-of-two block of leading disks holding those poured by its end
   (`jaxpile.engine.blocks`; parked disks past it cost nothing).
3. `ensemble`: B = 1, 8, 64, 256 lattice piles of 15 layers (120 disks) in one
   vmapped jaxpile call (`Ensemble`), members differing in ground friction
   (wall_mu from 1.0 down to 0.6) and ground tangential stiffness (wall_kt from
   kt down to kt / 2), against B LAMMPS runs one after the other. LAMMPS runs
   min(B, 8) members spread over the batch for real; its time for B members is
   the measured mean per member times B (extrapolated), from the loop times
   and, separately, from whole processes (start-up included). LAMMPS with two
   processes at once (two members concurrently: what 2 cores do with
   independent members) is timed too. One member's base forces are checked
   against its LAMMPS run (1%).

jaxpile's times exclude compilation (`RunInfo.compile_seconds`, reported
apart). LAMMPS's are the summed "Loop time" lines of its log, with the whole
process wall time beside them. Without a LAMMPS binary (`lmp` on the PATH, or
$LAMMPS_BIN) jaxpile is reported alone and the LAMMPS fields are null.

    python benchmarks/vs_lammps.py [--small] [--cases lattice,pour,ensemble] [--layers 45]
        [--ramp 20000] [--hold 20000] [--pour-n 1000] [--pour-settle 30000]
        [--members 1,8,64,256] [--ensemble-steps 5000,5000] [--out FILE]
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import numpy as np

import jaxpile
from jaxpile import analysis, io
from jaxpile.engine import ensemble
from jaxpile.engine import RunInfo, Simulator, gravity_ramp
from jaxpile.laws import hooke
from jaxpile.protocols import lattice, pour
from jaxpile.protocols import Setup
from jaxpile.measure import heap

try:
    from benchmarks import lammps_peer as peer
    from benchmarks.machine import describe, details
except ImportError:  # run as a script: benchmarks/ is on sys.path
    import lammps_peer as peer
    from machine import describe, details

# as the commands run: float64 and XLA's settings, multi-output fusion included
# (jaxpile.config), unless JAXPILE_MULTI_OUTPUT_FUSION=0
jaxpile.configure()

FULL = {"ramp": 20_000, "hold": 20_000, "pour_n": 1000, "pour_settle": 30_000, "ensemble_steps": "5000,5000"}
SMALL = {"ramp": 20_000, "hold": 20_000, "pour_n": 200, "pour_settle": 20_000, "ensemble_steps": "1000,1000"}
DT = lattice.PAPER_SETTING["dt"]
OTHER_POUR_LAWS = ("liffman", "lee-herrmann", "baxter")


def rate(work: float, seconds: float | None) -> float | None:
    return work / seconds if seconds else None


def ratio(a: float | None, b: float | None) -> float | None:
    return a / b if a and b else None


def lammps_fields(run: peer.Run, work: float) -> dict:
    """A LAMMPS run's timings and rates (null rates when it failed)."""
    ok = run.ok
    return {"ok": ok, "error": run.error, "procs": run.procs, "steps": run.steps, "runs": run.runs,
            "loop_seconds": run.loop_seconds if ok else None, "process_seconds": run.wall_seconds,
            "particle_steps_per_s": rate(work, run.loop_seconds) if ok else None,
            "particle_steps_per_s_process": rate(work, run.wall_seconds) if ok else None}


# ------------------------------------------------------------------ lattice
def lattice_params(wall_mu: float = None, wall_kt: float = None):
    values = dict(lattice.PAPER_SETTING["params"]["hooke"])
    if wall_mu is not None:
        values["wall_mu"] = wall_mu
    if wall_kt is not None:
        values["wall_kt"] = wall_kt
    return hooke.make_params(**values)


def lattice_box(particles):
    pos = np.asarray(particles.position)
    return (pos[:, 0].min() - 5.0, pos[:, 0].max() + 5.0), (-1.0, pos[:, 1].max() + 5.0)


def lattice_job(workdir: str, particles, boundaries, params, ramp: int, hold: int) -> tuple[str, str]:
    """(script, workdir) of the LAMMPS twin of a ramped lattice pile; writes its data file."""
    os.makedirs(workdir, exist_ok=True)
    peer.write_data(os.path.join(workdir, "pile.data"), particles.position, 2.0 * np.asarray(particles.radius),
                    lattice_box(particles))
    script = peer.ramp_pile_script("pile.data", params=params, boundaries=boundaries, mass=particles.mass, dt=DT,
                                   ramp_steps=ramp, hold_steps=hold, rotation=False, dump_file="final.dump")
    return script, workdir


def base_deviation(base, x, normal, horizontal) -> dict:
    """Largest per-disk differences of two sets of ground forces (sorted by x):
    |dN| / max N and |dH| / max |H|."""
    out = {"contacts": [int(len(base.x)), int(len(x))]}
    if len(x) != len(base.x):
        return out
    return {**out, "max_dx": float(np.max(np.abs(base.x - x))),
            "max_rel_dev_normal": float(np.max(np.abs(base.normal - normal)) / np.max(np.abs(normal))),
            "max_rel_dev_horizontal": float(np.max(np.abs(base.horizontal - horizontal)) / np.max(np.abs(horizontal)))}


def agreement(base, run: peer.Run, ramp=None, tol: float = 0.01) -> dict:
    """jaxpile's ground forces against a LAMMPS dump, disk by disk (sorted by x);
    with `ramp` = (step, positions, velocities) of jaxpile at the ramp's end, also
    the largest position and velocity differences there."""
    if not run.ok:
        return {"agree": None, "error": run.error}
    dump = peer.read_dump(os.path.join(run.workdir, "final.dump"))
    out = base_deviation(base, *peer.ground_forces(dump))
    out["agree"] = bool(out.get("max_rel_dev_normal", np.inf) < tol and out.get("max_rel_dev_horizontal", np.inf) < tol)
    if ramp is not None:
        step, position, velocity = ramp
        mid = peer.read_dump(os.path.join(run.workdir, "ramp.dump"), timestep=step)
        out["ramp_end_max_position_diff"] = float(np.max(np.abs(position - np.stack([mid["x"], mid["y"]], 1))))
        out["ramp_end_max_velocity_diff"] = float(np.max(np.abs(velocity - np.stack([mid["vx"], mid["vy"]], 1))))
    return out


def nudged_control(sim, params, particles, boundaries, ramp: int, hold: int, base, nudge: float = 1e-12,
                   disk: int | None = None) -> tuple[dict, analysis.BaseForces]:
    """The same jaxpile run with one disk (default: the middle one) moved by
    `nudge` sigma: how far the pile's own sensitivity to round-off carries two
    runs apart (no code can agree with another better than this). Returns the
    deviations and the nudged run's base forces."""
    middle = particles.count // 2 if disk is None else int(disk)
    moved = particles.set(position=particles.position.at[middle, 0].add(nudge))
    state = sim.init(params, moved, boundaries)
    state = sim.run(params, sim.run(params, state, ramp, progress=False), hold, progress=False)
    other = analysis.base_forces(sim, params, state)
    return {"nudge": nudge, "disk": middle, **base_deviation(other, base.x, base.normal, base.horizontal)}, other


OUTCOME_NUDGES = (0.1, 0.9)
"""Extra nudged runs (disks at these fractions of the pile's ids) that map the
outcomes round-off can select. The 45-layer pile ends in one of (at least) two
static piles whose base forces differ by ~5%: measured, 1e-12 nudges of
five disks put 2 of 5 runs in the second, for the half-list step and the old
full-list step alike. Which one a run lands in is a coin toss of round-off, so
LAMMPS is held to the nearest outcome jaxpile reaches (`agree_with_an_outcome`)."""


def lattice_case(args, binary, root) -> tuple[dict, list]:
    layers, ramp, hold = args.layers, args.ramp, args.hold
    particles, boundaries = lattice.equilateral_pile(layers)
    n = particles.count
    params = lattice_params()
    sim = Simulator(hooke.law(rotation=False), DT, schedule=gravity_ramp(ramp), chunk_steps=max(ramp, hold))
    state = sim.init(params, particles, boundaries)
    info = RunInfo()
    state = sim.run(params, state, ramp, progress=False, info=info)
    ramp_end = (ramp, np.asarray(state.particles.position), np.asarray(state.particles.velocity))
    state = sim.run(params, state, hold, progress=False, info=info)
    base = analysis.base_forces(sim, params, state)
    control, nudged = nudged_control(sim, params, particles, boundaries, ramp, hold, base)
    outcomes = [base, nudged] + [nudged_control(sim, params, particles, boundaries, ramp, hold, base,
                                                disk=int(f * n))[1] for f in OUTCOME_NUDGES]
    work = float(n) * (ramp + hold)
    jax_rate = work / info.wall_seconds
    out = {"disks": n, "layers": layers, "ramp_steps": ramp, "hold_steps": hold, "dt": DT,
           "params": {k: float(v) for k, v in vars(params).items() if v is not None},
           "jaxpile": {"run_seconds": info.wall_seconds, "compile_seconds": info.compile_seconds,
                       "reallocations": info.reallocations, "particle_steps_per_s": jax_rate,
                       "mean_base_normal": float(np.mean(base.normal))},
           "round_off_control": control, "lammps_serial": None, "lammps_np2": None}
    print(f"lattice: {layers} layers = {n} disks, {ramp} + {hold} steps")
    print(f"  jaxpile        {jax_rate:.3g} particle-steps/s ({info.wall_seconds:.2f} s run, "
          f"{info.compile_seconds:.2f} s compile); mean N {np.mean(base.normal):.3g} mg")
    print(f"  round-off control: jaxpile against itself with disk {control['disk']} moved 1e-12 sigma: "
          f"dN {control.get('max_rel_dev_normal', float('nan')):.2e}, "
          f"dH {control.get('max_rel_dev_horizontal', float('nan')):.2e}")
    title = f"lattice {layers} layers ({n} disks), {ramp}+{hold} steps"
    rows = []
    if binary is None:
        rows.append({"case": title, "jaxpile": jax_rate, "lammps": None, "ratio": None, "note": "no LAMMPS binary"})
        return out, rows
    launcher, launch_note = peer.mpi_launcher(binary, 2, os.path.join(root, "mpi_probe"))
    for key, procs in (("lammps_serial", 1), ("lammps_np2", 2)):
        if procs > 1 and launcher is None:
            out[key] = {"ok": False, "error": launch_note}
            rows.append({"case": f"{title}, LAMMPS np=2", "jaxpile": jax_rate, "lammps": None, "ratio": None,
                         "note": launch_note})
            print(f"  LAMMPS np=2    skipped: {launch_note}")
            continue
        script, workdir = lattice_job(os.path.join(root, f"lattice_np{procs}"), particles, boundaries, params,
                                      ramp, hold)
        run = peer.run(binary, script, workdir, launcher if procs > 1 else None)
        fields = lammps_fields(run, work)
        a = agreement(base, run, ramp_end)
        if run.ok:
            nearest = [agreement(o, run) for o in outcomes]
            a["nearest_outcome_max_rel_dev"] = min(max(d.get("max_rel_dev_normal", np.inf),
                                                       d.get("max_rel_dev_horizontal", np.inf)) for d in nearest)
            a["agree_with_an_outcome"] = bool(any(d["agree"] for d in nearest))
        if "max_rel_dev_normal" in a and "max_rel_dev_normal" in control:
            # the pile amplifies round-off (see round_off_control): no closer than that can be asked
            a["within_round_off_spread"] = bool(
                a["max_rel_dev_normal"] <= 2.0 * max(control["max_rel_dev_normal"], 1e-9)
                and a["max_rel_dev_horizontal"] <= 2.0 * max(control["max_rel_dev_horizontal"], 1e-9))
        fields.update(agreement=a, version=run.version)
        if procs > 1:
            fields["launcher"] = launch_note
        out[key] = fields
        lmp = fields["particle_steps_per_s"]
        label = "serial" if procs == 1 else "np=2"
        if run.ok:
            print(f"  LAMMPS {label:7s} {lmp:.3g} particle-steps/s ({run.loop_seconds:.2f} s loop, "
                  f"{run.wall_seconds:.2f} s process); jaxpile / LAMMPS = {jax_rate / lmp:.3g}; base forces: "
                  f"dN {a.get('max_rel_dev_normal', float('nan')):.2e}, "
                  f"dH {a.get('max_rel_dev_horizontal', float('nan')):.2e}"
                  f" -> agree {a['agree']} (within twice the round-off spread: {a.get('within_round_off_spread')}; "
                  f"within 1% of one of jaxpile's {len(outcomes)} round-off outcomes: {a.get('agree_with_an_outcome')}); "
                  f"positions at the ramp's end within {a['ramp_end_max_position_diff']:.1e}")
        else:
            print(f"  LAMMPS {label} failed: {run.error}")
        rows.append({"case": f"{title}, LAMMPS {'serial' if procs == 1 else 'mpirun -np 2'}", "jaxpile": jax_rate,
                     "lammps": lmp, "ratio": ratio(jax_rate, lmp),
                     "note": f"LAMMPS loop time; base forces within 1%: {a['agree']}, of one of jaxpile's "
                             f"round-off outcomes: {a.get('agree_with_an_outcome')} (dN "
                             f"{a.get('max_rel_dev_normal', float('nan')):.1e}; jaxpile vs itself nudged 1e-12: "
                             f"{control.get('max_rel_dev_normal', float('nan')):.1e})"})
    return out, rows


# --------------------------------------------------------------------- pour
def heap_stats(x, y, vx, vy, *, x0: float, spacing: float, rows: int, base_y: float) -> dict:
    """Numbers of a poured heap that both codes can be held to.

    `on_row`: disks on the substrate (not fallen off); the heap is the contiguous
    run of occupied columns (one substrate spacing wide) around the highest one,
    with its `height` (apex centre above the row's centre line) and `width`.
    These move in steps of a disk, so the comparison uses two averages over the
    heap's disks as well: `centroid_height` (mean centre height above the row)
    and `rms_width` (standard deviation of x). `moving`: disks faster than 0.01."""
    x, y = np.asarray(x), np.asarray(y)
    speed = np.hypot(vx, vy)
    column = np.clip(np.round((x - x0) / spacing).astype(int), 0, rows - 1)
    top = np.full(rows, -np.inf)
    np.maximum.at(top, column, y)
    filled = np.isfinite(top)
    lo = hi = int(np.argmax(top))
    while lo > 0 and filled[lo - 1]:
        lo -= 1
    while hi < rows - 1 and filled[hi + 1]:
        hi += 1
    heap = (column >= lo) & (column <= hi)
    return {"on_row": int(len(x)), "strays": int((~heap).sum()), "height": float(top[lo:hi + 1].max() - base_y),
            "width": float((hi - lo + 1) * spacing), "centroid_height": float(np.mean(y[heap] - base_y)),
            "rms_width": float(np.std(x[heap])), "moving": int((speed > 1e-2).sum()),
            "max_speed": float(speed.max()) if len(x) else 0.0}


HEAP_CHECKS = ("on_row", "centroid_height", "rms_width")  # held to 10%; height and width reported


def heap_text(h: dict) -> str:
    return (f"{h['on_row']} on the row, centroid height {h['centroid_height']:.2f}, rms width {h['rms_width']:.2f}, "
            f"apex height {h['height']:.2f}, width {h['width']:.1f}, {h['moving']} moving")


POUR_CHUNK = 2000
"""Steps per chunk of the pour (the protocol's own default): each chunk runs on
the disks poured by its end (`jaxpile.engine.blocks`), so shorter chunks follow the
growing heap more closely; the host's work between chunks is timed with them."""


def pour_setup(n: int, interval: float, seed: int):
    # disks appear just above the steepest heap at the speed of a fall from 100 sigma
    return pour.SPEC.set_up(None, n, insert_height=heap.steepest_heap_height(n) + 4.0, interval=interval, dt=DT,
                            seed=seed)


def jax_pour(law: str, protocol, settle: int, integrator: str | None, chunk: int):
    _, contact_law, params = pour.law_and_params(law)
    kwargs = {} if integrator is None else {"integrator": integrator}
    sim = pour.make_simulator(law, dt=DT, chunk_steps=chunk, **kwargs)
    state = sim.init(params, protocol.particles, protocol.boundaries, box=protocol.box,
                     protocol_state=protocol.protocol_state)
    info = RunInfo()
    state = sim.run(params, state, protocol.info["pour_steps"], progress=False, info=info)
    state = sim.run(params, state, settle, progress=False, info=info)
    return sim, contact_law, params, state, info


def pour_case(args, binary, root) -> tuple[dict, list]:
    n, settle = args.pour_n, args.pour_settle
    protocol = pour_setup(n, args.pour_interval, args.seed)
    info_p = protocol.info
    ps = protocol.protocol_state
    rows_sub = int(ps.first)
    total = rows_sub + n
    steps = info_p["pour_steps"] + settle
    work = float(total) * steps
    geometry = dict(x0=0.0, spacing=info_p["spacing"], rows=rows_sub, base_y=info_p["base_y"])
    chunk = POUR_CHUNK
    out = {"poured": n, "substrate_disks": rows_sub, "disks": total, "steps": steps,
           "pour_steps": info_p["pour_steps"], "settle_steps": settle, "interval_steps": info_p["interval_steps"],
           "insert_height": info_p["insert_height"], "insert_speed": info_p["insert_speed"], "dt": DT,
           "work_particle_steps": work, "replica": "exact set-up (same disks, steps, positions, velocities, law, dt); "
           "trajectories diverge (run set-ups re-evaluate forces, chaotic impacts), so agreement is statistical"}
    print(f"pour: {n} disks onto {rows_sub} fixed disks, one every {info_p['interval_steps']} steps, "
          f"{info_p['pour_steps']} + {settle} steps; work counted as {total} disks x {steps} steps")

    sim, contact_law, params, state, info = jax_pour("hooke", protocol, settle, "velocity_verlet", chunk)
    p = state.particles
    movable = np.asarray(p.movable)
    pos, vel = np.asarray(p.position)[movable], np.asarray(p.velocity)[movable]
    jax_stats = heap_stats(pos[:, 0], pos[:, 1], vel[:, 0], vel[:, 1], **geometry)
    jax_rate = work / info.wall_seconds
    out["jaxpile"] = {"law": "hooke", "integrator": "velocity_verlet", "rotation": contact_law.rotation,
                      "params": {k: float(v) for k, v in vars(params).items() if v is not None},
                      "run_seconds": info.wall_seconds, "compile_seconds": info.compile_seconds,
                      "reallocations": info.reallocations, "particle_steps_per_s": jax_rate, "heap": jax_stats}
    print(f"  jaxpile hooke  {jax_rate:.3g} particle-steps/s ({info.wall_seconds:.2f} s run, "
          f"{info.compile_seconds:.2f} s compile)\n    heap: {heap_text(jax_stats)}")
    title = f"pour {n} disks, hooke, {steps} steps"
    rows = []
    out["lammps"] = None
    if binary is None:
        rows.append({"case": title, "jaxpile": jax_rate, "lammps": None, "ratio": None, "note": "no LAMMPS binary"})
    else:
        startup = peer.startup_seconds(binary, os.path.join(root, "startup"))
        position, radius, mass = (np.asarray(a) for a in (protocol.particles.position, protocol.particles.radius,
                                                          protocol.particles.mass))
        release, velocity = np.asarray(ps.release_position), np.asarray(ps.release_velocity)
        releases = [(*release[i], *velocity, 2.0 * radius[i], mass[i]) for i in range(rows_sub, total)]
        box = ((-2.0, info_p["substrate_length"] + 1.0),
               (float(ps.lost_below), info_p["base_y"] + info_p["insert_height"] + 2.0))  # ylo: jaxpile's lost line
        lmp = {"startup_seconds": startup}
        for setup_each in (True, False):
            workdir = os.path.join(root, f"pour_pre_{'yes' if setup_each else 'no'}")
            os.makedirs(workdir, exist_ok=True)
            peer.write_data(os.path.join(workdir, "substrate.data"), position[:rows_sub], 2.0 * radius[:rows_sub], box)
            script = peer.pour_script("substrate.data", params=params, rotation=contact_law.rotation,
                                      mass=mass[:rows_sub], fixed_ids=rows_sub, releases=releases,
                                      interval=info_p["interval_steps"], settle_steps=settle, dt=DT, gravity=1.0,
                                      dump_file="final.dump", setup_each=setup_each)
            run = peer.run(binary, script, workdir)
            fields = lammps_fields(run, work)
            if run.ok:
                dump = peer.read_dump(os.path.join(workdir, "final.dump"))
                grains = dump["id"] > rows_sub
                fields["heap"] = heap_stats(dump["x"][grains], dump["y"][grains], dump["vx"][grains],
                                            dump["vy"][grains], **geometry)
                overhead = run.wall_seconds - run.loop_seconds - startup
                fields.update(mean_disks_integrated=run.atom_steps / max(run.steps, 1),
                              segment_overhead_seconds=overhead, segment_overhead_per_run=overhead / max(run.runs, 1),
                              segment_overhead_fraction=overhead / run.wall_seconds)
            lmp["pre_yes" if setup_each else "pre_no"] = fields
        main_run = lmp["pre_yes"]
        lmp_rate = main_run["particle_steps_per_s"]
        if main_run["ok"]:
            checks = {}
            for key in HEAP_CHECKS + ("height", "width"):
                a, b = jax_stats[key], main_run["heap"][key]
                checks[key] = {"jaxpile": a, "lammps": b,
                               "rel_diff": abs(a - b) / abs(b) if b else (0.0 if a == b else None)}
            agree = all(checks[k]["rel_diff"] is not None and checks[k]["rel_diff"] < 0.10 for k in HEAP_CHECKS)
            lmp["agreement"] = {"checked": list(HEAP_CHECKS), "figures": checks, "agree": agree}
            other = lmp["pre_no"]
            if other["ok"]:
                # a pour is chaotic: LAMMPS's two runs (pre yes / pre no round differently) are two
                # realisations, and their heaps differ as much as either does from jaxpile's
                def within(run):
                    return all(abs(jax_stats[k] - run["heap"][k]) < 0.10 * abs(run["heap"][k]) for k in HEAP_CHECKS)

                lmp["agreement"]["agree_pre_no"] = within(other)
                lmp["agreement"]["lammps_self_spread"] = {
                    k: abs(main_run["heap"][k] - other["heap"][k]) / abs(main_run["heap"][k])
                    if main_run["heap"][k] else None for k in HEAP_CHECKS + ("height", "width")}
            for key in ("pre_yes", "pre_no"):
                f = lmp[key]
                if f["ok"]:
                    print(f"  LAMMPS pre {key[4:]:3s} {f['particle_steps_per_s']:.3g} particle-steps/s "
                          f"({f['loop_seconds']:.2f} s loop, {f['process_seconds']:.2f} s process, segments cost "
                          f"{f['segment_overhead_per_run'] * 1e3:.2f} ms each = {f['segment_overhead_fraction']:.0%} "
                          f"of the process)\n    heap: {heap_text(f['heap'])}")
            print(f"  jaxpile / LAMMPS = {jax_rate / lmp_rate:.3g}; heaps agree within 10% "
                  f"({', '.join(HEAP_CHECKS)}): {agree}; "
                  + ", ".join(f"{k} " + ("-" if c["rel_diff"] is None else f"{c['rel_diff']:.1%}")
                             for k, c in checks.items()))
            if "agree_pre_no" in lmp["agreement"]:
                spread = lmp["agreement"]["lammps_self_spread"]
                print(f"    within 10% of LAMMPS pre no's heap: {lmp['agreement']['agree_pre_no']}; LAMMPS pre yes "
                      "against pre no (two realisations of the pour): "
                      + ", ".join(f"{k} " + ("-" if v is None else f"{v:.1%}") for k, v in spread.items()))
        else:
            lmp["agreement"] = {"agree": None}
            print(f"  LAMMPS failed: {main_run['error']}")
        out["lammps"] = lmp
        rows.append({"case": title, "jaxpile": jax_rate, "lammps": lmp_rate, "ratio": ratio(jax_rate, lmp_rate),
                     "note": f"LAMMPS create_atoms per disk (run segments, pre yes), loop time; heap within 10%: "
                             f"{lmp['agreement']['agree']}"
                             + (f" (of LAMMPS pre no's: {lmp['agreement']['agree_pre_no']}; LAMMPS's two runs differ "
                                f"by up to {max(v for v in lmp['agreement']['lammps_self_spread'].values() if v is not None):.0%})"
                                if "agree_pre_no" in lmp["agreement"] else "")})

    others = {}
    for law in [law for law in args.pour_laws.split(",") if law]:
        _, law_c, _, state, info = jax_pour(law, protocol, settle, None, chunk)
        p = state.particles
        movable = np.asarray(p.movable)
        pos, vel = np.asarray(p.position)[movable], np.asarray(p.velocity)[movable]
        r = work / info.wall_seconds
        others[law] = {"integrator": pour.PAPER_SETTING["integrator"], "rotation": law_c.rotation,
                       "run_seconds": info.wall_seconds, "compile_seconds": info.compile_seconds,
                       "reallocations": info.reallocations, "particle_steps_per_s": r,
                       "heap": heap_stats(pos[:, 0], pos[:, 1], vel[:, 0], vel[:, 1], **geometry)}
        print(f"  jaxpile {law:12s} {r:.3g} particle-steps/s ({info.wall_seconds:.2f} s run, "
              f"{info.compile_seconds:.2f} s compile)")
        rows.append({"case": f"pour {n} disks, {law}, {steps} steps", "jaxpile": r, "lammps": None, "ratio": None,
                     "note": "jaxpile only (the paper's own law; LAMMPS has no such pair style)"})
    out["jaxpile_other_laws"] = others
    return out, rows


# ----------------------------------------------------------------- ensemble
def member_params(count: int) -> list:
    """Member i of `count`: ground friction from 1.0 down to 0.6 and ground
    tangential stiffness from kt down to kt / 2 (member 0: the paper's setting)."""
    kt = float(lattice_params().kt)
    spread = np.linspace(0.0, 1.0, count) if count > 1 else np.zeros(1)
    return [lattice_params(wall_mu=1.0 - 0.4 * u, wall_kt=kt * (1.0 - 0.5 * u)) for u in spread]


def ensemble_case(args, binary, root) -> tuple[dict, list]:
    ramp, hold = (int(s) for s in args.ensemble_steps.split(","))
    steps = ramp + hold
    layers = args.ensemble_layers
    particles, boundaries = lattice.equilateral_pile(layers)
    n = particles.count
    sim = Simulator(hooke.law(rotation=False), DT, schedule=gravity_ramp(ramp), chunk_steps=steps)
    out = {"layers": layers, "disks_per_pile": n, "ramp_steps": ramp, "hold_steps": hold, "dt": DT, "batches": {}}
    rows = []
    print(f"ensemble: {layers}-layer piles ({n} disks), {ramp} + {hold} steps; members differ in ground mu and kt")
    for count in [int(b) for b in args.members.split(",")]:
        params = member_params(count)
        ens = ensemble.Ensemble(sim)
        t0 = time.perf_counter()
        state = ens.init(params, [Setup(particles, boundaries)] * count)
        init_seconds = time.perf_counter() - t0
        info = RunInfo()
        state = ens.run(params, state, steps, progress=False, info=info)
        work = float(count) * n * steps
        jax_rate = work / info.wall_seconds
        entry = {"members": count,
                 "jaxpile": {"run_seconds": info.wall_seconds, "compile_seconds": info.compile_seconds,
                             "init_seconds": init_seconds, "reallocations": info.reallocations,
                             "particle_steps_per_s": jax_rate, "per_member_particle_steps_per_s": jax_rate / count},
                 "lammps": None}
        print(f"  B = {count:3d}: jaxpile {jax_rate:.3g} particle-steps/s ({info.wall_seconds:.2f} s run, "
              f"{info.compile_seconds:.2f} s compile)")
        title = f"ensemble B={count} x {n} disks, {steps} steps"
        if binary is None:
            rows.append({"case": title, "jaxpile": jax_rate, "lammps": None, "ratio": None, "note": "no LAMMPS binary"})
            out["batches"][str(count)] = entry
            continue
        picked = np.unique(np.round(np.linspace(0, count - 1, min(count, args.lammps_members))).astype(int))
        member_work = float(n) * steps
        seq = [peer.run(binary, *lattice_job(os.path.join(root, f"ens_B{count}", f"seq_{i}"), particles, boundaries,
                                             params[i], ramp, hold)) for i in picked]
        jobs = [lattice_job(os.path.join(root, f"ens_B{count}", f"pair_{i}"), particles, boundaries, params[i],
                            ramp, hold) for i in picked]
        pair, pair_wall = peer.run_concurrently(binary, jobs, parallel=2)
        check = int(picked[-1])
        base = analysis.base_forces(sim, params[check], ensemble.member(state, check))
        agree = agreement(base, seq[-1])
        ok = all(r.ok for r in seq + pair)
        loop = float(np.mean([r.loop_seconds for r in seq])) if ok else None
        proc = float(np.mean([r.wall_seconds for r in seq])) if ok else None
        seq_rate = rate(member_work, loop)
        pair_rate = rate(member_work * len(picked), pair_wall) if ok else None
        pair_loop = float(np.mean([r.loop_seconds for r in pair])) if ok else None
        entry["lammps"] = {
            "measured_members": picked.tolist(), "ok": ok,
            "errors": [r.error for r in seq + pair if not r.ok],
            "per_member_loop_seconds": loop, "per_member_process_seconds": proc,
            "sequential_loop_seconds_extrapolated": None if loop is None else loop * count,
            "sequential_process_seconds_extrapolated": None if proc is None else proc * count,
            "two_at_once_seconds_extrapolated": None if pair_rate is None else pair_wall / len(picked) * count,
            "sequential_particle_steps_per_s": seq_rate,
            "sequential_particle_steps_per_s_process": rate(member_work, proc),
            "two_at_once_particle_steps_per_s": pair_rate,
            "two_at_once_particle_steps_per_s_loop": None if pair_loop is None else 2.0 * member_work / pair_loop,
            "extrapolated": f"from {len(picked)} measured member(s) of {count}",
            "check_member": check, "agreement": agree}
        entry["jaxpile_over_lammps_sequential"] = ratio(jax_rate, seq_rate)
        entry["jaxpile_over_lammps_sequential_process"] = ratio(jax_rate, rate(member_work, proc))
        entry["jaxpile_over_lammps_two_at_once"] = ratio(jax_rate, pair_rate)
        out["batches"][str(count)] = entry
        if ok:
            print(f"           LAMMPS sequential {seq_rate:.3g} (loop) / {rate(member_work, proc):.3g} (process) "
                  f"particle-steps/s, two at once {pair_rate:.3g}; jaxpile / LAMMPS = {jax_rate / seq_rate:.3g} "
                  f"(loop), {entry['jaxpile_over_lammps_two_at_once']:.3g} (two at once); member {check} "
                  f"base forces dN {agree.get('max_rel_dev_normal', float('nan')):.2e}, "
                  f"dH {agree.get('max_rel_dev_horizontal', float('nan')):.2e} -> agree {agree['agree']}")
        else:
            print(f"           LAMMPS failed: {entry['lammps']['errors'][:1]}")
        note = f"LAMMPS per-member loop time x B, extrapolated from {len(picked)} run(s)"
        rows.append({"case": f"{title}, LAMMPS sequential", "jaxpile": jax_rate, "lammps": seq_rate,
                     "ratio": ratio(jax_rate, seq_rate), "note": f"{note}; member {check} agrees: {agree['agree']}"})
        rows.append({"case": f"{title}, LAMMPS two processes at once", "jaxpile": jax_rate, "lammps": pair_rate,
                     "ratio": ratio(jax_rate, pair_rate),
                     "note": f"LAMMPS wall time of {len(picked)} run(s), two at a time (start-up included), x B"})
    return out, rows


# --------------------------------------------------------------------- main
def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="lattice,pour,ensemble")
    parser.add_argument("--small", action="store_true",
                        help="sizes for `make bench` (all three cases in a few minutes on 2 cores)")
    parser.add_argument("--layers", type=int, default=lattice.PAPER_SETTING["layers"])
    parser.add_argument("--ramp", type=int, default=None, help="lattice: gravity ramp steps (20000, also small: shorter loads fail the 1%% check, see the docstring)")
    parser.add_argument("--hold", type=int, default=None, help="lattice: steps at full gravity (20000)")
    parser.add_argument("--pour-n", type=int, default=None, help="pour: disks (1000; small 200)")
    parser.add_argument("--pour-interval", type=float, default=0.15, help="pour: time between releases")
    parser.add_argument("--pour-settle", type=int, default=None, help="pour: steps after the last release")
    parser.add_argument("--pour-laws", default=",".join(OTHER_POUR_LAWS), help="pour: jaxpile-only laws")
    parser.add_argument("--members", default="1,8,64,256", help="ensemble: batch sizes B")
    parser.add_argument("--ensemble-layers", type=int, default=15)
    parser.add_argument("--ensemble-steps", default=None, help="ensemble: RAMP,HOLD (5000,5000; small 1000,1000)")
    parser.add_argument("--lammps-members", type=int, default=8, help="ensemble: LAMMPS runs per batch size")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workdir", default=None, help="keep LAMMPS inputs, logs and dumps here")
    parser.add_argument("--out", default=None, help="JSON file for the figures")
    args = parser.parse_args(argv)
    for key, value in (SMALL if args.small else FULL).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    cases = [c for c in args.cases.split(",") if c]
    unknown = set(cases) - {"lattice", "pour", "ensemble"}
    if unknown:
        parser.error(f"unknown case(s) {sorted(unknown)}")

    binary, root, version = peer.open_race(args.workdir, "vs_lammps-")
    out = {"machine": describe(), "machine_details": details(), "jax_version": jax.__version__, "lammps_version": version, "lammps_binary": binary,
           **peer.run_cases((("lattice", lattice_case), ("pour", pour_case), ("ensemble", ensemble_case)), cases,
                            args, binary, root, keep=args.workdir is not None)}
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
