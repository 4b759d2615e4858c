"""The papers side by side (issue 16, item 4): one script for the table in docs/papers.md.

    python benchmarks/studies/papers/papers.py             # rewrite docs/papers.md's table and the docs/ figures from the results JSON
    python benchmarks/studies/papers/papers.py --check     # exit 1 when docs/papers.md's table is not the one the JSON gives
    python benchmarks/studies/papers/papers.py --run [--only lattice,sloped,sloped_angles,networks,tilt,flux,vcut,kn_gamma,drop,heap,heap1000,heap1000_n36,spacing,voidage,height,width]
                                            # first run what is missing (resumable; hours on 2 cores)

Every number in the table is read from a results file that a committed command
wrote (the command is in the file): the 1992 lattice and sloped piles
(`jaxpile pile`, summary.json), the 1993 tilt ensemble and the 1992 dropped
piles (`paper_ensembles.py`, one JSON per pile), the 1993 flux piles and
its k_n and gamma_n boxes (`jaxpile sweep`, sweep.csv), and the 1997 heaps
(`baxter_readings.py`, one JSON per heap). A study with fewer piles than its
target shows what it has ("k of 8"); one not run yet says how to run it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent  # benchmarks/studies/papers
ROOT = HERE.parents[2]
RESULTS = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "papers.md"
START, END = "<!-- papers-table:start -->\n", "<!-- papers-table:end -->"
sys.path.insert(0, str(HERE))  # its sibling studies (paper_ensembles, baxter_readings)
sys.path.insert(1, str(ROOT / "benchmarks"))  # docs_block

PILES = 8  # the ensembles' target size (issue 16)


def _pm(stat: dict | None, digits: int = 1, unit: str = "°") -> str:
    if not stat or stat.get("mean") is None or not math.isfinite(stat["mean"]):
        return "—"
    se = stat.get("stderr")
    if se is None or not math.isfinite(se):
        return f"{stat['mean']:.{digits}f}{unit}"
    return f"{stat['mean']:.{digits}f} ± {se:.{digits}f}{unit}"


def _load(path: pathlib.Path) -> dict | None:
    return json.loads(path.read_text()) if path.exists() else None


def _missing(study: str) -> str:
    return f"not run yet (`python benchmarks/studies/papers/papers.py --run --only {study}`)"


def _se(stat: dict | None) -> float:
    """A statistic's standard error, 0 for one without (a deterministic pile)."""
    se = (stat or {}).get("stderr")
    return se if se is not None and math.isfinite(se) else 0.0


def _sign(difference: float, *errors: float, agree: str = "agrees", differ: str = "differs") -> str:
    """A difference's verdict at two combined standard errors: `agree` when it
    is above them, `differ` when below minus them, else not resolved."""
    bound = 2.0 * math.hypot(*errors) if errors else 0.0
    if difference > bound:
        return agree
    if difference < -bound:
        return differ
    return f"not resolved (within 2 s.e., {bound:.2g})"


def _close(difference: float, *errors: float) -> str:
    """Agreement with a value: the difference within two combined standard errors."""
    bound = 2.0 * math.hypot(*errors)
    return f"agrees (within 2 s.e., {bound:.2g})" if abs(difference) <= bound else f"differs (2 s.e.: {bound:.2g})"


def _against_reported_dip(mean: float, se: float) -> str:
    """A mean dip against Smid–Novosad's 20–30 %: in it, within two standard errors of it, or not."""
    from jaxpile.fit.targets import SMID_NOVOSAD_DIP_RANGE

    low, high = SMID_NOVOSAD_DIP_RANGE
    return ("in 20–30%" if low <= mean <= high else
            "within 2 s.e. of 20–30%" if low - 2 * se <= mean <= high + 2 * se else "differs from 20–30%")


def _every(checks: list[bool], what: str) -> str:
    return f"agrees ({what})" if all(checks) else f"differs ({sum(not c for c in checks)} of {len(checks)} not {what})"


# ----------------------------------------------------------------- 1992
LATTICE = RESULTS / "liffman_1992" / "lattice45_liffman.json"
SLOPED = RESULTS / "liffman_1992" / "sloped30_n5490.json"
SLOPED_ANGLES = {a: RESULTS / "liffman_1992" / "sloped_n360" / f"alpha{a}.json" for a in (30, 45, 50, 55)}
"""The paper's piles of Figs. 12-14: about 360 disks at each angle of repose (sec. 5)."""
DROP = RESULTS / "liffman_1992" / "drop_n968"
NETWORKS = RESULTS / "liffman_1992" / "networks.json"
"""The sink, the force lines, the 32.6 deg pile, the tents and the collisions (`liffman_networks.py`)."""


def _rows_networks() -> list[list[str]]:
    """The 1992 results read off one pile each (deterministic): the base
    disks' sink (sec. 4), the force lines (Figs. 10, 16), the 32.6 deg pile
    against Smid-Novosad (Fig. 17), the tents (Figs. 18-19) and the SLIP /
    NOSLIP collisions (eqs. 4-19)."""
    net = _load(NETWORKS)
    if net is None:
        return [["1992", "the base's sink, the force lines, the 32.6° pile, the tents, SLIP/NOSLIP",
                 "sec. 4, Figs. 10, 16–19, eqs. 4–19", _missing("networks"), "—"]]
    lat, s30, s326, tents, hard = net["lattice"], net["sloped30"], net["sloped32_6"], net["tents"], net["collisions"]
    tent = net["tent_pile"]
    sink_off = lat["max_sink_sigma"] / lat["theory_max_sink_sigma"] - 1
    strong, weak = lat["lines"]["strongest"], lat["lines"]["weakest"]
    mirrored = min(strong["left_at_60"], strong["right_at_120"]) > 0.5 or min(strong["left_at_120"],
                                                                              strong["right_at_60"]) > 0.5
    horizontal = lat["lines"]["largest_horizontal_force_mg"] / lat["lines"]["mean_contact_force_mg"]
    s_strong, s_weak = s30["lines"]["strongest"], s30["lines"]["weakest"]
    peaked, flat = tents["peaked_30_45"], tents["flattened_45_30"]
    noslip, slip = hard["noslip"], hard["slip"]
    eq8 = abs(noslip["tangential_velocity_after"]) < 1e-12 and not noslip["slipping"]
    eq7 = (slip["slipping"] and abs(slip["impulse_ratio_t_over_n"] - slip["mu"]) < 1e-12
           and 0 < slip["tangential_velocity_after"] / slip["tangential_velocity_before"] < 1)
    kept = max(abs(c[k]) for c in (noslip, slip) for k in ("restitution_residual", "momentum_residual")) < 1e-12
    return [
        ["1992", "45-layer lattice (`liffman` law): the bottom row's sink into the ground (sec. 4, eqs. 42, 45–46)",
         "about 2.3e-3 σ", f"{lat['max_sink_sigma']:.3g} σ at most ({lat['centre_sink_sigma']:.3g} σ at the centre); "
         f"(k + 1)/2 mg / K_s = {lat['theory_max_sink_sigma']:.3g} σ",
         "agrees (within 5%)" if abs(sink_off) < 0.05 else f"differs ({100 * sink_off:+.0f}%)"],
        ["1992", "the same pile: the lines of strongest and weakest force (Fig. 10, eqs. 47–48; "
                 "`docs/liffman1992_force_lines.png`)",
         "at π/3 or 2π/3, one diagonal each side of the centre; no horizontal forces",
         f"strongest at π/3 or 2π/3 for {100 * strong['at_60_or_120']:.0f}% of {strong['lines']} disks (left half "
         f"{100 * strong['left_at_60']:.0f}% / {100 * strong['left_at_120']:.0f}% at π/3 / 2π/3, right half "
         f"{100 * strong['right_at_60']:.0f}% / {100 * strong['right_at_120']:.0f}%); weakest at π/3 or 2π/3 for "
         f"{100 * weak['at_60_or_120']:.0f}%; " + ("no two disks of one level in contact" if not lat["lines"]["horizontal_pairs"]
                                             else f"the largest horizontal pair force {horizontal:.1e} of the mean"),
         "agrees" if strong["at_60_or_120"] > 0.95 and mirrored and horizontal < 1e-3 else "differs"],
        ["1992", f"sloped pile 30°, {s30['n_particles']} disks: the force lines (Fig. 16; the same figure)",
         "strongest still at π/3 or 2π/3; weakest now horizontal, some at π/3",
         f"strongest at π/3 or 2π/3 for {100 * s_strong['at_60_or_120']:.0f}%; weakest horizontal for "
         f"{100 * s_weak['horizontal']:.0f}%, at π/3 or 2π/3 for {100 * s_weak['at_60_or_120']:.0f}%",
         "agrees" if s_strong["at_60_or_120"] > 0.9 and s_weak["horizontal"] > 0.25 and s_weak["at_60_or_120"] > 0
         else "differs"],
        ["1992", f"sloped pile 32.6° (Smid–Novosad's angle), {s326['n_particles']} disks (Fig. 17)",
         "H as the experiment's; N without its central depression",
         f"central slope of H {100 * s326['central_slope_rel_dev']:+.0f}% from eq. 57; central N "
         f"{100 * s326['central_normal_rel_dev']:+.1f}% from eq. 56, dip {100 * s326['central_normal_dip']:.1f}%",
         "agrees: no dip in N (H against the experiment not judged: its points are not in the tree)"
         if s326["central_normal_dip"] < 0.05 else "differs: a dip in N"],
        ["1992", "tent piles, analytic (Figs. 18–19): α1 = 30°, α2 = 45°, X1 = 0.38 B, and α1 = 45°, α2 = 30°",
         "a central depression of N only when α2 > α1",
         f"dip {100 * peaked['central_dip']:.1f}% (maximum at x/B = {peaked['x_over_b_of_max']:.2f}); "
         f"flattened: dip {100 * flat['central_dip']:.1f}%",
         "agrees" if peaked["central_dip"] > 0.01 and flat["central_dip"] < 1e-3 else "differs"],
        ["1992", f"the tent of Fig. 19 built of disks: α1 = 30°, α2 = 45°, X1 = 0.38 B, {tent['n_particles']} disks "
                 "(no random input: one pile)",
         "the analytic dip not replicated",
         f"base N's centre over its maximum (means over 0.1 B): dip {100 * tent['measured']['central_dip']:.1f}% "
         f"(maximum at x/B = {tent['measured']['x_over_b_of_max']:.2f}); the analytic tent at the same B: "
         f"{100 * tent['analytic']['central_dip']:.1f}%",
         "agrees (no dip where the analytic tent has one)" if tent["measured"]["central_dip"] < 0.01
         < tent["analytic"]["central_dip"] else "differs"],
        ["1992", "hard collisions, SLIP and NOSLIP (eqs. 4–19): two spinning disks of unlike size, oblique",
         "NOSLIP stops the contact point's slip (eq. 8); SLIP takes the tangential impulse μ times the normal "
         "(eq. 7), the slip reduced",
         f"μ = {noslip['mu']:g}: NOSLIP, slip after {noslip['tangential_velocity_after']:.1e}; μ = {slip['mu']:g}: "
         f"SLIP, tangential over normal impulse {slip['impulse_ratio_t_over_n']:.15g}, slip {slip['tangential_velocity_before']:.3f} "
         f"-> {slip['tangential_velocity_after']:.3f}; eqs. 4, 6 to round-off",
         "agrees (to round-off)" if eq8 and eq7 and kept else "differs"],
    ]


