"""Statistics an ensemble fit and its inverse regression share: the weight of
each fitted statistic and the confidence quantile of an interval."""

from __future__ import annotations

import math

import numpy as np


def unit_groups(labels) -> list[np.ndarray]:
    """Indices of the statistics that share a unit: each column alone, the
    normal profile's bins, the horizontal profile's bins."""
    labels = list(labels)
    groups = {}
    for i, label in enumerate(labels):
        key = label.split("[")[0] if label.endswith("]") else label
        groups.setdefault(key, []).append(i)
    return [np.asarray(g) for g in groups.values()]


def weights(target, floor: float = 0.01) -> np.ndarray:
    """`[k]` 1 / spread^2 of each statistic, in its own units. Within a group
    of one unit (the bins of a profile) the spread is held at least
    sqrt(floor) x the group's largest: a bin outside every pile has no spread
    and must not weigh infinitely. A statistic with no spread at all (one
    pile, or a deterministic protocol) weighs 1."""
    spread2 = np.nan_to_num(np.asarray(target.spread, float) ** 2, nan=0.0)
    w = np.ones_like(spread2)
    for g in unit_groups(target.labels):
        top = spread2[g].max()
        if top > 0:
            w[g] = 1.0 / np.maximum(spread2[g], floor * top)
    return w


def t_quantile(dof: float) -> float:
    """The two-sided 95 % Student-t quantile (1.96 for many degrees of freedom)."""
    from scipy import stats

    if dof == math.inf:  # errors taken as known: the normal quantile
        return float(stats.norm.ppf(0.975))
    return float(stats.t.ppf(0.975, dof)) if math.isfinite(dof) and dof > 0 else float("nan")
