"""Shear banding in the 1997 heaps (Baxter et al., Figs. 2 and 6), as the
contrast of their density maps.

The paper sees "shear banding" in the density maps of its n = 36 heaps
(Fig. 2: lines of low density through a denser matrix) and finds that with
n = 144 and the short tail r0 = 1.047 sigma it "largely disappears", the map
resembling the equivalent Hooke law's. This reads the final states
`baxter_readings.py` saved (`<folder>/<setting>_seed<k>.npz`), maps each
heap's packing fraction on square cells of `--cell` diameters
(`measure.voidage.voidage_map`, exact areas), keeps the cells wholly inside
the heap (a diameter below its surface and above the substrate's top), and
measures the map's contrast: the standard deviation of the cells' packing
fraction, and the share of cells looser than the heap's median by more than
0.05 (the light patches of the figures). Bands make both larger. Mean +-
standard error over heaps, per setting. No simulation; seconds.

    python benchmarks/studies/papers/baxter_banding.py --folder benchmarks/results/baxter_readings/n1000
"""

from __future__ import annotations

import argparse
import glob
import json
import pathlib
import sys

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # baxter_readings (mean +- s.e.)

LOOSER = 0.05
"""A cell is a light patch when its packing fraction is this far below the heap's median."""


def heap_contrast(path: str, cell: float = 2.0) -> dict:
    """One saved heap's density-map contrast over its inner cells."""
    from jaxpile import analysis
    from jaxpile.engine.checkpoint import read_leaves
    from jaxpile.measure import voidage

    s = read_leaves(path)
    pos, rad = np.asarray(s[".particles.position"]), np.asarray(s[".particles.radius"])
    poured = np.asarray(s[".particles.active"]) & ~np.asarray(s[".particles.fixed"])
    row = int(s[".protocol_state.first"])
    floor = float(pos[0, 1] + rad[0])
    spacing = float(pos[1, 0] - pos[0, 0])
    surface = analysis.surface_profile(pos[poured], rad[poured], x_min=float(pos[0, 0]),
                                       width=float(pos[row - 1, 0] - pos[0, 0]), column_width=spacing)
    top = float(np.max((pos[:, 1] + rad)[poured]))
    region = (float(pos[0, 0]), float(pos[row - 1, 0]), floor, top)
    vmap = voidage.voidage_map(pos, rad, cell, active=poured, region=region)
    fraction = np.asarray(vmap.packing_fraction)
    xe, ye = np.asarray(vmap.x_edges), np.asarray(vmap.y_edges)
    full = np.isclose(np.asarray(vmap.cell_area), cell * cell)  # whole cells (the last row and column may be cut)
    xs, ys = 0.5 * (xe[1:] + xe[:-1]), 0.5 * (ye[1:] + ye[:-1])
    height = np.nan_to_num(np.asarray(surface.height), nan=-np.inf)
    # a cell is inside when the surface stands a diameter above its top over its whole width
    lowest = np.array([np.min(height[np.abs(np.asarray(surface.x) - x) <= 0.5 * cell + 0.5 * spacing])
                       for x in xs])
    inside = full & (ys[:, None] + 0.5 * cell <= lowest[None, :] - 1.0) & (ys[:, None] - 0.5 * cell >= floor + 1.0)
    inner = fraction[inside]
    median = float(np.median(inner))
    return {"cells": int(inner.size), "median": median, "std": float(inner.std(ddof=1)),
            "looser_share": float(np.mean(inner < median - LOOSER))}


def main(argv=None) -> dict:
    from baxter_readings import mean_stderr

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", default="benchmarks/results/baxter_readings/n1000")
    parser.add_argument("--cell", type=float, default=2.0, help="the map's cell, in diameters")
    parser.add_argument("--out", default=None, help="JSON (default: <folder>/banding.json)")
    args = parser.parse_args(argv)
    import jaxpile

    jaxpile.configure()
    by_setting: dict[str, list[str]] = {}
    for f in sorted(glob.glob(f"{args.folder}/*_seed*.npz")):
        by_setting.setdefault(pathlib.Path(f).stem.rsplit("_seed", 1)[0], []).append(f)
    if not by_setting:
        parser.error(f"no saved heaps in {args.folder} (run baxter_readings.py with its summary's command)")
    heaps = {w: {pathlib.Path(f).stem: heap_contrast(f, args.cell) for f in files} for w, files in by_setting.items()}
    command = "python benchmarks/studies/papers/baxter_banding.py " + " ".join(sys.argv[1:] if argv is None else argv)
    out = {"command": command, "cell": args.cell, "looser": LOOSER,
           "settings": {w: {"heaps": len(h), "std": mean_stderr([v["std"] for v in h.values()]),
                            "looser_share": mean_stderr([v["looser_share"] for v in h.values()]),
                            "median": mean_stderr([v["median"] for v in h.values()])} for w, h in heaps.items()},
           "heaps": heaps}
    for w, s in out["settings"].items():
        print(f"{w:22s} {s['heaps']} heaps: std {s['std']['mean']:.4f} +- {s['std']['stderr']:.4f}, looser share "
              f"{s['looser_share']['mean']:.3f} +- {s['looser_share']['stderr']:.3f}")
    target = args.out or f"{args.folder}/banding.json"
    pathlib.Path(target).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