def _rows_sloped_angles() -> list[list[str]]:
    """Figs. 13-14: the 360-disk sloped piles at 30, 45, 50 and 55 deg against
    eqs. 56-57 (the plateau of N, the central slope of H), and H's central slope
    against alpha, which eq. 57 makes grow as sin a / sin(2 pi/3 - a)."""
    piles = {a: _load(path) for a, path in SLOPED_ANGLES.items()}
    if not all(piles.values()):
        return [["1992", "sloped piles 30, 45, 50, 55°, 360 disks (Figs. 13, 14): central N, H vs eqs. 56, 57",
                 "close to eqs. 54–59", _missing("sloped_angles"), "—"]]
    angles = "/".join(f"{a}" for a in piles)
    what = f"sloped piles {angles}°, 360 disks (Figs. 12–14; no random input: one pile each)"
    n_dev = [p["central_normal_rel_dev"] for p in piles.values()]
    dips = [p.get("central_normal_dip", 0) > 0.05 for p in piles.values()]
    h_dev = [p["central_slope_rel_dev"] for p in piles.values()]
    slopes = [p["central_slope_horizontal"] for p in piles.values()]
    theory = [p["theory_central_slope_horizontal"] for p in piles.values()]
    grows, ratio, ratio_theory = all(b > a for a, b in zip(slopes, slopes[1:])), slopes[-1] / slopes[0], theory[-1] / theory[0]
    later = []
    if (large := _load(SLOPED)) is not None:  # Fig. 15: the 30 deg pile at 5490 disks against 360
        small = piles[30]
        closer = abs(large["central_normal_rel_dev"]) < abs(small["central_normal_rel_dev"])
        h_off = abs(large["central_slope_rel_dev"]) > 0.05
        later.append(["1992", "30° pile, 5490 disks against 360 (Fig. 15)",
                     "N closer to eq. 56; H does not converge to eq. 57",
                     f"central N {100 * large['central_normal_rel_dev']:+.1f}% against "
                     f"{100 * small['central_normal_rel_dev']:+.1f}%; central slope of H "
                     f"{100 * large['central_slope_rel_dev']:+.0f}% against {100 * small['central_slope_rel_dev']:+.0f}%",
                     "agrees" if closer and h_off else
                     "differs (" + ("N not closer" if not closer else "H within 5% of eq. 57") + ")"])
    return [
        ["1992", f"{what}: central N vs eq. 56", "close to the plateau (Fig. 13)",
         ", ".join(f"{100 * d:+.1f}%" for d in n_dev) + f"; {'a dip in ' + str(sum(dips)) if any(dips) else 'no dip in any'}",
         _every([abs(d) < 0.05 and not dip for d, dip in zip(n_dev, dips)], "within 5% without a dip")],
        ["1992", "the same: central slope of H vs eq. 57", "close, not equal (Fig. 14)",
         ", ".join(f"{100 * d:+.0f}%" for d in h_dev), _every([abs(d) < 0.15 for d in h_dev], "within 15%")],
        ["1992", "the same: H's central slope against α (Fig. 14: it depends on α)",
         f"grows with α as eq. 57: ×{ratio_theory:.2f} from {angles.split('/')[0]}° to {angles.split('/')[-1]}°",
         f"{', '.join(f'{v:.3f}' for v in slopes)} (in units of χg): ×{ratio:.2f}",
         "agrees (grows, ratio within 10% of eq. 57's)" if grows and abs(ratio / ratio_theory - 1) < 0.1 else
         "differs (" + ("not monotonic" if not grows else f"ratio {ratio:.2f} against {ratio_theory:.2f}") + ")"],
    ] + later


def rows_1992() -> list[list[str]]:
    rows = []
    lat = _load(LATTICE)
    # the lattice and sloped piles have no random input: their ensemble is one pile
    rows.append(["1992", "45-layer lattice pile, max deviation of N, H from eqs. 42, 44 (no random input: one pile)",
                 "< 1%",
                 f"{100 * lat['max_rel_dev_normal']:.2f}%, {100 * lat['max_rel_dev_horizontal']:.2f}% (`liffman` law)"
                 if lat else _missing("lattice"),
                 ("agrees" if max(lat["max_rel_dev_normal"], lat["max_rel_dev_horizontal"]) < 0.01 else "differs")
                 if lat else "—"])
    slo = _load(SLOPED)
    if slo:
        dip = "a dip" if slo.get("central_normal_dip", 0) > 0.05 else "no dip"
        rows.append(["1992", "sloped pile 30°, 5490 disks (no random input: one pile): central N vs eq. 56",
                     "plateau, no dip",
                     f"{100 * slo['central_normal_rel_dev']:+.1f}%, {dip}",
                     "agrees" if dip == "no dip" and abs(slo["central_normal_rel_dev"]) < 0.05 else "differs"])
        rows.append(["1992", "the same: central slope of H vs eq. 57", "close, not equal",
                     f"{100 * slo['central_slope_rel_dev']:+.0f}%",
                     "agrees (within 15%)" if abs(slo["central_slope_rel_dev"]) < 0.15 else "differs (beyond 15%)"])
    else:
        rows.append(["1992", "sloped pile 30°, 5490 disks: central N and H vs eqs. 56, 57", "plateau, no dip",
                     _missing("sloped"), "—"])
    rows.extend(_rows_sloped_angles())
    rows.extend(_rows_networks())
    import paper_ensembles as pe

    piles = pe.pile_rows(DROP)
    if piles:

        s = pe.summarise_drop(piles)
        dip = s["central_dip"]
        rows.append(["1992", f"dropped pile, 968 disks (Fig. 20): central dip of the base normal force "
                             f"({len(piles)} of {PILES} piles)", "a slight depression; Smid–Novosad 20–30%",
                     f"{_pm(dip, 2, '')} (dip > 5% in {s['has_central_dip']} of {len(piles)})",
                     _sign(dip["mean"], _se(dip), agree="agrees: a depression", differ="differs: a central peak")
                     + ("; Smid–Novosad's 20–30%: not reached" if dip["mean"] + 2 * _se(dip) < 0.2 else "")])
    else:
        rows.append(["1992", "dropped pile, 968 disks (Fig. 20): central dip", "a slight depression",
                     _missing("drop"), "—"])
    return rows


# ----------------------------------------------------------------- 1993
TILT = RESULTS / "lee_herrmann_1993" / "tilt_n409" / "summary.json"
FLUX = RESULTS / "lee_herrmann_1993" / "flux_w4"
"""The constant-flux piles (sec. 5, Fig. 5): `FLUX_SWEEP`'s sweep.csv, sweep.json and command.txt."""
FLUX_SWEEP = ["sweep", "--protocol", "flux", "--n", "300", "--mu", "0.2", "--seeds", str(PILES),
              "--checkpoint-every", "200000", "--no-progress"]
"""Fig. 5's setting (W = 4, v_cut = 0.1 cm/s, the paper's law at mu = 0.2), 300 disks fed, one pile a seed."""
VCUT = RESULTS / "lee_herrmann_1993" / "flux_w4_vcut"
VCUT_LONGER = (RESULTS / "lee_herrmann_1993" / "flux_w4_vcut0.01_t130", RESULTS / "lee_herrmann_1993" / "flux_w4_vcut0.001_t190")
"""The smaller v_cut run for longer (max_time 130 s, 190 s), so that as many disks go in as at 0.1 in 60 s."""
"""The same flux piles at v_cut = 0.01 and 0.001 cm/s (sec. 5: "no essential difference")."""
VCUT_SWEEP = ["sweep", "--protocol", "flux", "--n", "300", "--mu", "0.2", "--seeds", str(PILES), "--vary",
              "v_cut=0.01,0.001", "--checkpoint-every", "200000", "--no-progress"]


def rows_1993() -> list[list[str]]:
    tilt = _load(TILT)
    if not tilt:
        return [["1993", "θ_R, θ_T against μ (Figs. 3, 4, 7)", "", _missing("tilt"), "—"]]
    s = tilt["summary"]
    mus = sorted(s, key=float)
    piles = min(s[m]["piles"] for m in mus)

    def series(key, digits=1):
        return ", ".join(_pm(s[m][key], digits, "") for m in mus) + "°"

    ms = ", ".join(f"{s[m]['theta_ms_theory']:.1f}" for m in mus) + "°"
    mu_text = f"μ = {mus[0]} … {mus[-1]}"

    def below_ms(key):  # below theta_MS at every mu, judged at two standard errors
        verdicts = {m: _sign(s[m]["theta_ms_theory"] - s[m][key]["mean"], _se(s[m][key])) for m in mus}
        if all(v == "agrees" for v in verdicts.values()):
            return "agrees (below by 2 s.e. at every μ)"
        worst = [m for m, v in verdicts.items() if v != "agrees"]
        kind = "differs" if any(verdicts[m] == "differs" for m in worst) else "not resolved"
        return f"{kind} at μ = {', '.join(worst)} (elsewhere below by 2 s.e.)"

    # the paper's 17.88 +- 1.76 deg (sec. 3, method 3) is a mean and its sample-to-sample fluctuation over ten
    # piles: its standard error is 1.76 / sqrt(10); sec. 4 gives 17.99 +- 0.64 over 20 at the same parameters
    at_02 = s.get("0.2", {}).get("theta_r")
    paper_02 = _close(at_02["mean"] - 17.88, _se(at_02), 1.76 / math.sqrt(10)) if at_02 else "not run"
    rises = _sign(s[mus[-1]]["theta_r"]["mean"] - s[mus[0]]["theta_r"]["mean"], _se(s[mus[-1]]["theta_r"]),
                  _se(s[mus[0]]["theta_r"]), differ="differs: falls")
    small = [abs(s[m]["theta_t"]["mean"] - s[m]["theta_t_theory"]["mean"]) < 3.0 for m in mus]
    few = [0 < s[m]["theta_t"]["mean"] - 2 * _se(s[m]["theta_t"]) and s[m]["theta_t"]["mean"] < 10 for m in mus]
    return [
        ["1993", f"θ_R against {mu_text} (W = H = 4, 409 disks, method 3), {piles} piles each; the paper: only "
         "μ ≤ 0.2 is free of finite-size effects at W = 4 (μ = 0.3 still falls there, Fig. 2b)",
         "θ_R < θ_MS; 17.88 ± 1.76° at μ = 0.2 (ten piles, sec. 3; 17.99 ± 0.64 over 20, sec. 4)",
         f"{series('theta_r')} (θ_MS = arctan 3μ: {ms})",
         f"below θ_MS: {below_ms('theta_r')}; rises with μ: {rises}; "
         f"at μ = 0.2: {paper_02} ({at_02['mean'] - 17.88:+.1f}°)" if at_02 else "—"],
        ["1993", f"θ_T against {mu_text}, tilting 1e-3 °/step (Fig. 4), same piles", "a few degrees",
         series("theta_t"), _every(few, "between 0 and 10° by 2 s.e.")],
        ["1993", "the same against eq. 4 at each pile's θ_R (Fig. 7b)", "\"the difference is small\"",
         f"eq. 4: {series('theta_t_theory')}", _every(small, "within 3°")],
        ["1993", "θ_R + θ_T against θ_MS = arctan 3μ (Fig. 7a)", "below θ_MS (\"there is a difference\")",
         f"{series('theta_r_plus_theta_t')} against {ms} (`docs/lee_herrmann1993_tilt_ensemble.png`)",
         below_ms("theta_r_plus_theta_t")],
        row_linear_in_mu({float(m): s[m]["theta_r"] for m in mus}),
        row_flux(at_02),
        row_vcut(),
        *rows_kn_gamma(),
        row_height(),
        *rows_width(),
    ]


