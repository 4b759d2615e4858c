"""The benchmark harness: its LAMMPS twin is the same problem as jaxpile's (run
against LAMMPS when `lmp` is installed), and `make bench` rebuilds the
benchmark table of docs/performance.md from the results. No timings here: figures live in benchmarks/ (the
suite) and benchmarks/studies/ (the papers' ensembles, the fits' recoveries)."""

import json
import math
import pathlib
import sys

import numpy as np
import pytest

from jaxpile import analysis
from jaxpile.laws import hooke
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator, gravity_ramp

BENCHMARKS = pathlib.Path(__file__).resolve().parents[1] / "benchmarks"
# the suite (benchmarks/) and the studies (benchmarks/studies/papers, benchmarks/studies/fitting)
sys.path[:0] = [str(BENCHMARKS), str(BENCHMARKS / "studies" / "papers"), str(BENCHMARKS / "studies" / "fitting"),
                 str(BENCHMARKS / "studies" / "reproducibility"), str(BENCHMARKS / "studies" / "calibrate")]
import lammps_peer as peer  # noqa: E402
import run_all  # noqa: E402
import vs_lammps  # noqa: E402

LAYERS, RAMP, HOLD = 6, 1500, 1500


def test_lammps_twin_script_is_the_hooke_law_with_the_gravity_ramp(tmp_path):
    particles, boundaries = lattice.equilateral_pile(LAYERS)
    params = vs_lammps.lattice_params(wall_mu=0.8)
    script, _ = vs_lammps.lattice_job(str(tmp_path), particles, boundaries, params, RAMP, HOLD)
    lines = script.splitlines()
    pair = next(line for line in lines if line.startswith("pair_style")).split()
    assert pair[1] == "gran/hooke/history"
    # kn kt gamma_n gamma_t mu dampflag, with LAMMPS's kt = 2/7 kn default made explicit
    assert [float(v) for v in pair[2:7]] == pytest.approx([1e4, 2e4 / 7, 100.0, 50.0, 0.0])
    wall = next(line for line in lines if "wall/gran" in line).split()
    assert wall[3:5] == ["wall/gran", "hooke/history"]
    assert [float(v) for v in wall[5:10]] == pytest.approx([1e4, 2e4 / 7, 100.0, 50.0, 0.8])
    assert "yplane" in wall and "contacts" in wall
    assert any(line.startswith("fix") and line.split()[3] == "nve" for line in lines)  # rotation off
    assert f"run {RAMP + HOLD}" in lines
    data = (tmp_path / "pile.data").read_text()
    assert f"{particles.count} atoms" in data


def test_the_cone_replay_is_a_3d_pour_of_the_same_spheres_with_the_plate_frozen(tmp_path):
    """`cone_vs_lammps.py`'s LAMMPS input: spheres (no enforce2d, nve/sphere
    without `disc`, gravity along -z), one `create_atoms` per poured sphere at
    its release point and speed, the plate's spheres in the data file; and,
    with LAMMPS present, a short replay that keeps every sphere over the plate."""
    import argparse

    import cone_vs_lammps as race
    from jaxpile.protocols import cone

    args = argparse.Namespace(n=6, interval=0.2, release_height=30.0, settle=500, seed=0)
    setup = race.set_up(args, 0)
    _, _, params = cone.law_and_params("hooke")
    script, workdir = race.lammps_job(args, setup, str(tmp_path / "cone"), params, skin=0.2)
    lines = script.splitlines()
    assert "dimension 3" in lines and "boundary f f f" in lines and "fix move all nve/sphere" in lines
    assert not any("enforce2d" in line for line in lines)
    assert "neigh_modify exclude group base base" in lines  # no plate-plate pairs, as jaxpile lists none
    assert "fix grav all gravity 1.0 vector 0.0 0.0 -1.0" in lines
    creates = [line.split() for line in lines if line.startswith("create_atoms")]
    release = np.asarray(setup.protocol_state.release_position)[int(setup.protocol_state.first):]
    assert np.allclose([[float(v) for v in c[3:6]] for c in creates], release)
    speeds = [line for line in lines if line.startswith("set atom") and " vz " in line]
    assert len(speeds) == 6 and all(float(line.split()[-1]) == -setup.info["insert_speed"] for line in speeds)
    rows = int(setup.protocol_state.first)
    assert f"{rows} atoms" in (tmp_path / "cone" / "plate.data").read_text()
    stats = race.cone_stats(np.array([[3.0, 4.0, 1.5], [0.0, 0.0, 0.5]]), np.zeros((2, 3)), base_z=0.5)
    assert stats["on_plate"] == 2 and stats["centroid_height"] == 0.5 and stats["height"] == 1.0
    assert stats["rms_radius"] == pytest.approx(np.sqrt(12.5))
    if peer.find_binary() is not None:
        run = peer.run(peer.find_binary(), script, workdir)
        assert run.ok, run.error
        theirs = race.lammps_stats(run, rows, setup.info["base_z"])
        assert theirs["on_plate"] == 6 and 0.0 < theirs["centroid_height"] < 3.0


