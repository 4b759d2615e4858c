"""Ensemble fits (issue 17): Gauss-Newton and optax on ensemble means with
common random numbers, the sandwich interval, resume, and one tiny real box
fit through the CLI. The toy runner stands in for the protocol so the
machinery is checked exactly and fast."""

import json

import numpy as np
import pytest

from jaxpile import ensemble_fit as ef
from jaxpile.errors import InputError


class ToyRunner:
    """Piles whose statistics are [20 log(mu) + noise_b, 5 mu^2 + noise'_b]:
    smooth in mu, with a per-seed offset (the same at every mu: common random
    numbers), like an angle of repose and a profile feature."""

    protocol, options, params = "toy", None, None

    def __init__(self, noise=1.0):
        self.noise = noise
        self.calls = 0

    def check(self, statistics):
        return statistics

    def law_name(self):
        return "toy"

    def run(self, points, seeds, statistics, progress=None):
        self.calls += 1
        mu = np.array([p["mu"] for p in points])[:, None]
        seeds = np.asarray(list(seeds))
        e = self.noise * np.sin(1.7 * seeds + 0.3)[None, :]
        f = self.noise * 0.2 * np.cos(2.3 * seeds)[None, :]
        s = np.stack([20 * np.log(mu) + e, 5 * mu ** 2 + f], axis=-1) * np.ones((1, len(seeds), 1))
        return s, {"n_particles": 1, "batch_steps": 1, "total_seconds": 0.0}


STATS = ef.Statistics(columns=("angle", "feature"))


def _target(runner, truth=0.3137, seeds=range(100, 132)):
    s, _ = runner.run([{"mu": truth}], seeds, STATS)
    m = s[0]
    return ef.EnsembleTarget(STATS.labels(), m.mean(0), m.std(0, ddof=1), m, "toy", {"mu": truth}, list(seeds))


def test_gauss_newton_recovers_the_truth_inside_its_interval():
    runner = ToyRunner()
    target = _target(runner)
    result = ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=range(32), statistics=STATS, steps=8, progress=False)
    assert abs(result.values["mu"] / 0.3137 - 1) < 0.05
    lo, hi = result.interval["mu"]
    assert lo < 0.3137 < hi and lo < result.values["mu"] < hi
    assert result.history[-1]["converged"]
    # the interval is the sandwich: tighter with noiseless piles
    exact = ef.fit(ToyRunner(noise=1e-6), ["mu"], {"mu": 0.2}, _target(ToyRunner(noise=1e-6)), seeds=range(4),
                   statistics=STATS, steps=8, progress=False)
    assert abs(exact.values["mu"] / 0.3137 - 1) < 1e-4
    assert exact.interval["mu"][1] - exact.interval["mu"][0] < 1e-3 * (hi - lo)


def test_smoothing_with_adam_moves_toward_the_truth_and_resume_replays_the_optax_state(tmp_path):
    target = _target(ToyRunner())
    kw = dict(seeds=range(8), statistics=STATS, estimator="smoothing", optimizer="adam", lr=0.1, pairs=2,
              progress=False, interval=False)
    whole = ef.fit(ToyRunner(), ["mu"], {"mu": 0.2}, target, steps=4, **kw)
    assert whole.values["mu"] > 0.2 * np.exp(0.25)  # four adam steps of ~0.1 each, all upward
    ck = str(tmp_path / "fit.json")
    ef.fit(ToyRunner(), ["mu"], {"mu": 0.2}, target, steps=2, checkpoint=ck, **kw)
    resumed = ef.fit(ToyRunner(), ["mu"], {"mu": 0.2}, target, steps=4, resume=ck, **kw)
    assert resumed.values == whole.values
    assert [h["gradient"] for h in resumed.history] == [h["gradient"] for h in whole.history]


