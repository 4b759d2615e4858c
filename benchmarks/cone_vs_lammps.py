"""The cone pour (spheres, `protocols.cone`) against LAMMPS on the same problem:
how many particle-steps per second does each manage, and how much memory does
jaxpile take per sphere?

Both codes run the `hooke` law, LAMMPS's `pair gran/hooke/history`, with
rotation (`fix nve/sphere`, I = 2 m r^2 / 5) and velocity Verlet in float64,
the cone's own parameters and dt. The plate's fixed spheres are frozen (`fix
freeze`), and neither code lists a pair of two of them (`neigh_modify exclude
group base base`; jaxpile never lists two fixed particles). The cone has no wall: a sphere that rolls off the plate falls below
`lost_below` and leaves play (jaxpile parks it; LAMMPS deletes it at the
box's floor, `thermo_modify lost ignore`), so no `fix wall/gran` is needed.
LAMMPS replays the protocol as `vs_lammps.py`'s 2D pour does: each sphere is
created with `create_atoms` at the same step, position and velocity, one `run`
segment per sphere (`pre yes`), then the heap settles for `--settle` steps. A
pour is chaotic, so the heaps are held to each other statistically: spheres on
the plate, the heap's centroid height and rms radius within 10 %.

Three cases:

1. `one`: one cone, jaxpile against LAMMPS serial (its loop time).
2. `large`: the same for a cone of `--large-n` spheres, one every
   `--large-interval` (not run by default).
3. `ensemble`: B cones (seeds 0..B-1) in one jaxpile batch, run as `jaxpile
   sweep` runs it (on one CPU device the members one after another inside each
   compiled chunk, each deciding its own rebuilds), against the same B replays
   in LAMMPS, one after another (the sum of their loop times) and two processes
   at once (the wall time of the set, start-up included: what two cores do
   with independent members). Run with `JAXPILE_HOST_DEVICES=2` to give
   jaxpile both cores as two devices (the members then run side by side).

The work counted for both codes is (plate + poured spheres) x steps; LAMMPS
carries only the spheres created so far, jaxpile each chunk's block of those
poured by its end. Memory: the bytes of jaxpile's state per sphere (particles,
contact history, neighbour list) and XLA's temporaries of the compiled chunk.
Without a LAMMPS binary jaxpile is reported alone.

    python benchmarks/cone_vs_lammps.py [--n 200] [--interval 0.2] [--settle 20000]
        [--cases one,large,ensemble] [--large-n 1000] [--large-interval 0.25] [--members 8] [--out FILE]
"""

from __future__ import annotations

import argparse
import os
import sys

import jax
import numpy as np

import jaxpile
from jaxpile import io
from jaxpile.batches import batch_of
from jaxpile.engine import RunInfo, ensemble
from jaxpile.protocols import cone

try:
    from benchmarks import lammps_peer as peer
    from benchmarks.machine import describe, details
except ImportError:  # run as a script: benchmarks/ is on sys.path
    import lammps_peer as peer
    from machine import describe, details

jaxpile.configure()

HEAP_CHECKS = ("on_plate", "centroid_height", "rms_radius")  # held to 10%; the apex height reported beside
CHUNK = 2000
"""The cone's own chunk: each runs on the block of spheres poured by its end."""


def rate(work: float, seconds: float | None) -> float | None:
    return work / seconds if seconds else None


def ratio(a: float | None, b: float | None) -> float | None:
    return a / b if a and b else None


def cone_stats(position, velocity, *, base_z: float) -> dict:
    """Numbers of a poured cone that both codes can be held to (`position`,
    `velocity`: `[m, 3]` of the poured spheres still in play): how many, their
    mean height above the plate's centres, their rms distance from the axis,
    the highest centre, and how many still move faster than 0.01."""
    position, velocity = np.asarray(position, float), np.asarray(velocity, float)
    if not len(position):
        return {"on_plate": 0, "centroid_height": 0.0, "rms_radius": 0.0, "height": 0.0, "moving": 0}
    return {"on_plate": int(len(position)), "centroid_height": float(np.mean(position[:, 2] - base_z)),
            "rms_radius": float(np.sqrt(np.mean(position[:, 0] ** 2 + position[:, 1] ** 2))),
            "height": float(position[:, 2].max() - base_z),
            "moving": int((np.linalg.norm(velocity, axis=1) > 1e-2).sum())}


def stats_text(h: dict) -> str:
    return (f"{h['on_plate']} on the plate, centroid height {h['centroid_height']:.2f}, rms radius "
            f"{h['rms_radius']:.2f}, apex {h['height']:.2f}, {h['moving']} moving")


