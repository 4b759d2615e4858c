"""Ensemble fits (issue 17): Gauss-Newton and optax on ensemble means with
common random numbers, the sandwich interval, resume, and one tiny real box
fit through the CLI. The toy runner stands in for the protocol so the
machinery is checked exactly and fast."""

import json

import numpy as np
import pytest

from jaxpile.fit import ensemble_fit as ef
from jaxpile.fit import ensemble_runs
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
        return s, {"n_particles": 1, "batch_steps": 1, "total_seconds": 0.0, "particle_steps": s.shape[0] * s.shape[1]}


STATS = ef.Statistics(columns=("angle", "feature"))


def _target(runner, truth=0.3137, seeds=range(100, 132)):
    s, _ = runner.run([{"mu": truth}], seeds, STATS)
    m = s[0]
    return ef.EnsembleTarget(STATS.labels(), m.mean(0), m.std(0, ddof=1), m, "toy", {"mu": truth}, list(seeds))


def test_gauss_newton_recovers_the_truth_inside_its_interval():
    runner = ToyRunner()
    target = _target(runner)
    result = ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=range(32), statistics=STATS, progress=False,
                    stopping=ef.Stopping(steps=8))
    assert abs(result.values["mu"] / 0.3137 - 1) < 0.05
    lo, hi = result.interval["mu"]
    assert lo < 0.3137 < hi and lo < result.values["mu"] < hi
    assert result.history[-1]["converged"]
    # every ensemble the fit ran is kept, for a regression over them: theta and theta +- h, then the end's
    for h in result.history:
        assert np.allclose(np.asarray(h["points"])[:, 0], h["theta"][0] + np.array([0.0, 0.05, -0.05]))
        assert np.shape(h["point_means"]) == (3, 2) and h["point_means"][0] == h["mean"]
    assert np.allclose(np.asarray(result.record["final_points"])[0], np.log(result.values["mu"]))
    assert np.allclose(result.record["final_point_means"][0], result.fitted_mean)
    # the interval is the sandwich: tighter with noiseless piles
    exact = ef.fit(ToyRunner(noise=1e-6), ["mu"], {"mu": 0.2}, _target(ToyRunner(noise=1e-6)), seeds=range(4),
                   statistics=STATS, progress=False, stopping=ef.Stopping(steps=8))
    assert abs(exact.values["mu"] / 0.3137 - 1) < 1e-4
    assert exact.interval["mu"][1] - exact.interval["mu"][0] < 1e-3 * (hi - lo)


def test_gauss_newton_stops_once_its_step_is_inside_the_noise():
    """A step smaller than its own standard error cannot be told from the
    ensembles' noise: the fit stops there (`noise_stop`), before a tolerance
    that only a noiseless fit could reach, and says why."""
    target = _target(ToyRunner())
    kw, stop = dict(seeds=range(32), statistics=STATS, progress=False, interval=False), dict(steps=8, tolerance=1e-14)
    noisy = ef.fit(ToyRunner(), ["mu"], {"mu": 0.2}, target, **kw, stopping=ef.Stopping(**stop, noise_stop=True))
    strict = ef.fit(ToyRunner(), ["mu"], {"mu": 0.2}, target, **kw, stopping=ef.Stopping(**stop))  # the tolerance alone
    last = noisy.history[-1]
    assert last["converged"] and last["stopped_by"] == "noise"
    assert abs(np.asarray(last["next_theta"]) - np.asarray(last["theta"]))[0] < last["step_stderr"][0]
    assert all(not h["converged"] for h in noisy.history[:-1])
    assert len(noisy.history) < len(strict.history) and strict.history[-1]["stopped_by"] in ("tolerance", "")
    assert abs(noisy.values["mu"] / 0.3137 - 1) < 0.05


