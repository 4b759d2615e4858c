"""Liffman, Chan & Hughes 1992, the results the table had no row for: the base
disks' sink (sec. 4), the lines of strongest and weakest force (Figs. 10, 16),
the 32.6 deg pile of Fig. 17, the tent piles (Figs. 18-19: analytic, and
built of disks) and the SLIP / NOSLIP collisions (eqs. 4-19). Every pile here is
deterministic (the paper's lattice and sloped piles: one pile is the ensemble).

    python benchmarks/studies/papers/liffman_networks.py     # ~20 s on 2 cores (a minute compiling afresh)

writes benchmarks/results/liffman_1992/networks.json (the command in it),
which `papers.py` reads for its 1992 rows, and docs/liffman1992_force_lines.png
drawn from it (`figure`).
"""

from __future__ import annotations

import math
import pathlib
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
OUT = HERE.parents[2] / "benchmarks" / "results" / "liffman_1992" / "networks.json"
COMMAND = "python benchmarks/studies/papers/liffman_networks.py"
TOLERANCE_DEGREES = 10.0
"""A contact line counts as horizontal, at pi/3 or at 2 pi/3 within this many degrees."""


def line_angles(position: np.ndarray, disk: np.ndarray, partner: np.ndarray) -> np.ndarray:
    """The angle of each line disk -> partner to the horizontal, in [0, 180) degrees."""
    d = position[partner] - position[disk]
    return np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180.0


def near(angles: np.ndarray, target: float) -> np.ndarray:
    return np.abs((angles - target + 90.0) % 180.0 - 90.0) < TOLERANCE_DEGREES


def force_lines(pile) -> dict:
    """Each disk's strongest and weakest disk contact (Figs. 10, 16: the paper's
    lines of maximum and minimum force): the share of those lines at pi/3 or 2
    pi/3 to the horizontal and horizontal, each half of the pile separately, and
    the largest force any horizontal pair carries."""
    from jaxpile import analysis

    state = pile.state
    chains = analysis.force_chains_of(pile.simulator, pile.params, state, min_force=1e-9)
    position = np.asarray(state.particles.position)
    n = position.shape[0]
    apex = float(position[np.argmax(position[:, 1]), 0])
    out = {"position": np.round(position, 5).tolist(), "radius": np.round(np.asarray(state.particles.radius), 5).tolist()}
    for which, partner in (("strongest", np.asarray(chains.strongest)), ("weakest", np.asarray(chains.weakest))):
        disk = np.flatnonzero((partner >= 0) & (partner < n))  # a disk partner (the ground's lines are vertical)
        angles = line_angles(position, disk, partner[disk])
        left, right = position[disk, 0] < apex - 0.25, position[disk, 0] > apex + 0.25
        out[which] = {
            "pairs": np.stack([disk, partner[disk]], axis=1).tolist(),  # for the figure
            "lines": int(disk.size),
            "at_60_or_120": float(np.mean(near(angles, 60.0) | near(angles, 120.0))),
            "horizontal": float(np.mean(near(angles, 0.0))),
            "left_at_60": float(np.mean(near(angles[left], 60.0))), "left_at_120": float(np.mean(near(angles[left], 120.0))),
            "right_at_60": float(np.mean(near(angles[right], 60.0))),
            "right_at_120": float(np.mean(near(angles[right], 120.0))),
        }
    network = analysis.contact_network(pile.simulator, pile.params, state)
    i, j = np.asarray(network.i), np.asarray(network.j)
    horizontal = near(line_angles(position, i, j), 0.0)
    force = np.hypot(np.asarray(network.normal), np.asarray(network.tangential))
    out["horizontal_pairs"] = int(horizontal.sum())
    out["largest_horizontal_force_mg"] = float(force[horizontal].max()) if horizontal.any() else 0.0
    out["mean_contact_force_mg"] = float(force.mean())
    return out


def lattice(layers: int = 45) -> dict:
    """The 45-layer equilateral pile with the paper's own law: its bottom row's
    sink into the ground against (k + 1)/2 mg / K_s (eqs. 42, 45-46: about
    2.3e-3 sigma) and its force lines (Fig. 10)."""
    import jaxpile as jp

    t0 = time.perf_counter()
    pile = jp.run("lattice", "liffman", layers)
    state = pile.state
    position, radius = np.asarray(state.particles.position), np.asarray(state.particles.radius)
    bottom = position[:, 1] < radius + 0.1
    sink = radius[bottom] - position[bottom, 1]  # the ground is y = 0
    gravity = float(np.linalg.norm(np.asarray(state.boundaries.gravity)))
    mass = float(np.asarray(state.particles.mass)[0])
    theory = 0.5 * (layers + 1) * mass * gravity / float(pile.params.ks)
    return {"layers": layers, "law": "liffman", "at_rest": bool(pile.measurements["at_rest"]),
            "bottom_disks": int(bottom.sum()), "max_sink_sigma": float(sink.max()), "centre_sink_sigma":
            float(sink[np.argmin(np.abs(position[bottom, 0] - np.median(position[bottom, 0])))]),
            "theory_max_sink_sigma": theory, "lines": force_lines(pile), "seconds": time.perf_counter() - t0}


