"""Input checks the host-side measurements share: a pile's disks as numpy
arrays, and a positive number."""

from __future__ import annotations

import numpy as np

from jaxpile.errors import InputError


def disk_arrays(position, radius, active=None):
    """Checked `[n, 2]` positions, `[n]` radii and `[n]` active mask (float64 numpy)."""
    position = np.asarray(position, dtype=np.float64)
    if position.ndim != 2 or position.shape[1] != 2:
        raise InputError(f"position must have shape [n, 2]; got {position.shape}.")
    n = position.shape[0]
    if n == 0:
        raise InputError("no disks: position is empty.")
    radius = np.asarray(radius, dtype=np.float64)
    if radius.ndim > 1 or (radius.ndim == 1 and radius.shape[0] != n):
        raise InputError(f"radius must be a scalar or have one value per disk ({n}); got shape {radius.shape}.")
    radius = np.broadcast_to(radius, (n,))
    if not np.all(np.isfinite(position)) or not np.all(np.isfinite(radius)) or np.any(radius <= 0):
        raise InputError("positions must be finite and radii positive and finite.")
    active = np.ones(n, bool) if active is None else np.asarray(active, dtype=bool)
    if active.shape != (n,):
        raise InputError(f"active must have shape [{n}]; got {active.shape}.")
    return position, radius, active


def positive_number(name: str, value) -> float:
    value = float(value)
    if not (value > 0 and np.isfinite(value)):
        raise InputError(f"{name} must be positive and finite; got {value!r}.")
    return value


__all__ = ["disk_arrays", "positive_number"]
