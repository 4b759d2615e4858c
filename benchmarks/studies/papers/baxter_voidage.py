"""How densely the 1997 heaps are packed at each height below the apex.

Baxter et al. 1997 draw the voidage of their heaps (Figs. 2d, 5a, 8) and say
what they see: for the paper's law, "the central region of the heap, around
halfway between the apex and the base, has a low density ... with a patchwork
of compacted regions formed close to the base ... regions near the base of the
heap are most densely packed, with looser packing towards the edges and apex";
for the equivalent Hooke law "a large region of low voidage below the apex";
with 5 and 10 % polydispersity "much higher levels of compaction".

This reads the final states `baxter_readings.py` saved (`<folder>/<setting>_seed<k>.npz`)
and measures, in the column under the apex (x within `--half-width` x B of it,
B the heap's base width), the area fraction of the poured disks in bands of the
apex height above the substrate's top, exactly (`measure.voidage.packing_fraction`),
and at the heap's edges, in the two columns 0.3-0.4 B either side of the apex,
in the base band (below their surface). Mean +- standard error over heaps, per setting. No simulation;
seconds. The saved states are a run's workings, not committed: they come from
running `baxter_readings.py` with its summary's command (docs/papers.md gives
the cost); this script's JSON and figure are committed.

    python benchmarks/studies/papers/baxter_voidage.py --folder benchmarks/results/baxter_readings/n1000
        [--settings hooke-k500,mu0.2,...] [--out FILE] [--figure PNG]
"""

from __future__ import annotations

import argparse
import glob
import json
import pathlib
import sys

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # baxter_readings (one definition of mean +- s.e.)

BANDS = ((0.0, 0.2), (0.2, 0.4), (0.4, 0.6), (0.6, 0.8))
"""Bands of the apex height above the substrate's top: the base band first."""


def heap_packing(path: str, half_width: float = 0.1) -> dict:
    """One saved heap: the poured disks' area fraction in each of `BANDS` of
    the column under the apex (x within `half_width` B of it), and in the base
    band of the two columns 0.3-0.4 B either side of it (`edges`)."""
    from jaxpile.engine.checkpoint import read_leaves
    from jaxpile.measure import analysis
    from jaxpile.measure.voidage import packing_fraction

    s = read_leaves(path)
    pos, rad = np.asarray(s[".particles.position"]), np.asarray(s[".particles.radius"])
    poured = np.asarray(s[".particles.active"]) & ~np.asarray(s[".particles.fixed"])
    row = int(s[".protocol_state.first"])  # the substrate: disks 0 .. row-1
    floor = float(pos[0, 1] + rad[0])  # the substrate's top
    spacing = float(pos[1, 0] - pos[0, 0])
    surface = analysis.surface_profile(pos[poured], rad[poured], x_min=float(pos[0, 0]),
                                       width=float(pos[row - 1, 0] - pos[0, 0]), column_width=spacing)
    apex = float(analysis.apex_x(surface))
    height = float(np.max((pos[:, 1] + rad)[poured])) - floor
    filled = surface.x[np.isfinite(surface.height) & (surface.height > floor + 0.25)]
    base = float(filled.max() - filled.min())

    def fraction(x0, x1, y0, y1):
        region = (x0, x1, floor + y0 * height, floor + y1 * height)
        return float(packing_fraction(pos, rad, region, active=poured))

    lo, hi = BANDS[0]
    edges = [fraction(apex - 0.4 * base, apex - 0.3 * base, lo, hi), fraction(apex + 0.3 * base, apex + 0.4 * base, lo, hi)]
    return {"apex_x": apex, "height": height, "base_width": base,
            "bands": [fraction(apex - half_width * base, apex + half_width * base, y0, y1) for y0, y1 in BANDS],
            "edges": float(np.mean(edges))}


def summarise(heaps: list[dict]) -> dict:
    from baxter_readings import mean_stderr

    return {"heaps": len(heaps),
            "bands": [mean_stderr([h["bands"][k] for h in heaps]) for k in range(len(BANDS))],
            "edges": mean_stderr([h["edges"] for h in heaps]),
            "base_minus_middle": mean_stderr([h["bands"][0] - h["bands"][2] for h in heaps]),
            "middle_minus_top": mean_stderr([h["bands"][2] - h["bands"][3] for h in heaps]),
            "centre_minus_edges": mean_stderr([h["bands"][0] - h["edges"] for h in heaps])}


def figure(out: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    middle = [0.5 * (lo + hi) for lo, hi in BANDS]
    for k, (name, s) in enumerate(out["settings"].items()):
        mean = [b["mean"] for b in s["bands"]]
        err = [b["stderr"] or 0.0 for b in s["bands"]]
        ax.errorbar(mean, middle, xerr=err, marker="o", color=f"C{k}", capsize=3,
                    label=f"{name} ({s['heaps']} heaps)")
    ax.set(xlabel="packing fraction of the column under the apex", ylabel="height / apex height",
           title=f"Baxter et al. 1997: packing by height, heaps of {out['n']} disks")
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", default="benchmarks/results/baxter_readings/n1334")
    parser.add_argument("--settings", default=None, help="comma-separated file prefixes (default: every one saved)")
    parser.add_argument("--half-width", type=float, default=0.1, help="the column under the apex, in B")
    parser.add_argument("--out", default=None, help="JSON (default: <folder>/voidage.json)")
    parser.add_argument("--figure", default=None)
    args = parser.parse_args(argv)
    import jaxpile

    jaxpile.configure()  # float64, as the heaps were saved
    files = sorted(glob.glob(f"{args.folder}/*_seed*.npz"))
    by_setting: dict[str, list[str]] = {}
    for f in files:
        by_setting.setdefault(pathlib.Path(f).stem.rsplit("_seed", 1)[0], []).append(f)
    wanted = args.settings.split(",") if args.settings else sorted(by_setting)
    missing = [w for w in wanted if w not in by_setting]
    if missing or not wanted:
        parser.error(f"no saved heaps for {missing or 'any setting'} in {args.folder}")
    heaps = {w: {pathlib.Path(f).stem: heap_packing(f, args.half_width) for f in by_setting[w]} for w in wanted}
    n = int(json.loads((pathlib.Path(args.folder) / "summary.json").read_text())["n"])
    command = "python benchmarks/studies/papers/baxter_voidage.py " + " ".join(sys.argv[1:] if argv is None else argv)
    out = {"n": n, "command": command, "half_width": args.half_width, "bands": [list(b) for b in BANDS],
           "settings": {w: summarise(list(h.values())) for w, h in heaps.items()}, "heaps": heaps}
    for w, s in out["settings"].items():
        bands = ", ".join(f"{b['mean']:.3f}" for b in s["bands"])
        d = {k: f"{s[k]['mean']:+.3f} +- {s[k]['stderr']:.3f}" for k in ("base_minus_middle", "middle_minus_top",
                                                                        "centre_minus_edges")}
        print(f"{w:22s} {s['heaps']} heaps: bands {bands}; edges {s['edges']['mean']:.3f}; {d}")
    target = args.out or f"{args.folder}/voidage.json"
    pathlib.Path(target).write_text(json.dumps(out, indent=1))
    if args.figure:
        figure(out, args.figure)
    return out


if __name__ == "__main__":
    main()
