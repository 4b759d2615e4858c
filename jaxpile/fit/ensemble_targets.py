"""What an ensemble fit matches: ensemble means of per-pile statistics with
the spread of one pile about them, made from piles at known parameters
(`make_target`), read back from a fit's files, or declared (Smid & Novosad's
central dip)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxpile.errors import InputError
from jaxpile.fit.ensemble_runs import Runner, Statistics, fill_missing
from jaxpile.fit.targets import SMID_NOVOSAD_DIP_RANGE


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
    """

    labels: list
    mean: np.ndarray
    spread: np.ndarray
    members: np.ndarray | None
    source: str
    truth: dict | None = None
    seeds: list | None = None
    setting: dict | None = None

    def to_json(self) -> dict:
        return {"labels": list(self.labels), "mean": self.mean.tolist(), "spread": self.spread.tolist(),
                "members": None if self.members is None else self.members.tolist(), "source": self.source,
                "truth": self.truth, "seeds": self.seeds, "setting": self.setting}

    @classmethod
    def from_json(cls, record: dict, where: str = "the record") -> "EnsembleTarget":
        need = ("labels", "mean", "spread")
        if not isinstance(record, dict) or any(k not in record for k in need):
            raise InputError(f"{where} is not an ensemble target: a target holds {', '.join(need)} (the "
                             "target.json a fit writes, or its fit.json).")
        members = record.get("members")
        return cls(list(record["labels"]), np.asarray(record["mean"], float), np.asarray(record["spread"], float),
                   None if members is None else np.asarray(members, float), record.get("source", ""),
                   record.get("truth"), record.get("seeds"), record.get("setting"))


def make_target(runner: Runner, truth: dict, seeds, statistics: Statistics, progress=None) -> EnsembleTarget:
    """A synthetic target: the ensemble of `seeds` at the law parameters
    `truth` (use seeds the fit never sees)."""
    s, _ = runner.run([truth], seeds, statistics, progress=progress)
    s, _ = fill_missing(s)
    members = s[0]
    spread = members.std(axis=0, ddof=1) if members.shape[0] > 1 else np.ones(members.shape[1])
    return EnsembleTarget(statistics.labels(), members.mean(axis=0), spread, members,
                          f"{runner.protocol} ensemble of {len(members)} at {truth}", dict(truth),
                          [int(x) for x in seeds], runner.setting())


def smid_novosad_target() -> EnsembleTarget:
    """Smid & Novosad's central dip as an ensemble target: the per-pile
    column `central_dip` (1 - the central bin over the lower flank maximum,
    `jaxpile.measure.heap.central_dip`; the drop and the pour measure it) at
    0.25, the middle of the reported 0.20-0.30 (`fit.SMID_NOVOSAD_DIP_RANGE`),
    with half that range, 0.05, as its spread. A declared value, not piles: no
    members, no seeds, no setting (any protocol that measures the column may be
    fitted to it). With one statistic the spread only scales the loss."""
    low, high = SMID_NOVOSAD_DIP_RANGE
    return EnsembleTarget(["central_dip"], np.asarray([0.5 * (low + high)]), np.asarray([0.5 * (high - low)]), None,
                          f"Smid & Novosad's central dip, {low:.2f}-{high:.2f} below the maximum (Liffman et al. "
                          "1992, Introduction)")

