"""The 1997 heap as an ensemble, in each reading of the paper and each of its
settings: poured heaps over seeds, with the angle of repose and the M depth per
heap and their mean +- standard error.

Settings (`--settings`, comma-separated; see SETTINGS):
- the readings of Baxter et al.'s printed equations, options of
  `jaxpile.laws.baxter.law` (see its docstring): `contact-point/hold` (the
  default law), `centre-distance/hold` (eqs. 6 and 13 as printed),
  `contact-point/accumulate`, `centre-distance/accumulate` (delta_F past delta_max),
  `disk-damping-mass` (the printed m in the damping against the fixed substrate);
- the paper's other heaps, in the default reading: `n144-r1.047`, `n144-r1.2`,
  `hooke-k500` (the equivalent Hooke law, Fig. 5), `poly5`, `poly10`
  (polydisperse, Fig. 8), `mu0.2`, `mu0.6`;
- the row's length, which the paper does not print: `row35`, `row30`, rows
  just long enough for a heap of the n disks at 35 / 30 deg, which a flatter
  heap spills over (the default row holds a 15 deg heap and 5 sigma more);
- the row's spacing S (the paper's 1.1 sigma): `S1.0`, `S1.05`, `S1.2`, `S1.3`;
- a flat floor instead of the row (sec. II): `flat-smooth` (wall_mu = 0), `flat-rough`.
The paper: angle of repose 35 +- 5 deg (1334 disks; 31 deg for n = 36 beside
35 deg for n = 144, 1000 disks), base force M-shaped with flank maxima 20-30%
above the centre for n = 36, r0 = 1.2; no clear M for n = 144 short tail and
Hooke; polydisperse heaps flatter; insensitive to mu in 0.2-0.6.

Each (setting, seed) heap is one job whose result is written to
`<out>/n<N>/<setting>_seed<k>.json` as soon as it finishes, its state saved
beside it (`.npz`: every `--checkpoint-every` steps while it runs, the final
state at the end). A rerun skips the jobs already done and resumes a heap in
progress from its last saved state, so a long study continues where it stopped.
Those per-heap files are the study's workings and are not committed: what is
committed is `<out>/n<N>/summary.json`, each setting's mean +- standard error
with the command that made it and every heap's row (`heaps`, written as each
heap finishes, `keep_heaps`), which the papers table and the figures read. Rerunning the committed commands costs about 2.3 h
(n = 300), 18 h (n = 1000) and 3.5 h (n = 1334) of one CPU core.
`--workers 2` runs two heaps at once (one pile keeps about one core busy).
On a GPU, run many at once (`--workers 16` on a 16-core host: measured on one
H100, 12-16 heaps of 1000 disks side by side each ran ~2,400 steps/s, the GPU
~3 % busy). `--batched` pours each group of settings that share a law and pour
options as one batched ensemble instead (`heap_batch`); on 2 CPU cores that is
~1.7x slower per heap than one heap per process (the vmapped step), and on
the H100, before ensembles ran on the poured disks only (commit 74df37c), a
batch of 16 such heaps did not reach 100,000 steps in 7 minutes: measure it
again before relying on it.

    python benchmarks/studies/papers/baxter_readings.py [--n 300] [--seeds 4] [--settings contact-point/hold,centre-distance/hold]
        [--workers 2] [--checkpoint-every 200000] [--out benchmarks/results/baxter_readings]

The angle of each heap is the mean of its two flanks, by five measures:
`mid_flank` (a line through the flank's columns between 20% and 80% of the apex
height, `analysis.mid_flank_angle`), Lee & Herrmann 1993's three methods over
the whole flank (`analysis.repose_angles`), and atan(2 h / B) from the heap's
height and base.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import glob
import json
import math
import os
import pathlib
import sys
import time

_DEFAULT = {"law": "baxter", "params": {}, "pour": {}, "dt": None, "row_angle": None,
            "law_options": {"lever_arm": "contact-point", "slip": "hold", "damping_mass": "pair"}}
SETTINGS = {
    "contact-point/hold": {},
    "centre-distance/hold": {"law_options": {"lever_arm": "centre-distance", "slip": "hold"}},
    "contact-point/accumulate": {"law_options": {"lever_arm": "contact-point", "slip": "accumulate"}},
    "centre-distance/accumulate": {"law_options": {"lever_arm": "centre-distance", "slip": "accumulate"}},
    "disk-damping-mass": {"law_options": {"lever_arm": "contact-point", "slip": "hold", "damping_mass": "disk"}},
    # n = 144 is 4x stiffer at contact: the paper's "typically 0.001" is above the leapfrog's limit
    # (6.9e-4, the check in `Simulator`), so these heaps run at half of it
    "n144-r1.047": {"params": {"n": 144.0, "r0": 1.047}, "dt": 5.0e-4},
    "n144-r1.2": {"params": {"n": 144.0, "r0": 1.2}, "dt": 5.0e-4},
    "hooke-k500": {"law": "hooke", "law_options": {}},  # pour.PAPER_SETTING's hooke: k = 500
    "poly5": {"pour": {"polydispersity": 0.05}},
    "poly10": {"pour": {"polydispersity": 0.10}},
    "mu0.2": {"params": {"mu": 0.2}},
    "mu0.6": {"params": {"mu": 0.6}},
    # Smid-Novosad's dip against the law (issue 17): n's tail either side of the paper's 36, and mu beyond it
    "n12": {"params": {"n": 12.0}},
    "n24": {"params": {"n": 24.0}},
    "n72": {"params": {"n": 72.0}},
    "mu0.8": {"params": {"mu": 0.8}},
    # the row's length is not printed: rows just long enough for a heap of the n disks at 35 / 30 deg
    # (no margin), which a flatter heap spills over (disks past an end are lost)
    "row35": {"row_angle": 35.0},
    "row30": {"row_angle": 30.0},
    # the substrate's spacing S (sec. III: the angle falls as S grows, a plateau for S >= 1.1 sigma)
    "S1.0": {"pour": {"spacing": 1.0}},
    "S1.05": {"pour": {"spacing": 1.05}},
    "S1.2": {"pour": {"spacing": 1.2}},
    "S1.3": {"pour": {"spacing": 1.3}},
    # sec. II: on "a flat smooth structureless surface" no stable heap formed: the ground wall under the row's
    # span, smooth (wall_mu = 0) and rough (wall_mu = mu); 500 time units after the pour to come to rest
    "flat-smooth": {"pour": {"floor": "flat", "max_settle_steps": 500_000}, "params": {"wall_mu": 0.0}},
    "flat-rough": {"pour": {"floor": "flat", "max_settle_steps": 500_000}},
}
READINGS = tuple(SETTINGS)[:5]
ANGLE_METHODS = ("mid_flank", "endpoints", "least_squares", "cumulative_parabola")


def setting_of(name: str) -> dict:
    return {**_DEFAULT, **SETTINGS[name]}


def one_heap(setting: str, seed: int, n: int, out: str, insert_height: float | None,
             checkpoint_every: int = 200_000) -> dict:
    """Pours one heap in `setting` and writes its measurements to `out`."""
    import jaxpile
    jaxpile.configure()  # float64 and the commands' XLA settings
    from jaxpile.measure import heap, poured_heap
    from jaxpile.protocols import pour

    spec = setting_of(setting)
    if insert_height is None:
        insert_height = heap.steepest_heap_height(n) + 6.0
    state_file = out.replace(".json", ".npz")  # checkpoints during the run, the final state after it
    resume = state_file if os.path.exists(state_file) else None
    t0 = time.perf_counter()
    dt = {} if spec["dt"] is None else {"dt": spec["dt"]}
    if spec["row_angle"] is not None:
        spacing = spec["pour"].get("spacing", pour.PAPER_SETTING["spacing"])
        spec["pour"] = {**spec["pour"], "substrate_disks": heap.substrate_size(n, spacing, spec["row_angle"], margin=0.0)}
    _, result = pour.SPEC.run(spec["law"], n, seed=seed, insert_height=insert_height, params=spec["params"] or None,
                              **dt, law_options=spec["law_options"], progress=False,
                              checkpoint=(state_file, checkpoint_every), resume=resume, **spec["pour"])
    run = {"steps": result["steps"], "at_rest": result["at_rest"], "max_speed": result["final_max_speed"],
           **{k: result[k] for k in ("wall_seconds", "compile_seconds", "total_seconds", "neighbor_reallocations")}}
    setup = {k: v for k, v in result["info"].items() if k != "law_options"}
    row = {"setting": setting, "seed": seed, "n": n, "insert_height": insert_height,
           "seconds": time.perf_counter() - t0, **poured_heap.summary(result), "run": run, "setup": setup,
           "device": device()}
    pathlib.Path(out).write_text(json.dumps(row, indent=1))
    return row


def device() -> str:
    """What ran a heap (a row's `device`): platform, device kind, jax version."""
    import jax

    d = jax.devices()[0]
    return f"{d.platform}: {d.device_kind}, jax {jax.__version__}"


def groups(settings: list[str]) -> list[list[str]]:
    """The settings that can share one batch: the same law, law options and pour
    options (they may differ in law parameters, each member its own)."""
    out: dict[str, list[str]] = {}
    for name in settings:
        spec = setting_of(name)
        key = json.dumps([spec["law"], spec["law_options"], spec["pour"], spec["dt"], spec["row_angle"]], sort_keys=True)
        out.setdefault(key, []).append(name)
    return list(out.values())


def heap_batch(settings: list[str], seeds: list[int], n: int, folder: str, insert_height: float | None,
               checkpoint_every: int = 200_000) -> list[dict]:
    """Pours the heaps of `settings` (one of `groups`) for `seeds` as one batched
    `Ensemble` (`jaxpile.sweeps`, one compiled call for every member: what a GPU
    runs fast) and writes each heap's row as `one_heap` does. The batch saves
    itself every `checkpoint_every` steps and a rerun resumes it. Each member
    runs until the whole batch is poured and at rest (a heap at rest stays so)."""
    import jaxpile
    jaxpile.configure()  # float64 and the commands' XLA settings
    from jaxpile import sweeps
    from jaxpile.measure import heap, poured_heap
    from jaxpile.protocols import pour
    from jaxpile.engine import max_speed

    specs = [setting_of(name) for name in settings]
    if len(groups(settings)) != 1:
        raise ValueError(f"{settings} differ in law or pour options: one batch each (see `groups`)")
    law, law_options, pour_options, dt = (specs[0][k] for k in ("law", "law_options", "pour", "dt"))
    if law_options not in ({}, _DEFAULT["law_options"]):
        raise ValueError(f"{settings}: a batch runs the law's default reading; run the others with --workers")
    if specs[0]["row_angle"] is not None:
        raise ValueError(f"{settings}: a batch pours on the default row; run the row settings with --workers")
    if insert_height is None:
        insert_height = heap.steepest_heap_height(n) + 6.0
    tolerance = pour.PAPER_SETTING["speed_tolerance"]
    stem = os.path.join(folder, f"batch_{'+'.join(s.replace('/', '_') for s in settings)}_seeds"
                                f"{'-'.join(map(str, seeds))}")
    state_file = stem + ".npz"
    resume = state_file if os.path.exists(state_file) else None

    def extra(sim, params, state, protocol):
        return {"summary": poured_heap.summary(poured_heap.measure(sim, params, state)), "max_speed": float(max_speed(state)),
                "setup": dict(protocol.info)}

    t0 = time.perf_counter()
    result = sweeps.sweep("pour", law, points=[dict(spec["params"]) for spec in specs], seeds=list(seeds),
                         options={"n": n, "insert_height": insert_height, **pour_options}, dt=dt,
                         checkpoint=(state_file, checkpoint_every), resume=resume, extra_measure=extra)
    seconds = time.perf_counter() - t0
    written = []
    for k, member in enumerate(result.rows):
        setting, seed = settings[k // len(seeds)], int(member["seed"])
        run = {"steps": member["steps"], "at_rest": member["max_speed"] < tolerance, "max_speed": member["max_speed"],
               "batch_members": result.info["members"], "batch_steps": result.info["batch_steps"],
               "wall_seconds": result.info["run_seconds"], "compile_seconds": result.info["compile_seconds"],
               "device": device()}
        row = {"setting": setting, "seed": seed, "n": n, "insert_height": insert_height, "seconds": seconds,
               **member["summary"], "run": run, "setup": member["setup"]}
        path = os.path.join(folder, f"{setting.replace('/', '_')}_seed{seed}.json")
        if not os.path.exists(path):  # a heap already poured one at a time keeps its row
            pathlib.Path(path).write_text(json.dumps(row, indent=1, default=float))
            written.append(row)
    if os.path.exists(state_file):
        os.remove(state_file)  # the rows are written: the batch is done
    return written


def name_of(row: dict) -> str:
    return row.get("setting", row.get("reading"))  # rows written before the settings were "readings"


def angle(row: dict, method: str) -> float | None:
    """Both flanks' mean angle by `method`, or None if a flank was not measured."""
    if method == "mid_flank":
        values = [v for v in (row.get("angle_mid_flank") or {}).values() if v is not None]
        return sum(values) / len(values) if len(values) == 2 else None
    flanks = row.get("angle_of_repose") or {}
    values = [flanks[f][method] for f in ("left", "right") if flanks.get(f)]
    return sum(values) / len(values) if len(values) == 2 else None


def _profile(row: dict):
    """The row's base profile (summary.json form) with the `BaseProfile` fields
    `jaxpile.measure.heap` reads, or None."""
    from types import SimpleNamespace

    profile = row.get("base_profile")
    if not profile:
        return None
    return SimpleNamespace(x_over_b=profile["x_over_b"], normalised=profile["normalised"],
                           force=profile.get("force_mg"))


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def flank_over_centre(row: dict) -> float | None:
    """The M depth without selection bias (`jaxpile.measure.heap.flank_over_centre`):
    the mean normalised base force in fixed flank windows (x/B in 0.2-0.4 and
    0.6-0.8) over its mean in the centre window (0.4-0.6). The M ratio of
    `heap.m_shape` divides the largest of ~10 noisy flank bins by one central
    bin, which noise alone pushes above 1."""
    from jaxpile.measure import heap

    profile = _profile(row)
    return None if profile is None else _finite_or_none(heap.flank_over_centre(profile))


def central_dip(row: dict) -> float | None:
    """Smid & Novosad's reading, as the dropped pile's (`jaxpile.measure.heap.central_dip`):
    1 - the central bin over the lower of the two flank maxima (0.2-0.3 reported;
    <= 0 when the centre carries the most). Like the M ratio, it takes maxima of
    noisy bins, so noise alone pushes it up: `flank_over_centre` is the unbiased
    comparison."""
    from jaxpile.measure import heap

    profile = _profile(row)
    return None if profile is None or profile.force is None else _finite_or_none(heap.central_dip(profile))


def mean_stderr(values) -> dict:
    values = [v for v in values if v is not None and math.isfinite(v)]
    k = len(values)
    if k == 0:
        return {"mean": None, "stderr": None, "count": 0}
    mean = sum(values) / k
    spread = math.sqrt(sum((v - mean) ** 2 for v in values) / (k - 1)) if k > 1 else float("nan")
    return {"mean": mean, "stderr": spread / math.sqrt(k) if k > 1 else None, "count": k}


def _one(value) -> str:
    """A progress line's angle: one decimal, or "—" for a heap with none (no heap formed)."""
    return "—" if value is None else f"{value:.1f}"


def summarise(rows: list[dict]) -> dict:
    out = {}
    for name in dict.fromkeys(name_of(r) for r in rows):
        mine = [r for r in rows if name_of(r) == name]
        out[name] = {
            "heaps": len(mine),
            "angle": {m: mean_stderr([angle(r, m) for r in mine]) for m in ANGLE_METHODS},
            "angle_height_base": mean_stderr([r.get("angle_height_base") for r in mine]),
            "m_ratio": mean_stderr([(r.get("m_shape") or {}).get("ratio") for r in mine]),
            "flank_over_centre": mean_stderr([flank_over_centre(r) for r in mine]),
            "central_dip": mean_stderr([central_dip(r) for r in mine]),
            "m_shaped": sum(bool((r.get("m_shape") or {}).get("m_shaped")) for r in mine),
            "lost": mean_stderr([r["counts"]["lost"] for r in mine]),
            "at_rest": sum(bool(r["run"]["at_rest"]) for r in mine),
        }
    return out


def figure(rows: list[dict], path: str, title: str) -> None:
    """Each setting's base profile (every heap thin, the mean with its standard
    error shaded; x/B on a common grid) and each heap's two flank angles
    against the paper's 35 +- 5 deg."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(dict.fromkeys(name_of(r) for r in rows))
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    grid = np.linspace(0.02, 0.98, 25)
    for k, name in enumerate(names):
        colour = f"C{k}"
        mine = [r for r in rows if name_of(r) == name and r.get("base_profile")]
        curves = np.array([np.interp(grid, r["base_profile"]["x_over_b"], r["base_profile"]["normalised"])
                           for r in mine])
        for c in curves:
            left.plot(grid, c, color=colour, lw=0.5, alpha=0.4)
        if len(curves):
            mean = curves.mean(0)
            err = curves.std(0, ddof=1) / np.sqrt(len(curves)) if len(curves) > 1 else 0 * mean
            left.plot(grid, mean, color=colour, lw=2, label=f"{name} ({len(curves)} heaps)")
            left.fill_between(grid, mean - err, mean + err, color=colour, alpha=0.25)
        for j, r in enumerate(rows_of(rows, name)):
            flanks = r.get("angle_mid_flank") or {}
            x = k + 0.8 * (j + 0.5) / max(1, len(rows_of(rows, name))) - 0.4
            for side, marker in (("left", "<"), ("right", ">")):
                if flanks.get(side) is not None:
                    right.plot(x, flanks[side], marker, color=colour)
            ls = angle(r, "least_squares")
            if ls is not None:
                right.plot(x, ls, "o", color=colour, mfc="none")
    left.set_xlabel("x / B")
    left.set_ylabel("base normal force / max")
    left.set_title("base normal force (mean +- s.e.)")
    left.legend(fontsize=8)
    right.axhspan(30, 40, color="0.85", label="paper: 35 +- 5 deg")
    right.set_xticks(range(len(names)), names, fontsize=8)
    right.set_ylabel("angle (deg)")
    right.set_title("each heap: mid-flank < left, > right flank; o: least squares")
    right.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def study_rows(folder, entry: str, key, pattern: str) -> list[dict]:
    """A study's rows in `folder`: its committed summary.json's `entry` list, with
    any row whose own file (`pattern`: a run in progress) is there read from
    that file instead; one row per `key(row)`, sorted by it."""
    folder = pathlib.Path(folder)
    summary_file = folder / "summary.json"
    rows = {}
    if summary_file.exists():
        for row in json.loads(summary_file.read_text()).get(entry, []):
            rows[key(row)] = row
    for path in folder.glob(pattern):
        row = json.loads(path.read_text())
        rows[key(row)] = row
    return [rows[k] for k in sorted(rows)]


def heap_rows(folder) -> list[dict]:
    """Every heap's row in `folder` (one heap size): the committed summary's
    `heaps` and any heap's own file (`study_rows`), by setting, then seed."""
    return study_rows(folder, "heaps", lambda row: (name_of(row), row["seed"]), "*_seed*.json")


def saved_heap_arguments(parser, out_name: str) -> None:
    """The flags of a study that reads the saved heaps of one setting: --folder, --setting, --out."""
    parser.add_argument("--folder", default="benchmarks/results/baxter_readings/n1334")
    parser.add_argument("--setting", default="contact-point/hold", help="a setting (or its file prefix)")
    parser.add_argument("--out", default=None, help=f"JSON (default: <folder>/{out_name}_<setting>.json)")


def saved_heaps(folder, setting: str) -> list[str]:
    """The saved end states of `setting`'s heaps in `folder` (`<setting>_seed<k>.npz`, "/" as "_")."""
    return sorted(glob.glob(f"{folder}/{setting.replace('/', '_')}_seed*.npz"))


def write_summary(path, out: dict) -> None:
    """A heap size's summary.json: its settings' table indented to read, each
    heap's row on one line (the rows' profiles would otherwise take a line a number)."""
    heaps = out.get("heaps", [])
    head = json.dumps({k: v for k, v in out.items() if k != "heaps"}, indent=1)
    rows = ",\n".join("  " + json.dumps(row, separators=(",", ":")) for row in heaps)
    pathlib.Path(path).write_text(head[:-2] + (',\n "heaps": [\n' + rows + "\n ]\n}" if heaps else "\n}") + "\n")


def keep_heaps(folder) -> int:
    """Writes every finished heap's row in `folder` into its summary.json
    (`heaps`), so that a study stopped before its end keeps what it has done
    in the one committed file (the per-heap files are not committed). Returns
    the number of heaps kept."""
    folder = pathlib.Path(folder)
    summary_file = folder / "summary.json"
    out = json.loads(summary_file.read_text()) if summary_file.exists() else {"n": None, "settings": {}}
    out["heaps"] = heap_rows(folder)
    if out["n"] is None and out["heaps"]:
        out["n"] = out["heaps"][0]["n"]
    write_summary(summary_file, out)
    return len(out["heaps"])


def rows_of(rows: list[dict], name: str) -> list[dict]:
    return [r for r in rows if name_of(r) == name]


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300, help="disks per heap (the paper: 1334)")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--settings", "--readings", dest="settings", default="contact-point/hold",
                        help=f"comma-separated, from {list(SETTINGS)}")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--batched", action="store_true",
                        help="each group of settings (same law and pour options) as one batched ensemble of all "
                             "its missing heaps (meant for a GPU; measured slow there so far: see the module notes)")
    parser.add_argument("--checkpoint-every", type=int, default=200_000,
                        help="steps between saved states of a heap in progress (a rerun resumes from them)")
    parser.add_argument("--insert-height", type=float, default=None,
                        help="where disks appear, moving at their free-fall speed from 100 sigma (default: "
                             "6 sigma above a 45-degree heap; the paper's 100 sigma costs 14000 steps a disk)")
    parser.add_argument("--out", default=str(pathlib.Path(__file__).resolve().parents[2] / "results" / "baxter_readings"))
    parser.add_argument("--figure", default=None, help="also draw the profiles and angles to this PNG")
    args = parser.parse_args(argv)
    settings = args.settings.split(",")
    unknown = set(settings) - set(SETTINGS)
    if unknown:
        parser.error(f"unknown setting(s) {sorted(unknown)}; known: {list(SETTINGS)}")
    folder = pathlib.Path(args.out) / f"n{args.n}"
    folder.mkdir(parents=True, exist_ok=True)

    # seed by seed across the settings: a study stopped early has the same number of heaps in each
    jobs = [(r, s, str(folder / f"{r.replace('/', '_')}_seed{s}.json")) for s in range(args.seeds) for r in settings]
    done = {(name_of(row), row["seed"]) for row in heap_rows(folder)}
    todo = [j for j in jobs if (j[0], j[1]) not in done]
    print(f"{len(jobs)} heaps of {args.n} disks, {len(jobs) - len(todo)} already done; results in {folder}")
    if args.batched:
        batches = []
        for group in groups(settings):
            seeds = sorted({s for r, s, _ in todo if r in group})
            if seeds:
                batches.append((group, seeds))
        with concurrent.futures.ProcessPoolExecutor(max_workers=args.workers) as pool:
            futures = [pool.submit(heap_batch, group, seeds, args.n, str(folder), args.insert_height,
                                   args.checkpoint_every) for group, seeds in batches]
            for future in concurrent.futures.as_completed(futures):
                for row in future.result():
                    keep_heaps(folder)
                    print(f"  {name_of(row):28s} seed {row['seed']}: mid flank {angle(row, 'mid_flank')}, "
                          f"atan(2h/B) {_one(row.get('angle_height_base'))}, at rest {row['run']['at_rest']}, "
                          f"batch of {row['run']['batch_members']}: {row['seconds']:.0f} s", flush=True)
        todo = []
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = {pool.submit(one_heap, r, s, args.n, path, args.insert_height, args.checkpoint_every): (r, s) for r, s, path in todo}
        for future in concurrent.futures.as_completed(futures):
            row = future.result()
            keep_heaps(folder)  # a study stopped early keeps the heaps it finished
            print(f"  {name_of(row):28s} seed {row['seed']}: angle (least squares) "
                  f"{_one(angle(row, 'least_squares'))}, mid flank {angle(row, 'mid_flank')}, "
                  f"atan(2h/B) {_one(row.get('angle_height_base'))}, M ratio {(row.get('m_shape') or {}).get('ratio')}, "
                  f"lost {row['counts']['lost']}, {row['seconds']:.0f} s", flush=True)

    every = heap_rows(folder)
    wanted = {(r, s) for r, s, _ in jobs}
    rows = [row for row in every if (name_of(row), row["seed"]) in wanted]
    table = summarise(rows)
    print(f"\n{'setting':28s} {'heaps':>5s} {'mid flank':>12s} {'endpoints':>12s} {'least sq.':>12s} {'cum. parab.':>12s} "
          f"{'atan(2h/B)':>12s} {'M ratio':>12s} {'flank/centre':>12s} {'central dip':>12s}")
    fmt = lambda s: "—" if s["mean"] is None else f"{s['mean']:.1f}±{(s['stderr'] or float('nan')):.1f}"
    fmt2 = lambda s: "—" if s["mean"] is None else f"{s['mean']:.2f}±{(s['stderr'] or float('nan')):.2f}"
    for reading, t in table.items():
        print(f"{reading:28s} {t['heaps']:5d} " + " ".join(f"{fmt(t['angle'][m]):>12s}" for m in ANGLE_METHODS)
              + f" {fmt(t['angle_height_base']):>12s} {fmt2(t['m_ratio']):>12s} {fmt2(t['flank_over_centre']):>12s}"
              + f" {fmt2(t['central_dip']):>12s}")
    command = "python benchmarks/studies/papers/baxter_readings.py " + " ".join(argv if argv is not None else sys.argv[1:])
    for entry in table.values():
        entry["command"] = command
    # one summary per heap size, each setting's entry from the last command that covered it
    summary_file = folder / "summary.json"
    out = json.loads(summary_file.read_text()) if summary_file.exists() else {"n": args.n, "settings": {}}
    out["settings"].update(table)
    out["heaps"] = every
    write_summary(summary_file, out)
    if args.figure:
        figure(rows, args.figure, f"Baxter et al. 1997 heaps of {args.n} disks, poured onto S = 1.1 sigma")
        print(f"figure: {args.figure}")
    return out


if __name__ == "__main__":
    main()