def rows_width() -> list[list[str]]:
    """Fig. 2(b): theta_R against the box's width W at H / W = 2. The text: at mu
    = 0.2 the angle falls for small sizes and saturates from about W = 3.5; at mu
    = 0.3 it falls until W = 4; at mu = 0.1 no obvious trend down to W = 1.5.
    Tested as the slope of theta_R against W over the smaller widths (W <= 3)
    and over the larger (W >= 3), each against two standard errors."""
    what = "θ_R against the box's width W, H / W = 2 (Fig. 2b)"
    if not all((WIDTH / f"w{w:g}" / "sweep.csv").exists() for w in WIDTHS):
        return [["1993", what, "falls, then saturates: from W ≈ 3.5 at μ = 0.2, later at 0.3, no trend at 0.1",
                 _missing("width"), "—"]]
    rows = [{**r, "width": w} for w in WIDTHS for r in _sweep_csv(WIDTH / f"w{w:g}" / "sweep.csv")]
    says = {0.1: ("no obvious trend down to W = 1.5", ("flat", "flat")),
            0.2: ("falls for small W, saturates from W ≈ 3.5", ("falls", "flat")),
            0.3: ("falls until W = 4", ("falls", "falls"))}

    def verdict(found: tuple, expected: tuple) -> str:
        if found == expected:
            return "agrees"
        if any(f != "flat" and e == "flat" or f == "rises" for f, e in zip(found, expected)):
            return "differs"
        return "not resolved (a fall the piles do not resolve)"

    out = []
    for mu, (said, expected) in says.items():
        stats = [_angle([r for r in rows if float(r["mu"]) == mu and r["width"] == w]) for w in WIDTHS]
        small, large = [(w, a) for w, a in zip(WIDTHS, stats) if w <= 3.0], [(w, a) for w, a in zip(WIDTHS, stats) if w >= 3.0]
        s_small, e_small = _trend(*zip(*small))
        s_large, e_large = _trend(*zip(*large))
        judge = lambda slope, se: ("falls" if slope < -2 * se else "rises" if slope > 2 * se else "flat")
        shown = ", ".join(f"{w:g}: {_pm(a)}" for w, a in zip(WIDTHS, stats))
        out.append(["1993", f"{what}, μ = {mu:g}, {min(a['count'] for a in stats)} piles a width", said,
                    f"θ_R (method 3) at W = {shown}; slope {s_small:+.1f} ± {e_small:.1f}°/W up to W = 3, "
                    f"{s_large:+.1f} ± {e_large:.1f}°/W from W = 3",
                    f"{verdict((judge(s_small, e_small), judge(s_large, e_large)), expected)}: W ≤ 3 "
                    f"{judge(s_small, e_small)}, W ≥ 3 {judge(s_large, e_large)} (at 2 s.e.)"])
    return out


def row_linear_in_mu(theta_r: dict) -> list[str]:
    """Sec. 4 (Fig. 3): "in the range of mu we studied, there seems to be a
    linear relation between the angle and mu" (and it "cannot be true for the
    entire range"): the curvature of a weighted quadratic fit of theta_R over
    mu, against two standard errors, at small mu (<= 0.3, the paper's figure
    does not print its range) and over the whole ensemble."""
    import numpy as np

    def curvature(mus):
        x = np.asarray(mus)
        y = np.asarray([theta_r[m]["mean"] for m in mus])
        w = 1.0 / np.asarray([max(_se(theta_r[m]), 1e-12) for m in mus])
        coef, cov = np.polyfit(x, y, 2, w=w, cov="unscaled")
        return float(coef[0]), float(np.sqrt(cov[0, 0]))

    mus = sorted(theta_r)
    parts = []
    for label, chosen in (("μ ≤ 0.3", [m for m in mus if m <= 0.3]), (f"μ ≤ {mus[-1]:g}", mus)):
        if len(chosen) < 3:
            continue
        c, se = curvature(chosen)
        parts.append((label, c, se, "linear" if abs(c) <= 2 * se else ("concave" if c < 0 else "convex")))
    return ["1993", "θ_R linear in μ (Fig. 3; the box ensemble above)", "linear in the range studied, "
            "not for every μ", "; ".join(f"{label}: curvature {c:+.0f} ± {se:.0f}°/μ²" for label, c, se, _ in parts),
            "; ".join(f"{label}: {shape}" for label, _, _, shape in parts)
            + ("" if not parts else "; " + ("agrees" if parts[0][3] == "linear" else "differs") + " at small μ")]


def _trend(xs: list[float], stats: list[dict]) -> tuple[float, float]:
    """The slope of a weighted least-squares line through `(x, mean +- stderr)`, with its standard error."""
    import numpy as np

    x = np.asarray(xs, float)
    y = np.asarray([s["mean"] for s in stats], float)
    w = 1.0 / np.asarray([max(_se(s), 1e-12) ** 2 for s in stats], float)
    xm = np.sum(w * x) / np.sum(w)
    slope = np.sum(w * (x - xm) * (y - np.sum(w * y) / np.sum(w))) / np.sum(w * (x - xm) ** 2)
    return float(slope), float(1.0 / np.sqrt(np.sum(w * (x - xm) ** 2)))


def row_height() -> list[str]:
    """Fig. 2(a): theta_R against the box's height H at W = 2, mu = 0.2: "no
    systematic dependency", tested as the slope of theta_R against H."""
    what = "θ_R against the box's height H, W = 2, μ = 0.2 (Fig. 2a)"
    says = "no systematic dependence on H"
    path = HEIGHT / "sweep.csv"
    if not path.exists():
        return ["1993", what, says, _missing("height"), "—"]
    rows = _sweep_csv(path)
    heights = sorted({float(r["height"]) for r in rows})
    stats = [_angle([r for r in rows if float(r["height"]) == h]) for h in heights]
    slope, se = _trend(heights, stats)
    shown = ", ".join(f"{h:g}: {_pm(a)}" for h, a in zip(heights, stats))
    return ["1993", f"{what}, {min(a['count'] for a in stats)} piles a height", says,
            f"θ_R (method 3) at H = {shown}; slope {slope:+.2f} ± {se:.2f}° per unit H",
            ("agrees (no trend: slope within 2 s.e.)" if abs(slope) <= 2 * se else
             f"differs (a trend of {slope:+.2f}° per unit H, beyond 2 s.e.)")]


KN_GAMMA = RESULTS / "lee_herrmann_1993" / "kn_gamma"
"""Sec. 4's k_n and gamma_n study: each sweep's sweep.csv, sweep.json and command.txt in its folder."""
_BOX_W4 = ["sweep", "--protocol", "box", "--law", "lee-herrmann", "--mu", "0.2", "--seeds", str(PILES), "--option",
           "width=4", "--option", "height=4", "--checkpoint-every", "20000", "--no-progress"]
KN_GAMMA_SWEEPS = {
    "kn": [*_BOX_W4, "--vary", "kn=10000,100000,1000000"],
    "gamma50": [*_BOX_W4, "--vary", "gamma_n=50", "--set", "gamma_s=0.5"],
    "gamma100": [*_BOX_W4, "--vary", "gamma_n=100", "--set", "gamma_s=1.0"],
}
"""The paper's box (W = H = 4, mu = 0.2, its law: k_n = 1e6, gamma_n = 500, gamma_s = gamma_n / 100) at
its three k_n and its three gamma_n (500 is the k_n sweep's 1e6 point), `PILES` piles each (the paper's 20
take 2.5 times the CPU: about 1.5 hours on 2 cores for the k_n sweep alone)."""
HEIGHT_SWEEP = ["sweep", "--protocol", "box", "--law", "lee-herrmann", "--mu", "0.2", "--seeds", str(PILES), "--option",
                "width=2", "--vary", "height=1,2,3,4,5", "--checkpoint-every", "20000", "--no-progress"]
"""Fig. 2(a): theta_R against the box's height H at W = 2, mu = 0.2 (the paper's H values are not printed)."""
HEIGHT = RESULTS / "lee_herrmann_1993" / "height_w2"
WIDTHS = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
WIDTH_SWEEPS = {w: ["sweep", "--protocol", "box", "--law", "lee-herrmann", "--seeds", str(PILES), "--option",
                    f"width={w:g}", "--option", f"height={2 * w:g}", "--vary", "mu=0.1,0.2,0.3", "--checkpoint-every",
                    "20000", "--no-progress"] for w in WIDTHS}
"""Fig. 2(b): theta_R against the box's width W at aspect ratio H / W = 2, mu = 0.1, 0.2, 0.3: one sweep a W."""
WIDTH = RESULTS / "lee_herrmann_1993" / "width_aspect2"
KN_PAPER = {1e4: (16.53, 0.73), 1e5: (18.65, 0.70), 1e6: (17.99, 0.64)}
GAMMA_PAPER = {50.0: (16.47, 0.75), 100.0: (17.15, 0.62), 500.0: (17.99, 0.64)}
METHODS_PAPER = {"repose_endpoints": (20.14, 2.15), "repose_least_squares": (18.90, 1.49),
                 "repose_cumulative_parabola": (17.88, 1.76)}
"""Sec. 3: the three methods at mu = 0.2, 400 disks, over ten piles (mean and sample-to-sample fluctuation)."""


def _sweep_rows(name: str) -> list[dict] | None:
    import csv

    path = KN_GAMMA / name / "sweep.csv"
    if not path.exists():
        return None
    with open(path) as fh:
        return list(csv.DictReader(fh))


def _angle(rows: list[dict], key: str = "repose_cumulative_parabola") -> dict:
    from baxter_readings import mean_stderr

    return mean_stderr([float(r[key]) for r in rows if r[key] not in ("", "None", "nan")])


def _against_paper(ours: dict, paper: tuple[float, float], piles: int) -> tuple[bool, bool]:
    """Whether our mean is within two combined standard errors of the paper's,
    its +- read as a standard error, and read as a sample-to-sample
    fluctuation over `piles` piles (the two readings the text leaves open)."""
    value, pm = paper
    as_se = abs(ours["mean"] - value) <= 2 * math.hypot(_se(ours), pm)
    as_sd = abs(ours["mean"] - value) <= 2 * math.hypot(_se(ours), pm / math.sqrt(piles))
    return as_se, as_sd


