"""Figures a person would rather look at than read: the pile with its force
network, and base-force profiles with the papers' theory overlaid."""

from __future__ import annotations

import textwrap

# No backend is forced here, so notebooks draw inline; the CLI picks the
# file-only Agg backend itself, and matplotlib falls back to it without a display.
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import EllipseCollection, LineCollection


def pile_figure(position, radius, network=None, *, active=None, title: str = "", path=None, max_width: float = 4.0,
                length_unit: str = "diameters"):
    """Disks, with each disk-disk contact drawn as a line between centres whose
    width (and colour) is the normal force; spheres (`[n, 3]`) as
    `spheres_figure` draws them.

    Args:
      position: `[n, 2]`; radius: `[n]`.
      network: optional `analysis.ContactNetwork` (forces in mg).
      active: `[n]` bool, default all.
      length_unit: the axes' unit label.
    """
    position, radius = np.asarray(position), np.asarray(radius)
    if position.shape[1] == 3:  # spheres: from the side and from above
        return spheres_figure(position, radius, active=active, title=title, path=path, length_unit=length_unit)
    active = np.ones(len(radius), bool) if active is None else np.asarray(active)
    pos, rad = position[active], radius[active]
    width = np.ptp(pos[:, 0]) + 2 * rad.max()
    height = np.ptp(pos[:, 1]) + 2 * rad.max()
    fig_w = 10.0
    fig, ax = plt.subplots(figsize=(fig_w, max(3.0, fig_w * height / max(width, 1e-9)) + 0.6))
    ax.add_collection(EllipseCollection(2 * rad, 2 * rad, 0.0, units="xy", offsets=pos, offset_transform=ax.transData,
                                        facecolors="#e8e2d0", edgecolors="#9a927c", linewidths=0.3))
    if network is not None and len(network.i):
        f = np.abs(np.asarray(network.normal))
        segments = np.stack([position[network.i], position[network.j]], axis=1)
        scale = f / f.max() if f.max() > 0 else f
        lines = LineCollection(segments, linewidths=0.2 + max_width * scale, cmap="inferno_r", array=f)
        ax.add_collection(lines)
        fig.colorbar(lines, ax=ax, label="contact normal force (mg)", shrink=0.7)
    ax.set_xlim(pos[:, 0].min() - rad.max(), pos[:, 0].max() + rad.max())
    ax.set_ylim(min(0.0, pos[:, 1].min() - rad.max()), pos[:, 1].max() + rad.max())
    ax.axhline(0.0, color="k", lw=1)
    ax.set_aspect("equal")
    ax.set_xlabel(f"x ({length_unit})")
    ax.set_ylabel(f"y ({length_unit})")
    if title:
        ax.set_title(_wrapped(title))
    fig.tight_layout()
    return _finish(fig, path)


def spheres_figure(position, radius, *, active=None, title: str = "", path=None, length_unit: str = "diameters"):
    """Spheres seen from the side (x, z; the nearer drawn over the farther,
    shaded by depth) and from above (x, y, coloured by height): a heap as a
    person looks at it."""
    position, radius = np.asarray(position), np.asarray(radius)
    active = np.ones(len(radius), bool) if active is None else np.asarray(active)
    pos, rad = position[active], radius[active]
    fig, (side, above) = plt.subplots(1, 2, figsize=(12.0, 5.2))
    order = np.argsort(pos[:, 1])[::-1]  # the farthest (largest y) first, the nearest on top
    depth = (pos[order, 1] - pos[:, 1].min()) / max(np.ptp(pos[:, 1]), 1e-9)
    side.add_collection(EllipseCollection(2 * rad[order], 2 * rad[order], 0.0, units="xy", offsets=pos[order][:, [0, 2]],
                                          offset_transform=side.transData, array=depth, cmap="Greys", clim=(-0.6, 1.4),
                                          edgecolors="#6b6455", linewidths=0.2))
    high = np.argsort(pos[:, 2])  # the highest drawn last
    dots = above.add_collection(EllipseCollection(2 * rad[high], 2 * rad[high], 0.0, units="xy",
                                                  offsets=pos[high][:, :2], offset_transform=above.transData,
                                                  array=pos[high, 2], cmap="viridis", edgecolors="none"))
    fig.colorbar(dots, ax=above, label=f"height z ({length_unit})", shrink=0.8)
    reach = rad.max()
    for ax, (a, b), labels in ((side, (0, 2), ("x", "z")), (above, (0, 1), ("x", "y"))):
        ax.set_xlim(pos[:, a].min() - reach, pos[:, a].max() + reach)
        ax.set_ylim(pos[:, b].min() - reach, pos[:, b].max() + reach)
        ax.set_aspect("equal")
        ax.set_xlabel(f"{labels[0]} ({length_unit})")
        ax.set_ylabel(f"{labels[1]} ({length_unit})")
    side.set_title("from the side")
    above.set_title("from above")
    if title:
        fig.suptitle(_wrapped(title))
    fig.tight_layout()
    return _finish(fig, path)