@pytest.mark.skipif(peer.find_binary() is None, reason="LAMMPS (lmp) is not installed")
def test_lammps_and_jaxpile_give_the_same_base_forces_on_a_small_lattice_pile(tmp_path):
    particles, boundaries = lattice.equilateral_pile(LAYERS)
    params = vs_lammps.lattice_params()
    sim = Simulator(hooke.law(rotation=False), lattice.PAPER_SETTING["dt"], schedule=gravity_ramp(RAMP))
    state = sim.run(params, sim.init(params, particles, boundaries), RAMP + HOLD, progress=False)
    base = analysis.base_forces(sim, params, state)
    run = peer.run(peer.find_binary(), *vs_lammps.lattice_job(str(tmp_path), particles, boundaries, params, RAMP, HOLD))
    assert run.ok, run.error
    check = vs_lammps.agreement(base, run)
    assert check["contacts"] == [LAYERS, LAYERS]
    # same integrator, same law, same ramp: the two codes agree to round-off on a small pile
    assert check["max_rel_dev_normal"] < 1e-8 and check["max_rel_dev_horizontal"] < 1e-8, check
    assert run.steps == RAMP + HOLD


def test_performance_table_is_rebuilt_from_the_results_files(tmp_path, monkeypatch):
    results = tmp_path / "results" / "cpu"
    results.mkdir(parents=True)
    rows = [{"case": "lattice", "jaxpile": 2.0e6, "lammps": 1.0e7, "ratio": 0.2, "note": "n1"},
            {"case": "scaling", "jaxpile": 3.0e6, "lammps": None, "ratio": None, "note": "n2"}]
    (results / "a.json").write_text(json.dumps({"machine": "m", "table": rows}))
    study = tmp_path / "results" / "hopper"  # a study's own table beside the benchmarks: not a benchmark row
    study.mkdir()
    (study / "beverloo.json").write_text(json.dumps({"table": [{"orifice": 4, "flow_rate_mean": 4.7}]}))
    page = tmp_path / "performance.md"
    page.write_text(f"intro\n{run_all.START}\nold table\n{run_all.END}\nafter\n")
    monkeypatch.setattr(run_all, "PAGE", page)
    assert run_all.update_page(run_all.table(tmp_path / "results"))
    text = page.read_text()
    assert "old table" not in text and text.startswith("intro\n") and text.endswith("after\n")
    assert "| m | lattice | 2e+06 | 1e+07 | 0.20x | n1 |" in text
    assert "| m | scaling | 3e+06 | — | — | n2 |" in text
    page.write_text("no markers\n")
    assert not run_all.update_page("x")  # says so rather than appending somewhere


def test_bench_lists_only_scripts_that_exist():
    for script, _, _ in run_all.BENCHMARKS.values():
        assert (pathlib.Path(run_all.HERE) / script).exists()
    assert np.all([name.isidentifier() for name in run_all.BENCHMARKS])


def test_baxter_study_measures_the_m_without_selection_bias_and_averages_flanks():
    """The 1997 study's M depth (Baxter et al. 1997, sec. III: flank maxima
    20-30% above the centre) in fixed windows: an M profile reads above 1, a
    humped one below, and a flat noisy one near 1 where the largest-bin ratio
    of `heap.m_shape` reads above 1. Mean +- standard error over heaps."""
    import baxter_readings as br

    x = list(np.linspace(0.025, 0.975, 20))
    m = {"base_profile": {"x_over_b": x, "normalised": [1.0 - 0.6 * abs(abs(v - 0.5) - 0.3) for v in x]}}
    hump = {"base_profile": {"x_over_b": x, "normalised": [1.0 - abs(v - 0.5) for v in x]}}
    assert br.flank_over_centre(m) > 1.05 and br.flank_over_centre(hump) < 0.95
    noisy = np.random.default_rng(0).normal(1.0, 0.1, 20)
    flat = {"base_profile": {"x_over_b": x, "normalised": list(noisy)}}
    assert abs(br.flank_over_centre(flat) - 1.0) < 0.15 and max(noisy[:8]) / noisy[9] > 1.0
    assert br.flank_over_centre({}) is None
    s = br.mean_stderr([1.0, 2.0, 3.0, None])
    assert s["mean"] == 2.0 and s["count"] == 3 and abs(s["stderr"] - 1 / np.sqrt(3)) < 1e-12
    row = {"angle_mid_flank": {"left": 20.0, "right": 30.0},
           "angle_of_repose": {"left": {"least_squares": 22.0}, "right": None}}
    assert br.angle(row, "mid_flank") == 25.0 and br.angle(row, "least_squares") is None