def rows_kn_gamma() -> list[list[str]]:
    """Sec. 4: theta_R against k_n and gamma_n at mu = 0.2, and sec. 3's three angle methods
    (the k_n = 1e6 piles: the paper's parameters)."""
    kn, gammas = _sweep_rows("kn"), {g: _sweep_rows(f"gamma{g}") for g in (50, 100)}
    quantity_kn = "θ_R against k_n = 1e4, 1e5, 1e6 at μ = 0.2 (sec. 4; W = H = 4, 409 disks, method 3)"
    paper_kn = "16.53 ± 0.73, 18.65 ± 0.70, 17.99 ± 0.64° (20 piles each): \"no systematic dependency\""
    if kn is None:
        return [["1993", quantity_kn, paper_kn, _missing("kn_gamma"), "—"]]
    by_kn = {float(v): [r for r in kn if float(r["kn"]) == float(v)] for v in KN_PAPER}
    angles = {v: _angle(rows) for v, rows in by_kn.items()}
    piles = min(len(rows) for rows in by_kn.values())

    def trend(points: dict, x_of) -> tuple[float, float]:
        """The least-squares slope of the piles' angles against x_of(value), and its standard error."""
        import numpy as np

        x, y = [], []
        for v, rows in points.items():
            for r in rows:
                if r["repose_cumulative_parabola"] not in ("", "None", "nan"):
                    x.append(x_of(v))
                    y.append(float(r["repose_cumulative_parabola"]))
        x, y = np.asarray(x), np.asarray(y)
        A = np.stack([np.ones_like(x), x], 1)
        coef, res, *_ = np.linalg.lstsq(A, y, rcond=None)
        sigma2 = float(np.sum((y - A @ coef) ** 2) / max(len(y) - 2, 1))
        cov = sigma2 * np.linalg.inv(A.T @ A)
        return float(coef[1]), float(math.sqrt(cov[1, 1]))

    def paper_readings(table: dict, ours: dict) -> str:
        readings = [_against_paper(ours[v], table[v], 20) for v in table]
        return (f"each within 2 combined s.e. of the paper's: {sum(a for a, _ in readings)} of {len(readings)} "
                f"with its ± as a standard error, {sum(b for _, b in readings)} of {len(readings)} as a "
                "standard deviation over its 20 piles")

    slope, slope_se = trend(by_kn, lambda v: math.log10(v))
    flat = abs(slope) <= 2 * slope_se
    rows = [["1993", f"{quantity_kn}, {piles} piles each", paper_kn,
             ", ".join(_pm(angles[v], 2, "") for v in KN_PAPER) + f"° (slope {slope:+.2f} ± {slope_se:.2f}° per "
             "decade of k_n)",
             f"no trend in k_n: {'agrees' if flat else 'differs'} (slope within 2 s.e. of 0: "
             f"{'yes' if flat else 'no'}); {paper_readings(KN_PAPER, angles)}"]]

    quantity_g = "θ_R against γ_n = 50, 100, 500 (γ_s = γ_n / 100) at μ = 0.2 (sec. 4; same box)"
    paper_g = "16.47 ± 0.75, 17.15 ± 0.62, 17.99 ± 0.64°: falls as γ_n falls, by ~5 %"
    if any(v is None for v in gammas.values()):
        rows.append(["1993", quantity_g, paper_g, _missing("kn_gamma"), "—"])
    else:
        by_g = {50.0: gammas[50], 100.0: gammas[100], 500.0: by_kn[1e6]}
        g_angles = {v: _angle(r) for v, r in by_g.items()}
        g_slope, g_se = trend(by_g, lambda v: math.log10(v))
        falls = _sign(g_slope, g_se, agree="agrees", differ="differs: rises as γ_n falls")
        rows.append(["1993", f"{quantity_g}, {min(len(r) for r in by_g.values())} piles each", paper_g,
                     ", ".join(_pm(g_angles[v], 2, "") for v in GAMMA_PAPER) + f"° (slope {g_slope:+.2f} ± "
                     f"{g_se:.2f}° per decade of γ_n)",
                     f"falls as γ_n falls: {falls}; {paper_readings(GAMMA_PAPER, g_angles)}"])

    paper_piles = by_kn[1e6]
    methods = {k: _angle(paper_piles, k) for k in METHODS_PAPER}

    def paired(a: str, b: str) -> dict:
        from baxter_readings import mean_stderr

        return mean_stderr([float(r[a]) - float(r[b]) for r in paper_piles
                            if r[a] not in ("", "None", "nan") and r[b] not in ("", "None", "nan")])

    d12, d23 = paired("repose_endpoints", "repose_least_squares"), paired("repose_least_squares",
                                                                           "repose_cumulative_parabola")
    order = [_sign(d["mean"], _se(d)) for d in (d12, d23)]
    rows.append(["1993", f"the three angle methods at μ = 0.2 (sec. 3: (1) the line h(0)–h(W), (2) least squares, "
                 f"(3) the cumulative parabola), the k_n = 1e6 piles ({len(paper_piles)})",
                 "20.14 ± 2.15, 18.90 ± 1.49, 17.88 ± 1.76° (ten piles): (1) > (2) > (3), within the error bars",
                 ", ".join(_pm(methods[k]) for k in METHODS_PAPER) + f"; paired (1) − (2) {_pm(d12)}, (2) − (3) "
                 f"{_pm(d23)}",
                 f"(1) > (2): {order[0]}; (2) > (3): {order[1]}"])
    return rows


def row_vcut() -> list[str]:
    """Sec. 5: the flux pile's steady level at v_cut = 0.1, 0.01 and 0.001 cm/s
    ("no essential difference"), each smaller v_cut against 0.1 at two
    standard errors."""
    import csv

    from baxter_readings import mean_stderr

    quantity = "flux pile (sec. 5): the steady level against v_cut = 0.1, 0.01, 0.001 cm/s, W = 4, μ = 0.2, 300 disks"
    paper = "no essential difference"
    if not (FLUX / "sweep.csv").exists() or not (VCUT / "sweep.csv").exists():
        return ["1993", quantity, paper, _missing("vcut"), "—"]  # a run under way resumes from its checkpoint
    runs = {}  # v_cut -> (insertions, levels) of its longest run
    for folder in (FLUX, VCUT, *VCUT_LONGER):
        if not (folder / "sweep.csv").exists():
            continue  # a longer run still under way
        found = {}
        with open(folder / "sweep.csv") as fh:
            for r in csv.DictReader(fh):
                v = float(r.get("v_cut") or 0.1)
                count, level = found.setdefault(v, ([], []))
                count.append(int(r["inserted"]))
                if r["steady_mean"] not in ("", "None", "nan"):
                    level.append(float(r["steady_mean"]))
        for v, run in found.items():
            if v not in runs or sum(run[0]) > sum(runs[v][0]):
                runs[v] = run
    inserted = {v: run[0] for v, run in runs.items()}
    levels = {v: run[1] for v, run in runs.items()}
    stats = {v: mean_stderr(levels[v]) for v in sorted(levels, reverse=True)}
    counts = {v: sum(inserted[v]) / len(inserted[v]) for v in stats}
    base = stats[0.1]
    shown = ", ".join(f"v_cut {v:g}: {_pm(s)} ({counts[v]:.0f} insertions)" for v, s in stats.items())
    # a level read over far fewer insertions comes from an earlier stage of the growth: in 60 s the 0.001 piles
    # inserted 99 disks and read 25.0 deg, in 190 s 208 and 29.0 deg, against 296 and 29.8 deg at 0.1
    if min(counts.values()) < 0.6 * max(counts.values()):
        # a smaller v_cut waits longer for rest, so fewer disks go in within the same time: the level is then
        # read over an earlier, lower part of the pile's growth, not like for like
        return ["1993", f"{quantity}, {min(s['count'] for s in stats.values())} piles each", paper, shown,
                "not like for like: within the same 60 s the smaller v_cut insert fewer disks, so their level is "
                "read earlier in the pile's growth (a rerun with max_time scaled by the insertion rate compares them)"]
    verdicts = [f"{v:g}: " + _close(s["mean"] - base["mean"], _se(s), _se(base)) for v, s in stats.items() if v != 0.1]
    verdicts.append("the smaller v_cut run longer (130 s, 190 s) for their insertions")
    return ["1993", f"{quantity}, {min(s['count'] for s in stats.values())} piles each", paper, shown,
            "; ".join(verdicts)]


def row_flux(theta_r: dict | None) -> list[str]:
    """Fig. 5: the angle of a pile fed one disk whenever it rests, read before each
    insertion (method 3) over the second half of the insertions: its mean level,
    its spread about that level (the figure's dotted lines) and its largest value,
    against the box pile's θ_R at the same μ (the paper: the largest angle a pile
    reaches before it avalanches is above θ_R)."""
    import csv

    from baxter_readings import mean_stderr

    quantity = "flux pile (Fig. 5): W = 4, μ = 0.2, 300 disks fed, the angle before each insertion (second half)"
    paper = "noisy level; its largest above θ_R (θ_MS > θ_R)"
    if not (FLUX / "sweep.csv").exists():
        return ["1993", quantity, paper, _missing("flux"), "—"]
    with open(FLUX / "sweep.csv") as fh:
        rows = list(csv.DictReader(fh))

    def stat(key):
        return mean_stderr([float(r[key]) for r in rows if r[key] not in ("", "None", "nan")])

    level, spread, largest = stat("steady_mean"), stat("steady_std"), stat("steady_max")
    fed = sum(int(r["inserted"]) == 300 for r in rows)
    jaxpile = (f"level {_pm(level)} (spread about it {_pm(spread)}), largest {_pm(largest)}; "
               f"{fed} of {len(rows)} piles fed all 300; θ_R (box, μ = 0.2) {_pm(theta_r)}; θ_MS = arctan 0.6 = 31.0°")
    if theta_r is None:
        return ["1993", f"{quantity}, {len(rows)} piles", paper, jaxpile, "— (no box θ_R at μ = 0.2)"]
    verdict = ("largest above θ_R: " + _sign(largest["mean"] - theta_r["mean"], _se(largest), _se(theta_r))
               + "; level above θ_R: " + _sign(level["mean"] - theta_r["mean"], _se(level), _se(theta_r)))
    return ["1993", f"{quantity}, {len(rows)} piles", paper, jaxpile, verdict]


# ----------------------------------------------------------------- 1997
HEAPS = RESULTS / "baxter_readings"
HEAP_SETTINGS = {  # setting -> what the paper says of it
    "hooke-k500": ("the equivalent Hooke law k = 500", "no clear M with a Hooke law"),
    "n144-r1.2": ("n = 144, r0 = 1.2 σ", "long tail: shear banding, no clear M (closer to experiment)"),
    "n144-r1.047": ("n = 144, r0 = 1.047 σ", "short tail: no clear M"),
    "poly10": ("10% polydisperse", "flatter heaps"),
    "poly5": ("5% polydisperse", "flatter heaps"),
    "mu0.2": ("μ = 0.2", "insensitive to μ in 0.2–0.6"),
    "mu0.6": ("μ = 0.6", "insensitive to μ in 0.2–0.6"),
}


def _m_shape(stat: dict) -> str:
    """What the flank/centre ratio of base force says, with its standard error:
    an M only when the flanks carry more than the centre by two errors."""
    mean, se = stat["mean"], stat.get("stderr")
    if se is None or not math.isfinite(se):
        return "one heap: " + ("flanks above the centre" if mean > 1 else "no M")
    if mean - 2 * se > 1:
        return "an M"
    return "no M" if mean + 2 * se < 1 else "no clear M"


def _heaps(n: int) -> dict[str, list[dict]]:
    import baxter_readings as br

    out: dict[str, list[dict]] = {}
    for row in br.heap_rows(HEAPS / f"n{n}"):
        out.setdefault(br.name_of(row), []).append(row)
    return out


def _angles(s: dict) -> str:
    a = s["angle"]
    return (f"{_pm(a['mid_flank'])} mid-flank, {_pm(a['least_squares'])} least squares, "
            f"{_pm(s['angle_height_base'])} from height and base")


def _m_verdict(shape: str, m_expected: bool) -> str:
    if shape == "no clear M" or shape.startswith("one heap"):
        return "not resolved (within 2 s.e. of 1)"
    return "agrees" if (shape == "an M") == m_expected else "differs"


HEAP_EXPECTS = {  # setting -> (an M expected, how its angle compares with the paper's law's: -1 flatter, 0 the same)
    "hooke-k500": (False, None), "n144-r1.2": (False, None), "n144-r1.047": (False, None),
    "poly10": (None, -1), "poly5": (None, -1), "mu0.2": (None, 0), "mu0.6": (None, 0),
}