def test_the_figure_shows_each_statistic_against_its_target_in_units_of_its_spread():
    """Statistics of different units on one axis (a dip of 0.25, an angle of 32.6 deg): each as
    (mean - target) / spread, so the target sits at 0 +- 1 and a statistic 0.5 spreads off reads 0.5."""
    runner = ToyRunner()
    target = _target(runner)
    result = ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=range(8), statistics=STATS, progress=False,
                    stopping=ef.Stopping(steps=2))
    ax = ef.figure(result).axes[2]
    target_y, start_y, fit_y = (line.get_ydata() for line in ax.lines[:3])
    assert list(target_y) == [0.0, 0.0]
    np.testing.assert_allclose(start_y, (result.start_mean - target.mean) / target.spread, rtol=1e-12)
    np.testing.assert_allclose(fit_y, (result.fitted_mean - target.mean) / target.spread, rtol=1e-12)
    assert abs(start_y[0]) > 5 and abs(fit_y[0]) < abs(start_y[0]) / 5  # the angle, 20 log(mu), moved in


def test_smoothing_with_adam_moves_toward_the_truth_and_resume_replays_the_optax_state(tmp_path):
    target = _target(ToyRunner())
    kw = dict(seeds=range(8), statistics=STATS, gradient=ef.Gradient(estimator="smoothing", pairs=2), optimizer="adam",
              lr=0.1, progress=False, interval=False)
    whole = ef.fit(ToyRunner(), ["mu"], {"mu": 0.2}, target, **kw, stopping=ef.Stopping(steps=4))
    assert whole.values["mu"] > 0.2 * np.exp(0.25)  # four adam steps of ~0.1 each, all upward
    ck = str(tmp_path / "fit.json")
    ef.fit(ToyRunner(), ["mu"], {"mu": 0.2}, target, **kw, stopping=ef.Stopping(steps=2),
           saving=ef.Saving(checkpoint=ck))
    resumed = ef.fit(ToyRunner(), ["mu"], {"mu": 0.2}, target, **kw, stopping=ef.Stopping(steps=4),
                     saving=ef.Saving(resume=ck))
    assert resumed.values == whole.values
    assert [h["gradient"] for h in resumed.history] == [h["gradient"] for h in whole.history]


def test_bad_fits_are_refused_in_one_line():
    runner = ToyRunner()
    target = _target(runner)
    with pytest.raises(InputError, match="overlap"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 100], statistics=STATS, progress=False)
    with pytest.raises(InputError, match="Gauss-Newton"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 1], statistics=STATS, progress=False,
               gradient=ef.Gradient(estimator="smoothing"))
    with pytest.raises(InputError, match="statistics"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 1], statistics=ef.Statistics(columns=("angle",)),
               progress=False)
    with pytest.raises(InputError, match="exactly"):
        ef.fit(runner, ["mu"], {"mu": 0.2, "kn": 1.0}, target, seeds=[0, 1], statistics=STATS, progress=False)
    with pytest.raises(InputError):
        ef.Runner("box").check(ef.Statistics())
    with pytest.raises(InputError, match="fewer --bins"):  # a profile too big for the memory, before any pile runs
        ef.Runner("box").run([{"mu": 0.3}], [0], ef.Statistics(bins=10**12))