def sloped(alpha: float, n: int = 360) -> dict:
    """The 1992 sloped pile at `alpha` (the protocol's default law, as the
    table's 360-disk piles): its comparison with eqs. 54-59 and its force lines."""
    import jaxpile as jp

    t0 = time.perf_counter()
    pile = jp.run("sloped", None, n, alpha_degrees=alpha)
    m = pile.measurements
    keys = ("n_particles", "at_rest", "central_normal_rel_dev", "central_normal_dip", "central_slope_horizontal",
            "theory_central_slope_horizontal", "central_slope_rel_dev", "law")
    return {"alpha_degrees": alpha, **{k: m[k] for k in keys}, "lines": force_lines(pile),
            "seconds": time.perf_counter() - t0}


def tents(base: float = 100.0, points: int = 401) -> dict:
    """Figs. 18-19 from the analytic construction: the tent of alpha1 = 30,
    alpha2 = 45 deg, X_1 = 0.38 B (a peaked top: the paper finds a central
    depression of N), and the flattened tent alpha1 = 45, alpha2 = 30 deg (no
    minimum)."""
    from jaxpile import theory

    x = np.linspace(0.0, base, points)
    out = {}
    for name, a1, a2 in (("peaked_30_45", 30.0, 45.0), ("flattened_45_30", 45.0, 30.0)):
        normal, horizontal = theory.tent_ground_forces(x, math.radians(a1), math.radians(a2), 0.38 * base, base)
        normal = np.asarray(normal)
        half = normal[: points // 2 + 1]  # the left half, up to the centre (the profile is symmetric)
        out[name] = {"alpha1": a1, "alpha2": a2, "knee_over_b": 0.38,
                     "central_dip": float(1.0 - normal[points // 2] / half.max()),  # 0 where the centre is the maximum
                     "x_over_b_of_max": float(x[np.argmax(half)] / base)}
    return out


def central_dip(x: np.ndarray, normal: np.ndarray, base: float, window: float = 0.1) -> dict:
    """A base profile's central dip: 1 - N at the centre over the largest N,
    each the mean over a window of `window` B (a dip > 0, a peak < 0)."""
    centres = np.linspace(0.5 * window, 1 - 0.5 * window, 19) * base
    means = np.array([normal[np.abs(x - c) <= 0.5 * window * base].mean() for c in centres])
    return {"central_dip": float(1.0 - means[len(centres) // 2] / means.max()),
            "x_over_b_of_max": float(centres[np.argmax(means)] / base)}


def tent_pile(n: int = 360) -> dict:
    """Fig. 19's tent (alpha1 = 30, alpha2 = 45 deg, X_1 = 0.38 B) built of
    close-packed disks (the sloped protocol with `top_alpha_degrees` and
    `knee`), loaded and relaxed: its base normal force's central dip against
    the analytic tent's at the same B. The paper: the analytic dip "is not
    replicated" by the discrete pile."""
    import jaxpile as jp
    from jaxpile import analysis, theory

    t0 = time.perf_counter()
    pile = jp.run("sloped", None, n, alpha_degrees=30.0, top_alpha_degrees=45.0, knee=0.38)
    base = float(pile.measurements["info"]["base"])
    forces = analysis.base_forces(pile.simulator, pile.params, pile.state)
    x, normal = np.asarray(forces.x), np.asarray(forces.normal)
    grid = np.linspace(0.0, base, 801)
    analytic, _ = theory.tent_ground_forces(grid, math.radians(30.0), math.radians(45.0), 0.38 * base, base)
    return {"n_particles": pile.measurements["n_particles"], "base": base, "at_rest": pile.measurements["at_rest"],
            "law": pile.measurements["law"], "measured": central_dip(x, normal, base),
            "analytic": central_dip(grid, np.asarray(analytic), base), "seconds": time.perf_counter() - t0}


def collisions() -> dict:
    """Eqs. 4-19 on two oblique collisions of spinning disks of unlike size:
    with mu = 10 the NOSLIP branch (eq. 8: the contact point's tangential
    velocity after is 0), with mu = 0.05 the SLIP branch (eq. 7: |P_t| = mu
    |P_n|, the slip reduced, not reversed); both keep momentum (eq. 6) and the
    normal restitution (eq. 4)."""
    from jaxpile.engine import collisions as hard

    m1, m2, r1, r2, eps = 1.0, 2.25, 0.5, 0.75, 0.6
    i1, i2 = 0.5 * m1 * r1**2, 0.5 * m2 * r2**2
    x1, x2 = np.array([0.0, 0.0]), np.array([1.25 * math.cos(0.4), 1.25 * math.sin(0.4)])
    c1, c2, w1, w2 = np.array([1.0, 0.3]), np.array([-0.2, -0.4]), 2.0, -1.0
    n = (x2 - x1) / np.linalg.norm(x2 - x1)
    t = np.array([-n[1], n[0]])

    def contact_velocity(c1, c2, w1, w2):  # eq. 9 with eqs. 17-18, along t
        return float((c1 - c2) @ t + r1 * w1 + r2 * w2)

    out = {}
    for name, mu in (("noslip", 10.0), ("slip", 0.05)):
        r = hard.collide(m1, m2, i1, i2, r1, r2, x1, x2, c1, c2, w1, w2, eps, mu)
        a1, a2, s1, s2, p = (np.asarray(v, dtype=float) for v in (r.c1, r.c2, r.w1, r.w2, r.impulse))
        before, after = contact_velocity(c1, c2, w1, w2), contact_velocity(a1, a2, float(s1), float(s2))
        out[name] = {"mu": mu, "slipping": bool(r.slipping),
                     "tangential_velocity_before": before, "tangential_velocity_after": after,
                     "impulse_ratio_t_over_n": float(abs(p @ t) / abs(p @ n)),
                     "restitution_residual": float((a1 - a2) @ n + eps * (c1 - c2) @ n),
                     "momentum_residual": float(np.abs(m1 * a1 + m2 * a2 - m1 * c1 - m2 * c2).max())}
    return out


def figure(result: dict, path) -> None:
    """Figs. 10 and 16 redrawn from the summary: each disk's strongest and
    weakest disk contact as a line, in the 45-layer lattice and the 30 deg pile."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    fig, axes = plt.subplots(2, 2, figsize=(12, 7.5), gridspec_kw={"height_ratios": [1.6, 1]})
    for row, (key, title) in enumerate((("lattice", "45-layer lattice (Fig. 10)"), ("sloped30", "30° pile (Fig. 16)"))):
        lines = result[key]["lines"]
        position = np.asarray(lines["position"])
        for col, which in enumerate(("strongest", "weakest")):
            ax = axes[row, col]
            pairs = np.asarray(lines[which]["pairs"], dtype=int)
            ax.add_collection(LineCollection(position[pairs], colors="C3" if col == 0 else "C0", linewidths=0.8))
            ax.scatter(position[:, 0], position[:, 1], s=1.0, c="0.6")
            ax.set_aspect("equal")
            ax.set_title(f"{title}: lines of {'maximum' if col == 0 else 'minimum'} force", fontsize=10)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle("Liffman, Chan & Hughes 1992: each disk's strongest and weakest contact "
                 "(`benchmarks/studies/papers/liffman_networks.py`)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def write(result: dict) -> None:
    """The summary, its numbers indented and the figure's positions and pairs one compact line each."""
    import json

    def compact(value):
        if isinstance(value, dict):
            return {k: compact(v) for k, v in value.items()}
        if isinstance(value, list) and value and isinstance(value[0], list):
            return "@" + json.dumps(value, separators=(",", ":")) + "@"
        return value

    text = json.dumps(compact(result), indent=1, default=float)
    text = text.replace('"@[', "[").replace(']@"', "]")
    OUT.write_text(text + "\n")
    json.loads(OUT.read_text())  # still JSON


FIGURE = HERE.parents[2] / "docs" / "liffman1992_force_lines.png"


def main() -> int:
    import jaxpile as jp

    jp.configure()
    t0 = time.perf_counter()
    result = {"command": COMMAND, "tolerance_degrees": TOLERANCE_DEGREES, "lattice": lattice(),
              "sloped30": sloped(30.0), "sloped32_6": sloped(32.6), "tents": tents(), "tent_pile": tent_pile(),
              "collisions": collisions(),
              "settings": jp.settings()}
    result["seconds"] = time.perf_counter() - t0
    OUT.parent.mkdir(parents=True, exist_ok=True)
    write(result)
    figure(result, FIGURE)
    print(f"wrote {OUT.relative_to(HERE.parents[2])} in {result['seconds']:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