def rows_1997() -> list[list[str]]:
    import baxter_readings as br

    rows = []
    paper = _heaps(1334).get("contact-point/hold", [])
    base = None  # the paper's law's mid-flank angle, which the other settings are compared with
    if paper:
        s = br.summarise(paper)["contact-point/hold"]
        base = s["angle"]["mid_flank"]
        rows.append(["1997", f"1334-disk heap (n = 36, r0 = 1.2 σ, S = 1.1 σ, dt = 1e-3), {len(paper)} heaps: "
                             "angle of repose", "35 ± 5°",
                     f"{_angles(s)}: {35 - base['mean']:.0f}° flatter than the paper's 35°; "
                     "no reading of the printed law closes the gap (`docs/baxter1997_audit.md`)",
                     "agrees" if 30 - 2 * _se(base) <= base["mean"] <= 40 + 2 * _se(base) else
                     "differs (below 30° by more than 2 s.e.)" if base["mean"] < 30 else "differs (above 40°)"])
        m = _m_shape(s["flank_over_centre"])
        rows.append(["1997", "the same: base normal force", "M, flank maxima 20–30% above the centre",
                     f"{m}: mean force at x/B 0.2–0.4 and 0.6–0.8 over 0.4–0.6 is "
                     f"{_pm(s['flank_over_centre'], 3, '')}", _m_verdict(m, True)])
    else:
        rows.append(["1997", "1334-disk heap: angle of repose and base force", "35 ± 5°, M", _missing("heap"), "—"])
    heaps = _heaps(1000)
    for name, (what, says) in HEAP_SETTINGS.items():
        mine = heaps.get(name)
        if not mine:
            continue
        s = br.summarise(mine)[name]
        count = f"{len(mine)} heaps" if len(mine) >= PILES else f"{len(mine)} of {PILES} heaps"
        m = _m_shape(s["flank_over_centre"])
        m_expected, angle_sign = HEAP_EXPECTS[name]
        if m_expected is not None:
            verdict = _m_verdict(m, m_expected)
        elif base is None:
            verdict = "— (no heaps of the paper's law to compare with)"
        else:
            a = s["angle"]["mid_flank"]
            d = a["mean"] - base["mean"]
            verdict = ((_sign(-d, _se(a), _se(base)) if angle_sign < 0 else _close(d, _se(a), _se(base)))
                       + f": mid-flank angle {d:+.1f}° from the 1334-disk heaps'")
        rows.append(["1997", f"1000-disk heaps, {what} ({count})", says,
                     f"{m}: flank/centre {_pm(s['flank_over_centre'], 2, '')}; angle {_angles(s)}", verdict])
    rows.extend(_rows_mu(heaps))
    rows.extend(_rows_n144(heaps))
    rows.extend(_rows_voidage())
    rows.extend(_rows_arch())
    rows.extend(_rows_banding())
    rows.extend(_rows_spacing())
    rows.extend(_rows_flat())
    rows.extend(_rows_avalanches())
    return rows


READ_SIZES = (1000, 300)
"""The heap sizes the spacing, flat-floor and avalanche rows read, largest first: the first with
`PILES` heaps of every setting the row compares (a study still running is not read)."""


def _largest_heaps(names) -> tuple[int, dict[str, list[dict]]] | None:
    """`(n, heaps by setting)` of the largest size of `READ_SIZES` whose
    `baxter_readings` heaps hold `PILES` of each setting in `names`, or None."""
    for n in READ_SIZES:
        heaps = _heaps(n)
        if all(len(heaps.get(name, ())) >= PILES for name in names):
            return n, heaps
    return None


def _rows_avalanches() -> list[list[str]]:
    """Sec. III as measured statements: the paper's law grows its heap "by a
    series of avalanches in a boundary layer ~3-4 particles thick", the Hooke
    law's "by small numbers of grains rolling down the sides". The layer: the
    deepest disk that moved 0.5 sigma between samples, 90th percentile of a
    heap's samples, within 3-4 diameters at 2 s.e.; the contrast: more disks
    moving at once under the paper's law than under Hooke's, at 2 s.e.; and
    Hooke's "small numbers": two or fewer at once, at 2 s.e."""
    says = "baxter: avalanches in a layer ~3–4 disks thick, the interior static; Hooke: small numbers of grains roll"
    for n in READ_SIZES:
        found = _load(HEAPS / f"n{n}" / "avalanches.json")
        if found is not None and all(found["summary"].get(law, {}).get("heaps", 0) >= PILES
                                     for law in ("baxter", "hooke-k500")):
            break
    else:
        return [["1997", "heaps while fed: avalanches in a surface layer against single rolling grains (sec. III)",
                 says, _missing("avalanches"), "—"]]
    what = f"{n}-disk heaps while fed: avalanches in a surface layer against single rolling grains (sec. III)"
    b, h = found["summary"]["baxter"], found["summary"]["hooke-k500"]
    layer = b["thickness_p90"]
    low, high = 3.0 - 2 * _se(layer), 4.0 + 2 * _se(layer)
    measured = "; ".join(
        f"{name}: {_pm(s['moving'], 1, '')} disks moving at once, the layer {_pm(s['thickness_p90'], 1, '')} "
        f"diameters deep (90% of samples), {_pm({k: 100 * v if isinstance(v, float) else v for k, v in s['collective'].items()}, 0, '%')} "
        f"of samples with 5 or more moving"
        for name, s in (("baxter", b), ("Hooke", h)))
    single = h["moving"]["mean"] - 2 * _se(h["moving"]) <= 2.0  # "small numbers of grains": two or fewer at once
    verdict = (f"layer {'agrees' if low <= layer['mean'] <= high else 'differs'} (3–4 diameters); baxter against "
               "Hooke, disks moving at once: " + _sign(b["moving"]["mean"] - h["moving"]["mean"], _se(b["moving"]),
                                                      _se(h["moving"]), agree="agrees (more)", differ="differs (fewer)")
               + f"; Hooke's single rolling grains: {'agrees' if single else 'differs'} "
               f"({h['moving']['mean']:.1f} at once, a shallower layer)")
    return [["1997", f"{what}, {min(b['heaps'], h['heaps'])} heaps a law", says, measured, verdict]]


FLATS = {"flat-smooth": "smooth (wall_mu = 0)", "flat-rough": "rough (wall_mu = mu = 0.5)"}
"""The flat floors of the pours (`pour`'s `floor="flat"`), by their setting."""


def _rows_flat() -> list[list[str]]:
    """Sec. II: on "a flat smooth structureless surface ... a stable heap could
    not be formed": the share of the poured disks still on a flat floor of
    the row's length 500 time units after the pour, against the row's, for the
    largest pours of `READ_SIZES` with `PILES` on each; no stable heap when
    under half stay (2 s.e.) or none came to rest."""
    import baxter_readings as br

    says = "no stable heap on a flat smooth surface; stable heaps on the row"
    if (found := _largest_heaps((*FLATS, "contact-point/hold"))) is None:
        return [["1997", "pours on a flat floor, the row's length (sec. II)", says, _missing("flat"), "—"]]
    n, heaps = found
    what = f"{n}-disk pours on a flat floor, the row's length (sec. II)"
    kept, shown = {}, []
    for name in (*FLATS, "contact-point/hold"):
        rows = heaps[name]
        kept[name] = br.mean_stderr([1.0 - r["counts"]["lost"] / r["n"] for r in rows])
        percent = {k: 100 * v if isinstance(v, float) else v for k, v in kept[name].items()}
        angle = br.summarise(rows)[name]["angle"]["mid_flank"]
        label = FLATS.get(name, "the row (S = 1.1 σ)")
        shown.append(f"{label}: {_pm(percent, 1, '%')} of the disks stay"
                     + (f", mid-flank angle {_pm(angle)}" if angle["count"] else ", no heap to read"))
    smooth = kept["flat-smooth"]
    no_heap = (smooth["mean"] + 2 * _se(smooth) < 0.5
               or not any(r["run"]["at_rest"] for r in heaps["flat-smooth"]))
    row_holds = kept["contact-point/hold"]["mean"] > 0.9
    count = min(len(heaps[name]) for name in FLATS)
    return [["1997", f"{what}, {count} heaps a floor", says, "; ".join(shown),
             ("agrees" if no_heap and row_holds else "differs")
             + f": on the smooth floor {'no' if no_heap else 'a'} stable heap"]]


SPACINGS = {1.0: "S1.0", 1.05: "S1.05", 1.1: "contact-point/hold", 1.2: "S1.2", 1.3: "S1.3"}
"""The substrate spacings S (sigma) of the heaps, by their setting (1.1: the paper's)."""


def _rows_spacing() -> list[list[str]]:
    """Sec. III: "the angle of repose was found to decrease with increasing
    substrate particle spacing S, with a local plateau in the range S >= 1.1
    sigma": the mid-flank angle at each S, of the largest heaps of
    `READ_SIZES` with `PILES` at every S (a study still running is not read)."""
    import baxter_readings as br

    says = "falls as S grows, a plateau for S ≥ 1.1 σ"
    if (found := _largest_heaps(SPACINGS.values())) is None:
        return [["1997", "the angle against the substrate's spacing S (sec. III)", says, _missing("spacing"), "—"]]
    n, heaps = found
    what = f"{n}-disk heaps: the angle against the substrate's spacing S (sec. III)"
    angle = {S: br.summarise(heaps[name])[name]["angle"]["mid_flank"] for S, name in SPACINGS.items()}
    shown = ", ".join(f"{S:g}: {_pm(a)}" for S, a in angle.items())
    falls = angle[1.3]["mean"] - angle[1.0]["mean"]
    plateau = [angle[S] for S in (1.1, 1.2, 1.3)]
    spread = max(a["mean"] for a in plateau) - min(a["mean"] for a in plateau)
    bound = 2.0 * math.hypot(*sorted((_se(a) for a in plateau), reverse=True)[:2])
    return [["1997", f"{what}, {min(len(heaps[n]) for n in SPACINGS.values())} heaps a value", says,
             f"mid-flank angle at S = {shown}",
             "falls from 1.0 to 1.3: " + _sign(-falls, _se(angle[1.3]), _se(angle[1.0]))
             + f"; plateau from 1.1: {'agrees' if spread <= bound else 'differs'} (spread {spread:.1f}°, 2 s.e. {bound:.1f}°)"]]


def _voidage(n: int) -> dict:
    """`baxter_voidage.py`'s summary of the n-disk heaps, by setting (file prefix)."""
    found = _load(HEAPS / f"n{n}" / "voidage.json")
    return {} if found is None else found["settings"]


ARCH = RESULTS / "baxter_readings" / "n1334" / "arch_contact-point_hold.json"
"""The arch under the apex (Fig. 3a), read off the 1334-disk heaps' saved states (`baxter_arch.py`)."""


def _rows_arch() -> list[list[str]]:
    """Fig. 3a as a measured statement: the disks' pressure (the trace of their
    stress) in the column under the apex over the columns beside it, at the same
    heights, in the heap's lower half; an arch makes it less than 1."""
    arch = _load(ARCH)
    if arch is None:
        return [["1997", "1334-disk heaps: the arch under the apex (Fig. 3a)", "stresses smaller beneath the arch",
                 "not run yet (`python benchmarks/studies/papers/baxter_arch.py`, on the heaps' saved states)", "—"]]
    s = arch["summary"]
    at, over = s["lower_pressure_centre_over_sides"], s["lower_centre_over_sides"]
    return [["1997", f"1334-disk heaps ({s['count']}): the arch under the apex (Fig. 3a): disks' pressure under the "
                     "apex (within 0.1 B of it) over 0.15–0.3 B beside it, lower half of the heap",
             "lines of principal stress meet below the apex in an arch, the stresses beneath it smaller",
             f"{_pm(at, 2, '')} at the same heights (the column under the apex is deeper); over the depth above each "
             f"disk {_pm(over, 2, '')}",
             _sign(1.0 - at["mean"], _se(at), agree="agrees: an arch", differ="differs: no arch, the centre carries "
                                                                               "more (as the base force, no M)")]]


BANDING = RESULTS / "baxter_readings" / "n1000" / "banding.json"
"""The density maps' contrast of the 1000-disk heaps (Figs. 2, 6), from their saved states (`baxter_banding.py`)."""