def test_the_truncated_estimator_is_offered_where_it_can_run_and_refused_in_one_line_elsewhere(tmp_path, capsys):
    """`--estimator truncated` runs a one-stage construction as rollouts and
    differentiates its base profile: a protocol of two stages, an angle among the
    statistics or Gauss-Newton (it gives no Jacobian) are refused before any
    pile runs; the pour's dry run fits the profile alone."""
    from jaxpile import cli

    runner = ToyRunner()
    target = _target(runner)
    with pytest.raises(InputError, match="runs for box, drop, lattice, pour, sloped"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 1], statistics=STATS, optimizer="adam", progress=False,
               gradient=ef.Gradient(estimator="truncated"))
    for statistics, optimizer, match in ((ef.Statistics(columns=("repose_mean",), bins=4), "adam", "profile alone"),
                                         (ef.Statistics(bins=4), "gauss-newton", "Gauss-Newton")):
        with pytest.raises(InputError, match=match):
            ef.fit(ef.Runner("pour"), ["n"], {"n": 30.0}, target, seeds=[0, 1], optimizer=optimizer,
                   statistics=statistics, progress=False, gradient=ef.Gradient(estimator="truncated"))
    assert cli.main(["fit", "--protocol", "pour", "--params", "n", "--truth", "n=30", "--ensemble", "2",
                     "--estimator", "truncated", "--bins", "4", "--dry-run", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "['normal[0]'" in out and "repose" not in out and "3 ensembles" in out
    assert cli.main(["fit", "--protocol", "tilt", "--params", "mu", "--truth", "mu=0.3", "--estimator", "truncated",
                     "--dry-run", "--out", str(tmp_path)]) == 2
    assert "no base extent" in capsys.readouterr().err  # the tilt's piles have no base profile to fit
    assert cli.main(["fit", "--protocol", "pour", "--params", "n", "--truth", "n=30", "--estimator", "truncated",
                     "--truncation-window", "0", "--dry-run", "--out", str(tmp_path)]) == 2


def test_a_truncated_fit_takes_the_constructions_gradient_and_records_it(monkeypatch):
    """The fit's truncated branch, on a toy construction whose piles relax
    toward [20 theta, 5 exp(2 theta)] (theta = log mu) in 400 steps: with one
    window as long as the construction, the gradient it records is the exact
    one through the rollout. (The pour's `Construction` gave the estimator
    study's own rollouts bit for bit over 40 000 steps when it replaced them;
    compiling a real one costs minutes on 2 cores.)"""
    import jax
    import jax.numpy as jnp

    from jaxpile.fit import construction

    class Toy:
        steps, particles = 400, 1

        def __init__(self, runner, seeds, statistics, names, theta):
            self.start = jnp.zeros((len(list(seeds)), 2))

        def advance(self, t, state, k):
            target = jnp.stack([20 * t[0], 5 * jnp.exp(2 * t[0])])
            return target + (state - target) * jnp.exp(-0.01 * k)

        def statistics(self, t, state):
            return state

        def particle_steps(self):
            return 3.0 * self.start.shape[0] * self.steps

    monkeypatch.setattr(construction, "Construction", Toy)
    monkeypatch.setattr(construction, "check", lambda runner, statistics: None)
    runner = ToyRunner()
    target = _target(runner)
    theta = np.log([0.2])
    result = ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 1], statistics=STATS, optimizer="adam",
                    progress=False, interval=False, gradient=ef.Gradient(estimator="truncated", window=400),
                    stopping=ef.Stopping(steps=1))
    toy, w = Toy(None, [0, 1], None, None, None), ef.weights(target)
    exact = jax.grad(lambda t: ef.objective_for(target, w)(toy.advance(t, toy.start, 400).mean(0)))(jnp.asarray(theta))
    entry = result.history[0]
    np.testing.assert_allclose(entry["gradient"], np.asarray(exact), rtol=1e-10)
    assert entry["particle_steps"] == 2400 and result.record["window"] == 400 and entry["theta"] == theta.tolist()
    assert entry["next_theta"][0] == pytest.approx(theta[0] - 0.1 * np.sign(exact[0]), abs=1e-6)  # adam's first step
    Toy.statistics = lambda self, t, state: state * jnp.nan  # a heap without a profile: no step on a NaN
    result = ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=[0, 1], statistics=STATS, optimizer="adam",
                    progress=False, interval=False, gradient=ef.Gradient(estimator="truncated", window=400),
                    stopping=ef.Stopping(steps=3))
    assert len(result.history) == 1 and result.history[0]["next_theta"] == theta.tolist()
    assert "not finite" in result.record["message"] and result.values["mu"] == pytest.approx(0.2)


