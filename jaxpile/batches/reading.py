"""What a batch of piles reads of each protocol, keyed by the protocol's name:
the columns of a member's sweep row, the columns a sweep summarises and draws,
where a member's base profile is read for a fit, and how members share a
compiled loop. `sweeps` and the ensemble fits read it; a protocol module holds
its physics alone.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from jaxpile.errors import InputError
from jaxpile.measure.cone_heap import ROW_COLUMNS as CONE_ROW_COLUMNS
from jaxpile.measure.cone_heap import sweep_row as cone_row
from jaxpile.measure.poured_heap import ROW_COLUMNS as POUR_ROW_COLUMNS
from jaxpile.measure.poured_heap import sweep_row as pour_row
from jaxpile.measure.sloped_pile import COMPARED as SLOPED_COMPARED
from jaxpile.measure.theory import marginal_stability_overlay
from jaxpile.protocols import drop, lattice
from jaxpile.protocols.geometry import bottom_row_extent, heap_extent
from jaxpile.protocols.loaded_pile import OWN_COLUMNS


@dataclass(frozen=True)
class Batch:
    """What a sweep and an ensemble fit read of a protocol besides the run itself.

    Attributes:
      row: the keys of the protocol's measurements a sweep row carries, or
        `measured -> row`.
      angles: the columns to summarise and plot (the first is the headline).
      row_columns: with a computed `row`, the keys that row always holds, so an
        ensemble fit refuses an unknown statistic before a pile runs.
      unit: of the `angles` columns ("deg", "" for plain numbers).
      theory: optional `(name, values) -> (label, values)` overlaid on the sweep's figure.
      extent: optional `setup -> (base, x_left, x_right)`: where a member's
        base profile is read for fitting; the same for every member of one set-up.
      fit_statistics: what an ensemble fit compares by default:
        `{"columns": (...), "bins": b}`.
      readings: the column a measured quantity is compared with, by the name
        a measurement file gives it (`fit.measured.READINGS`): e.g.
        `{"angle_of_repose": "repose_mean"}`.
      deterministic: every seed builds the same pile: one seed is an ensemble.
      simulator_options: the options the simulator depends on (None: all);
        members whose options differ only in others share one compiled batch.
      sequential: a batch's members advance one after another on one CPU
        device (`engine.ensemble.Ensemble`): where they act out of phase
        (heaps poured or fed a disk at a time, silos discharging), so that
        side by side every member would rebuild its list, or run a driver's
        branch, whenever any member needs to (docs/choices.md).
    """

    row: tuple | Callable
    angles: tuple
    row_columns: tuple | None = None
    unit: str = "deg"
    theory: Callable | None = None
    extent: Callable | None = None
    fit_statistics: dict = field(default_factory=dict)
    readings: dict = field(default_factory=dict)
    deterministic: bool = False
    simulator_options: frozenset | None = None
    sequential: bool = False

    def member_row(self, measured: dict) -> dict:
        """One member's sweep row from its measurements."""
        return self.row(measured) if callable(self.row) else {k: measured[k] for k in self.row}

    def columns(self) -> frozenset | None:
        """A row's columns where they are known before a pile runs (None: a
        computed row that declares no `row_columns`)."""
        if not callable(self.row):
            return frozenset(self.row)
        return None if self.row_columns is None else frozenset(self.row_columns)


def _loaded(compared: tuple, angles: tuple) -> Batch:
    """The 1992 loaded piles (lattice, sloped): deterministic, read along the bottom row."""
    return Batch(row=(*compared, *OWN_COLUMNS), angles=angles, unit="", extent=bottom_row_extent,
                 fit_statistics={"bins": 9}, deterministic=True)


