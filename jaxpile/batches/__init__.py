"""Piles run in batches: what a batch reads of each protocol (`reading`:
`Batch`, `BATCHES`, `batch_of`) and the runner that runs a protocol over a
grid of members (`runs`: `sweep`, `plan`, `ensemble_for`). A sweep study
(`jaxpile.sweeps`) and an ensemble fit (`jaxpile.fit`) sit beside each other
above it."""

from jaxpile.batches.reading import BATCHES, Batch, batch_of
from jaxpile.batches.runs import (MEMBER_COLUMNS, Plan, SweepResult, ensemble_for, first_setup, grid, option_names,
                                  plan, spec_of, sweep)

__all__ = ["BATCHES", "Batch", "MEMBER_COLUMNS", "Plan", "SweepResult", "batch_of", "ensemble_for", "first_setup",
           "grid", "option_names", "plan", "spec_of", "sweep"]