def test_a_tiny_box_fit_from_the_command_line_moves_mu_toward_the_truth(tmp_path):
    """Lee & Herrmann 1993 boxes (the angle of repose grows with mu, Fig. 3):
    the target at mu = 0.35 from seeds 10000.., the fit from mu = 0.2 on seeds
    0, 1, one Gauss-Newton step; the base profile on 4 bins rides along. The
    differences span mu = 0.12-0.33 (log-step 0.5), where the angle grows by
    some 25 degrees, four times two boxes' spread, so the slope's sign holds
    on any CPU (a box pile is chaotic: at the default step, 0.19-0.21, it is
    noise)."""
    from jaxpile import cli

    out = tmp_path / "fit"
    rc = cli.main(["fit", "--protocol", "box", "--params", "mu", "--set", "mu=0.2", "--truth", "mu=0.35",
                   "--difference-step", "0.5",
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
    result = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, seeds=[0], statistics=statistics, progress=False,
                    stopping=ef.Stopping(steps=4))
    assert abs(result.values["ks"] / 13_700.0 - 1) < 1e-3
    assert result.record["sensitivity"]["ks"] > 0


def test_a_construction_rolled_out_ends_where_the_batch_of_the_same_pile_ends():
    """`construction.Construction` builds any one-stage protocol's piles as
    the sweep builds them: the 4-layer liffman lattice (deterministic) rolled
    out to the construction's length has the base profile its batch run
    measures, to round-off (the rollout's lists are sized once, the batch's
    at every chunk, so the sums may differ in their last bits)."""
    from jaxpile.fit import construction

    runner = ef.Runner("lattice", "liffman", options={"layers": 4, "ramp_steps": 1000})
    statistics = ef.Statistics(bins=4)
    theta = np.log([13_700.0])
    built = construction.Construction(runner, [0], statistics, ["ks"], theta)
    rolled = np.asarray(built.statistics(theta, built.advance(theta, built.start, built.steps)))
    measured, _ = runner.run([{"ks": 13_700.0}], [0], statistics)
    assert np.all(np.isfinite(rolled)) and rolled.shape == (1, 8)  # normal, then horizontal
    np.testing.assert_allclose(rolled, measured[0], rtol=1e-9, atol=1e-12 * float(np.max(np.abs(measured))))


class _Stopped(Exception):
    """A fit stopped from outside (a session's end, a kill) right after a batch save."""


def test_a_fit_stopped_inside_an_iteration_resumes_its_batch_and_ends_as_the_uninterrupted_fit(tmp_path,
                                                                                              monkeypatch, capsys):
    """fit(batch_checkpoint=(path, every)): a fit stopped right after the first save of its first
    iteration's batch (no iteration finished) resumes from its history, written before the first
    iteration, and from that save, and ends with the uninterrupted fit's history and values; each batch's
    save is removed when the batch is measured, and a fresh fit removes one left in its place."""
    from jaxpile.engine import checkpoint as ckpt

    runner = ef.Runner("lattice", "liffman", options={"layers": 4, "ramp_steps": 1000})
    statistics = ef.Statistics(columns=("height",), bins=4)
    target = ef.make_target(runner, {"ks": 13_700.0}, [7], statistics)
    kw = dict(seeds=[0], statistics=statistics, stopping=ef.Stopping(steps=1), progress=False, interval=False)
    whole = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **kw)

    saves, save = [], ckpt.save

    def save_then_stop(path, *args, **extra):
        save(path, *args, **extra)
        saves.append(path)
        raise _Stopped

    history, batch = str(tmp_path / "fit.json"), tmp_path / "batch.npz"
    monkeypatch.setattr(ckpt, "save", save_then_stop)
    with pytest.raises(_Stopped):
        ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **kw,
               saving=ef.Saving(checkpoint=history, batch=(str(batch), 200)))
    monkeypatch.setattr(ckpt, "save", save)
    assert saves == [str(batch)] and ckpt.read_metadata(batch)["extra"]["batch_start"] == 0
    from jaxpile import batches

    resumes, sweep = [], batches.sweep
    monkeypatch.setattr(batches, "sweep", lambda *a, **k: resumes.append(k["resume"]) or sweep(*a, **k))
    resumed = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **kw,
                     saving=ef.Saving(checkpoint=history, resume=history, batch=(str(batch), 200)))
    assert resumes == [str(batch), None]  # the iteration's batch from its save, the final one afresh
    assert not batch.exists()
    assert resumed.values == whole.values
    def same(h):  # as JSON: NaN standard errors (one pile) compare equal
        return json.dumps({k: v for k, v in h.items() if k != "seconds"})

    assert [same(h) for h in resumed.history] == [same(h) for h in whole.history]
    batch.write_bytes(b"another fit's batch")
    again = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **kw, saving=ef.Saving(batch=(str(batch), 200)))
    assert again.values == whole.values and not batch.exists()
    # a save of another batch (here: a resume in batches of another size) is removed with a warning, not
    # continued nor a failure
    monkeypatch.setattr(ckpt, "save", save_then_stop)
    with pytest.raises(_Stopped):
        ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **kw,
               saving=ef.Saving(checkpoint=history, batch=(str(batch), 200)))
    monkeypatch.setattr(ckpt, "save", save)
    resumes.clear()
    with pytest.warns(UserWarning, match="another batch of piles"):
        other = ef.fit(runner._replace(batch_size=1), ["ks"], {"ks": 9_000.0}, target, **kw,
                       saving=ef.Saving(checkpoint=history, resume=history, batch=(str(batch), 200)))
    assert resumes == [None, None] and other.values == whole.values and not batch.exists()
    # stopped in the final batch (the interval's, after the last iteration): the resume runs no iteration
    # and continues that batch
    calls = []

    def save_in_final(path, *args, **extra):
        save(path, *args, **extra)
        if len(calls) == 2:
            raise _Stopped

    monkeypatch.setattr(batches, "sweep", lambda *a, **k: calls.append(k["resume"]) or sweep(*a, **k))
    monkeypatch.setattr(ckpt, "save", save_in_final)
    with pytest.raises(_Stopped):
        ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **{**kw, "interval": True},
               saving=ef.Saving(checkpoint=history, batch=(str(batch), 200)))
    monkeypatch.setattr(ckpt, "save", save)
    calls.clear()
    final = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **{**kw, "interval": True},
                   saving=ef.Saving(checkpoint=history, resume=history, batch=(str(batch), 200)))
    assert calls == [str(batch)] and not batch.exists()
    uninterrupted = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **{**kw, "interval": True})
    assert final.values == uninterrupted.values and final.interval == uninterrupted.interval
    # stopped in a later iteration (the second's batch): the resume takes the first from the history,
    # continues the second's batch from its save and runs the final one
    two = {**kw, "stopping": ef.Stopping(steps=2)}
    calls.clear()
    monkeypatch.setattr(ckpt, "save", save_in_final)  # stops at the first save of the second batch run
    with pytest.raises(_Stopped):
        ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **two,
               saving=ef.Saving(checkpoint=history, batch=(str(batch), 200)))
    monkeypatch.setattr(ckpt, "save", save)
    assert calls == [None, None] and len(json.loads(open(history).read())["history"]) == 1
    calls.clear()
    later = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **two,
                   saving=ef.Saving(checkpoint=history, resume=history, batch=(str(batch), 200)))
    assert calls == [str(batch), None] and not batch.exists()  # the second from its save, the final one afresh
    both = ef.fit(runner, ["ks"], {"ks": 9_000.0}, target, **two)
    assert len(both.history) == 2 and later.values == both.values
    assert [same(h) for h in later.history] == [same(h) for h in both.history]
    monkeypatch.setattr(batches, "sweep", lambda *a, **k: resumes.append(k["resume"]) or sweep(*a, **k))

    # the command line: OUT/fit_batch.npz, and OUT/target_batch.npz for a target stopped before the fit began,
    # which --resume continues
    from jaxpile import cli

    out = tmp_path / "cli"
    argv = ["fit", "--protocol", "lattice", "--law", "liffman", "--layers", "4", "--ramp-steps", "1000", "--bins",
            "4", "--statistics", "height", "--params", "ks", "--set", "ks=9000", "--truth", "ks=13700",
            "--target-seeds", "7", "--estimator", "central", "--ensemble", "1", "--steps", "1",
            "--checkpoint-every", "200", "--no-progress", "--out", str(out)]
    saves.clear()
    monkeypatch.setattr(ckpt, "save", save_then_stop)
    with pytest.raises(_Stopped):
        cli.main(argv)
    monkeypatch.setattr(ckpt, "save", save)
    assert saves == [str(out / "target_batch.npz")] and not (out / "fit_checkpoint.json").exists()
    resumes.clear()  # --resume continues the target's save without --checkpoint-every (saved as often as before)
    plain = argv[:argv.index("--checkpoint-every")] + argv[argv.index("--checkpoint-every") + 2:]
    capsys.readouterr()
    assert cli.main(plain + ["--resume"]) == 0
    assert "jaxpile: resuming the target's piles in" in capsys.readouterr().out  # --resume says what it resumes
    assert resumes[0] == str(out / "target_batch.npz") and resumes[1:] == [None, None]
    record = json.loads((out / "fit.json").read_text())
    assert record["values"] == whole.values and not list(out.glob("*_batch.npz"))
    (out / "target_batch.npz").write_bytes(b"another command's target")  # a new command makes its own target
    resumes.clear()
    assert cli.main(argv) == 0 and resumes == [None, None, None] and not list(out.glob("*_batch.npz"))
    capsys.readouterr()
    assert cli.main(["fit", "--params", "ks", "--target", str(tmp_path / "profile.csv"), "--checkpoint-every",
                     "200", "--out", str(tmp_path / "pathwise")]) == 2
    assert "a pathwise fit runs one pile" in capsys.readouterr().err
    assert cli.main(argv[:argv.index("--checkpoint-every")] + ["--checkpoint-every", "0", "--dry-run", "--out",
                                                               str(tmp_path / "zero")]) == 2


