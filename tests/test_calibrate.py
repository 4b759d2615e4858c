"""Calibrating to a measurement: the base every protocol stands on (`jaxpile.base_forces`)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile as jp
from jaxpile.errors import InputError
from jaxpile.measure import analysis


@pytest.fixture(scope="module")
def poured():
    """A 12-disk heap poured onto 15 fixed disks (the pour's CLI test pile)."""
    jp.configure()
    return jp.run("pour", "baxter", 12, release_height=8.0, substrate_disks=15, speed_tolerance=1e-3)


def test_base_forces_of_a_poured_heap_are_its_fixed_row_contacts(poured):
    base = jp.base_forces(poured.simulator, poured.params, poured.state)
    row = analysis.substrate_forces(poured.simulator, poured.params, poured.state)
    assert base.x.size == row.x.size > 0
    np.testing.assert_array_equal(base.particle, row.particle)
    np.testing.assert_allclose(base.normal, row.normal, rtol=1e-12)
    # at rest the row carries the heap's weight (its force balance), in mg
    assert abs(base.normal.sum() / poured.measurements["weight"] - 1.0) < 1e-2
    with pytest.raises(InputError, match="no active wall"):  # its floor wall is switched off: a reading of none
        jp.base_forces(poured.simulator, poured.params, poured.state, base="ground")


def test_base_forces_refuse_a_set_up_without_a_base():
    particles = jp.make_particles(np.array([[0.0, 2.0], [1.0, 2.0]]), np.array([0.5, 0.5]))
    boundaries = jp.set_wall(jp.make_boundaries(sides=False), 0, active=False)
    from jaxpile.laws import hooke

    sim = jp.Simulator(hooke.law(), dt=1e-4)
    params = hooke.make_params(kn=1e4)
    state = sim.init(params, particles, boundaries)
    with pytest.raises(InputError, match="neither an active floor wall nor fixed disks"):
        jp.base_forces(sim, params, state)


def test_grad_of_a_poured_heaps_base_force_matches_central_differences(poured):
    """On a deterministic window (200 steps of relaxation from the settled heap)."""
    sim, state = poured.simulator, poured.state

    def peak(mu):
        p = poured.params.set(mu=mu)
        return jp.base_forces(sim, p, sim.rollout(p, state, 200)).normal.max()

    mu, h = jnp.asarray(float(poured.params.mu)), 1e-5
    exact = float(jax.grad(peak)(mu))
    value = jax.jit(peak)
    central = float((value(mu + h) - value(mu - h)) / (2 * h))
    assert abs(exact - central) <= 1e-6 * max(abs(central), 1e-3)
    # the traced reading is the eager one with padding: the same largest force
    eager = jp.base_forces(sim, poured.params, sim.rollout(poured.params, state, 200))
    assert float(value(mu)) == pytest.approx(float(eager.normal.max()), rel=1e-12)


# ------------------------------------------------------------ measurements
from jaxpile.fit import ensemble_fit as ef  # noqa: E402
from jaxpile.fit import measured, verdict  # noqa: E402
from jaxpile.fit.targets import load_profile_csv  # noqa: E402
from jaxpile.measure.base_reading import pile_base, profile_at_points  # noqa: E402
from jaxpile.measure.forces import BaseForces  # noqa: E402
from jaxpile.protocols import PROTOCOLS  # noqa: E402

PROFILE = "x/B,normal/max,stderr\n0,0.2,0.05\n0.25,0.8,0.05\n0.5,0.6,0.05\n0.75,0.8,0.05\n1,0.2,0.05\n"


def test_a_measured_profile_keeps_its_standard_errors_on_its_scale(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text(PROFILE.replace("normal/max", "normal").replace("0.8,", "1.6,").replace("0.6,0.05", "1.2,0.1")
                    .replace("0.2,0.05", "0.4,0.1").replace("1.6,0.05", "1.6,0.1"))
    p = load_profile_csv(path)  # raw forces: values and errors divided by the largest value together
    np.testing.assert_allclose(p.normal, [0.25, 1.0, 0.75, 1.0, 0.25])
    np.testing.assert_allclose(p.normal_stderr, [0.0625] * 5)
    assert p.normalised_by == "max" and p.horizontal is None
    averaged = tmp_path / "a.csv"  # the mean of heaps each over its own maximum peaks below 1: kept as given
    averaged.write_text("x/B,normal/max\n0,0.3\n0.5,0.9\n1,0.3\n")
    assert load_profile_csv(averaged).normal.tolist() == [0.3, 0.9, 0.3]
    weight = tmp_path / "w.csv"
    weight.write_text("x/B,normal/weight\n0,0.5\n0.5,1.5\n1,0.5\n")
    w = load_profile_csv(weight)  # per unit x/B over the weight: kept as given
    assert w.normalised_by == "weight" and w.normal.tolist() == [0.5, 1.5, 0.5] and w.normal_stderr is None
    plain = tmp_path / "n.csv"
    plain.write_text("x/B,normal\n0,0.5\n0.5,1.5\n1,0.5\n")
    assert load_profile_csv(plain, "weight").normal.tolist() == [0.5, 1.5, 0.5]
    with pytest.raises(InputError, match="scaled by weight .its header., not by max"):
        load_profile_csv(weight, "max")
    bad = tmp_path / "b.csv"
    bad.write_text("x/B,normal/max,stderr\n0,0.5,0.1\n0.5,1,0\n1,0.5,0.1\n")
    with pytest.raises(InputError, match="line 3: a standard error of 0.0; it must be positive"):
        load_profile_csv(bad)


def test_a_measurement_file_holds_scalars_with_errors_and_a_profile_beside_it(tmp_path):
    (tmp_path / "p.csv").write_text(PROFILE)
    toml = tmp_path / "heap.toml"
    toml.write_text('source = "heap A"\nprofile = "p.csv"\n[scalars]\nangle_of_repose = { value = 32.1, stderr = 0.8 }\n'
                    "core_packing_fraction = [0.81, 0.01]\n")
    m = measured.load_measurement(toml)
    assert m.source == "heap A" and m.scalars == {"angle_of_repose": (32.1, 0.8), "core_packing_fraction": (0.81, 0.01)}
    stats = measured.statistics_of(m, PROTOCOLS["pour"])  # the pour's names for what was measured
    assert stats.columns == ("repose_mean", "core_packing_fraction") and stats.at == (0.0, 0.25, 0.5, 0.75, 1.0)
    assert stats.bandwidth == pytest.approx(0.125) and stats.normalised_by == "max"
    target = measured.target_of(m, stats)
    assert target.labels == ["repose_mean", "core_packing_fraction", "normal[x/B=0]", "normal[x/B=0.25]",
                             "normal[x/B=0.5]", "normal[x/B=0.75]", "normal[x/B=1]"]
    np.testing.assert_allclose(target.mean, [32.1, 0.81, 0.2, 0.8, 0.6, 0.8, 0.2])
    np.testing.assert_allclose(target.error, [0.8, 0.01] + [0.05] * 5)
    assert ef.EnsembleTarget.from_json(target.to_json()).error.tolist() == target.error.tolist()
    with pytest.raises(InputError, match="the drop protocol measures no angle of repose"):
        measured.statistics_of(m, PROTOCOLS["drop"])
    js = tmp_path / "angle.json"
    js.write_text('{"scalars": {"angle_of_repose": 30.0}}')  # no error: taken from the piles, said
    no_error = measured.target_of(measured.load_measurement(js), measured.statistics_of(
        measured.load_measurement(js), PROTOCOLS["box"]))
    assert no_error.labels == ["repose_cumulative_parabola"] and np.isnan(no_error.error).all()
    for text, match in (('{"scalar": {}}', "unknown key"), ('{"scalars": {"angle_of_repose": [30, -1]}}', "positive"),
                        ("{}", "no profile and no scalars"), ('{"scalars": {"x": "a"}}', "finite number")):
        js.write_text(text)
        with pytest.raises(InputError, match=match):
            measured.load_measurement(js)


def test_a_piles_profile_is_read_across_its_own_base_as_the_measurement_was():
    """A uniform row of contacts reads 1 per unit x/B over its weight inside, and
    a stray disk far off is not the pile's foot."""
    x = np.r_[np.arange(20) + 0.5, 60.0]
    forces = BaseForces(x=x, normal=np.r_[np.ones(20), 5.0], horizontal=np.r_[np.linspace(-1, 1, 20), 0.0],
                        particle=np.arange(21))
    left, right, members = pile_base(forces.x, forces.normal)
    assert (left, right) == (0.0, 20.0) and members.sum() == 20
    at = np.array([0.25, 0.5, 0.75])
    weight, shear = profile_at_points(forces, at, bandwidth=0.05, normalised_by="weight")
    np.testing.assert_allclose(weight, 1.0, rtol=1e-6)
    np.testing.assert_allclose(shear, [-0.5, 0.0, 0.5], atol=0.03)
    peak, _ = profile_at_points(forces, at, bandwidth=0.05, normalised_by="max")
    np.testing.assert_allclose(peak, 1.0, rtol=1e-6)
    with pytest.raises(InputError, match="too few"):
        pile_base(np.array([1.0]), np.array([1.0]))


# ------------------------------------------------------------- the verdict
def _central(effects, b=6, k=3, seed=0):
    """`[2d + 1, B, k]` statistics whose means move by `effects[i]` (per statistic) between the +- points."""
    rng = np.random.default_rng(seed)
    d = len(effects)
    base = rng.normal(size=(b, k))
    s = np.repeat(base[None], 2 * d + 1, axis=0) + 0.3 * rng.normal(size=(2 * d + 1, b, k))
    for i, e in enumerate(effects):
        s[1 + i] += 0.5 * np.asarray(e)
        s[1 + d + i] -= 0.5 * np.asarray(e)
    return s


def _target(k=3):
    return ef.EnsembleTarget([f"c{i}" for i in range(k)], np.zeros(k), np.ones(k), None, "toy")


def test_first_pass_tells_a_parameter_that_moves_the_statistics_from_one_that_moves_nothing():
    s = _central([np.full(3, 3.0), np.zeros(3)])
    report = verdict.first_pass(s, 0.05, np.ones(3), _target(), ["mu", "kn"], 40)
    assert report["parameters"]["mu"]["identifiable"] is True
    assert report["parameters"]["mu"]["z"] > 10 > report["parameters"]["mu"]["needed"]
    assert report["parameters"]["kn"]["identifiable"] is False and report["identifiable"] is False
    lines = verdict.first_pass_lines(report)
    assert "at 40 disks" in lines[1] and "cannot identify kn" in lines[1]
    one_of_twelve = verdict.first_pass(_central([np.r_[3.0, np.zeros(11)]], k=12), 0.05, np.ones(12), _target(12),
                                       ["mu"], 40)  # one statistic moved among eleven that are not: not diluted
    assert one_of_twelve["parameters"]["mu"]["identifiable"] is True
    assert one_of_twelve["parameters"]["mu"]["most_moved"] == "c0"
    two = verdict.first_pass(_central([np.full(3, 3.0)], b=2), 0.05, np.ones(3), _target(), ["mu"], 40)
    assert two["parameters"]["mu"]["identifiable"] is None and two["identifiable"]  # 2 piles measure no noise
    alike = verdict.first_pass(_central([np.full(3, 3.0), np.full(3, 3.1)]), 0.05, np.ones(3), _target(),
                               ["mu", "mu_roll"], 40)
    assert alike["poorly_told_apart"] == [["mu", "mu_roll"]]
    assert any("tells them poorly apart" in line for line in verdict.first_pass_lines(alike))


def test_the_verdict_says_why_a_fit_stopped_and_whether_the_model_fits():
    jac, w, target = np.ones((3, 1)), np.ones(3), _target()
    members = np.random.default_rng(1).normal(size=(8, 3)) * 0.1
    step = {"theta": [0.0], "next_theta": [0.5], "step_stderr": [0.1], "loss": 1.0}
    budget = verdict.verdict([step], jac, w, members, target, ["mu"], False, "", 1)
    assert budget["why"] == "budget" and not budget["converged"] and not budget["interval_trusted"]
    assert "did NOT converge" in verdict.verdict_lines(budget)[0]
    # three steps each within twice their standard error, back and forth: the noise floor; one way: a drift
    wander = [{**step, "next_theta": [x]} for x in (0.15, -0.18, 0.12)]
    floor = verdict.verdict(wander, jac, w, members, target, ["mu"], False, "", 3)
    assert floor["why"] == "noise floor" and floor["converged"] and floor["interval_trusted"]
    drift = [{**step, "next_theta": [x]} for x in (0.15, 0.18, 0.12)]
    assert verdict.verdict(drift, jac, w, members, target, ["mu"], False, "", 3)["why"] == "budget"
    assert verdict.verdict(wander[:2], jac, w, members, target, ["mu"], False, "", 2)["why"] == "budget"
    far = verdict.verdict(wander, jac, w, members + 5.0, target, ["mu"], False, "", 3)
    assert far["p_value"] < 1e-6 and not far["interval_trusted"] and "does not fit the target" in far["doubts"][0]
    flat = verdict.verdict(wander, np.zeros((3, 1)), w, members, target, ["mu"], True, "", 3)
    assert flat["jacobian_rank"] == 0 and "rank 0" in flat["doubts"][0]


def test_a_measurements_own_error_widens_the_interval_by_its_jacobian():
    """d = k = 1, piles without spread: Var(theta) = e^2 / J^2 from the measurement's error e alone."""
    jac, w = np.array([[2.0]]), np.array([1 / 0.3 ** 2])
    members = np.full((4, 1), 0.5)
    target = ef.EnsembleTarget(["c"], np.array([0.5]), np.array([0.3]), None, "m", error=np.array([0.3]))
    cov, dof = ef.confidence(jac, w, members, target)
    assert cov[0, 0] == pytest.approx(0.3 ** 2 / 2.0 ** 2, rel=1e-12) and dof == np.inf


# the ensemble fit's toy piles: [20 log(mu) + noise_b, 5 mu^2 + noise'_b], the same noise at every point and
# nothing that depends on kn
from test_ensemble_fit import ToyRunner as Toy  # noqa: E402


TOY = ef.Statistics(columns=("angle", "feature"))


def _measured(mu=0.3137):
    """A measurement at `mu` without standard errors (the piles' own spread stands in)."""
    return ef.EnsembleTarget(TOY.labels(), np.array([20 * np.log(mu), 5 * mu ** 2]), np.full(2, np.nan), None,
                             "a toy measurement", error=np.full(2, np.nan))


def test_a_parameter_the_target_cannot_see_is_refused_before_the_fit_steps():
    runner = Toy()
    with pytest.raises(InputError, match=r"cannot identify kn at 1 disks .* kn moves angle most, by 0.0x its noise"):
        ef.fit(runner, ["mu", "kn"], {"mu": 0.2, "kn": 1e4}, _measured(), seeds=range(8), statistics=TOY,
               progress=False)
    assert runner.calls == 1  # the first pass alone: no iteration, no interval


def test_a_measurement_without_errors_is_fitted_with_one_piles_spread_and_says_so(tmp_path):
    runner = Toy()
    result = ef.fit(runner, ["mu"], {"mu": 0.2}, _measured(), seeds=range(16), statistics=TOY, progress=False,
                    stopping=ef.Stopping(steps=8), saving=ef.Saving(checkpoint=str(tmp_path / "c.json")))
    first = result.record["first_pass"]
    assert first["errors_from_piles"] == ["angle", "feature"]
    spread = np.asarray(first["spread"])
    seeds = np.arange(16)
    assert spread[0] == pytest.approx(np.std(np.sin(1.7 * seeds + 0.3), ddof=1), rel=1e-12)
    assert first["report"]["parameters"]["mu"]["identifiable"] is True
    judged = result.record["verdict"]
    assert judged["converged"] and judged["interval_trusted"], judged
    lo, hi = result.interval["mu"]
    assert lo < 0.3137 < hi
    # the interval counts the measurement's error (one pile's, through d angle / d log mu = 20), not only
    # the 16 fitted piles' (a quarter of it)
    assert np.log(hi / lo) > 0.95 * 2 * 1.96 * spread[0] / 20
    # the first iteration reused the first pass's ensembles: one run fewer than iterations + 2
    assert runner.calls == len(result.history) + 1


def test_a_measured_profile_is_fitted_from_the_command_line_by_the_pours_ensemble_mean(tmp_path, capsys):
    from jaxpile import cli, io

    csv, out = tmp_path / "heap.csv", tmp_path / "fit"
    csv.write_text(PROFILE)
    common = ["fit", "--protocol", "pour", "--target", str(csv), "--params", "mu", "--n", "12", "--option",
              "release_height=8", "--option", "substrate_disks=15", "--ensemble", "3", "--out", str(out)]
    assert cli.main(common + ["--dry-run"]) == 0  # the statistics the file holds, read where it was taken
    said = capsys.readouterr().out
    assert "'normal[x/B=0]', 'normal[x/B=0.25]', 'normal[x/B=0.5]', 'normal[x/B=0.75]', 'normal[x/B=1]'" in said
    assert "repose_mean" not in said
    assert cli.main(common + ["--estimator", "pathwise"]) == 2  # one random pile's gradient: refused, and why
    err = capsys.readouterr().err
    assert "builds random piles" in err and "--estimator central" in err
    assert cli.main(common + ["--statistics", "repose_mean"]) == 2
    assert "leave --statistics and --bins out" in capsys.readouterr().err
    assert cli.main(common + ["--steps", "1", "--fit-anyway", "--no-progress"]) == 0
    said = capsys.readouterr().out
    assert "first pass: at 12 disks, mu from" in said and "verdict: the fit" in said
    record = io.read_json(str(out / "fit.json"), "fit")
    assert record["target"]["labels"][2] == "normal[x/B=0.5]"
    np.testing.assert_allclose(record["target"]["error"], 0.05)  # the file's errors, on its scale
    judged = record["verdict"]
    assert set(judged) >= {"converged", "why", "misfit", "chi2", "p_value", "interval_trusted", "doubts"}
    assert record["converged"] == judged["converged"] == (judged["why"] in ("tolerance", "noise floor"))
    assert set(record["first_pass"]["report"]["parameters"]) == {"mu"}
    assert (out / "fit.png").exists()


class Scarce(Toy):
    """The toy's piles, the feature missing (NaN) from most of them, or from all at mu above 0.25."""

    def __init__(self, most=True):
        super().__init__()
        self.most = most

    def run(self, points, seeds, statistics, progress=None):
        s, info = super().run(points, seeds, statistics, progress)
        mu = np.array([p["mu"] for p in points])
        if self.most:
            s[:, : 2 * s.shape[1] // 3, 1] = np.nan
        else:
            s[mu > 0.25, :, 1] = np.nan
        return s, info


def test_a_statistic_most_piles_lack_is_refused_at_the_first_pass_and_one_all_lack_later_stops_the_fit(tmp_path):
    with pytest.raises(InputError, match="at 1 disks 'feature' is missing from 5 of 8 piles in the first pass's ensembles"):
        ef.fit(Scarce(), ["mu"], {"mu": 0.2}, _measured(), seeds=range(8), statistics=TOY, progress=False)
    checkpoint = str(tmp_path / "c.json")
    with pytest.raises(InputError, match=r"the fit stopped in iteration 2: the statistic 'feature' is missing from "
                                         r"every pile at mu = 0.2\d+ .*a larger pile; its 1 iteration\(s\) are kept in"):
        ef.fit(Scarce(most=False), ["mu"], {"mu": 0.2}, _measured(), seeds=range(8), statistics=TOY, progress=False,
               stopping=ef.Stopping(steps=6), saving=ef.Saving(checkpoint=checkpoint))
    assert len(io_json(checkpoint)["history"]) == 1


def io_json(path):
    import json

    with open(path) as fh:
        return json.load(fh)


def test_a_deterministic_piles_measurement_without_errors_is_fitted_by_least_squares():
    """One pile (a deterministic protocol) has no spread to stand in for missing errors: the points weigh
    alike and the interval comes from the misfit (s^2 H^-1), neither refused nor of zero width."""
    target = _measured()._replace(mean=_measured().mean + np.array([0.3, -0.02]))  # a model that misses a little
    result = ef.fit(Toy(), ["mu"], {"mu": 0.2}, target, seeds=[0], statistics=TOY, progress=False,
                    stopping=ef.Stopping(steps=8))
    assert result.record["first_pass"]["errors_from_misfit"] == ["angle", "feature"]
    lo, hi = result.interval["mu"]
    assert 0 < hi - lo < 0.1 and lo < result.values["mu"] < hi
    assert np.isnan(result.record["verdict"]["p_value"])  # no error to judge the misfit in


def test_a_pathwise_fit_refuses_a_profile_it_would_read_otherwise(tmp_path, capsys):
    from jaxpile import cli

    csv = tmp_path / "p.csv"
    csv.write_text(PROFILE)  # with standard errors
    assert cli.main(["fit", "--protocol", "lattice", "--target", str(csv), "--params", "mu", "--layers", "3",
                     "--dry-run", "--out", str(tmp_path / "f")]) == 2
    assert "a pathwise fit" in capsys.readouterr().err


def test_a_gauss_newton_step_that_undoes_the_last_bisects_it_and_is_judged_as_proposed():
    from jaxpile.fit.ensemble_fit import _damped

    last = {"theta": [0.0, 0.0], "next_theta": [-0.3, 0.1]}
    np.testing.assert_allclose(_damped(np.array([0.3, 0.2]), last), [0.15, 0.2])  # reversed: half; onward: kept
    np.testing.assert_allclose(_damped(np.array([0.05, -0.01]), last), [0.05, -0.01])  # within half: as proposed
    assert _damped(np.array([0.3, 0.2]), None).tolist() == [0.3, 0.2]
    # the noise floor and the tolerance read the proposals: a damped step is not a converged one
    wander = [{"theta": [0.0], "next_theta": [x], "proposed_step": [p], "step_stderr": [0.1]}
              for x, p in ((0.15, 0.15), (-0.05, -0.3), (0.02, 0.12))]
    assert not verdict.at_noise_floor(wander)  # the middle proposal is 3 errors long
