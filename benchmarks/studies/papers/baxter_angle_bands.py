"""Where on its flank a 1997 heap would stand at the paper's 35 deg: the angle of
the saved heaps measured in other height bands, and flank by flank.

Baxter et al. give "the angle between the inclined surface and the base" and
no method. `baxter_readings.py` fits a line through the flank's columns between
20% and 80% of the apex height (`analysis.mid_flank_angle`). This reads the
final states those runs saved (`<folder>/<setting>_seed<k>.npz`) and measures
the same line over other bands (the toe half, the upper half, the middle), and
the steeper and the shallower flank of each heap apart: whether any reasonable
way of reading the angle off our heaps reaches 35 +- 5 deg. No simulation;
seconds. The saved states are a run's workings, not committed: rerun
`baxter_readings.py` with the summary's command to have them (about 3.5 h of
one core for the eight 1334-disk heaps); its result here is committed.

    python benchmarks/studies/papers/baxter_angle_bands.py [--folder benchmarks/results/baxter_readings/n1334]
        [--setting contact-point_hold] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from jaxpile.engine.checkpoint import read_leaves
from jaxpile.measure import analysis

BANDS = {"0.2-0.8": (0.2, 0.8), "0.1-0.5": (0.1, 0.5), "0.3-0.7": (0.3, 0.7), "0.5-0.9": (0.5, 0.9)}
"""Height bands (fractions of the apex height); 0.2-0.8 is `baxter_readings.py`'s `mid_flank`."""


def heap_angles(path: str) -> dict:
    """Each band's angle of both flanks of one saved heap: {band: [left, right]} (None: too few columns)."""
    s = read_leaves(path)
    pos, rad = s[".particles.position"], s[".particles.radius"]
    poured = s[".particles.active"] & ~s[".particles.fixed"]
    row = int(s[".protocol_state.first"])  # the substrate: disks 0 .. row-1
    base_y, spacing = float(pos[0, 1]), float(pos[1, 0] - pos[0, 0])
    surface = analysis.surface_profile(pos[poured], rad[poured], x_min=float(pos[0, 0]),
                                       width=float(pos[row - 1, 0] - pos[0, 0]), column_width=spacing)
    apex = analysis.apex_x(surface)
    return {name: [analysis.mid_flank_angle(surface, flank=flank, base=base_y, band=band, apex=apex)
                   for flank in ("left", "right")] for name, band in BANDS.items()}


def mean_se(values) -> dict:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    se = float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else float("nan")
    return {"mean": float(v.mean()), "se": se, "heaps": int(len(v))}


def main(argv=None) -> dict:
    from baxter_readings import saved_heap_arguments, saved_heaps

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    saved_heap_arguments(parser, "angle_bands")
    args = parser.parse_args(argv)
    import jaxpile

    jaxpile.configure()  # float64 and the commands' XLA settings

    setting = args.setting.replace("/", "_")  # the file prefix
    files = saved_heaps(args.folder, setting)
    if not files:
        parser.error(f"no saved heaps {args.folder}/{setting}_seed*.npz")
    heaps = {pathlib.Path(f).stem: heap_angles(f) for f in files}
    out = {"folder": args.folder, "setting": setting, "bands": {}, "heaps": heaps}
    for name in BANDS:
        both = [np.mean([a for a in h[name] if a is not None]) for h in heaps.values() if any(h[name])]
        out["bands"][name] = mean_se(both)
    main_band = [[a for a in h["0.2-0.8"] if a is not None] for h in heaps.values()]
    out["steeper_flank"] = mean_se([max(a) for a in main_band if a])
    out["shallower_flank"] = mean_se([min(a) for a in main_band if a])

    print(f"{len(files)} heaps in {args.folder} ({setting}); the paper: 35 +- 5 deg")
    for name, r in out["bands"].items():
        print(f"  band {name} of the apex height, both flanks: {r['mean']:.1f} +- {r['se']:.1f} deg")
    for key in ("steeper_flank", "shallower_flank"):
        r = out[key]
        print(f"  {key.replace('_', ' ')} (band 0.2-0.8): {r['mean']:.1f} +- {r['se']:.1f} deg")
    target = args.out or f"{args.folder}/angle_bands_{setting}.json"
    pathlib.Path(target).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
