"""How the ensembles of an ensemble fit are built (`Runner`: the protocol,
law and set-up, run through `batches.sweep`) and what each pile contributes to
it (`Statistics`: columns of the sweep's row, the base profile)."""

from __future__ import annotations

import json
import math
import os
import warnings
from typing import Callable, NamedTuple, Sequence

import numpy as np

from jaxpile import batches, budget
from jaxpile.batches import batch_of
from jaxpile.engine.checkpoint import Checkpoint
from jaxpile.errors import InputError
from jaxpile.fit.profiles import base_load, smooth_base_profile
from jaxpile.measure.base_reading import profile_at_points
from jaxpile.measure.forces import base_forces
from jaxpile.batches import MEMBER_COLUMNS


class Statistics(NamedTuple):
    """What each pile contributes to the fit.

    Attributes:
      columns: scalar columns of the protocol's sweep row (its spec's `row`
        of its measurement), e.g. `("repose_least_squares",)` or `("central_dip",)`.
      bins: > 0: the pile's base-force profile on this many bins across the
        protocol's fixed extent (`Batch.extent` of its spec), normal force over its peak
        (`fit.smooth_base_profile`); 0: no profile.
      horizontal: the horizontal profile as well (on the same scale).
      bandwidth: the profile's smoothing width (default one bin); with `at`,
        the reading's width in x/B.
      at: the x/B (of each pile's own base, foot to foot) where a measured
        profile was taken: the profile read there as `fit.measured.read_profile`
        reads it, instead of on `bins`.
      normalised_by: the scale of a profile read `at` points: `"max"` or `"weight"`.
    """

    columns: tuple = ()
    bins: int = 0
    horizontal: bool = True
    bandwidth: float | None = None
    at: tuple = ()
    normalised_by: str = "max"

    def labels(self) -> list[str]:
        labels = list(self.columns)
        if self.bins:
            labels += [f"normal[{i}]" for i in range(self.bins)]
            if self.horizontal:
                labels += [f"horizontal[{i}]" for i in range(self.bins)]
        if self.at:
            labels += [f"normal[x/B={u:g}]" for u in self.at]
            if self.horizontal:
                labels += [f"horizontal[x/B={u:g}]" for u in self.at]
        return labels


def _check_statistics(statistics: Statistics, spec) -> Statistics:
    if not isinstance(statistics, Statistics):
        raise InputError(f"statistics must be an ensemble_fit.Statistics; got {type(statistics).__name__}.")
    statistics = statistics._replace(columns=tuple(statistics.columns))
    if int(statistics.bins) != statistics.bins or statistics.bins < 0:
        raise InputError(f"bins must be a whole number >= 0; got {statistics.bins!r}.")
    if not statistics.columns and not statistics.bins and not statistics.at:
        raise InputError("a fit needs something to compare: name columns, or bins > 0 for the base profile.")
    statistics = statistics._replace(at=tuple(float(u) for u in statistics.at))
    if statistics.at:
        if statistics.bins:
            raise InputError("a profile is read on bins or at measured points (at), not both.")
        if not all(0 <= u <= 1 for u in statistics.at) or list(statistics.at) != sorted(set(statistics.at)):
            raise InputError(f"the measured points must be x/B in [0, 1], increasing; got {list(statistics.at)}.")
        if not (statistics.bandwidth is not None and 0 < statistics.bandwidth <= 0.5):
            raise InputError(f"a profile read at measured points needs a bandwidth in x/B in (0, 0.5]; got "
                             f"{statistics.bandwidth!r}.")
        if statistics.normalised_by not in ("max", "weight"):
            raise InputError(f"a profile is normalised by max or weight; got {statistics.normalised_by!r}.")
    if statistics.bins and batch_of(spec).extent is None:
        raise InputError("this protocol declares no base extent, so it cannot fit a base profile; fit columns.")
    columns = batch_of(spec).columns()
    if columns is not None:  # before a pile runs, where the protocol names its row (else after, per row)
        known = columns | set(MEMBER_COLUMNS)
        unknown = [c for c in statistics.columns if c not in known]
        if unknown:
            raise InputError(f"the protocol's measurement has no column {unknown[0]!r}; it has {sorted(known)}.")
    return statistics