def test_baxter_angle_bands_read_the_saved_heaps_as_the_study_measured_them():
    """`baxter_angle_bands.py` re-measures the 1997 heaps (Baxter et al. 1997,
    sec. III, "the angle between the inclined surface and the base") from their
    saved final states: its 0.2-0.8 band is the study's own `angle_mid_flank`,
    heap by heap, and the rows of a row spilled over by the heap (`row35`) hold
    fewer disks than they poured."""
    import baxter_angle_bands as bands
    import baxter_readings as br

    root = pathlib.Path(__file__).resolve().parents[1]
    rows = {(br.name_of(r), r["seed"]): r for r in br.heap_rows(root / "benchmarks/results/baxter_readings/n300")}
    saved = root / "tests/data/baxter_heaps"  # two of the study's saved final states
    for setting, seed in (("row35", 0), ("contact-point/hold", 4)):
        measured = rows[(setting, seed)]["angle_mid_flank"]
        again = bands.heap_angles(str(saved / f"{setting.replace('/', '_')}_seed{seed}.npz"))["0.2-0.8"]
        assert again == pytest.approx([measured["left"], measured["right"]], abs=1e-9)
    spilled = [r["counts"]["lost"] for (setting, _), r in rows.items() if setting == "row35"]
    assert len(spilled) == 8 and sum(spilled) > 0


def test_papers_table_is_the_one_the_results_give():
    """benchmarks/studies/papers/papers.py writes the papers-side-by-side table of docs/papers.md
    from the committed results JSON (issue 16): the page must hold exactly that table."""
    import papers

    assert papers.rewrite_page(check=True), "run `python benchmarks/studies/papers/papers.py` and commit docs/papers.md"
    assert "| 1993 | θ_T against" in papers.table()


def test_the_1992_networks_summary_holds_what_its_analytic_parts_give_and_draws_its_figure(tmp_path):
    """liffman_networks.py's tents (Figs. 18-19) and SLIP/NOSLIP collisions
    (eqs. 4-19) recomputed here are the committed summary's (to round-off),
    and its figure is drawn from the summary alone."""
    import liffman_networks as ln

    saved = json.loads(ln.OUT.read_text())
    for name, tent in ln.tents().items():
        for key, value in tent.items():
            assert value == pytest.approx(saved["tents"][name][key], rel=1e-9, abs=1e-12), (name, key)
    for name, case in ln.collisions().items():
        for key, value in case.items():
            assert value == pytest.approx(saved["collisions"][name][key], rel=1e-9, abs=1e-12), (name, key)
    assert saved["collisions"]["noslip"]["slipping"] is False and saved["collisions"]["slip"]["slipping"] is True
    ln.figure(saved, tmp_path / "lines.png")
    assert (tmp_path / "lines.png").stat().st_size > 20_000


def test_the_cli_fit_row_says_whether_the_recovery_held_its_truth(tmp_path, monkeypatch):
    """papers.py's row for `jaxpile fit --target smid-novosad` (issue 50): the fitted value with
    both intervals, the dip and angle of the fitted heaps as mean +- s.e., and whether every
    interval of the recovery holds its truth; no row until both runs have written fit.json."""
    import papers

    def fit(value, interval, line, truth=None):
        members = [[0.2, 32.0], [0.3, 33.0], [0.25, 32.5], [0.35, 33.5]]  # dip 0.275 +- 0.032, angle 32.75 +- 0.32
        return {"names": ["mu_roll"], "values": {"mu_roll": value}, "interval": {"mu_roll": interval},
                "start": {"mu_roll": 0.1}, "params": {"mu": 0.5}, "seeds": [0, 1, 2, 3],
                "history": [{"theta": [-2.0], "next_theta": [-2.05], "step_stderr": [0.1]}],
                "target": {"labels": ["dip_below_flanks", "repose_mean"], "truth": truth and {"mu_roll": truth}},
                "fitted_members": members,
                "regression": {"values": {"mu_roll": line[0]}, "interval": {"mu_roll": line[1]}, "points": 9}}

    monkeypatch.setattr(papers, "CLI_FIT", tmp_path)
    write = lambda run, record: (tmp_path / run).mkdir(exist_ok=True) or (tmp_path / run / "fit.json").write_text(
        json.dumps(record))
    write("smid_novosad", fit(0.144, [0.114, 0.183], (0.141, [0.106, 0.187])))
    assert papers.rows_rolling_fit() == []  # the recovery has not ended
    write("recovery", fit(0.105, [0.062, 0.179], (0.121, [0.064, 0.229]), truth=0.13))
    (row,) = papers.rows_rolling_fit()
    assert "μ_r = 0.144 (95%: 0.114–0.183), through all 9 ensembles 0.141 (0.106–0.187)" in row[3]
    assert "the last step 0.5 s.e." in row[3] and "dip 0.28 ± 0.03, θ 32.8 ± 0.3°" in row[3]
    assert row[4].startswith("dip in 20–30% and angle agrees") and "the recovery's intervals hold the truth" in row[4]
    write("recovery", fit(0.105, [0.062, 0.179], (0.121, [0.064, 0.125]), truth=0.13))  # the line's misses it
    assert "the recovery missed the truth" in papers.rows_rolling_fit()[0][4]


