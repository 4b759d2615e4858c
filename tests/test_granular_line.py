"""A LAMMPS `pair_coeff` granular line as a law's name: on the command line
(`jaxpile pile --law "hertz/material ..."`), in Python (`jaxpile.run("pour",
"jkr ...")`), in the protocols, sweeps and fits, and the gradients of a base
force in the parameters a DEM user calibrates (E, nu, e, mu, mu_r, the surface
energy). The law's own physics and its LAMMPS twins are in `test_granular.py`
and `test_granular_lammps.py`."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

import jaxpile as jp
from jaxpile import cli, fit
from jaxpile.engine.simulate import Simulator, gravity_ramp
from jaxpile.errors import InputError
from jaxpile.laws import get_law_module, granular
from jaxpile.protocols import lattice

HERTZ_MINDLIN = "hertz/material 1e7 0.3 0.3 tangential mindlin NULL 1.0 0.5 damping tsuji rolling sds 1e3 50 0.1"
"""The issue's line (the coefficients LAMMPS's hertz/material takes: E, e, nu)."""


def test_a_line_is_a_law_whose_parameters_default_to_its_coefficients():
    """`get_law_module(line)`: a law module (one object per line, so that the
    laws it builds are equal and compile once) whose PARAM_NAMES are what the
    composition reads, whose make_params takes the line's numbers and
    overrides them by name; a line that cannot be read, a parameter the
    composition does not read and a --rolling beside the line's own are
    refused in one line."""
    module = get_law_module(HERTZ_MINDLIN)
    assert module is get_law_module("granular  " + HERTZ_MINDLIN.replace(" ", "  "))
    assert module.NAME == HERTZ_MINDLIN and module.model == granular.Model("hertz/material", "tsuji", "mindlin", "sds")
    assert set(module.PARAM_NAMES) == {"E", "nu", "restitution", "kt", "xgamma_t", "mu", "k_roll", "gamma_roll",
                                       "mu_roll"}
    params = module.make_params(mu=0.2)
    assert (float(params.E), float(params.restitution), float(params.mu), params.kt) == (1e7, 0.3, 0.2, None)
    assert module.law(rotation=True) == module.law(rotation=True)
    assert module.law(rotation=True).name == HERTZ_MINDLIN  # what summaries, checkpoints and `show` record
    assert get_law_module("hooke") is not module and get_law_module("hooke").NAME == "hooke"
    for make, match in ((lambda: get_law_module("hertz/material 1e7 0.3 tangential mindlin NULL 1.0 0.5"),
                         r"hertz/material takes 3 coefficients \(E, gamma_n \(or e with damping tsuji\), nu\); got 2"),
                        (lambda: module.make_params(kn=1e4), "does not read kn"),
                        (lambda: module.law(rolling="constant"), "names its rolling model"),
                        (lambda: get_law_module("hookean"), "or a LAMMPS pair_coeff granular line")):
        with pytest.raises(InputError, match=match):
            make()


def test_the_command_line_runs_a_box_with_the_line_and_show_reads_it_back(tmp_path, capsys):
    """`jaxpile pile --protocol box --law LINE` (the issue's Hertz-Mindlin line
    with tsuji damping and rolling sds): the law's default dt, too large for E
    = 1e7, is refused naming the stable one; at a smaller dt the box fills,
    its wall opens and the pile comes to rest; its summary records the line
    (and the line at the values run, to take back), and `jaxpile show` builds
    the law again from it."""
    argv = ["pile", "--protocol", "box", "--law", HERTZ_MINDLIN, "--rotation", "on", "--option", "width=2",
            "--option", "height=2", "--no-progress", "--out", str(tmp_path / "box")]
    assert cli.main(argv) == 2
    assert "above the stability limit" in capsys.readouterr().err
    assert cli.main(argv + ["--dt", "2e-4"]) == 0
    summary = json.loads((tmp_path / "box" / "summary.json").read_text())
    assert summary["law"] == HERTZ_MINDLIN and summary["at_rest"]
    assert summary["params"]["E"] == 1e7 and summary["params"]["mu_roll"] == 0.1
    model, params = granular.parse(summary["lammps_pair_coeff"])  # the line to take back to LAMMPS
    assert model == get_law_module(HERTZ_MINDLIN).model and float(params.E) == 1e7
    assert cli.main(["show", str(tmp_path / "box"), "--out", str(tmp_path / "shown")]) == 0
    assert (tmp_path / "shown" / "pile.png").stat().st_size > 10_000


@pytest.fixture(scope="module")
def poured():
    """A 12-disk heap of cohesive spheres' disks (jkr, tsuji, Mindlin,
    rolling sds) poured from Python onto 15 fixed disks."""
    jp.configure()
    return jp.run("pour", "jkr 1e5 0.3 0.3 0.05 damping tsuji tangential mindlin NULL 1.0 0.5 rolling sds 1e3 20 0.1",
                  12, release_height=8.0, substrate_disks=15, speed_tolerance=1e-3)


def central_differences(f, values, g, rel=1e-5):
    """`{name: (gradient, central difference)}` of `f` at `values`, steps of
    `rel` of each value."""
    out = {}
    for name, value in values.items():
        h = rel * float(value)
        up, down = dict(values), dict(values)
        up[name], down[name] = value + h, value - h
        out[name] = (float(g[name]), float((f(up) - f(down)) / (2 * h)))
    return out


def test_grad_of_a_cohesive_heaps_base_force_in_e_nu_and_the_surface_energy_matches_central_differences(poured):
    """On a 50-step window from the poured heap (float64): d(peak base
    force) / d(E, nu, w) by forward mode against central differences (steps
    1e-5 of each value). Measured 3e-8 (E), 6e-6 (nu), 8e-7 (w); a JKR
    contact jumps to -8/9 of its pull-off force when it forms, so the window
    is smooth only between contacts made, and the tolerance is 1e-4."""
    assert poured.measurements["counts"]["in_play"] >= 10
    sim, state = poured.simulator, poured.state

    def peak(values):
        p = poured.params.set(**values)
        return jp.base_forces(sim, p, sim.rollout(p, state, 50)).normal.max()

    values = {n: getattr(poured.params, n) for n in ("E", "nu", "cohesion")}
    for name, (exact, central) in central_differences(jax.jit(peak), values, jax.jit(jax.jacfwd(peak))(values)).items():
        assert abs(central) > 0, name
        assert exact == pytest.approx(central, rel=1e-4), name


def test_grad_of_a_loaded_lattices_base_force_in_e_nu_restitution_mu_and_mu_roll_matches_central_differences():
    """The 4-layer lattice of Hertz-Mindlin disks with rolling sds, loaded by
    a gravity ramp over 600 steps while its contacts slide and roll (float64):
    d(largest horizontal base force) / d(E, nu, e, mu, mu_r) against central
    differences (steps 1e-5 of each value). Measured within 4e-6 (e), the
    others 2e-9 to 4e-7."""
    module = get_law_module("hertz/material 1e5 0.5 0.3 damping tsuji tangential mindlin NULL 1.0 0.05 "
                            "rolling sds 2e2 5.0 0.02")
    params = module.make_params()
    particles, boundaries = lattice.equilateral_pile(4)
    sim = Simulator(module.law(rotation=True), 1e-3, schedule=gravity_ramp(400))
    state = sim.init(params, particles, boundaries)

    def peak(values):
        p = params.set(**values)
        return jp.base_forces(sim, p, sim.rollout(p, state, 600)).horizontal.max()

    values = {n: getattr(params, n) for n in ("E", "nu", "restitution", "mu", "mu_roll")}
    for name, (exact, central) in central_differences(jax.jit(peak), values, jax.jit(jax.jacfwd(peak))(values)).items():
        assert abs(central) > 0, name
        assert exact == pytest.approx(central, rel=1e-4), name


def test_jaxpile_fit_takes_a_lines_parameters_and_recovers_its_mu(tmp_path, capsys):
    """`jaxpile fit --law LINE --params ...`: a dry run accepts E, nu, e and mu
    of a Hertz-Mindlin line (E and mu in log space, nu and e in logit space:
    bounded above); a pathwise fit takes mu from 0.2 back to the 0.15 of a
    profile the same law made on the 4-layer lattice, and writes the fitted
    law as its LAMMPS line; the ensemble fit refuses a parameter bounded above
    in one line."""
    line = "hertz/material 1e5 0.5 0.3 damping tsuji tangential mindlin NULL 1.0 0.2"
    assert cli.main(["fit", "--protocol", "lattice", "--layers", "4", "--law", line, "--params",
                     "E,nu,restitution,mu", "--target", "smid-novosad", "--dry-run", "--out", str(tmp_path / "dry")]) == 0
    assert "E = 100000, nu = 0.3, restitution = 0.5, mu = 0.2" in capsys.readouterr().out
    params = get_law_module(line).make_params()
    u = fit.to_unconstrained(params, ["nu", "restitution", "mu"])
    assert float(u["nu"]) == pytest.approx(np.log(1.3 / 0.2)) and float(u["restitution"]) == pytest.approx(0.0)
    back = fit.to_constrained({"nu": u["nu"] + 10.0, "restitution": u["restitution"] - 10.0, "mu": u["mu"]}, params)
    assert 0.4999 < float(back.nu) < 0.5 and 0 < float(back.restitution) < 1e-4  # far steps stay inside

    problem = fit.problem("lattice", line, {"mu": 0.15}, size=4)
    made = jax.jit(problem.profile)(problem.params)
    target = tmp_path / "target.csv"
    rows = zip(np.asarray(made.x_over_b), np.asarray(made.normal), np.asarray(made.horizontal))
    target.write_text("x/B,normal/max,horizontal/max\n" + "\n".join(f"{x!r},{n!r},{h!r}" for x, n, h in
                                                                      ((float(a), float(b), float(c)) for a, b, c in rows)))
    out = tmp_path / "fit"
    assert cli.main(["fit", "--target", str(target), "--protocol", "lattice", "--layers", "4", "--law", line,
                     "--params", "mu", "--steps", "60", "--horizontal-weight", "10", "--no-progress",
                     "--out", str(out)]) == 0
    record = json.loads((out / "fit.json").read_text())
    assert record["fitted_values"]["mu"] == pytest.approx(0.15, rel=2e-3)
    assert float(granular.parse(record["lammps_pair_coeff"])[1].mu) == record["fitted_values"]["mu"]
    assert cli.main(["fit", "--protocol", "box", "--law", line, "--params", "restitution", "--truth",
                     "restitution=0.6", "--ensemble", "2", "--no-progress", "--out", str(tmp_path / "ens")]) == 2
    assert "bounded above" in capsys.readouterr().err