def _profile_hook(spec, statistics: Statistics) -> Callable | None:
    if statistics.at:
        def measure_at(sim, params, state, protocol):
            try:
                normal, horizontal = profile_at_points(base_forces(sim, params, state), statistics.at,
                                                       bandwidth=statistics.bandwidth,
                                                       normalised_by=statistics.normalised_by,
                                                       horizontal=statistics.horizontal)
            except InputError:  # this pile has no base profile to read (two contacts or fewer): it is missing
                nan = np.full(len(statistics.at), np.nan)
                normal, horizontal = nan, (nan if statistics.horizontal else None)
            return {"_profile_normal": normal, **({} if horizontal is None else {"_profile_horizontal": horizontal})}

        return measure_at
    if not statistics.bins:
        return None

    def measure(sim, params, state, protocol):
        base, x_left, x_right = batch_of(spec).extent(protocol)
        load = base_load(sim, params, state, base=base)
        profile = smooth_base_profile(load, x_left=x_left, x_right=x_right, bins=int(statistics.bins),
                                      bandwidth=statistics.bandwidth)
        out = {"_profile_normal": np.asarray(profile.normal)}
        if statistics.horizontal:
            out["_profile_horizontal"] = np.asarray(profile.horizontal)
        return out

    return measure


def _row_statistics(row: dict, statistics: Statistics) -> np.ndarray:
    values = []
    for column in statistics.columns:
        if column not in row:
            raise InputError(f"the protocol's measurement has no column {column!r}; it has "
                             f"{sorted(k for k in row if not k.startswith('_'))}.")
        v = row[column]
        if v is not None and not isinstance(v, (int, float, np.number)):
            raise InputError(f"the column {column!r} is not a number per pile ({type(v).__name__}); fit a numeric one.")
        values.append(float(v) if v is not None else math.nan)
    if statistics.bins or statistics.at:
        values += list(row["_profile_normal"])
        if statistics.horizontal:
            values += list(row["_profile_horizontal"])
    return np.asarray(values, dtype=float)


class Runner(NamedTuple):
    """How the ensembles of a fit are built: everything `batches.sweep` takes
    except the parameter points and seeds."""

    protocol: str
    law: str | None = None
    params: dict | None = None
    options: dict | None = None
    dt: float | None = None
    max_steps: int | None = None
    batch_size: int | None = None
    dtype: object = None
    law_options: dict | None = None
    rotation: bool | None = None

    def spec(self):
        return batches.spec_of(self.protocol)

    def check(self, statistics: Statistics) -> Statistics:
        """The statistics, checked against what the protocol can measure."""
        return _check_statistics(statistics, self.spec())

    def law_name(self) -> str:
        return self.law or self.spec().default_law

    def setting(self) -> dict:
        """What a target made with this runner was made with (fixed law
        parameters other than the fitted ones are compared by name)."""
        made = {"protocol": self.protocol, "law": self.law_name(), "options": dict(self.options or {})}
        made = {**made, "law_options": dict(self.law_options)} if self.law_options else made
        return made if self.rotation is None else {**made, "rotation": bool(self.rotation)}

    def run(self, points: Sequence[dict], seeds, statistics: Statistics, progress=None, checkpoint=None,
            resume=None) -> tuple[np.ndarray, dict]:
        """`[len(points), B, k]` statistics (the B seeds at every point, one
        batched run) and the sweep's record (`n_particles`, `batch_steps`,
        `total_seconds` are used). `checkpoint`, `resume`: as `batches.sweep`'s
        (a long batch saved as it runs, and continued)."""
        spec = self.spec()
        statistics = _check_statistics(statistics, spec)
        seeds = [int(s) for s in seeds]
        if statistics.bins and seeds:  # each pile's profile is a [contacts, bins] array: refuse one too big first
            law = self.law_name()
            p = batches.first_setup(spec, law, seeds[0], self.dt or spec.default_dt(law), self.options or {}, self.dtype)
            budget.check_host(24.0 * int(statistics.bins) * int(p.particles.count),
                              f"the base profile on {int(statistics.bins):,} bins of a {int(p.particles.count):,}-disk "
                              "pile", "Give fewer --bins.")
        result = batches.sweep(self.protocol, self.law, points=list(points), seeds=seeds, params=self.params,
                             options=self.options, dt=self.dt, max_steps=self.max_steps,
                             batch_size=self.batch_size, progress=progress, dtype=self.dtype,
                             extra_measure=_profile_hook(spec, statistics), checkpoint=checkpoint, resume=resume,
                             law_options=self.law_options, rotation=self.rotation)
        rows = result.rows  # point-major: every seed of point 0, then of point 1, ...
        s = np.stack([_row_statistics(r, statistics) for r in rows]).reshape(len(points), len(seeds), -1)
        # the cost: the steps every pile ran (a batch also carries its finished piles, frozen)
        return s, {**result.info, "particle_steps": result.info["n_particles"] * sum(int(r["steps"]) for r in rows)}