def test_missing_statistics_weights_and_resume_guards(tmp_path):
    """A pile missing a statistic at any point is left out of it at every
    point (common random numbers kept); each unit group is weighted by its own
    spread; a resume of another fit, or a target of other statistics, is refused."""
    s = np.array([[[1.0, 10.0], [3.0, 30.0], [5.0, 50.0]],
                  [[2.0, 20.0], [np.nan, 40.0], [6.0, 60.0]]])  # [points, piles, k]
    filled, missing = ensemble_runs.fill_missing(s)
    assert missing == 1
    # pile 1 is out of statistic 0 at both points: each point's mean is that of piles 0 and 2
    assert filled[0, :, 0].mean() == pytest.approx(3.0) and filled[1, :, 0].mean() == pytest.approx(4.0)
    np.testing.assert_array_equal(filled[:, :, 1], s[:, :, 1])
    with pytest.raises(InputError, match="every pile"):
        ensemble_runs.fill_missing(np.full((1, 2, 1), np.nan))

    target = ef.EnsembleTarget(["angle", "normal[0]", "normal[1]"], np.zeros(3), np.array([5.0, 0.2, 0.0]), None, "t")
    w = ef.weights(target)
    assert w[0] == pytest.approx(1 / 25) and w[1] == pytest.approx(1 / 0.04)
    assert w[2] == pytest.approx(1 / (0.01 * 0.04))  # a bin with no spread: floored within its own group

    runner = ToyRunner()
    toy = _target(runner)
    ck = str(tmp_path / "fit.json")
    ef.fit(runner, ["mu"], {"mu": 0.2}, toy, seeds=range(4), statistics=STATS, progress=False, interval=False,
           stopping=ef.Stopping(steps=1), saving=ef.Saving(checkpoint=ck))
    with pytest.raises(InputError, match="another fit.*step"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, toy, seeds=range(4), statistics=STATS, progress=False,
               gradient=ef.Gradient(step=0.1), stopping=ef.Stopping(steps=2), saving=ef.Saving(resume=ck))
    renamed = toy._replace(labels=["angle", "dip"])
    with pytest.raises(InputError, match="same statistics"):
        ef.fit(runner, ["mu"], {"mu": 0.2}, renamed, seeds=range(4), statistics=STATS, progress=False)


