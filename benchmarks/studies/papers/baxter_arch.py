"""The arch under the apex of the 1997 heaps (Baxter et al., Fig. 3a).

The paper: "Lines of principal stress intersect at a point below the apex to
form an arch, immediately beneath which the internal stresses are somewhat
smaller", with a minimum of the base force below it. This reads the final
states `baxter_readings.py` saved (`<folder>/<setting>_seed<k>.npz`), rebuilds
each heap's normal contact forces from its positions (the law's normal force
is the overlap's and, at rest, not the velocities'; the tangential springs are
not in the save and are not needed), and measures each disk's pressure, the
trace of its stress tensor (1/2) sum_c f_n |d_c| over its area, against the
depth of the surface above it. Under an arch the column below the apex
carries less than the columns beside it at the same height, although it is
deeper: the pressure in the column under the apex (|x - apex| < 0.1 B) over
that in the columns 0.15-0.3 B either side, in the lower half of the heap, is
below 1 (a heap without an arch carries more there: it is deeper), and so,
more weakly, is the same ratio of pressure over depth (1 in a fluid; below 1
in the 1992 construction too, whose base force is flat under the apex).
Mean +- standard error over heaps. No
simulation: about a minute for 8 heaps of 1334 disks.

    python benchmarks/studies/papers/baxter_arch.py --folder benchmarks/results/baxter_readings/n1334
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # baxter_readings (the settings, mean +- s.e.)


def heap_arch(path: str, setting: str) -> dict:
    """One saved heap: the pressure-over-depth ratio of the column under the
    apex to its sides, in the lower and the upper half of the heap."""
    from jaxpile import analysis, engine
    from jaxpile.engine.checkpoint import read_leaves
    from jaxpile.protocols import pour

    import baxter_readings as br

    spec = br.setting_of(setting)
    s = read_leaves(path)
    pos, rad = np.asarray(s[".particles.position"]), np.asarray(s[".particles.radius"])
    fixed, active = np.asarray(s[".particles.fixed"]), np.asarray(s[".particles.active"])
    mass = np.asarray(s[".particles.mass"])
    poured = active & ~fixed
    row = int(s[".protocol_state.first"])  # the substrate: disks 0 .. row-1
    _, _, params = pour.SPEC.law_and_params(spec["law"], spec["params"] or None, law_options=spec["law_options"])
    sim = pour.make_simulator(spec["law"], law_options=spec["law_options"], max_initial_overlap=0.5,  # a heap at rest
                              **({} if spec["dt"] is None else
                                                                              {"dt": spec["dt"]}))
    keep = active  # the substrate and the heap; disks lost below it are not in play
    particles = engine.make_particles(pos[keep], rad[keep], mass=mass[keep], fixed=fixed[keep])
    boundaries = engine.make_boundaries()
    for wall in (engine.GROUND, engine.LEFT_WALL, engine.RIGHT_WALL):
        boundaries = engine.set_wall(boundaries, wall, active=False)
    state = sim.init(params, particles, boundaries)
    network = analysis.contact_network(sim, params, state)
    i, j, fn = np.asarray(network.i), np.asarray(network.j), np.asarray(network.normal)
    p, r = pos[keep], rad[keep]
    length = np.linalg.norm(p[i] - p[j], axis=1)
    trace = np.zeros(len(p))
    np.add.at(trace, i, fn * 0.5 * length)  # each disk's share of the branch vector: its centre to the contact
    np.add.at(trace, j, fn * 0.5 * length)
    pressure = trace / (2.0 * np.pi * r**2)  # the mean stress, (1/2) trace, over the disk's area (in mg / sigma^2)

    heap = poured[keep]
    floor = float(p[0, 1] + r[0])
    spacing = float(p[1, 0] - p[0, 0])
    surface = analysis.surface_profile(p[heap], r[heap], x_min=float(p[0, 0]), width=float(p[row - 1, 0] - p[0, 0]),
                                       column_width=spacing)
    apex = float(analysis.apex_x(surface))
    height = float(np.max((p[:, 1] + r)[heap])) - floor
    filled = surface.x[np.isfinite(surface.height) & (surface.height > floor + 0.25)]
    base = float(filled.max() - filled.min())
    top = np.interp(p[:, 0], surface.x, np.nan_to_num(surface.height, nan=floor))
    depth = top - p[:, 1]
    ratio = np.where(depth > 2.0, pressure / np.maximum(depth, 1e-9), np.nan)  # a disk under 2 sigma of heap or more

    def mean_of(values, x0, x1, y0, y1):
        off = np.abs(p[:, 0] - apex) / base
        y = (p[:, 1] - floor) / height
        sel = heap & (off >= x0) & (off < x1) & (y >= y0) & (y < y1) & np.isfinite(ratio)
        return float(np.mean(values[sel])) if sel.any() else float("nan")

    out = {"apex_x": apex, "height": height, "base_width": base, "contacts": int(len(fn))}
    for name, (y0, y1) in (("lower", (0.0, 0.5)), ("upper", (0.5, 1.0))):
        centre, sides = mean_of(ratio, 0.0, 0.1, y0, y1), mean_of(ratio, 0.15, 0.3, y0, y1)
        at_centre, at_sides = mean_of(pressure, 0.0, 0.1, y0, y1), mean_of(pressure, 0.15, 0.3, y0, y1)
        out[name] = {"centre": centre, "sides": sides, "centre_over_sides": centre / sides,
                     "pressure_centre_over_sides": at_centre / at_sides}  # the same heights, not over depth
    return out


def main(argv=None) -> dict:
    from baxter_readings import mean_stderr, saved_heap_arguments, saved_heaps

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    saved_heap_arguments(parser, "arch")
    args = parser.parse_args(argv)
    import jaxpile

    jaxpile.configure()  # float64, as the heaps were saved
    stem = args.setting.replace("/", "_")
    files = saved_heaps(args.folder, args.setting)
    if not files:
        parser.error(f"no saved heaps of {args.setting} in {args.folder} (run baxter_readings.py with its "
                     "summary's command)")
    heaps = {pathlib.Path(f).stem: heap_arch(f, args.setting) for f in files}
    command = "python benchmarks/studies/papers/baxter_arch.py " + " ".join(sys.argv[1:] if argv is None else argv)
    out = {"command": command, "setting": args.setting, "heaps": heaps,
           "summary": {f"{band}_{what}": mean_stderr([h[band][what] for h in heaps.values()])
                       for band in ("lower", "upper") for what in ("centre_over_sides", "pressure_centre_over_sides")}}
    out["summary"]["count"] = len(heaps)
    for key, s in out["summary"].items():
        if key != "count":
            print(f"{key}: {s['mean']:.3f} +- {s['stderr']:.3f}")
    target = args.out or f"{args.folder}/arch_{stem}.json"
    pathlib.Path(target).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