def _rows_banding() -> list[list[str]]:
    """Figs. 2 and 6 as a measured statement: shear bands are lines of low
    density in the map, so they raise its contrast (the cells' spread of
    packing fraction, and the share of cells 0.05 looser than the median);
    n = 144 with the short tail against n = 36 at two standard errors."""
    out = _load(BANDING)
    what = "1000-disk heaps: shear banding (Figs. 2, 6) as the density map's contrast (2 σ cells inside the heap)"
    if out is None:
        return [["1997", what, "banding with n = 36; largely gone with n = 144, r0 = 1.047 σ",
                 "not run yet (`python benchmarks/studies/papers/baxter_banding.py`, on the heaps' saved states)", "—"]]
    s = out["settings"]
    n36, short, long_, hooke = (s.get(k) for k in ("contact-point_hold", "n144-r1.047", "n144-r1.2", "hooke-k500"))
    if not (n36 and short):
        return [["1997", what, "banding with n = 36; largely gone with n = 144, r0 = 1.047 σ", "—", "—"]]

    def text(name, x):
        return f"{name} {_pm(x['std'], 4, '')} (looser cells {_pm(x['looser_share'], 3, '')})"

    parts = [text("n = 36", n36), text("n = 144, r0 = 1.047 σ", short)]
    parts += [text(name, x) for name, x in (("n = 144, r0 = 1.2 σ", long_), ("Hooke k = 500", hooke)) if x]
    verdict = ("spread lower with n = 144, r0 = 1.047 σ: " + _sign(n36["std"]["mean"] - short["std"]["mean"],
                                                                 _se(n36["std"]), _se(short["std"]))
               + "; fewer loose cells: " + _sign(n36["looser_share"]["mean"] - short["looser_share"]["mean"],
                                                 _se(n36["looser_share"]), _se(short["looser_share"])))
    if hooke:
        verdict += "; its spread as the Hooke law's: " + _close(short["std"]["mean"] - hooke["std"]["mean"],
                                                              _se(short["std"]), _se(hooke["std"]))
    return [["1997", f"{what}, {n36['heaps']} heaps a setting", "banding with n = 36; largely gone with n = 144, "
             "r0 = 1.047 σ (the map then resembles the Hooke law's)", "spread of the cells' packing fraction: "
             + "; ".join(parts), verdict]]


def _rows_voidage() -> list[list[str]]:
    """Figs. 2d, 5a and 8 as measured statements: the poured disks' area
    fraction in bands of the apex height in the column under the apex, and at
    the edges (`baxter_voidage.py`); each difference against two standard errors."""
    rows = []
    paper = _voidage(1334).get("contact-point_hold")
    if paper:
        bands = ", ".join(f"{b['mean']:.3f}" for b in paper["bands"])
        d = {k: paper[k] for k in ("base_minus_middle", "middle_minus_top", "centre_minus_edges")}
        rows.append(["1997", f"1334-disk heaps ({paper['heaps']}): packing by height under the apex (Fig. 2d; "
                             "`docs/baxter1997_voidage_n1334.png`)",
                     "most dense near the base, low density about halfway up, looser towards the apex and edges",
                     f"area fraction {bands} from the base band to 0.6–0.8 of the height; edges "
                     f"{_pm(paper['edges'], 3, '')} (the soft law's overlaps count twice)",
                     "base above halfway: " + _sign(d["base_minus_middle"]["mean"], _se(d["base_minus_middle"]))
                     + "; halfway above the top: " + _sign(d["middle_minus_top"]["mean"], _se(d["middle_minus_top"]))
                     + "; centre above the edges: " + _sign(d["centre_minus_edges"]["mean"], _se(d["centre_minus_edges"]))])
    hooke = _voidage(1000).get("hooke-k500")
    if hooke:
        d = hooke["centre_minus_edges"]
        rows.append(["1997", f"1000-disk heaps, the equivalent Hooke law ({hooke['heaps']}): packing under the apex "
                             "against the wings (Fig. 5a)", "a large region of low voidage below the apex, moderately "
                     "dense wings", f"base band under the apex {_pm(hooke['bands'][0], 3, '')}, edges "
                     f"{_pm(hooke['edges'], 3, '')}: {d['mean']:+.3f}",
                     "denser under the apex: " + _sign(d["mean"], _se(d))])
    mono = _voidage(1000).get("contact-point_hold")
    for name, what in (("poly5", "5 %"), ("poly10", "10 %")):
        poly = _voidage(1000).get(name)
        if not poly:
            continue
        if not mono:
            rows.append(["1997", f"1000-disk heaps, {what} polydisperse against monodisperse: packing (Fig. 8)",
                         "much higher compaction", _missing("heap1000_n36,voidage"), "—"])
            continue
        mean = lambda s: sum(b["mean"] for b in s["bands"]) / len(s["bands"])
        err = lambda s: math.sqrt(sum(_se(b) ** 2 for b in s["bands"])) / len(s["bands"])
        rows.append(["1997", f"1000-disk heaps, {what} polydisperse against monodisperse ({poly['heaps']} and "
                             f"{mono['heaps']}): packing under the apex (Fig. 8)", "much higher compaction",
                     f"{mean(poly):.3f} against {mean(mono):.3f}",
                     "higher: " + _sign(mean(poly) - mean(mono), err(poly), err(mono))])
    return rows


def _rows_n144(heaps: dict) -> list[list[str]]:
    """Sec. III: at 1000 disks "the angle of repose was 35 deg as opposed to 31 deg
    for the n = 36 case": the n = 144 heaps (both tails) against the paper's law's."""
    import baxter_readings as br

    what = "1000-disk heaps, n = 144 against n = 36 (sec. III)"
    if not heaps.get("contact-point/hold"):
        return [["1997", what, "35° against 31°: n = 144 steeper by 4°", _missing("heap1000_n36"), "—"]]
    base = br.summarise(heaps["contact-point/hold"])["contact-point/hold"]["angle"]["mid_flank"]
    rows = []
    for name, tail in (("n144-r1.2", "long tail, r0 = 1.2 σ"), ("n144-r1.047", "short tail, r0 = 1.047 σ")):
        if not heaps.get(name):
            continue
        a = br.summarise(heaps[name])[name]["angle"]["mid_flank"]
        d = a["mean"] - base["mean"]
        rows.append(["1997", f"{what}: {tail} ({len(heaps[name])} and {len(heaps['contact-point/hold'])} heaps)",
                     "35° against 31°: steeper by 4°",
                     f"mid-flank {_pm(a)} against {_pm(base)}: {d:+.1f}°",
                     _sign(d, _se(a), _se(base), agree="agrees (steeper)", differ="differs (flatter)")])
    return rows


def _rows_mu(heaps: dict) -> list[list[str]]:
    """Sec. III's "heap properties ... relatively insensitive to the value of the
    friction coefficient in the sensible range 0.2 < mu < 0.6", as the 1000-disk
    heaps at mu = 0.2 and 0.6 measure it: the mid-flank angle and the base force's
    flank/centre ratio, each difference against two combined standard errors."""
    import baxter_readings as br

    if not (heaps.get("mu0.2") and heaps.get("mu0.6")):
        return []
    low, high = (br.summarise(heaps[k])[k] for k in ("mu0.2", "mu0.6"))
    a_low, a_high = low["angle"]["mid_flank"], high["angle"]["mid_flank"]
    f_low, f_high = low["flank_over_centre"], high["flank_over_centre"]
    d_angle, d_force = a_high["mean"] - a_low["mean"], f_high["mean"] - f_low["mean"]
    return [["1997", f"1000-disk heaps, μ = 0.6 against μ = 0.2 ({len(heaps['mu0.6'])} and {len(heaps['mu0.2'])} heaps)",
             "heap properties insensitive to μ in 0.2–0.6",
             f"mid-flank angle {d_angle:+.1f}° ({_pm(a_high)} against {_pm(a_low)}); base flank/centre "
             f"{d_force:+.2f} ({_pm(f_high, 2, '')} against {_pm(f_low, 2, '')})",
             "angle: " + _close(d_angle, _se(a_high), _se(a_low)) + "; base force: "
             + _close(d_force, _se(f_high), _se(f_low)).replace("agrees", "insensitive").replace("differs", "depends on μ")]]


# ----------------------------------------------------- rolling resistance
ROLLING = RESULTS / "rolling" / "gpu_h200" / "rolling_summary.json"


def rows_rolling() -> list[list[str]]:
    """Beyond the papers: the box's angle of repose and the drop's central dip with
    rolling resistance (`rolling_results.py`, from `gpu_rolling.sh`'s sweeps)."""
    s = _load(ROLLING)
    if s is None:
        return [["beyond", "rolling resistance (sds)", "—", "not run yet (`bash benchmarks/studies/papers/gpu_rolling.sh`)",
                 "—"]]
    box = s["box"]["points"]
    angles = ", ".join(_pm(p["repose_cumulative_parabola"]) for p in box)
    rolls = ", ".join(f"{p['mu_roll']:g}" for p in box)
    count = max(p["repose_cumulative_parabola"]["count"] + p["repose_cumulative_parabola"]["missing"] for p in box)
    rows = [["beyond", f"1993 box (W = H = 4, 409 disks, hooke μ = 0.2, spins on) with rolling resistance sds, "
                       f"θ_R against μ_r = {rolls}, {count} piles each",
             "rises with μ_r and saturates (Zhou et al. 2001; Ai et al. 2011)",
             f"{angles} (μ_r = 0: the disks roll off; `docs/rolling_resistance.md`)",
             "rises: " + _sign(box[-1]["repose_cumulative_parabola"]["mean"] - box[0]["repose_cumulative_parabola"]["mean"],
                               _se(box[-1]["repose_cumulative_parabola"]), _se(box[0]["repose_cumulative_parabola"]),
                               differ="differs: falls")]]
    drop = s["drop"]["points"]
    cells = "; ".join(f"μ = {p['mu']:g}, μ_r = {p['mu_roll']:g}: {_pm(p['central_dip'], 2, '')}" for p in drop)
    best = max(drop, key=lambda p: p["central_dip"]["mean"])["central_dip"]
    rows.append(["beyond", f"1992 drop, 300 disks, hooke with rolling resistance sds: central dip over (μ, μ_r), "
                           f"{drop[0]['central_dip']['count']} piles each",
                 "Smid–Novosad 20–30%; no dip without rolling resistance", cells,
                 f"the best, {_pm(best, 2, '')}, is {_against_reported_dip(best['mean'], _se(best))}"
                 " (one central bin: see `docs/rolling_resistance.md`)"])
    return rows + rows_rolling_pour() + rows_rolling_fit()


POUR_PROFILES = sorted((RESULTS / "rolling").glob("cpu_pour_profiles*/profiles.json"))
"""The poured heaps' mean base profiles (`pour_profiles.py`), one folder a sliding friction."""
POUR_GRIDS = [RESULTS / "rolling" / "pour_grid.json", *sorted((RESULTS / "rolling").glob("*/pour_grid.json"))]
"""The declared dip and angle against those heaps (`pour_profiles.py --grid`), one file a set-up of the pour."""