def test_bad_fits_are_refused_in_one_line():
    runner = ToyRunner()
    target = _target(runner)
    with pytest.raises(InputError, match="overlap"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 100], statistics=STATS, progress=False)
    with pytest.raises(InputError, match="Gauss-Newton"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 1], statistics=STATS, estimator="smoothing",
               progress=False)
    with pytest.raises(InputError, match="statistics"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 1], statistics=ef.Statistics(columns=("angle",)),
               progress=False)
    with pytest.raises(InputError, match="exactly"):
        ef.fit(runner, ["mu"], {"mu": 0.2, "kn": 1.0}, target, seeds=[0, 1], statistics=STATS, progress=False)
    with pytest.raises(InputError):
        ef.Runner("box").check(ef.Statistics())


def test_a_tiny_box_fit_from_the_command_line_moves_mu_toward_the_truth(tmp_path):
    """Lee & Herrmann 1993 boxes (the angle of repose grows with mu, Fig. 3):
    the target at mu = 0.35 from seeds 10000.., the fit from mu = 0.2 on seeds
    0, 1, one Gauss-Newton step; the base profile on 4 bins rides along."""
    from jaxpile import cli

    out = tmp_path / "fit"
    rc = cli.main(["fit", "--protocol", "box", "--params", "mu", "--set", "mu=0.2", "--truth", "mu=0.35",
                   "--ensemble", "2", "--steps", "1", "--option", "width=1.2", "--option", "height=1.2",
                   "--bins", "4", "--statistics", "repose_least_squares", "--out", str(out), "--no-progress"])
    assert rc == 0
    record = json.loads((out / "fit.json").read_text())
    assert record["values"]["mu"] > 0.2 and record["history"][0]["gradient"][0] < 0
    assert len(record["target"]["labels"]) == 1 + 4 + 4 and record["target"]["truth"] == {"mu": 0.35}
    assert (out / "fit.png").stat().st_size > 0
    assert cli.main(["show", str(out), "--out", str(tmp_path / "redrawn")]) == 0  # `show` redraws fit.png
    assert (tmp_path / "redrawn" / "fit.png").stat().st_size > 0
    assert cli.main(["fit", "--protocol", "drop", "--params", "mu_roll", "--target", "smid-novosad",
                     "--estimator", "pathwise", "--out", str(tmp_path / "x")]) == 2  # pathwise: lattice/pour only


@pytest.mark.parametrize("protocol", ["box", "pour", "lattice", "sloped", "drop", "flux", "tilt"])
def test_every_protocol_offers_an_ensemble_fit(protocol, tmp_path, capsys):
    """`jaxpile fit --protocol P` for every sweepable protocol (issue 18): the
    dry run sets one pile up and checks the statistics, runs nothing."""
    from jaxpile import cli

    law_param = {"lattice": "kn", "sloped": "kn", "drop": "ks", "pour": "n"}.get(protocol, "mu")
    assert cli.main(["fit", "--protocol", protocol, "--params", law_param, "--truth", f"{law_param}=0.3",
                     "--ensemble", "2", "--dry-run", "--out", str(tmp_path)]) == 0
    assert "runs nothing" in capsys.readouterr().out
    assert not (tmp_path / "fit.json").exists()


def test_a_deterministic_lattice_gives_back_its_stiffness_from_its_height():
    """Liffman et al. 1992 lattice (4 layers, liffman law, one pile: no
    randomness): K_s from a start 35 % low, through the pile's height (a static
    pile's base forces are set by statics, eqs. 42-44, whatever K_s)."""
    runner = ef.Runner("lattice", "liffman", options={"layers": 4, "ramp_steps": 1000})
    statistics = ef.Statistics(columns=("height",), bins=4)
    target = ef.make_target(runner, {"ks": 13_700.0}, [7], statistics)
    result = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, seeds=[0], statistics=statistics, steps=4,
                    progress=False)
    assert abs(result.values["ks"] / 13_700.0 - 1) < 1e-3
    assert result.record["sensitivity"]["ks"] > 0