def test_a_deterministic_fit_takes_its_interval_from_the_residual():
    """Identical piles (a deterministic protocol run with several seeds) have
    no spread: the interval comes from what the fit cannot explain, not zero."""
    jac = np.array([[2.0], [1.0]])
    piles = np.array([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0]])
    target = ef.EnsembleTarget(["a", "b"], np.array([1.1, 1.9]), np.zeros(2), piles, "t")
    cov, dof = ef.confidence(jac, np.ones(2), piles, target)
    assert dof == 1 and cov[0, 0] == pytest.approx((0.1 ** 2 + 0.1 ** 2) / 1 / 5.0)


def test_smid_novosad_is_an_ensemble_target_of_the_central_dip(tmp_path, capsys):
    """Issue 17, item 5: the declared dip (0.20-0.30 below the maximum; 0.25)
    as the target of an ensemble fit of the columns the drop and the pour
    measure, chosen by `--target smid-novosad --estimator central`."""
    from jaxpile import cli, fit

    target = ef.smid_novosad_target()
    assert target.labels == ["central_dip"] and target.members is None and target.setting is None
    low, high = fit.SMID_NOVOSAD_DIP_RANGE
    assert target.mean[0] == pytest.approx(0.5 * (low + high)) and target.spread[0] == pytest.approx(0.5 * (high - low))
    assert ef.EnsembleTarget.from_json(target.to_json()).mean.tolist() == target.mean.tolist()
    assert cli.main(["fit", "--protocol", "pour", "--params", "n,mu", "--target", "smid-novosad", "--estimator",
                     "central", "--ensemble", "2", "--dry-run", "--out", str(tmp_path)]) == 0
    assert "statistics ['central_dip']" in capsys.readouterr().out
    assert cli.main(["fit", "--protocol", "drop", "--params", "mu_roll", "--target", "smid-novosad", "--estimator",
                     "central", "--truth", "mu_roll=0.2", "--out", str(tmp_path)]) == 2  # two targets