def test_recovery_table_is_the_one_the_results_give():
    """benchmarks/studies/fitting/fit_recovery.py writes the recovery table of docs/fitting.md
    (issue 17) from the committed results JSON: the page must hold exactly that table."""
    import fit_recovery

    assert fit_recovery.rewrite_page(check=True), "run `python benchmarks/studies/fitting/fit_recovery.py --table`"


def test_measured_recovery_table_is_the_one_the_results_give():
    """benchmarks/studies/calibrate/measured_recovery.py writes docs/calibrate.md's table of measurements
    made at known truths and fitted from the command line: the page must hold exactly that table, and
    a case the first pass refused shows no fitted value."""
    import measured_recovery

    assert measured_recovery.rewrite_page(check=True), \
        "run `python benchmarks/studies/calibrate/measured_recovery.py --table`"
    rows = {r.split(" | ")[0].lstrip("| "): r for r in measured_recovery.table().splitlines()[2:]}
    assert "refused | — |" in rows["pour-profile-only"]


def test_estimator_study_table_is_the_one_the_results_give():
    """benchmarks/studies/fitting/estimator_study.py writes the estimator-study table of
    docs/fitting.md (issue 17, item 3) from the committed results JSON: the page must hold
    exactly that table, one row per (estimator, B, parameter) of each study."""
    import estimator_study

    assert estimator_study.rewrite_page(check=True), "run `python benchmarks/studies/fitting/estimator_study.py --table`"
    rows = estimator_study.table().splitlines()[2:]
    assert any("| box, 102 disks (mu = 0.25) | central differences, h = 0.1 | 32 | mu | 346, 199 |" in r for r in rows)


def test_the_machine_line_names_the_cpus_vector_instructions():
    """The same "AMD EPYC" VM ran the lattice race at 1.27x LAMMPS with AVX-512
    and 0.6-0.7x without it: each benchmark row must say which it had."""
    import machine

    assert machine.vector_isa({"fpu", "avx2", "avx512f"}) == "AVX-512"
    assert machine.vector_isa({"fpu", "avx", "avx2"}) == "AVX2"
    assert machine.vector_isa(set()) is None
    isa = machine.details()["vector_isa"]
    assert (f"({isa})" in machine.describe()) if isa else "(" not in machine.describe().split(",")[0]


def test_centre_below_flanks_reads_an_m_heap_by_heap_with_the_heaps_standard_error():
    """benchmarks/studies/papers/pour_profiles.py: the flank bins are the mean profile's largest on each
    side of the centre, and each heap gives (its two flank bins' mean - its centre bin) over the mean flank."""
    import pour_profiles  # benchmarks/studies/papers, on the path above

    bins, centre = pour_profiles.BINS, pour_profiles.BINS // 2
    heaps = np.full((4, bins), 0.5)
    heaps[:, 3], heaps[:, centre + 4] = 1.0, 1.0  # the flank maxima, off-centre on purpose
    heaps[:, centre] = [0.7, 0.8, 0.8, 0.9]  # 0.2 below the flanks on average
    heaps[0, 4] = 0.95  # a high bin beside a maximum is not a maximum of the mean
    got = pour_profiles.centre_below_flanks(heaps)
    assert got["flank_bins"] == [3, centre + 4] and got["centre_bin"] == centre
    drop = 1.0 - heaps[:, centre]
    assert got["value"] == pytest.approx(0.2) and got["stderr"] == pytest.approx(drop.std(ddof=1) / 2.0)
    flat = np.full((3, bins), 0.5)
    flat[:, centre] = 0.6  # a central peak reads negative
    assert pour_profiles.centre_below_flanks(flat)["value"] == pytest.approx(-0.2)
    # noise that raises one bin in each heap: chosen on the same heaps it reads as an M, held out it does not
    noisy = np.full((3, bins), 0.5)
    noisy[0, 2] = noisy[1, 4] = noisy[2, centre + 2] = 0.8
    assert pour_profiles.centre_below_flanks(noisy)["value"] > 0.05
    held = pour_profiles.centre_below_flanks(noisy, held_out=True)
    assert held["value"] == pytest.approx(0.0, abs=1e-12) and held["flank_bins"] is None
    # where the heaps agree on their flanks, holding out changes nothing
    assert pour_profiles.centre_below_flanks(heaps, held_out=True)["value"] == pytest.approx(got["value"])


