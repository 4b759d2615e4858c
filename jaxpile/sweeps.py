"""Parameter sweeps over seeds as a study: run (`sweep`, the batch runner
`jaxpile.batches.sweep`), summarised per grid point (`summarise`: mean and
standard error), written and read back as a tidy CSV with its record
(`write_csv`, `read`: what `jaxpile show` redraws from) and drawn (`figure`).

`sweep("box", "lee-herrmann", vary={"mu": [0.1, 0.2]}, seeds=16)` runs one
box per seed for every mu, batched; `summarise(result, "mu",
"repose_cumulative_parabola")` gives the angle's mean and standard error at
each mu.

Protocols (every registered `ProtocolSpec`, `jaxpile.protocols.PROTOCOLS`):
`box` (Lee & Herrmann 1993: angle of repose by the
three methods), `pour` (Baxter et al. 1997: flank angles, base-force M
ratio, force balance), `lattice` and `sloped` (Liffman et al. 1992: the
ground forces against eqs. 42-44 and 54-59, e.g. against K_s) and `drop`
(1992 Fig. 20: the base profile's central dip over seeds) and `flux`
(1993 Fig. 5: the steady angle under a flux of disks) and `tilt` (1993
Fig. 4: a box pile, then tilted until it moves: theta_T; two stages, each
member starting the second where it ended the first) and `hopper` (a silo's
flow rate, Beverloo's law).
"""

from __future__ import annotations

import math

import numpy as np

from jaxpile.batches import SweepResult, batch_of, sweep
from jaxpile.errors import InputError


def summarise(result: SweepResult, by: str, value: str) -> dict:
    """Mean, standard error and count of `value` at each value of `by` (NaNs,
    e.g. unmeasurable surfaces, left out and counted in `missing`)."""
    x, y = result.column(by), result.column(value)
    out = {"x": [], "mean": [], "stderr": [], "count": [], "missing": []}
    for v in sorted(set(x[np.isfinite(x)].tolist())):
        sel = y[x == v]
        ok = sel[np.isfinite(sel)]
        out["x"].append(v)
        out["mean"].append(float(ok.mean()) if ok.size else math.nan)
        out["stderr"].append(float(ok.std(ddof=1) / math.sqrt(ok.size)) if ok.size > 1 else math.nan)
        out["count"].append(int(ok.size))
        out["missing"].append(int(sel.size - ok.size))
    return out


def write_csv(path, result: SweepResult) -> None:
    """The rows as a tidy CSV (one row per member, one column per quantity)."""
    import csv

    columns = []
    for row in result.rows:
        for key in row:
            if key not in columns:
                columns.append(key)
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        for row in result.rows:
            writer.writerow({k: row.get(k, "") for k in columns})


def _cell(text: str):
    """A CSV cell as written by `write_csv`: a number, a bool, empty (None) or text."""
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    try:
        number = float(text)
    except ValueError:
        return text
    return int(number) if number.is_integer() and "." not in text and "e" not in text.lower() else number


def read(folder) -> SweepResult:
    """The `SweepResult` of a `jaxpile sweep` folder, from its `sweep.csv` and
    `sweep.json` (what `jaxpile show` redraws from)."""
    import csv
    import os

    paths = [os.path.join(folder, name) for name in ("sweep.csv", "sweep.json")]
    missing = [p for p in paths if not os.path.exists(p)]
    if missing:
        raise InputError(f"{folder} is not a finished `jaxpile sweep` folder ({', '.join(missing)} missing).")
    with open(paths[0], newline="") as fh:
        rows = [{k: _cell(v) for k, v in row.items()} for row in csv.DictReader(fh)]
    from jaxpile import io

    info = io.read_json(paths[1], "a sweep's sweep.json")
    need = ("protocol", "law", "vary", "angles", "members", "seeds")  # what `figure` and `show` read
    if not isinstance(info, dict) or any(k not in info for k in need):
        raise InputError(f"{paths[1]} is not a sweep's record: `jaxpile sweep` writes one holding "
                         f"{', '.join(need)}.")
    return SweepResult(rows, info)


def figure(result: SweepResult, by: str | None = None, path=None):
    """Mean +- standard error of the protocol's angles against the varied
    parameter `by` (default: the first varied one), with the theory overlaid
    where there is one (theta_MS = arctan 3 mu for friction)."""
    from jaxpile import plot

    by = by or next(iter(result.info["vary"]), None)
    if by is None:
        raise InputError("the sweep varied no parameter: nothing to plot against.")
    series = {name: summarise(result, by, name) for name in result.info["angles"]}
    batch = batch_of(result.info["protocol"])
    x = result.column(by)
    theory_x = np.linspace(np.nanmin(x), np.nanmax(x), 50)
    theory = batch.theory(by, theory_x) if batch.theory else None
    title = (f"{result.info['protocol']} / {result.info['law']}: {result.info['members']} members, "
             f"{len(result.info['seeds'])} seeds each")
    # the columns are angles (unit "deg") or plain numbers (unit "": the drop's central dip, a lattice's height)
    ylabel = ("angle (degrees)" if batch.unit == "deg" else
              ", ".join(series) + (f" ({batch.unit})" if batch.unit else ""))
    return plot.sweep_figure(series, by, theory=None if theory is None else (theory_x, *theory), title=title,
                             ylabel=ylabel, path=path)


__all__ = ["SweepResult", "figure", "read", "summarise", "sweep", "write_csv"]