def test_smid_novosad_declares_the_dip_and_the_angle_of_repose_liffman1992_fig17(tmp_path, capsys):
    """The declared pile holds the reported 32.6 deg angle of repose (Liffman et
    al. 1992, text of Fig. 17) beside the dip: `--statistics
    central_dip,repose_mean` fits a pour with rolling resistance to both; a
    statistic Smid & Novosad did not report is refused before any pile runs."""
    from jaxpile import cli, fit

    both = ef.smid_novosad_target(["central_dip", "repose_mean"])
    assert both.labels == ["central_dip", "repose_mean"] and both.members is None and both.setting is None
    assert both.mean.tolist() == [0.25, fit.SMID_NOVOSAD_ANGLE_DEGREES] == [0.25, 32.6]
    assert both.spread.tolist() == [ef.smid_novosad_target().spread[0], 1.0]
    assert "32.6" in both.source and "Fig. 17" in both.source
    assert ef.smid_novosad_target(["repose_mean"]).mean.tolist() == [32.6]
    # the dip read in fixed narrow windows (heap.dip_below_flanks) is the same declared 0.25 +- 0.05
    narrow = ef.smid_novosad_target(["dip_below_flanks", "repose_mean"])
    assert narrow.mean.tolist() == both.mean.tolist() and narrow.spread.tolist() == both.spread.tolist()
    for bad in (["height"], [], ["central_dip", "central_dip"]):
        with pytest.raises(InputError, match="declares central_dip, dip_below_flanks, repose_mean"):
            ef.smid_novosad_target(bad)
    rolling = ["--rolling", "sds", "--rotation", "on", "--set", "k_roll=1000", "--set", "mu_roll=0.2"]
    assert cli.main(["fit", "--protocol", "pour", "--params", "mu,mu_roll", "--target", "smid-novosad",
                     "--statistics", "central_dip,repose_mean", "--estimator", "central", *rolling, "--ensemble", "2",
                     "--dry-run",
                     "--out", str(tmp_path)]) == 0
    assert "statistics ['central_dip', 'repose_mean']" in capsys.readouterr().out
    # the cone, Smid & Novosad's own heap, reads its angle of repose as `angle` (from h(r))
    assert ef.smid_novosad_target(["central_dip", "angle"]).mean.tolist() == [0.25, 32.6]
    assert cli.main(["fit", "--protocol", "cone", "--n", "60", "--params", "mu_roll", "--target", "smid-novosad",
                     "--statistics", "central_dip,angle", *rolling[:2], *rolling[4:], "--dry-run",
                     "--out", str(tmp_path)]) == 0
    assert "spheres a pile" in capsys.readouterr().out
    assert cli.main(["fit", "--protocol", "pour", "--params", "mu", "--target", "smid-novosad", "--statistics",
                     "central_dip,height", "--estimator", "central", "--dry-run", "--out", str(tmp_path)]) == 2
    assert "declares central_dip, dip_below_flanks, repose_mean" in capsys.readouterr().err
    # resumed with the command that began it, a fit to the declared dip compares the dip again (not the
    # protocol's own statistics, which its saved target does not hold)
    assert cli.main(["fit", "--protocol", "drop", "--params", "mu_roll", "--target", "smid-novosad", "--estimator",
                     "central", "--resume", "--dry-run", "--out", str(tmp_path)]) == 0
    assert "statistics ['central_dip']" in capsys.readouterr().out