def test_on_the_grid_interpolates_where_the_angle_meets_smid_novosads_and_the_dip_there():
    """benchmarks/studies/papers/pour_profiles.py: grid points at mu_roll = 0 and 0.3 whose angles (28.6 +- 1,
    38.6 +- 2 deg) straddle the declared 32.6 meet it 0.4 of the way, at 0.12, where the dip is interpolated
    too; the errors are the linear interpolation's, propagated from each point's standard error; the loss
    is the fit's (the mean of the weighted squared misses); records of one mu_roll are pooled; a heap
    without an angle is left out of its point's angle; a point at another mu is left out of the line
    along mu_roll and read in `every_point` with the rest."""
    import pour_profiles  # benchmarks/studies/papers, on the path above

    def summary(mu, mu_roll, angles, dips, n=300):
        rows = [{"mu_roll": mu_roll, "repose_mean": a, "central_dip": d} for a, d in zip(angles, dips)]
        return {"mu": mu, "n": n, "bins": pour_profiles.BINS, "rows": rows, "by_mu_roll": {}}

    low = summary(None, 0.0, [27.6, 29.6, math.nan], [-0.05, 0.05, 0.0])  # 28.6 +- 1, 0.0 +- e0
    high = summary(0.5, 0.3, [36.6], [0.25])  # pooled with the next: 38.6 +- 2, 0.30 +- 0.05
    high_more = summary(0.5, 0.3, [40.6], [0.35])
    m_shape = np.full(pour_profiles.BINS, 0.5)
    m_shape[3] = m_shape[-4] = 1.0
    high["rows"][0]["profile"], high_more["rows"][0]["profile"] = m_shape.tolist(), (0.9 * m_shape).tolist()
    other = summary(0.3, 0.15, [32.6, 32.6], [0.25, 0.25])
    no_angle = summary(0.5, -0.1, [None, math.nan], [0.0, 0.0])
    grid = pour_profiles.on_the_grid([high, other, no_angle, low, high_more], mu=0.5)
    assert list(grid["points"]) == ["-0.1", "0.0", "0.3"]
    assert grid["points"]["0.0"]["repose_mean"] == pytest.approx([28.6, 1.0, 2])
    assert grid["points"]["0.3"]["heaps"] == 2
    below = pour_profiles.centre_below_flanks(np.array([m_shape, 0.9 * m_shape]))  # the pooled heaps' profiles
    assert grid["points"]["0.3"]["centre_below_flanks"] == pytest.approx([below["value"], below["stderr"], 2])
    held = pour_profiles.centre_below_flanks(np.array([m_shape, 0.9 * m_shape]), held_out=True)
    assert grid["points"]["0.3"]["centre_below_flanks_held_out"] == pytest.approx([held["value"], held["stderr"], 2])
    assert grid["points"]["0.0"]["centre_below_flanks"] is None  # no profiles: not read
    # each heap's own dip in fixed windows (heap.dip_below_flanks): bins 3, 4, 10, 11 against bin 7
    assert 1.0 - m_shape[7] / np.mean(m_shape[[3, 4, 10, 11]]) == pytest.approx(1 / 3)  # either scale
    assert grid["points"]["0.3"]["dip_below_flanks"] == pytest.approx([1 / 3, 0.0, 2])
    assert grid["points"]["0.0"]["dip_below_flanks"] is None
    assert grid["points"]["0.3"]["loss"] == pytest.approx(0.5 * (((0.30 - 0.25) / 0.05) ** 2 + 6.0 ** 2))
    (crossing,) = grid["crossings"]
    assert crossing["between"] == [0.0, 0.3]
    assert crossing["centre_below_flanks"] is None and crossing["dip_below_flanks"] is None  # one end has none
    # t = (32.6 - a0) / (a1 - a0) = 0.4; dt/da0 = (32.6 - a1) / 100 = -0.06, dt/da1 = -(32.6 - a0) / 100 = -0.04
    t_err = math.hypot(0.06 * 1.0, 0.04 * 2.0)
    assert crossing["mu_roll"] == pytest.approx([0.12, 0.3 * t_err])
    e0 = np.std([-0.05, 0.05, 0.0], ddof=1) / math.sqrt(3)
    assert crossing["central_dip"] == pytest.approx([0.12, math.sqrt((0.6 * e0) ** 2 + (0.4 * 0.05) ** 2
                                                                     + (0.3 * t_err) ** 2)])
    # every (mu, mu_roll) of the records, this mu's points among them, in (mu, mu_roll) order
    assert [(p["mu"], p["mu_roll"]) for p in grid["every_point"]] == [(0.3, 0.15), (0.5, -0.1), (0.5, 0.0), (0.5, 0.3)]
    assert grid["every_point"][0]["repose_mean"] == pytest.approx([32.6, 0.0, 2])
    assert grid["every_point"][0]["central_dip"] == pytest.approx([0.25, 0.0, 2])
    assert grid["every_point"][3]["repose_mean"] == pytest.approx([38.6, 2.0, 2])
    assert pour_profiles.on_the_grid([low], mu=0.5)["crossings"] == []  # one point crosses nothing
    with pytest.raises(ValueError, match="mix set-ups"):  # at another mu too: every point is read
        pour_profiles.on_the_grid([low, summary(0.3, 0.3, [36.6], [0.25], n=100)])
    same_seed = [{**summary(mu, 0.3, [36.6], [0.25]), "rows": [{"mu_roll": 0.3, "seed": 0, "repose_mean": 36.6}]}
                 for mu in (0.3, 0.5)]  # one seed at two mu: two heaps
    assert [p["heaps"] for p in pour_profiles.on_the_grid(same_seed)["every_point"]] == [1, 1]
    with pytest.raises(ValueError, match="mix set-ups"):
        pour_profiles.on_the_grid([low, summary(0.5, 0.3, [36.6], [0.25], n=100)])
    slower = {**summary(0.5, 0.3, [36.6], [0.25]), "interval": 3.224}  # a slower pour is another set-up
    with pytest.raises(ValueError, match="mix set-ups"):
        pour_profiles.on_the_grid([low, slower])
    narrower = {**summary(0.5, 0.3, [36.6], [0.25]), "spread": 0.5}  # a narrower source is another set-up
    with pytest.raises(ValueError, match="mix set-ups"):
        pour_profiles.on_the_grid([low, narrower])
    paper_rate = {**summary(0.5, 0.3, [36.6], [0.25]), "interval": 1.612, "spread": 3.0}  # the paper's: the same
    assert list(pour_profiles.on_the_grid([low, paper_rate])["points"]) == ["0.0", "0.3"]
    named = pour_profiles.on_the_grid([paper_rate, low])  # the paper's values named: labelled as the paper's
    assert named["interval"] is None and named["spread"] is None and pour_profiles.set_up_label(named) == ""
    seeded = [{**summary(0.5, 0.3, [36.6], [0.25]), "rows": [{"mu_roll": 0.3, "seed": 0, "repose_mean": 36.6}]}] * 2
    with pytest.raises(ValueError, match="seed 0 is in two records"):
        pour_profiles.on_the_grid(seeded)
    with pytest.raises(ValueError, match="no results at mu = 0.7"):
        pour_profiles.on_the_grid([low], mu=0.7)


