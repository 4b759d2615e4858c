"""What an ensemble fit matches: ensemble means of per-pile statistics with
the spread of one pile about them, made from piles at known parameters
(`make_target`), read back from a fit's files, or declared (Smid & Novosad's
central dip)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxpile.errors import InputError
from jaxpile.fit.ensemble_runs import Runner, Statistics, fill_missing, run_saved
from jaxpile.fit.targets import SMID_NOVOSAD_ANGLE_DEGREES, SMID_NOVOSAD_DIP_RANGE


class EnsembleTarget(NamedTuple):
    """The target of a fit: ensemble means of `Statistics` with the spread of
    one pile about them.

    Attributes:
      labels: `[k]` what each statistic is.
      mean: `[k]` the target values.
      spread: `[k]` the standard deviation of one pile's statistic (weights).
      members: `[B_t, k]` the target's own piles (its sampling error enters
        the confidence interval), or None.
      source: where it came from.
      truth: the law parameters it was made with (a synthetic target), or None.
      seeds: the seeds of its piles (a fit must use others), or None.
      setting: the protocol, law, options and fixed parameters it was made
        with (a fit of another set-up is refused), or None (from data).
      error: `[k]` the standard error of each target value itself (a
        measurement's; NaN: to be taken as one pile's spread at the fit's
        start), or None (the members carry it, or a declared value has none).
    """

    labels: list
    mean: np.ndarray
    spread: np.ndarray
    members: np.ndarray | None
    source: str
    truth: dict | None = None
    seeds: list | None = None
    setting: dict | None = None
    error: np.ndarray | None = None

    def to_json(self) -> dict:
        return {"labels": list(self.labels), "mean": self.mean.tolist(), "spread": self.spread.tolist(),
                "members": None if self.members is None else self.members.tolist(), "source": self.source,
                "truth": self.truth, "seeds": self.seeds, "setting": self.setting,
                **({} if self.error is None else {"error": self.error.tolist()})}

    @classmethod
    def from_json(cls, record: dict, where: str = "the record") -> "EnsembleTarget":
        need = ("labels", "mean", "spread")
        if not isinstance(record, dict) or any(k not in record for k in need):
            raise InputError(f"{where} is not an ensemble target: a target holds {', '.join(need)} (the "
                             "target.json a fit writes, or its fit.json).")
        members, error = record.get("members"), record.get("error")
        return cls(list(record["labels"]), np.asarray(record["mean"], float), np.asarray(record["spread"], float),
                   None if members is None else np.asarray(members, float), record.get("source", ""),
                   record.get("truth"), record.get("seeds"), record.get("setting"),
                   None if error is None else np.asarray(error, float))


def make_target(runner: Runner, truth: dict, seeds, statistics: Statistics, progress=None,
                batch_checkpoint=None) -> EnsembleTarget:
    """A synthetic target: the ensemble of `seeds` at the law parameters
    `truth` (use seeds the fit never sees); its batch saved and continued as
    `ensemble_runs.run_saved` does with `batch_checkpoint`."""
    s, _ = run_saved(runner, [truth], seeds, statistics, batch_checkpoint, progress=progress)
    s, _ = fill_missing(s)
    members = s[0]
    spread = members.std(axis=0, ddof=1) if members.shape[0] > 1 else np.ones(members.shape[1])
    return EnsembleTarget(statistics.labels(), members.mean(axis=0), spread, members,
                          f"{runner.protocol} ensemble of {len(members)} at {truth}", dict(truth),
                          [int(x) for x in seeds], runner.setting())


SMID_NOVOSAD_ANGLE_SPREAD_DEGREES = 1.0
"""The declared angle's weight: one degree off counts as much as a dip 0.05 off
(a quarter to a third of one poured heap's scatter in each, docs/rolling_resistance.md)."""


def smid_novosad_target(labels=("central_dip",)) -> EnsembleTarget:
    """Smid & Novosad's pile as an ensemble target of declared values (not
    piles: no members, no seeds, no setting; any protocol that measures the
    columns may be fitted to it), one per label:

    - `central_dip` (1 - the central bin over the lower flank maximum,
      `jaxpile.measure.heap.central_dip`; the drop and the pour measure it) at
      0.25, the middle of the reported 0.20-0.30 (`fit.SMID_NOVOSAD_DIP_RANGE`),
      with half that range, 0.05, as its spread;
    - `dip_below_flanks` (1 - the centre over the flanks in fixed narrow
      windows, `jaxpile.measure.heap.dip_below_flanks`; the pour measures it on
      heaps whose base is at least 15 substrate spacings) at the same 0.25 with
      the same spread: the reading that does not average a narrow dip away;
    - `repose_mean` (the pour's angle of repose, degrees) at the reported 32.6
      (`fit.SMID_NOVOSAD_ANGLE_DEGREES`), spread `SMID_NOVOSAD_ANGLE_SPREAD_DEGREES`;
    - `angle` (the cone's angle of repose from its azimuthally averaged
      surface, degrees, `jaxpile.measure.cone_heap`) at the same 32.6 and spread:
      the heap Smid & Novosad measured was such a cone.

    With one statistic the spread only scales the loss; with both it weighs
    the angle against the dip."""
    low, high = SMID_NOVOSAD_DIP_RANGE
    declared = {
        "central_dip": (0.5 * (low + high), 0.5 * (high - low),
                        f"central dip, {low:.2f}-{high:.2f} below the maximum", "Introduction"),
        "dip_below_flanks": (0.5 * (low + high), 0.5 * (high - low),
                             f"centre {low:.2f}-{high:.2f} below the flanks", "Introduction"),
        "repose_mean": (SMID_NOVOSAD_ANGLE_DEGREES, SMID_NOVOSAD_ANGLE_SPREAD_DEGREES,
                        f"angle of repose, {SMID_NOVOSAD_ANGLE_DEGREES} deg", "text of Fig. 17"),
        "angle": (SMID_NOVOSAD_ANGLE_DEGREES, SMID_NOVOSAD_ANGLE_SPREAD_DEGREES,
                  f"cone's angle of repose, {SMID_NOVOSAD_ANGLE_DEGREES} deg", "text of Fig. 17"),
    }
    labels = list(labels)
    unknown = [lab for lab in labels if lab not in declared]
    if not labels or unknown or len(set(labels)) != len(labels):
        raise InputError(f"Smid & Novosad's pile declares {', '.join(declared)} (each once); got {labels}: "
                         "choose among them (--statistics dip_below_flanks,repose_mean).")
    return EnsembleTarget(labels, np.asarray([declared[lab][0] for lab in labels], float),
                          np.asarray([declared[lab][1] for lab in labels], float), None,
                          f"Smid & Novosad's {' and '.join(declared[lab][2] for lab in labels)} (Liffman et al. "
                          f"1992, {'; '.join(declared[lab][3] for lab in labels)})")