def base_profile_figure(x, normal, horizontal, *, theory_normal=None, theory_horizontal=None, title: str = "", path=None):
    """Normal and horizontal base forces against x / B (B the base width), with
    theory curves (arrays on the same x) when given."""
    x = np.asarray(x)
    span = np.ptp(x) if len(x) > 1 else 1.0  # (no contacts: empty panels, not a crash)
    u = (x - x.min()) / span if len(x) and span > 0 else np.zeros_like(x)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, sim, th, label in (
        (axes[0], normal, theory_normal, "ground normal force N (mg)"),
        (axes[1], horizontal, theory_horizontal, "horizontal force on ground H (mg)"),
    ):
        ax.plot(u, sim, "o", ms=4, mfc="none", label="jaxpile")
        if th is not None:
            ax.plot(u, th, "-", color="C3", lw=1.5, label="theory")
        ax.set_xlabel("x / B")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend()
    if title:
        fig.suptitle(_wrapped(title))
    fig.tight_layout()
    return _finish(fig, path)


def series_figure(x, series: dict, *, xlabel: str, ylabel: str, title: str = "", logy: bool = False,
                  hlines: dict | None = None, path=None):
    """One or more named series against a common x (e.g. the kinetic energy per
    disk against time, Lee & Herrmann 1993 Fig. 1(b); the pile angle before each
    insertion, Fig. 5), with optional labelled horizontal reference lines."""
    x = np.asarray(x, dtype=float)
    fig, ax = plt.subplots(figsize=(8, 4))
    for label, y in series.items():
        ax.plot(x, np.asarray(y, dtype=float), "-o" if len(x) < 60 else "-", ms=3, lw=1, label=label)
    for k, (label, value) in enumerate((hlines or {}).items()):
        if value is not None and np.isfinite(value):
            ax.axhline(value, ls="--", lw=1, color=f"C{k + len(series)}", label=label)
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(_wrapped(title))
    fig.tight_layout()
    return _finish(fig, path)


def sweep_figure(series: dict, xlabel: str, *, theory=None, ylabel: str = "angle (degrees)", title: str = "",
                 path=None):
    """Mean +- standard error of each named quantity against a swept parameter,
    with an optional theory curve.

    Args:
      series: name -> `jaxpile.summarise` dict (`x`, `mean`, `stderr`, `count`).
      theory: optional `(x, label, y)`.
    """
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for k, (name, s) in enumerate(series.items()):
        x, m = np.asarray(s["x"], float), np.asarray(s["mean"], float)
        e = np.nan_to_num(np.asarray(s["stderr"], float))
        ax.errorbar(x + 0.004 * k * (np.ptp(x) or 1.0), m, yerr=e, fmt="o-", ms=4, lw=1, capsize=3,
                    label=f"{name} (mean +- s.e., n = {min(s['count']) if s['count'] else 0}"
                          f"{'-' + str(max(s['count'])) if s['count'] and max(s['count']) != min(s['count']) else ''})")
    if theory is not None:
        tx, label, ty = theory
        ax.plot(tx, ty, "k--", lw=1, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(_wrapped(title), fontsize=10)
    fig.tight_layout()
    return _finish(fig, path)


def _wrapped(title: str, width: int = 90) -> str:
    """A title on lines of at most `width` characters (a LAMMPS line as the
    law's name runs past the figure's edge)."""
    return "\n".join(textwrap.wrap(title, width)) or title


def _finish(fig, path):
    if path is not None:
        fig.savefig(path, dpi=130)
        plt.close(fig)
        return path
    return fig