def test_fit_along_the_grid_meets_both_targets_on_a_straight_line_and_recovers_each_point():
    """benchmarks/studies/papers/pour_profiles.py `fit_along`: heaps whose dip and angle are straight lines
    in mu_roll (0.1 + mu_roll, 28 + 30 mu_roll) give the weighted least-squares mu_roll of the declared pair
    in the fit's weights (1 / 0.05^2, 1 / 1^2): (400 x 0.15 + 30 x 4.6) / (400 + 900) = 0.1523, where the
    line reads 0.2523 and 32.57 deg, with no error and the fit's loss there; with noise about the line the
    interval widens and holds that value, and the lack-of-fit test rejects a bent dip, not a straight one. `recover_along` takes each grid point's even or odd seeds as the
    target and fits from the others: on the exact line every truth comes back."""
    import pour_profiles  # benchmarks/studies/papers, on the path above

    from jaxpile.fit.ensemble_targets import smid_novosad_target
    from jaxpile.fit.stats import weights

    target = smid_novosad_target(("central_dip", "repose_mean"))
    w = weights(target)
    rng = np.random.default_rng(3)

    def heaps(noise):
        return {x: [{"seed": s, "central_dip": 0.1 + x + noise * 0.05 * rng.normal(),
                     "repose_mean": 28 + 30 * x + noise * rng.normal()} for s in range(8)]
                for x in (0.0, 0.1, 0.2)}

    exact = heaps(0.0)
    exact[0.1].append({"seed": 8, "central_dip": None, "repose_mean": 31.0})  # a heap without a dip: left out
    fit = pour_profiles.fit_along(exact, target.mean, w)
    best = (400 * 0.15 + 30 * 4.6) / 1300
    assert fit["mu_roll"] == pytest.approx([best, 0.0], abs=1e-9)
    assert fit["central_dip"][0] == pytest.approx(0.1 + best) and fit["repose_mean"][0] == pytest.approx(28 + 30 * best)
    assert fit["loss"] == pytest.approx(0.5 * (400 * (0.1 + best - 0.25) ** 2 + (28 + 30 * best - 32.6) ** 2))
    assert fit["heaps"] == 24 and fit["dof"] == 22 and fit["grid"] == [0.0, 0.1, 0.2]
    assert fit["line"]["slope"] == pytest.approx([1.0, 30.0])
    assert fit["lack_of_fit"] == [None, None]  # no scatter at a grid point: nothing to test the line against
    noisy = pour_profiles.fit_along(heaps(1.0), target.mean, w)
    assert noisy["mu_roll"][1] > 0.005 and noisy["interval"][0] < best < noisy["interval"][1]
    assert min(noisy["lack_of_fit"]) > 0.01  # straight lines: the test does not reject them
    bent = heaps(1.0)
    for x, rows in bent.items():  # the dip bends: 0.1 + x - 30 x (x - 0.2), up 0.3 in the middle
        for r in rows:
            r["central_dip"] -= 30 * x * (x - 0.2)
    p_dip, p_angle = pour_profiles.fit_along(bent, target.mean, w)["lack_of_fit"]
    assert p_dip < 1e-3 and p_angle > 0.01  # the angle still straight
    assert pour_profiles.fit_along({0.1: exact[0.1]}, target.mean, w) is None  # one grid point: no line
    recovered = pour_profiles.recover_along(heaps(0.0), w)
    assert [(r["truth"], r["target_half"]) for r in recovered] == [(x, h) for x in (0.0, 0.1, 0.2) for h in
                                                                  ("even", "odd")]
    assert all(r["fit"]["mu_roll"][0] == pytest.approx(r["truth"], abs=1e-9) for r in recovered)
    assert all(r["target_heaps"] == 4 and r["fit"]["heaps"] == 12 for r in recovered)
    # the dip read off the mean profile: each heap's held-out drop, whose mean is the held-out reading
    m_shape = np.full(pour_profiles.BINS, 0.5)
    m_shape[3] = m_shape[-4] = 1.0
    rows = [{"seed": k, "profile": (m_shape * (1 + 0.1 * k)).tolist(), "repose_mean": 30.0} for k in range(4)]
    drops = pour_profiles.profile_drops(rows + [{"seed": 9, "repose_mean": 31.0}])  # no profile: left out
    held = pour_profiles.centre_below_flanks(np.array([r["profile"] for r in rows]), held_out=True)
    assert [r["seed"] for r in drops] == [0, 1, 2, 3]
    assert np.mean([r["centre_below_flanks_held_out"] for r in drops]) == pytest.approx(held["value"])
    assert pour_profiles.profile_drops(rows[:2]) == []  # a held-out flank needs two other heaps
    # each heap's own dip in fixed windows: the M reads 1 - 0.5 / ((1 + 0.5) / 2) whatever its scale
    narrow = pour_profiles.narrow_dips(rows + [{"seed": 9, "repose_mean": 31.0}])
    assert [r["seed"] for r in narrow] == [0, 1, 2, 3]
    assert [r["dip_below_flanks"] for r in narrow] == pytest.approx([1 / 3] * 4)