class ChaoticToyRunner(ToyRunner):
    """Piles whose statistics move with log mu by ~4 per-pile spreads plus
    noise that changes with mu as well as with the seed: common random numbers do not cancel it, as in a
    silo's discharge (docs/fitting.md, the hopper recovery)."""

    def run(self, points, seeds, statistics, progress=None):
        mu = np.array([p["mu"] for p in points])[:, None]
        noise = self.noise * np.array([[np.random.default_rng([round(m * 1e9), s]).normal() for s in seeds]
                                       for m in mu[:, 0]])  # a draw for each (mu, seed)
        s = np.stack([3 * np.log(mu) + noise, np.log(mu) - 0.5 * noise], axis=-1)
        return s, {"n_particles": 1, "batch_steps": 1, "total_seconds": 0.0, "particle_steps": s.size}


def test_regression_over_every_ensemble_is_exact_on_a_line_and_honest_in_chaos():
    """jaxpile.fit.regression: inverse regression through all of a fit's
    ensembles. On statistics linear in log mu it returns the truth exactly; on
    a chaotic toy (noise that changes with mu) it lands no farther from the
    truth than Gauss-Newton's last step on average, and its interval holds the
    truth where the last step's misses it."""
    from jaxpile.fit import regression

    truth, stats = 0.3137, ef.Statistics(columns=("angle", "feature"))
    exact = ChaoticToyRunner(noise=0.0)
    result = ef.fit(exact, ["mu"], {"mu": 0.2}, _target(exact, truth), seeds=range(8), statistics=stats, progress=False,
                    stopping=ef.Stopping(steps=4))
    assert result.record["regression"]["values"]["mu"] == pytest.approx(truth, rel=1e-9)
    gn_errors, regression_errors, gn_inside, regression_inside = [], [], 0, 0
    for k in range(6):  # independent targets and fits
        runner = ChaoticToyRunner(noise=1.0)
        target = _target(runner, truth, seeds=range(1000 * (k + 1), 1000 * (k + 1) + 32))
        fit = ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=range(100 * k, 100 * k + 32), statistics=stats,
                     progress=False, gradient=ef.Gradient(step=0.2),  # h as fit_recovery's chaotic cases
                     stopping=ef.Stopping(steps=6))
        again = regression.estimate(fit)  # from the result alone, as for a fit.json
        assert again.values == fit.record["regression"]["values"]
        assert again.points == 3 * (len(fit.history) - 1) + 3  # the start's iteration left out, the end's in
        gn_errors.append(abs(np.log(fit.values["mu"] / truth)))
        regression_errors.append(abs(np.log(again.values["mu"] / truth)))
        gn_inside += fit.interval["mu"][0] < truth < fit.interval["mu"][1]
        regression_inside += again.interval["mu"][0] < truth < again.interval["mu"][1]
    # the target's own noise is common to both, so the gain is in the interval: the last step's counts the
    # noise of its means but not that of its finite-difference Jacobian (3 of 6 hold the truth here)
    assert np.mean(regression_errors) < np.mean(gn_errors), (regression_errors, gn_errors)
    assert regression_inside >= 5 and regression_inside > gn_inside, (regression_inside, gn_inside)


def test_inverse_regression_interval_holds_the_answer_when_the_target_cannot_be_met():
    """jaxpile.fit.regression.inverse where the line misses the target (Smid and Novosad's dip and angle
    against poured heaps, whose dip stays far below it): the answer then moves with the line's slope as
    well as its level, and the interval must count both. 1000 data sets drawn about a known line (three
    grid points of 16 heaps, the scatter of the committed heaps): the 95 % interval holds the true line's
    answer in at least 92 % of them (the level alone: about 86 %)."""
    from jaxpile.fit import regression

    rng = np.random.default_rng(11)
    a, jac = np.array([0.05, 27.7]), np.array([[0.3], [34.0]])
    target, w = np.array([0.25, 32.6]), np.array([1 / 0.05 ** 2, 1.0])
    best = float(np.squeeze((jac.T * w) @ (target - a) / ((jac.T * w) @ jac)))
    x = np.repeat([0.0, 0.15, 0.3], 16)[:, None]
    inside = 0
    for _ in range(1000):
        means = a + x @ jac.T + rng.normal(size=(len(x), 2)) * np.array([0.22, 3.9])
        line = regression.inverse(x, means, target, w)
        half = regression.t_quantile(line.dof) * np.sqrt(line.cov[0, 0])
        inside += abs(line.theta[0] - best) < half
    assert 920 <= inside <= 990, inside