def run_saved(runner, points: Sequence[dict], seeds, statistics: Statistics, batch_checkpoint=None,
              progress=None) -> tuple[np.ndarray, dict]:
    """`runner.run`, its batch saved to `batch_checkpoint` `(path, every)`
    every `every` steps as it runs (None: not saved), continued from a save
    left at `path` by this same batch, and the save removed once the batch is
    measured. A save of another batch (other points, seeds, set-up or batch
    size: a fit resumed with other settings) is removed with a warning, and
    the batch starts afresh."""
    if batch_checkpoint is None:
        return runner.run(points, seeds, statistics, progress=progress)
    path, every = str(batch_checkpoint[0]), int(batch_checkpoint[1])
    batch = json.loads(json.dumps({"points": list(points), "seeds": [int(x) for x in seeds],
                                   "statistics": statistics.labels(), "setting": runner.setting(),
                                   "params": runner.params, "batch_size": runner.batch_size, "every": every},
                                  default=float))
    resume = path if os.path.exists(path) else None

    def which(record):  # the batch a save holds; how often it was saved may change on resume
        return {k: v for k, v in (record or {}).items() if k != "every"}

    if resume is not None and which(saved_batch(path)) != which(batch):
        warnings.warn(f"{path} holds another batch of piles than this one (a fit resumed with other settings): "
                      "removed, and the batch starts afresh.", stacklevel=2)
        os.remove(path)
        resume = None
    out = runner.run(points, seeds, statistics, progress=progress, checkpoint=Checkpoint(path, every, {"fit_batch": batch}),
                     resume=resume)
    if os.path.exists(path):  # the batch is measured: the next one starts afresh
        os.remove(path)
    return out


def saved_batch(path: str) -> dict | None:
    """What `run_saved` recorded in the save at `path` (its points, seeds,
    set-up and `every`), or None for a file it did not write."""
    from jaxpile.engine import checkpoint

    try:
        return checkpoint.read_metadata(path)["extra"].get("fit_batch")
    except Exception:  # not a checkpoint, or damaged: not a batch of this fit
        return None


class MissingEverywhere(InputError):
    """A statistic no pile of an ensemble could give (`fill_missing`)."""


def fill_missing(s: np.ndarray, labels=None) -> tuple[np.ndarray, int]:
    """`[m, B, k]` statistics with the piles that could not give one (NaN: e.g.
    no surface to fit an angle to, a tilted pile that never moved) left out of
    that statistic at *every* point, so a difference between two points
    compares the same piles (common random numbers). They are left out by
    taking, at each point, the mean of the piles that gave the statistic at all
    points, which moves no mean (it narrows the spread a little: the count of
    such (pile, statistic) pairs is returned, to report). A statistic that
    no pile gives at some point raises `MissingEverywhere`, naming it
    (`labels`) and the point's index."""
    s = np.array(s, dtype=float)
    bad = np.isnan(s).any(axis=0)  # [B, k]: missing at some point
    missing = int(bad.sum())
    if missing:
        if bad.all(axis=0).any():
            k = int(np.flatnonzero(bad.all(axis=0))[0])
            point = int(np.flatnonzero(np.isnan(s[:, :, k]).all(axis=1))[0]) if np.isnan(s[:, :, k]).all(axis=1).any() \
                else None
            name = f"the statistic {labels[k]!r}" if labels is not None else "a statistic"
            error = MissingEverywhere(
                f"{name} is missing from every pile" + ("" if point is None else f" at point {point}")
                + " (e.g. no pile had a surface to measure, none moved, or the heaps were too narrow to read it); "
                "choose other statistics or a larger pile.")
            error.name, error.point = name, point
            raise error
        good = np.where(bad[None], np.nan, s)
        fill = np.nanmean(good, axis=1, keepdims=True)  # [m, 1, k]: the mean of the complete piles
        s = np.where(bad[None], np.broadcast_to(fill, s.shape), s)
    return s, missing