def test_pour_profiles_grid_command_writes_its_json_and_figure_and_refuses_run_options(tmp_path):
    """`pour_profiles.py --grid RESULTS ... --out DIR` makes DIR, writes pour_grid.json and pour_grid.png
    from the records, and refuses an option of a run beside it."""
    import pour_profiles  # benchmarks/studies/papers, on the path above

    rng = np.random.default_rng(0)
    folders = []
    for mu_roll, angle in ((0.0, 28.0), (0.3, 38.0)):
        rows = [{"mu_roll": mu_roll, "seed": s, "repose_mean": angle + rng.normal(), "central_dip": rng.normal(0.1, 0.1),
                 "profile": (0.5 + 0.1 * rng.random(pour_profiles.BINS)).tolist()} for s in range(4)]
        folder = tmp_path / f"mu_roll{mu_roll}"
        folder.mkdir()
        (folder / "profiles.json").write_text(json.dumps({"mu": None, "n": 300, "bins": pour_profiles.BINS,
                                                          "rows": rows, "by_mu_roll": {}}))
        folders.append(str(folder))
    out = tmp_path / "new" / "grid"
    pour_profiles.main(["--grid", *folders, "--out", str(out)])
    grid = json.loads((out / "pour_grid.json").read_text())
    assert list(grid["points"]) == ["0.0", "0.3"] and len(grid["crossings"]) == 1
    assert [p["mu_roll"] for p in grid["every_point"]] == [0.0, 0.3]
    assert grid["fit_narrow"]["heaps"] == 8 and len(grid["recovery_narrow"]) == 4  # each heap's own dip
    assert grid["command"].endswith(f"--out {out}")
    assert (out / "pour_grid.png").stat().st_size > 10_000
    with pytest.raises(SystemExit):
        pour_profiles.main(["--grid", *folders, "--out", str(out), "--interval", "3.0"])
    with pytest.raises(SystemExit):
        pour_profiles.main(["--grid", *folders, "--out", str(out), "--spread", "0.5"])


