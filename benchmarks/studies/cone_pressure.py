"""The cone's radial base pressure p(r), ensemble by ensemble: the mean over
heaps with its standard-error band, against r / R, from the `pressure_*`
columns of `jaxpile sweep --protocol cone` (p at r = 0.05 R .. 0.95 R, over
the mean pressure; `jaxpile.measure.cone_heap.PRESSURE_AT`).

Smid & Novosad's dip would show as p below its ring maximum at small r / R; a
hydrostatic cone (p proportional to the height above, h = H (1 - r / R)) is
drawn for comparison: p / mean = 3 (1 - r / R).

    python benchmarks/studies/cone_pressure.py SWEEP_FOLDER [...] [--by mu_roll] [--figure FILE]

Prints each setting's profile (mean +- s.e.) and writes the figure.
"""

from __future__ import annotations

import argparse
import csv
import math
import pathlib

import numpy as np

from jaxpile.measure.cone_heap import PRESSURE_AT, PRESSURE_COLUMNS


def profiles(folders, by: str) -> dict[float, np.ndarray]:
    """`{setting: [heaps, 10]}` p(r / R) of every heap in the folders' sweep.csv, by the column `by`."""
    out: dict[float, list] = {}
    for folder in folders:
        path = pathlib.Path(folder) / "sweep.csv"
        with open(path) as f:
            rows = list(csv.DictReader(f))
        missing = [c for c in (by, *PRESSURE_COLUMNS) if rows and c not in rows[0]]
        if missing:
            raise SystemExit(f"{path} has no column(s) {missing}: a sweep from before the cone's rows held p(r), "
                             "or another protocol's.")
        for row in rows:
            out.setdefault(float(row[by]), []).append([float(row[c]) for c in PRESSURE_COLUMNS])
    return {k: np.asarray(v, float) for k, v in sorted(out.items())}


def mean_and_error(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error over heaps, ring by ring (heaps with NaN left out of that ring)."""
    count = np.sum(np.isfinite(p), axis=0)
    mean = np.nanmean(p, axis=0)
    spread = np.nanstd(p, axis=0, ddof=1) if p.shape[0] > 1 else np.full(p.shape[1], np.nan)
    return mean, spread / np.sqrt(np.maximum(count, 1))


def figure(curves: dict[float, np.ndarray], by: str, path: str, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.asarray(PRESSURE_AT)
    fig, ax = plt.subplots(figsize=(5.2, 3.6), dpi=110)
    for setting, p in curves.items():
        mean, error = mean_and_error(p)
        line, = ax.plot(x, mean, marker="o", ms=3, label=f"{by} = {setting:g} ({p.shape[0]} heaps)")
        ax.fill_between(x, mean - error, mean + error, color=line.get_color(), alpha=0.25, lw=0)
    ax.plot(x, 3.0 * (1.0 - x), "k--", lw=1, label="hydrostatic cone, 3 (1 - r/R)")
    ax.set_xlabel("r / R")
    ax.set_ylabel("p(r) / mean pressure")
    ax.set_xlim(0, 1)
    ax.set_ylim(bottom=0)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, frameon=False)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", help="jaxpile sweep --protocol cone output folders")
    parser.add_argument("--by", default="mu_roll", help="the varied column the curves are drawn by")
    parser.add_argument("--figure", default=None, help="PNG to write (default: FOLDER/pressure.png of the first)")
    parser.add_argument("--title", default="cone base pressure, mean and standard error over heaps")
    args = parser.parse_args(argv)
    curves = profiles(args.folders, args.by)
    for setting, p in curves.items():
        mean, error = mean_and_error(p)
        text = ", ".join(f"{m:.2f}±{e:.2f}" if math.isfinite(m) else "-" for m, e in zip(mean, error))
        print(f"{args.by} = {setting:g} ({p.shape[0]} heaps): p at r/R = 0.05..0.95: {text}")
    path = args.figure or str(pathlib.Path(args.folders[0]) / "pressure.png")
    figure(curves, args.by, path, args.title)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