def rows_rolling_pour() -> list[list[str]]:
    """Beyond the papers: the 1997 heap's mean base profile with rolling resistance,
    the centre below the flanks heap by heap, each heap's flank bins chosen on
    the other heaps (`pour_profiles.centre_below_flanks(held_out=True)`: chosen
    on the same heaps, noise makes an M)."""
    import numpy as np
    import pour_profiles

    cells, best = [], None
    for path in POUR_PROFILES:
        s = json.loads(path.read_text())
        mu = 0.5 if s.get("mu") is None else s["mu"]  # the paper's, where the run did not set it
        rate = pour_profiles.set_up_label(s)
        for mu_roll, point in s["by_mu_roll"].items():
            profiles = np.array([r["profile"] for r in s["rows"]
                                 if str(r["mu_roll"]) == mu_roll and r.get("profile") is not None], float)
            below = pour_profiles.centre_below_flanks(profiles, held_out=True)
            cells.append(f"μ = {mu:g}, μ_r = {float(mu_roll):g}{rate}: {_pm({**below, 'mean': below['value']}, 2, '')}, "
                         f"θ {_pm(point['repose_mean'])}")
            if best is None or below["value"] > best[0]["value"]:
                best = (below, point["repose_mean"])
    if best is None:
        return []
    best, best_angle = best
    at_angle = ""
    for path in (p for p in POUR_GRIDS if p.exists()):  # the declared pair against each set-up's grid
        grid = json.loads(path.read_text())
        label = pour_profiles.set_up_label(grid)
        for c in grid.get("crossings", []):  # where the angle meets the reported one, interpolated
            held = c.get("centre_below_flanks_held_out")  # flank bins chosen on the other heaps: unbiased
            if held:
                at_angle += (f"; at the reported angle (μ = {grid['mu']:g}, μ_r ≈ {c['mu_roll'][0]:.2f} ± "
                             f"{c['mu_roll'][1]:.2f}{label}, interpolated) {held[0]:.2f} ± {held[1]:.2f}, "
                             + ("in 20–30%" if 0.2 <= held[0] <= 0.3 else
                                f"{(0.2 - held[0]) / held[1]:.1f} s.e. below 20%" if held[0] < 0.2 else
                                f"{(held[0] - 0.3) / held[1]:.1f} s.e. above 30%"))
        for key, reading in (("fit", "the per-heap dip"), ("fit_profile", "the mean profile's dip (held out)"),
                             ("fit_narrow", "each heap's dip in fixed narrow windows")):
            if fit := grid.get(key):  # μ_r fitted to both through the grid's heaps (`pour_profiles.fit_along`)
                (d, de), (a, ae) = fit["central_dip"], fit["repose_mean"]
                at_angle += (f"; fitted to dip and angle with {reading} (μ = {grid['mu']:g}{label}, a line through "
                             f"{fit['heaps']} heaps) μ_r = {fit['mu_roll'][0]:.3f} (95%: {fit['interval'][0]:.3f}–"
                             f"{fit['interval'][1]:.3f}), where the dip is {d:.2f} ± {de:.2f} ("
                             + ("in 20–30%" if 0.2 <= d <= 0.3 else f"{(0.2 - d) / de:.1f} s.e. below 20%" if d < 0.2
                                else f"{(d - 0.3) / de:.1f} s.e. above 30%") + f") at θ {a:.1f} ± {ae:.1f}°")
    return [["beyond", "1997 pour, 300 disks, baxter (n = 36, r0 = 1.2) with rolling resistance sds: the centre "
                       "below the flanks of the mean base profile (flank bins chosen on the other heaps), 16 heaps each",
             "Smid–Novosad 20–30% at 32.6°", "; ".join(cells),
             f"the largest, {best['value']:.2f} ± {best['stderr']:.2f} at θ {best_angle['mean']:.1f}°, is "
             + _against_reported_dip(best["value"], _se(best)) + at_angle + " (`docs/rolling_resistance.md`)"]]


CLI_FIT = RESULTS / "rolling" / "cli_fit"
"""`jaxpile fit` of mu_roll to the Smid–Novosad pair at 300 disks and its recovery of a known
mu_roll (their commands in `smid_novosad.cmd` and `recovery.cmd` beside them)."""


def _fitted(fit: dict, name: str) -> str:
    """`name`'s fitted value with its 95 % interval, Gauss-Newton's and the
    line's through every ensemble (`jaxpile.fit.regression`) where there is one."""
    lo, hi = fit["interval"][name]
    text = f"{fit['values'][name]:.3f} (95%: {lo:.3f}–{hi:.3f})"
    line = fit.get("regression")
    if line:
        lo, hi = line["interval"][name]
        text += f", through all {line['points']} ensembles {line['values'][name]:.3f} ({lo:.3f}–{hi:.3f})"
    return text


def _holds(fit: dict, name: str, truth: float) -> bool:
    """Whether every interval the fit reports holds `truth`."""
    intervals = [fit["interval"][name]] + ([fit["regression"]["interval"][name]] if fit.get("regression") else [])
    return all(lo <= truth <= hi for lo, hi in intervals)


def rows_rolling_fit() -> list[list[str]]:
    """Beyond the papers: `jaxpile fit --target smid-novosad` of mu_roll on 300-disk
    pours, after its recovery of a known mu_roll from a synthetic target."""
    import numpy as np
    from jaxpile.fit.targets import SMID_NOVOSAD_ANGLE_DEGREES as REPORTED_ANGLE

    fit, recovery = _load(CLI_FIT / "smid_novosad" / "fit.json"), _load(CLI_FIT / "recovery" / "fit.json")
    if fit is None or recovery is None:
        return []
    name = fit["names"][0]
    members = np.asarray(fit["fitted_members"], float)
    mean, se = members.mean(axis=0), members.std(axis=0, ddof=1) / np.sqrt(len(members))
    there = dict(zip(fit["target"]["labels"], zip(mean, se)))
    (dip, dip_se), (angle, angle_se) = there["dip_below_flanks"], there["repose_mean"]
    last = fit["history"][-1]  # the last Gauss-Newton step against its own standard error
    moved = abs(last["next_theta"][0] - last["theta"][0]) / last["step_stderr"][0]
    truth = recovery["target"]["truth"][name]
    held = _holds(recovery, name, truth)
    verdict = (f"dip {_against_reported_dip(dip, dip_se)} and angle {_close(angle - REPORTED_ANGLE, angle_se)} with "
               f"{REPORTED_ANGLE:g}°" + ("; the recovery's intervals hold the truth" if held else
                                         "; the recovery missed the truth"))
    return [["beyond", f"`jaxpile fit --target smid-novosad` of μ_r: 1997 pour, 300 disks, baxter (μ = "
                       f"{fit['params']['mu']:g}) with rolling sds, narrow source, {len(fit['seeds'])} heaps a point, "
                       f"{len(fit['history'])} Gauss–Newton iterations",
             "Smid–Novosad 20–30% at 32.6°",
             f"μ_r = {_fitted(fit, name)}, from {fit['start'][name]:g}, the last step {moved:.1f} s.e.; there dip {dip:.2f} ± {dip_se:.2f}, "
             f"θ {angle:.1f} ± {angle_se:.1f}°; recovery of μ_r = {truth:g} from "
             f"{recovery['start'][name]:g}: {_fitted(recovery, name)}",
             verdict + " (`docs/rolling_resistance.md`)"]]


CONE_GRID = (RESULTS / "cone" / "n300_mu_roll", RESULTS / "cone" / "n300_mu_roll_0.4")
"""The 3D cone (`jaxpile sweep --protocol cone`, 300 spheres, 8 heaps a mu_roll; commands beside them)."""


def rows_cone() -> list[list[str]]:
    """Beyond the papers, in 3D: Smid & Novosad's own heap, a cone of spheres,
    on a grid of mu_roll at mu = 0.5: does any give the reported dip at the
    reported angle?"""
    from jaxpile.fit.targets import SMID_NOVOSAD_ANGLE_DEGREES as REPORTED_ANGLE
    from jaxpile.fit.targets import SMID_NOVOSAD_DIP_RANGE

    points = []
    for path in (p / "sweep.json" for p in CONE_GRID):
        if (sweep := _load(path)) is None:
            continue
        summary = sweep["summaries"]
        for k, x in enumerate(summary["angle"]["x"]):
            points.append((x, *({part: summary[key][part][k] for part in ("mean", "stderr")}
                                for key in ("angle", "angle_height_base", "central_dip")), sweep))
    if not points:
        return []
    points.sort(key=lambda p: p[0])
    sweep = points[0][-1]
    cells = [f"μ_r = {x:g}: θ {angle['mean']:.1f} ± {angle['stderr']:.1f}° (atan h/R {base['mean']:.1f}°), dip "
             f"{dip['mean']:.2f} ± {dip['stderr']:.2f}" for x, angle, base, dip, _ in points]
    steepest = max(points, key=lambda p: p[1]["mean"])
    deepest = max(points, key=lambda p: p[3]["mean"])
    low = SMID_NOVOSAD_DIP_RANGE[0]
    below = (low - deepest[3]["mean"]) / deepest[3]["stderr"]
    verdict = (f"differs: no μ_r of the grid gives the reported pair; the steepest cone, {steepest[1]['mean']:.1f} ± "
               f"{steepest[1]['stderr']:.1f}° at μ_r = {steepest[0]:g}, is below {REPORTED_ANGLE:g}°, and every dip is "
               f"negative (the centre loaded most, as a hydrostatic cone's); the largest, {deepest[3]['mean']:.2f} at "
               f"μ_r = {deepest[0]:g}, is {below:.1f} s.e. below 20%: a measured no at {sweep['options']['n']} spheres "
               "(`docs/three_dimensions.md`)")
    return [["beyond", f"3D cone (Smid–Novosad's heap), {sweep['options']['n']} spheres poured from a narrow source "
                       f"onto a rough plate, hooke μ = 0.5 with rolling sds, {len(sweep['seeds'])} heaps a point: "
                       "the angle from h(r) and the dip of p(r)",
             f"Smid–Novosad 20–30% at {REPORTED_ANGLE:g}°", "; ".join(cells), verdict]]