BATCHES: dict[str, Batch] = {
    "lattice": _loaded(lattice.COMPARED, ("max_rel_dev_normal", "max_rel_dev_horizontal")),
    "sloped": _loaded(SLOPED_COMPARED, ("central_normal_rel_dev", "central_slope_horizontal")),
    "drop": Batch(
        row=drop.row, row_columns=drop.ROW_COLUMNS, angles=("central_dip",), unit="",
        extent=heap_extent("ground", "axis_x", "n_particles"), fit_statistics={"columns": ("central_dip",), "bins": 9},
        simulator_options=frozenset({"drop_height", "settle_speed", "quiet_time", "max_interval", "diameter",
                                     "hard_collisions"})),
    "box": Batch(
        row=("repose_endpoints", "repose_least_squares", "repose_cumulative_parabola", "at_rest", "wall_removed_step",
             "settled_step", "n_left", "fill_height"),
        angles=("repose_cumulative_parabola", "repose_least_squares", "repose_endpoints"),
        readings={"angle_of_repose": "repose_cumulative_parabola"},
        theory=marginal_stability_overlay, extent=lambda p: ("ground", 0.0, float(p.info["width"])),
        fit_statistics={"columns": ("repose_least_squares", "repose_cumulative_parabola")},
        simulator_options=frozenset()),  # the simulator reads no option: set-ups share a compile
    "tilt": Batch(
        row=("theta_t", "theta_r", "moved", "theta_r_plus_theta_t", "theta_ms_theory", "theta_t_theory", "box_settled",
             "tilt_held", "n_left"),
        angles=("theta_t", "theta_r", "theta_r_plus_theta_t"), theory=marginal_stability_overlay,
        fit_statistics={"columns": ("theta_t", "theta_r")}, readings={"angle_of_repose": "theta_r"},
        simulator_options=frozenset()),  # the simulator reads no option: set-ups share a compile
    "flux": Batch(
        row=("inserted", "steady_mean", "steady_std", "steady_max", "repose_cumulative_parabola", "at_rest",
             "settled_step", "n_left"),
        angles=("steady_mean", "repose_cumulative_parabola"), theory=marginal_stability_overlay,
        fit_statistics={"columns": ("steady_mean",)}, readings={"angle_of_repose": "steady_mean"},
        # the simulator reads no option: set-ups share a compile; piles fed out of phase
        simulator_options=frozenset(), sequential=True),
    "pour": Batch(
        row=pour_row, row_columns=POUR_ROW_COLUMNS, angles=("repose_mean", "angle_height_base"),
        theory=marginal_stability_overlay, extent=heap_extent("substrate", "centre_x", "n_poured"),
        fit_statistics={"columns": ("repose_mean",), "bins": 9},
        readings={"angle_of_repose": "repose_mean", "packing_fraction": "core_packing_fraction"},
        simulator_options=frozenset(), sequential=True),
    "cone": Batch(
        row=cone_row, row_columns=CONE_ROW_COLUMNS, angles=("angle", "angle_height_base", "central_dip"),
        fit_statistics={"columns": ("angle", "central_dip")},
        readings={"angle_of_repose": "angle", "packing_fraction": "packing_fraction"},
        simulator_options=frozenset(), sequential=True),
    "lift": Batch(
        row=cone_row, row_columns=CONE_ROW_COLUMNS, angles=("angle", "angle_height_base"),
        fit_statistics={"columns": ("angle",)}, readings={"angle_of_repose": "angle"},
        simulator_options=frozenset(), sequential=True),
    "hopper": Batch(
        row=("flow_rate", "beverloo_c", "discharged", "remaining", "clogged", "at_rest", "number_density",
             "dead_zone_angle", "dead_zone_left", "dead_zone_right"),
        angles=("flow_rate", "beverloo_c"), unit="disks / time", fit_statistics={"columns": ("flow_rate",)},
        readings={"flow_rate": "flow_rate"},
        # one simulator for every set-up: orifices share a compile; silos discharge out of phase
        simulator_options=frozenset(), sequential=True),
}


def batch_of(protocol) -> Batch:
    """What a batch reads of `protocol` (a name, or a spec by its name)."""
    name = getattr(protocol, "name", protocol)
    if name not in BATCHES:
        raise InputError(f"the {name} protocol declares no batch (jaxpile.batches.BATCHES): it runs one pile at a "
                         f"time; batched: {', '.join(BATCHES)}.")
    return BATCHES[name]


__all__ = ["BATCHES", "Batch", "batch_of"]
