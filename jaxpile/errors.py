"""Errors jaxpile raises: one clear message that names the input and the fix."""

from __future__ import annotations


class InputError(ValueError):
    """A bad input: a non-positive radius, mu < 0, a time step above the stability limit..."""


class SimulationError(RuntimeError):
    """A run went wrong (NaN/inf appeared). `last_good_state` holds the state at the
    last chunk boundary that was still finite, and `step` the step of the failure chunk."""

    def __init__(self, message: str, last_good_state=None, step: int | None = None):
        super().__init__(message)
        self.last_good_state = last_good_state
        self.step = step