# ----------------------------------------------------------------- table
def table() -> str:
    rows = rows_1992() + rows_1993() + rows_1997() + rows_rolling() + rows_cone()
    lines = ["| paper | quantity | paper | jaxpile | verdict |", "|---|---|---|---|---|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def rewrite_page(check: bool = False) -> bool:
    """Writes the table into docs/papers.md (between its markers); with `check`,
    only says whether it is already there. Returns True when the page holds it."""
    import docs_block

    return docs_block.rewrite(START, END, table(), check=check, page=PAGE)


# ---------------------------------------------------------------- figures
def figures(folder: pathlib.Path = ROOT / "docs", papers: tuple[str, ...] = ("1992", "1993", "1997")) -> list[str]:
    """The ensembles' figures, drawn from the same results JSON as the table
    (a study with no results draws nothing): the dropped piles' mean base
    profile with its band (1992 Fig. 20), theta_R, theta_T and theta_R + theta_T
    against mu with theta_MS (1993 Figs. 4, 7a), and each 1997 heap size's mean
    base profiles and flank angles. Returns the paths written."""
    import baxter_readings as br
    import paper_ensembles as pe

    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    drawn = []
    if "1992" in papers and (piles := pe.pile_rows(DROP)):
        drawn.append(str(folder / "liffman1992_drop_ensemble.png"))
        pe.figure_drop(piles, drawn[-1])
    if "1992" in papers and all(path.exists() for path in SLOPED_ANGLES.values()):
        drawn.append(str(folder / "liffman1992_sloped_angles.png"))
        figure_sloped_angles({a: _load(path) for a, path in SLOPED_ANGLES.items()}, drawn[-1])
    if "1993" in papers and all((WIDTH / f"w{w:g}" / "sweep.csv").exists() for w in WIDTHS):
        drawn.append(str(folder / "lee_herrmann1993_size.png"))
        figure_size(drawn[-1])
    if "1993" in papers and (tilts := pe.pile_rows(TILT.parent)):
        drawn.append(str(folder / "lee_herrmann1993_tilt_ensemble.png"))
        pe.figure_tilt(tilts, drawn[-1])
    if "1997" in papers and (voids := _load(HEAPS / "n1334" / "voidage.json")):
        import baxter_voidage as bv

        drawn.append(str(folder / "baxter1997_voidage_n1334.png"))
        bv.figure(voids, drawn[-1])
    elsewhere = set(FLATS) | {name for S, name in SPACINGS.items() if S != 1.1}  # not on the paper's row
    for n in ((1334, 1000) if "1997" in papers else ()):
        if heaps := [h for h in br.heap_rows(HEAPS / f"n{n}") if br.name_of(h) not in elsewhere]:
            drawn.append(str(folder / f"baxter1997_n{n}.png"))
            br.figure(heaps, drawn[-1], f"Baxter et al. 1997 heaps of {n} disks, poured onto S = 1.1 sigma")
    return drawn


def _sweep_csv(path: pathlib.Path) -> list[dict]:
    import csv

    with open(path) as fh:
        return list(csv.DictReader(fh))


def figure_size(path: str) -> None:
    """Fig. 2: theta_R (method 3) against the box's height H at W = 2 (a) and
    against its width W at H / W = 2 for three mu (b), mean +- s.e. over piles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (by_h, by_w) = plt.subplots(1, 2, figsize=(10, 4))
    if (HEIGHT / "sweep.csv").exists():
        rows = _sweep_csv(HEIGHT / "sweep.csv")
        heights = sorted({float(r["height"]) for r in rows})
        stats = [_angle([r for r in rows if float(r["height"]) == h]) for h in heights]
        by_h.errorbar(heights, [a["mean"] for a in stats], yerr=[_se(a) for a in stats], marker="s", capsize=3)
    by_h.set(xlabel="H", ylabel="θ_R (deg)", title="(a) against H, W = 2, μ = 0.2")
    rows = [{**r, "width": w} for w in WIDTHS for r in _sweep_csv(WIDTH / f"w{w:g}" / "sweep.csv")]
    for mu, marker in ((0.1, "D"), (0.2, "s"), (0.3, "o")):
        stats = [_angle([r for r in rows if float(r["mu"]) == mu and r["width"] == w]) for w in WIDTHS]
        by_w.errorbar(WIDTHS, [a["mean"] for a in stats], yerr=[_se(a) for a in stats], marker=marker, capsize=3,
                      label=f"μ = {mu:g}")
    by_w.set(xlabel="W", ylabel="θ_R (deg)", title="(b) against W, H / W = 2")
    by_w.legend(fontsize=8)
    fig.suptitle(f"Lee & Herrmann 1993 Fig. 2: the box's size, {PILES} piles a point")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def figure_sloped_angles(piles: dict, path: str) -> None:
    """Figs. 13 and 14: each sloped pile's base normal and horizontal forces,
    normalised by the largest simulated one as the paper does, against eqs. 54-59."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from jaxpile.measure import theory

    fig, (normal, horizontal) = plt.subplots(1, 2, figsize=(10, 4))
    for k, (alpha, pile) in enumerate(piles.items()):
        forces, base, a = pile["base_forces"], pile["base"], np.radians(alpha)
        x = np.asarray(forces["x"])
        grid = np.linspace(0.0, base, 400)
        for ax, column, eq in ((normal, "normal", theory.continuum_ground_normal_force),
                               (horizontal, "horizontal", theory.continuum_ground_horizontal_force)):
            values = np.asarray(forces[column])
            scale = np.abs(values).max()
            ax.plot(x / base, values / scale, "o", ms=3, color=f"C{k}", label=f"{alpha}°: simulated")
            ax.plot(grid / base, eq(grid, a, base) / scale, "-", color=f"C{k}", lw=1, label=f"{alpha}°: eqs.")
    normal.set_title("base normal force (Fig. 13; eqs. 54, 56, 58)")
    horizontal.set_title("base horizontal force (Fig. 14; eqs. 55, 57, 59)")
    for ax in (normal, horizontal):
        ax.set_xlabel("x / B")
        ax.set_ylabel("force / largest simulated")
    normal.legend(fontsize=7, ncol=2)
    fig.suptitle(f"Liffman et al. 1992: sloped piles of {piles[30]['n_particles']} disks")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def notebook_section(paper: str, folder: str = ".") -> list[str]:
    """A paper notebook's figures of its ensembles at the paper's sizes, drawn
    into `folder` from the files a committed command wrote (`make papers` runs
    what is missing); the notebook's closing table prints `verdict_rows`.
    Returns the figure paths."""
    return figures(pathlib.Path(folder), (paper,))


def verdict_rows(paper: str) -> list[tuple[str, str, str, str]]:
    """A paper's rows of the papers table as `(quantity, paper, jaxpile,
    verdict)`: each verdict judged at the paper's size from the committed
    ensemble (mean and standard error over piles; a pile with no random input
    is its own ensemble), for a notebook's closing table."""
    rows = {"1992": rows_1992, "1993": rows_1993, "1997": rows_1997}[paper]()
    return [tuple(r[1:]) for r in rows]


# ------------------------------------------------------------------- runs
def _pile_summary(args: list[str], dest: pathlib.Path, base_forces: bool = False) -> None:
    """`jaxpile pile ARGS` into a scratch folder; its summary.json kept as `dest`,
    with base_forces.csv's columns as `base_forces` when asked (for a figure)."""
    scratch = tempfile.mkdtemp(prefix="papers-")
    try:
        jaxpile = shutil.which("jaxpile") or str(pathlib.Path(sys.executable).with_name("jaxpile"))
        subprocess.run([jaxpile, "pile", *args, "--out", scratch, "--no-progress"], check=True)
        summary = json.loads((pathlib.Path(scratch) / "summary.json").read_text())
        summary["command"] = "jaxpile pile " + " ".join(args)
        if base_forces:
            import numpy as np

            table = np.genfromtxt(pathlib.Path(scratch) / "base_forces.csv", delimiter=",", names=True)
            summary["base_forces"] = {name: table[name].tolist() for name in table.dtype.names}
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_text(json.dumps(summary, indent=1))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _sweep_into(out: pathlib.Path, sweep: list[str]) -> None:
    """`jaxpile SWEEP --out OUT` (resumed from OUT/checkpoint.npz when a run stopped), unless OUT holds its
    sweep.csv already; the command is kept as OUT/command.txt."""
    if (out / "sweep.csv").exists():
        return
    jaxpile = shutil.which("jaxpile") or str(pathlib.Path(sys.executable).with_name("jaxpile"))
    resumed = (out / "checkpoint.npz").exists()
    subprocess.run([jaxpile, *(["sweep", "--resume", str(out)] if resumed else [*sweep, "--out", str(out)])], check=True)
    (out / "command.txt").write_text("jaxpile " + " ".join(sweep) + f" --out {out.relative_to(ROOT)}\n")


def run(studies: list[str]) -> None:
    """Runs each study that has fewer results than its target (each resumes)."""
    if "lattice" in studies and not LATTICE.exists():
        _pile_summary(["--protocol", "lattice", "--layers", "45", "--law", "liffman"], LATTICE)
    if "sloped" in studies and not SLOPED.exists():
        _pile_summary(["--protocol", "sloped", "--slope", "30", "--n", "5490"], SLOPED)
    if "networks" in studies and not NETWORKS.exists():
        subprocess.run([sys.executable, str(HERE / "liffman_networks.py")], check=True)
    if "sloped_angles" in studies:
        for alpha, dest in SLOPED_ANGLES.items():
            if not dest.exists():
                _pile_summary(["--protocol", "sloped", "--slope", str(alpha), "--n", "360"], dest, base_forces=True)
    if "tilt" in studies:
        import paper_ensembles as pe

        pe.main(["tilt", "--seeds", str(PILES), "--checkpoint-every", "20000",
                 "--figure", str(ROOT / "docs" / "lee_herrmann1993_tilt_ensemble.png")])
    if "flux" in studies:
        _sweep_into(FLUX, FLUX_SWEEP)
    if "vcut" in studies:
        _sweep_into(VCUT, VCUT_SWEEP)
    if "height" in studies:
        _sweep_into(HEIGHT, HEIGHT_SWEEP)
    if "width" in studies:
        for w, sweep in WIDTH_SWEEPS.items():
            _sweep_into(WIDTH / f"w{w:g}", sweep)
    if "kn_gamma" in studies:
        for name, sweep in KN_GAMMA_SWEEPS.items():
            _sweep_into(KN_GAMMA / name, sweep)
    if "drop" in studies:
        import paper_ensembles as pe

        pe.main(["drop", "--seeds", str(PILES), "--checkpoint-every", "50000",
                 "--figure", str(ROOT / "docs" / "liffman1992_drop_ensemble.png")])
    if "heap" in studies:
        import baxter_readings as br

        br.main(["--n", "1334", "--seeds", str(PILES), "--settings", "contact-point/hold",
                 "--figure", str(ROOT / "docs" / "baxter1997_n1334.png")])
    if "heap1000" in studies:
        import baxter_readings as br

        br.main(["--n", "1000", "--seeds", str(PILES), "--settings", ",".join(HEAP_SETTINGS), "--workers", "1"])
    if "heap1000_n36" in studies:  # the paper's law at 1000 disks, beside its n = 144 heaps (sec. III: 31 against 35 deg)
        import baxter_readings as br

        br.main(["--n", "1000", "--seeds", str(PILES), "--settings", "contact-point/hold", "--workers", "2"])
    if "spacing" in studies:  # sec. III: the angle against the substrate's spacing S (1000-disk heaps, ~4 min each)
        import baxter_readings as br

        br.main(["--n", "1000", "--seeds", str(PILES), "--settings", "S1.0,S1.05,S1.2,S1.3", "--workers", "1"])
    if "flat" in studies:  # sec. II: a flat floor instead of the row (1000-disk pours, ~4 min each)
        import baxter_readings as br

        br.main(["--n", "1000", "--seeds", str(PILES), "--settings", ",".join(FLATS), "--workers", "1"])
    if "avalanches" in studies:  # sec. III: how the heaps grow while fed (1000-disk pours, sampled)
        import baxter_avalanches as ba

        ba.main(["--n", "1000", "--seeds", str(PILES)])
    if "voidage" in studies:  # from the saved states of the heap studies' runs (seconds)
        import baxter_voidage as bv

        bv.main(["--folder", str(HEAPS / "n1334"), "--figure", str(ROOT / "docs" / "baxter1997_voidage_n1334.png")])
        bv.main(["--folder", str(HEAPS / "n1000")])


STUDIES = ("lattice", "sloped", "sloped_angles", "networks", "tilt", "flux", "vcut", "kn_gamma", "drop", "heap", "heap1000", "heap1000_n36", "spacing", "flat", "avalanches", "voidage", "height", "width")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="store_true", help="run the missing studies first (hours on 2 cores)")
    parser.add_argument("--only", default=",".join(STUDIES), help=f"with --run: among {', '.join(STUDIES)}")
    parser.add_argument("--check", action="store_true", help="exit 1 when docs/papers.md's table is out of date")
    args = parser.parse_args(argv)
    if args.run:
        chosen = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = set(chosen) - set(STUDIES)
        if unknown:
            parser.error(f"unknown studies {sorted(unknown)}; choose from {', '.join(STUDIES)}")
        run(chosen)
    if args.check:
        ok = rewrite_page(check=True)
        print("docs/papers.md's table is " + ("up to date" if ok else "out of date: run python benchmarks/studies/papers/papers.py"))
        return 0 if ok else 1
    same = rewrite_page()
    print("docs/papers.md's table " + ("was already up to date" if same else "rewritten") + f":\n{table()}")
    print("figures: " + ", ".join(os.path.relpath(p, ROOT) for p in figures()))
    return 0


if __name__ == "__main__":
    os.chdir(ROOT)
    raise SystemExit(main())