def set_up(args, seed: int):
    return cone.SPEC.set_up("hooke", args.n, seed=seed, interval=args.interval, release_height=args.release_height)


def in_play(state, setup) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities of the poured spheres still in play."""
    p = state.particles
    keep = np.asarray(p.active) & ~np.asarray(p.fixed) & ~np.asarray(state.protocol_state.lost)
    return np.asarray(p.position)[keep], np.asarray(p.velocity)[keep]


def state_bytes(state) -> int:
    return int(sum(x.nbytes for x in jax.tree_util.tree_leaves(state) if hasattr(x, "nbytes")))


def lammps_job(args, setup, workdir: str, params, skin: float) -> tuple[str, str]:
    """The replay of `setup` in LAMMPS: (script, workdir), the plate in its data file."""
    ps, info = setup.protocol_state, setup.info
    rows, total = int(ps.first), int(ps.first) + args.n
    position, radius, mass = (np.asarray(a, float) for a in (setup.particles.position, setup.particles.radius,
                                                             setup.particles.mass))
    release, velocity = np.asarray(ps.release_position, float), np.asarray(ps.release_velocity, float)
    releases = [(*release[i], *velocity, 2.0 * radius[i], mass[i]) for i in range(rows, total)]
    reach = info["base_radius"] + 10.0  # room for spheres that roll off the plate before they fall
    box = ((-reach, reach), (-reach, reach), (float(ps.lost_below), info["base_z"] + info["insert_height"] + 2.0))
    os.makedirs(workdir, exist_ok=True)
    peer.write_data(os.path.join(workdir, "plate.data"), position[:rows], 2.0 * radius[:rows], box)
    script = peer.pour_script("plate.data", params=params, rotation=True, mass=mass[:rows], fixed_ids=rows,
                              releases=releases, interval=info["interval_steps"], settle_steps=args.settle,
                              dt=info["dt"], gravity=1.0, dump_file="final.dump", skin=skin, dimension=3)
    return script, workdir


def lammps_stats(run: peer.Run, rows: int, base_z: float) -> dict | None:
    if not run.ok:
        return None
    dump = peer.read_dump(os.path.join(run.workdir, "final.dump"))
    poured = dump["id"] > rows
    column = lambda *names: np.stack([dump[k][poured] for k in names], 1)  # noqa: E731
    return cone_stats(column("x", "y", "z"), column("vx", "vy", "vz"), base_z=base_z)


def agreement(ours: dict, theirs: dict | None) -> dict:
    if theirs is None:
        return {"agree": None}
    figures = {k: {"jaxpile": ours[k], "lammps": theirs[k],
                   "rel_diff": abs(ours[k] - theirs[k]) / abs(theirs[k]) if theirs[k] else None}
               for k in HEAP_CHECKS + ("height",)}
    agree = all(figures[k]["rel_diff"] is not None and figures[k]["rel_diff"] < 0.10 for k in HEAP_CHECKS)
    return {"checked": list(HEAP_CHECKS), "figures": figures, "agree": agree}


def one_case(args, binary, root, folder: str = "one") -> tuple[dict, list]:
    setup = set_up(args, args.seed)
    info = setup.info
    rows = int(setup.protocol_state.first)
    total, steps = rows + args.n, info["pour_steps"] + args.settle
    work = float(total) * steps
    _, law, params = cone.law_and_params("hooke")
    sim = cone.simulator(cone.SPEC.make_options({"n": args.n}), law="hooke", dt=info["dt"], chunk_steps=CHUNK)
    state = sim.init(params, setup.particles, setup.boundaries, protocol_state=setup.protocol_state)
    skin = sim.neighbor_settings(params, setup.particles).skin  # LAMMPS rebuilds with the same skin
    run_info = RunInfo()
    state = sim.run(params, state, info["pour_steps"], progress=False, info=run_info)
    state = sim.run(params, state, args.settle, progress=False, info=run_info)
    compiled = sim._compiled_advance(params, state, None, RunInfo())  # the cached executable of a chunk
    temp = compiled.memory_analysis().temp_size_in_bytes if hasattr(compiled, "memory_analysis") else None
    ours = cone_stats(*in_play(state, setup), base_z=info["base_z"])
    jax_rate = work / run_info.wall_seconds
    out = {"poured": args.n, "plate_spheres": rows, "spheres": total, "steps": steps,
           "pour_steps": info["pour_steps"], "settle_steps": args.settle, "interval_steps": info["interval_steps"],
           "insert_height": info["insert_height"], "insert_speed": info["insert_speed"], "dt": info["dt"],
           "skin": skin, "work_particle_steps": work,
           "memory": {"state_bytes_per_sphere": state_bytes(state) / total,
                      "temp_bytes_per_sphere": None if temp is None else temp / total,
                      "neighbor_slots": int(state.neighbors.idx.shape[-1])},
           "jaxpile": {"run_seconds": run_info.wall_seconds, "compile_seconds": run_info.compile_seconds,
                       "reallocations": run_info.reallocations, "particle_steps_per_s": jax_rate, "heap": ours},
           "lammps": None}
    memory = out["memory"]
    print(f"one cone: {args.n} spheres onto a plate of {rows}, one every {info['interval_steps']} steps, "
          f"{info['pour_steps']} + {args.settle} steps; work counted as {total} spheres x {steps} steps\n"
          f"  jaxpile {jax_rate:.3g} particle-steps/s ({run_info.wall_seconds:.1f} s run, "
          f"{run_info.compile_seconds:.1f} s compile); {memory['state_bytes_per_sphere']:.0f} B/sphere state"
          + ("" if temp is None else f" + {memory['temp_bytes_per_sphere']:.0f} B/sphere XLA temporaries")
          + f"\n    heap: {stats_text(ours)}")
    title = f"cone {args.n} spheres (plate {rows}), hooke, {steps} steps"
    if binary is None:
        return out, [{"case": title, "jaxpile": jax_rate, "lammps": None, "ratio": None, "note": "no LAMMPS binary"}]
    run = peer.run(binary, *lammps_job(args, setup, os.path.join(root, folder), params, skin))
    theirs = lammps_stats(run, rows, info["base_z"])
    lmp_rate = rate(work, run.loop_seconds) if run.ok else None
    agree = agreement(ours, theirs)
    out["lammps"] = {"ok": run.ok, "error": run.error, "loop_seconds": run.loop_seconds,
                     "process_seconds": run.wall_seconds, "runs": run.runs, "particle_steps_per_s": lmp_rate,
                     "mean_spheres_integrated": run.atom_steps / max(run.steps, 1), "heap": theirs,
                     "agreement": agree}
    if run.ok:
        print(f"  LAMMPS  {lmp_rate:.3g} particle-steps/s ({run.loop_seconds:.1f} s loop, {run.wall_seconds:.1f} s "
              f"process)\n    heap: {stats_text(theirs)}\n  jaxpile / LAMMPS = {jax_rate / lmp_rate:.3g}; heaps "
              f"within 10% ({', '.join(HEAP_CHECKS)}): {agree['agree']}")
    else:
        print(f"  LAMMPS failed: {run.error}")
    return out, [{"case": title, "jaxpile": jax_rate, "lammps": lmp_rate, "ratio": ratio(jax_rate, lmp_rate),
                  "note": f"LAMMPS serial, create_atoms per sphere (run segments, pre yes), loop time; "
                          f"{memory['state_bytes_per_sphere']:.0f} B/sphere state; heap within 10%: {agree['agree']}"}]


def ensemble_case(args, binary, root) -> tuple[dict, list]:
    count = int(args.members)
    setups = [set_up(args, args.seed + k) for k in range(count)]
    info = setups[0].info
    rows = int(setups[0].protocol_state.first)
    total, steps = rows + args.n, info["pour_steps"] + args.settle
    member_work = float(total) * steps
    _, law, params = cone.law_and_params("hooke")
    sim = cone.simulator(cone.SPEC.make_options({"n": args.n}), law="hooke", dt=info["dt"], chunk_steps=CHUNK)
    # as `jaxpile sweep --protocol cone` runs a batch: on one CPU device the members one after another,
    # each with its own rebuilds (side by side, every member rebuilds whenever one needs it)
    ens = ensemble.Ensemble(sim, sequential=batch_of("cone").sequential)
    state = ens.init(params, setups)
    run_info = RunInfo()
    state = ens.run(params, state, info["pour_steps"], progress=False, info=run_info)
    state = ens.run(params, state, args.settle, progress=False, info=run_info)
    jax_rate = count * member_work / run_info.wall_seconds
    ours = [cone_stats(*in_play(ensemble.member(state, k), s), base_z=info["base_z"]) for k, s in enumerate(setups)]
    out = {"members": count, "spheres_per_member": total, "steps": steps, "devices": len(jax.devices()),
           "members_one_after_another": ens.sequential,
           "jaxpile": {"run_seconds": run_info.wall_seconds, "compile_seconds": run_info.compile_seconds,
                       "reallocations": run_info.reallocations, "particle_steps_per_s": jax_rate,
                       "heaps": ours}, "lammps": None}
    print(f"ensemble: {count} cones of {args.n} spheres (plate {rows}), {steps} steps, {len(jax.devices())} "
          f"device(s)\n  jaxpile {jax_rate:.3g} particle-steps/s ({run_info.wall_seconds:.1f} s run, "
          f"{run_info.compile_seconds:.1f} s compile)")
    title = f"ensemble of {count} cones x {total} spheres, hooke, {steps} steps"
    if binary is None:
        return out, [{"case": title, "jaxpile": jax_rate, "lammps": None, "ratio": None, "note": "no LAMMPS binary"}]
    skin = sim.neighbor_settings(params, setups[0].particles).skin
    jobs = [lammps_job(args, s, os.path.join(root, f"member_{k}"), params, skin) for k, s in enumerate(setups)]
    pair, pair_wall = peer.run_concurrently(binary, jobs, parallel=2)
    ok = all(r.ok for r in pair)
    theirs = [lammps_stats(r, rows, info["base_z"]) for r in pair]
    # the two-at-once processes' loop times, summed, are the serial cost of the members (one core each)
    serial_rate = rate(count * member_work, sum(r.loop_seconds for r in pair)) if ok else None
    pair_rate = rate(count * member_work, pair_wall) if ok else None
    out["lammps"] = {"ok": ok, "errors": [r.error for r in pair if not r.ok],
                     "loop_seconds": [r.loop_seconds for r in pair], "two_at_once_wall_seconds": pair_wall,
                     "sequential_particle_steps_per_s": serial_rate, "two_at_once_particle_steps_per_s": pair_rate,
                     "heaps": theirs,
                     "agreement": [agreement(a, b) for a, b in zip(ours, theirs)]}
    if ok:
        means = {k: (np.mean([h[k] for h in ours]), np.mean([h[k] for h in theirs])) for k in HEAP_CHECKS}
        print(f"  LAMMPS  {serial_rate:.3g} particle-steps/s one core per member (sum of loop times), "
              f"{pair_rate:.3g} two processes at once (wall)\n  jaxpile / LAMMPS = {jax_rate / serial_rate:.3g} "
              f"(per core-second of LAMMPS loop), {jax_rate / pair_rate:.3g} (two at once); ensemble means "
              + ", ".join(f"{k} {a:.2f} vs {b:.2f}" for k, (a, b) in means.items()))
    else:
        print(f"  LAMMPS failed: {out['lammps']['errors'][:1]}")
    return out, [
        {"case": f"{title}, LAMMPS one member after another", "jaxpile": jax_rate, "lammps": serial_rate,
         "ratio": ratio(jax_rate, serial_rate), "note": "LAMMPS serial, the sum of the members' loop times"},
        {"case": f"{title}, LAMMPS two processes at once", "jaxpile": jax_rate, "lammps": pair_rate,
         "ratio": ratio(jax_rate, pair_rate), "note": "LAMMPS wall time of the members two at a time (start-up "
                                                      "included)"}]


def large_case(args, binary, root) -> tuple[dict, list]:
    """`one` for a cone of `--large-n` spheres: how the ratio moves with the
    heap's size (a step's fixed costs weigh less on more spheres)."""
    larger = {**vars(args), "n": args.large_n, "interval": args.large_interval}
    return one_case(argparse.Namespace(**larger), binary, root, folder="large")


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="one,ensemble")
    parser.add_argument("--n", type=int, default=200, help="spheres poured per cone")
    parser.add_argument("--interval", type=float, default=0.2, help="time between releases")
    parser.add_argument("--release-height", type=float, default=cone.SETTING["release_height"])
    parser.add_argument("--settle", type=int, default=20_000, help="steps after the last release")
    parser.add_argument("--members", type=int, default=8, help="ensemble: cones in the batch")
    parser.add_argument("--large-n", type=int, default=1000, help="large: spheres poured in the larger cone")
    parser.add_argument("--large-interval", type=float, default=0.25,
                        help="large: time between releases (a taller cone falls further: 0.2 is too short)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workdir", default=None, help="keep LAMMPS inputs, logs and dumps here")
    parser.add_argument("--out", default=None, help="JSON file for the figures")
    args = parser.parse_args(argv)
    cases = [c for c in args.cases.split(",") if c]
    known = {"one", "large", "ensemble"}
    if set(cases) - known:
        parser.error(f"unknown case(s) {sorted(set(cases) - known)}; choose from {', '.join(sorted(known))}")
    binary, root, version = peer.open_race(args.workdir, "cone_vs_lammps-")
    out = {"machine": describe(), "machine_details": details(), "jax_version": jax.__version__,
           "lammps_version": version, "lammps_binary": binary, "argv": sys.argv[1:] if argv is None else list(argv),
           **peer.run_cases((("one", one_case), ("large", large_case), ("ensemble", ensemble_case)), cases, args,
                            binary, root,
                            keep=args.workdir is not None)}
    if args.out:
        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