def test_the_instruction_set_table_is_the_one_the_results_give():
    """benchmarks/studies/reproducibility/isa_box.py writes docs/testing.md's table of one box
    ensemble at several instruction sets from its committed JSON: the page holds exactly that table,
    and every pile it ran was measurable (README's recipe promises three piles a friction)."""
    import isa_box

    assert isa_box.rewrite_page(check=True), "run `python benchmarks/studies/reproducibility/isa_box.py --table`"
    record = json.loads(isa_box.RESULT.read_text())
    assert all(sum(r["summary"]["missing"]) == 0 for r in record["results"].values())


def test_a_study_keeps_its_finished_piles_in_its_summary_when_the_per_pile_files_are_gone(tmp_path):
    """The papers' studies commit one summary.json, not a file per pile: a
    finished heap's or pile's row goes into it as the pile ends (`keep_heaps`,
    `keep_piles`), so a study stopped early, on a fresh clone without the
    per-pile files, still has every pile it finished, and a rerun skips them."""
    import baxter_readings as br
    import paper_ensembles as pe

    heaps = tmp_path / "n10"
    heaps.mkdir()
    for seed in (1, 0):
        (heaps / f"mu0.2_seed{seed}.json").write_text(json.dumps({"setting": "mu0.2", "seed": seed, "n": 10}))
    (heaps / "summary.json").write_text(json.dumps({"n": 10, "settings": {"mu0.2": {"heaps": 2}}}))
    assert br.keep_heaps(heaps) == 2
    for f in heaps.glob("*_seed*.json"):
        f.unlink()
    assert [(r["setting"], r["seed"]) for r in br.heap_rows(heaps)] == [("mu0.2", 0), ("mu0.2", 1)]
    assert json.loads((heaps / "summary.json").read_text())["settings"] == {"mu0.2": {"heaps": 2}}  # kept
    piles = tmp_path / "tilt_n5"
    piles.mkdir()
    (piles / "mu0.1_seed0.json").write_text(json.dumps({"mu": 0.1, "seed": 0}))
    pe.keep_piles(piles, "tilt", 5)
    (piles / "mu0.1_seed0.json").unlink()
    assert pe.pile_rows(piles) == [{"mu": 0.1, "seed": 0}]


def test_the_1997_voidage_study_reads_the_poured_disks_packing_under_the_apex():
    """`baxter_voidage.py` (Baxter et al. 1997, Figs. 2d, 5a, 8): on a saved
    heap, each band of the column under the apex is packed as a disk heap is
    (0.7-1: the soft law's overlaps count twice), the heap is wider than high,
    and the summary's differences are the heaps' own."""
    import baxter_voidage as bv

    saved = pathlib.Path(__file__).resolve().parents[1] / "tests/data/baxter_heaps/contact-point_hold_seed4.npz"
    heap = bv.heap_packing(str(saved))
    assert len(heap["bands"]) == len(bv.BANDS) and all(0.7 < b < 1.0 for b in heap["bands"]), heap
    assert 0.0 < heap["edges"] < 1.0 and heap["height"] > 5 and heap["base_width"] > 2 * heap["height"]
    s = bv.summarise([heap, {**heap, "bands": [b - 0.01 for b in heap["bands"]]}])
    assert s["heaps"] == 2 and s["base_minus_middle"]["mean"] == pytest.approx(heap["bands"][0] - heap["bands"][2])


def test_baxter_readings_one_heap_writes_the_row_the_papers_table_reads(tmp_path):
    """`baxter_readings.one_heap` (the heaps poured one at a time) writes the
    row its batched twin writes: the heap's summary, `run` and `setup`."""
    import baxter_readings as br

    row = br.one_heap("contact-point/hold", 0, 12, str(tmp_path / "h_seed0.json"), None)
    saved = json.loads((tmp_path / "h_seed0.json").read_text())
    assert saved["run"]["at_rest"] and saved["run"]["steps"] == row["run"]["steps"] > 0
    assert saved["counts"]["poured"] == 12 and saved["setup"]["n_poured"] == 12 and "angle_of_repose" in saved
