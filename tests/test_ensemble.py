"""Batched ensembles (jaxpile.engine.ensemble, jaxpile.sweeps): a batch run gives each
member exactly what it gets alone, across a neighbour re-allocation and with
members frozen when they finish; the rebuild decision stays a real branch under
vmap; the batch shards over two CPU devices; `jaxpile sweep` writes its table
and figure, and a sweep member equals the protocol's own run."""

import csv
import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile import batches, ensemble, sweeps
from jaxpile.errors import InputError
from jaxpile.protocols import box, lattice
from jaxpile.engine.simulate import RunInfo, Simulator

LAW = "lee-herrmann"
BOX = {"width": 1.2, "height": 1.2}
STEPS = 900


@pytest.fixture(scope="module")
def batch():
    sim = box.make_simulator(LAW, chunk_steps=300)
    protocols = [box.SPEC.set_up(LAW, 30, seed=s, **BOX) for s in (0, 1, 2)]
    params = [box.law_and_params(LAW, {"mu": mu})[2] for mu in (0.1, 0.2, 0.4)]
    ens = ensemble.Ensemble(sim)
    return sim, ens, protocols, params, ens.init(params, protocols)


def _split(state):
    """Members finish at different steps: those whose first disk is the larger at 300."""
    r0 = np.asarray(state.particles.radius[:, 0])
    return float(np.median(r0))


def _overflowing(state):
    """`(batch, until)`: the batch with too few neighbour slots for anyone (its first chunk overflows and it
    re-allocates), and members finishing at 300 or 600 steps (those whose first disk is the larger at 300)."""
    small = ensemble.stack([ensemble.at_capacity(m, 2, m.neighbors.cell_list_capacity)
                            for m in ensemble.members(state)])
    split = _split(state)

    def until(s):
        return s.step >= jnp.where(s.particles.radius[0] > split, 300, 600)

    return small, until


def test_batched_run_equals_each_member_alone_across_reallocation_and_freezing(batch):
    sim, ens, protocols, params, state = batch
    small, until = _overflowing(state)
    info = RunInfo()
    out = ens.run(params, small, STEPS, until=until, progress=False, info=info)
    assert info.reallocations >= 1
    steps = np.asarray(out.step)
    assert sorted(set(steps.tolist())) == [300, 600]  # frozen at their own chunk boundary
    alones = []
    for i, alone in enumerate(ensemble.members(small)):
        alone = sim.run(params[i], alone, STEPS, progress=False, until=lambda s: bool(until(s)))
        got = ensemble.member(out, i)
        assert int(got.step) == int(alone.step)
        np.testing.assert_allclose(got.particles.position, alone.particles.position, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.particles.velocity, alone.particles.velocity, rtol=0, atol=1e-9)
        alones.append(alone)
    assert not bool(jnp.any(out.neighbors.did_buffer_overflow))
    # a batch run by hand ends in each member's measurements, as each pile's own
    measured = box.SPEC.measure_members(sim, params, out, protocols, n=30, **BOX)
    options = box.SPEC.make_options(n=30, **BOX)
    for i, m in enumerate(measured):
        own = box.SPEC.measure(sim, params[i], alones[i], protocols[i], options)
        assert set(m) == set(own)
        for key, value in own.items():
            if isinstance(value, float) and np.isfinite(value):
                assert m[key] == pytest.approx(value, rel=1e-9, abs=1e-9), key


def test_batch_wide_rebuild_decision_keeps_a_real_branch_under_vmap(batch):
    """jax-md's own cond turns into a select when vmapped (every member would
    rebuild every step); the batched step keeps the rebuild, with the history
    carried onto the new pairs inside it, as one real cond."""
    sim, ens, protocols, params, state = batch
    pb = ens.as_batch(params, 3)
    ours = str(jax.make_jaxpr(jax.vmap(ens.step, axis_name=ensemble.AXIS))(pb, state))
    naive = str(jax.make_jaxpr(jax.vmap(sim.step))(pb, state))
    assert ours.count(" cond[") == 1  # neighbour rebuild and history carry, one branch
    assert naive.count(" cond[") == 0


def test_ensemble_refuses_mismatched_members(batch):
    sim, ens, protocols, params, _ = batch
    with pytest.raises(InputError, match="3 members"):
        ens.init(params[:2], protocols)
    other = box.SPEC.set_up(LAW, 31, seed=0, **BOX)
    with pytest.raises(InputError, match="same number of disks"):
        ens.init(params[:2], protocols[:1] + [other])
    wrong_dt = box.SPEC.set_up(LAW, 30, seed=0, dt=1e-5, **BOX)
    with pytest.raises(InputError, match="dt"):
        ens.init(params[:1], [wrong_dt])
    particles, boundaries = lattice.equilateral_pile(2)
    from jaxpile.protocols.base import Setup
    with pytest.raises(InputError, match="driver"):
        ens.init(params[:1], [Setup(particles, boundaries, driver=lambda s: s)])
    with pytest.raises(InputError, match="at least one"):
        ens.init(params, [])


SHARDED = textwrap.dedent("""
    import jax, numpy as np
    import jaxpile
    jaxpile.configure(host_devices=2)  # the host split into two JAX devices, as the docs say
    from jaxpile import ensemble
    from jaxpile.laws import hooke
    from jaxpile.protocols import lattice
    from jaxpile.protocols.base import Setup
    from jaxpile.engine.simulate import Simulator
    assert len(jax.devices()) == 2
    particles, boundaries = lattice.equilateral_pile(3)
    sim = Simulator(hooke.law(rotation=False), 5e-4, chunk_steps=100, skin=0.02)
    params = [hooke.make_params(kn=kn, gamma_n=50.0, mu=0.0) for kn in (5e3, 1e4, 2e4)]
    protocols = [Setup(particles, boundaries)] * 3
    sharded = ensemble.Ensemble(sim)
    single = ensemble.Ensemble(sim, devices=jax.devices()[:1])
    a = sharded.run(params, sharded.init(params, protocols), 300, progress=False)
    b = single.run(params, single.init(params, protocols), 300, progress=False)
    assert a.particles.position.shape[0] == 4  # padded to a multiple of the devices
    shards = {d for s in a.particles.position.addressable_shards for d in [s.device]}
    np.testing.assert_allclose(a.particles.position[:3], b.particles.position, rtol=0, atol=1e-12)
    print("SHARDS", len(shards))
""")


def test_batch_shards_over_two_cpu_devices(tmp_path):
    script = tmp_path / "sharded.py"
    script.write_text(SHARDED)
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "SHARDS 2" in done.stdout


def test_sweep_cli_writes_table_and_figure_and_a_member_equals_the_protocol_run(tmp_path):
    from jaxpile import cli

    out = tmp_path / "sweep"
    argv = ["sweep", "--protocol", "box", "--law", LAW, "--mu", "0.15,0.3", "--seeds", "2", "--n", "30",
            "--option", "width=1.2", "--option", "height=1.2", "--no-progress", "--checkpoint-every", "3000",
            "--out", str(out)]
    assert cli.main(argv) == 0
    with open(out / "sweep.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4
    assert [(float(r["mu"]), int(r["seed"])) for r in rows] == [(0.15, 0), (0.15, 1), (0.3, 0), (0.3, 1)]
    assert all(r["at_rest"] == "True" for r in rows)
    summary = json.loads((out / "sweep.json").read_text())
    assert summary["members"] == 4 and summary["summary_by"] == "mu"
    assert (out / "sweep.png").stat().st_size > 10_000
    # `jaxpile show` redraws the sweep's figure from sweep.csv + sweep.json without running
    assert cli.main(["show", str(out), "--out", str(tmp_path / "redrawn")]) == 0
    assert (tmp_path / "redrawn" / "sweep.png").stat().st_size > 10_000
    reread = sweeps.read(out)
    assert reread.column("mu").tolist() == [0.15, 0.15, 0.3, 0.3] and reread.rows[3]["at_rest"] is True
    # resuming the finished sweep from its checkpoint runs no step and measures the same rows
    table = (out / "sweep.csv").read_text()
    assert cli.main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    assert (out / "sweep.csv").read_text() == table
    assert cli.main(["pile", "--resume", str(out)]) == 2  # a sweep is resumed with `jaxpile sweep`
    # member (mu = 0.3, seed 1) is the box protocol's own run with those settings, up to
    # round-off: the batch shares one neighbour capacity, so sums run over more empty
    # slots, and 30 000 steps of granular flow amplify the last bits
    _, alone = box.SPEC.run(LAW, 30, params={"mu": 0.3}, seed=1, **BOX)
    assert int(rows[3]["n_left"]) == alone["n_left"]
    assert int(rows[3]["settled_step"]) == pytest.approx(alone["settled_step"], abs=200)
    assert float(rows[3]["repose_cumulative_parabola"]) == pytest.approx(alone["repose_cumulative_parabola"], rel=1e-3)
    assert cli.main(argv[:-2] + ["--option", "colour=red", "--out", str(out)]) == 2  # unknown option refused


def test_an_ensemble_of_pours_runs_on_blocks_of_the_poured_disks_bit_identical_to_the_full_batch():
    """Issue 15 (pours pay for what is poured), in a batch: with the simulator's
    `in_play`, every chunk runs on the block of leading disks that holds each
    member's poured disks (here 64 of 145 for two chunks, then all), the
    same arithmetic as carrying every parked disk, so the same batch bit for bit."""
    from jaxpile.engine.ensemble import Ensemble
    from jaxpile.protocols import pour

    protocols = [pour.SPEC.set_up("hooke", 100, insert_height=14.0, interval=0.15, seed=seed) for seed in (4, 5)]
    params = [pour.law_params("hooke")] * 2
    states = {}
    for blocked in (True, False):
        ens = Ensemble(pour.make_simulator("hooke", chunk_steps=1000, **({} if blocked else {"in_play": None})))
        state = ens.init(params, protocols)
        if blocked:
            assert ens._block_for(state, 1000, {})[0] == 64
        states[blocked] = ens.run(params, state, 4000, progress=False)
    a, b = states[True], states[False]
    assert a.particles.position.shape == (2, 145, 2) and np.all(np.asarray(a.protocol_state.poured) == 27)
    for x, y in zip(jax.tree.leaves(a.particles), jax.tree.leaves(b.particles)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    np.testing.assert_array_equal(a.contacts.history, b.contacts.history)
    np.testing.assert_array_equal(a.neighbors.idx, b.neighbors.idx)


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="members run one after another on one CPU device only")
def test_members_one_after_another_give_the_side_by_side_states_bit_for_bit(batch, monkeypatch):
    """`Ensemble(sequential=True)` (the pour's, on one CPU device) advances the
    members one after another inside each compiled chunk (`lax.map` of each
    member's loop of the single pile's step, each deciding its own rebuilds);
    the default runs them side by side (vmapped, the rebuild decided for the
    batch, a member that did not move keeping its list). The two end bit for
    bit the same: across a re-allocation and with members frozen at different
    steps (the boxes), and on three pours whose disks land out of phase. The
    step is traced for one pile only when the members run one after another
    (benchmarks/ensemble_sequential.py times the two)."""
    from jaxpile.engine import neighbors as nb
    from jaxpile.engine.ensemble import AXIS, Ensemble
    from jaxpile.protocols import pour

    traced, update = [], nb.update_with_contacts

    def recorded(neighbors, contacts, position, settings, axis_name=None, fixed=None):
        traced.append(axis_name)
        return update(neighbors, contacts, position, settings, axis_name, fixed)

    monkeypatch.setattr(nb, "update_with_contacts", recorded)
    sim, _, _, params, state = batch
    small, until = _overflowing(state)
    ends = {}
    for sequential in (False, True):
        traced.clear()
        info = RunInfo()
        ens = Ensemble(sim, sequential=sequential)
        ends[sequential] = ens.run(params, small, STEPS, until=until, progress=False, info=info)
        assert info.reallocations >= 1 and ens.sequential == sequential
        assert set(traced) == ({None} if sequential else {AXIS})
    assert sorted(set(np.asarray(ends[True].step).tolist())) == [300, 600]
    for x, y in zip(jax.tree.leaves(ends[False]), jax.tree.leaves(ends[True])):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))

    protocols = [pour.SPEC.set_up("hooke", 100, insert_height=14.0, interval=0.15, seed=seed) for seed in (4, 5, 6)]
    pour_params = [pour.law_params("hooke")] * 3
    pour_sim = pour.make_simulator("hooke", chunk_steps=1000)
    assert not Ensemble(pour_sim).sequential and batches.batch_of("pour").sequential
    poured = {}
    for sequential in (False, True):
        ens = Ensemble(pour_sim, sequential=sequential)
        poured[sequential] = ens.run(pour_params, ens.init(pour_params, protocols), 3000, progress=False)
    assert np.all(np.asarray(poured[True].protocol_state.poured) > 10)  # disks fell and landed
    for x, y in zip(jax.tree.leaves(poured[False]), jax.tree.leaves(poured[True])):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    with pytest.raises(InputError, match="sequential must be"):
        Ensemble(sim, sequential="yes")


def test_pour_sweep_members_are_heaps_at_rest_carried_by_the_substrate():
    from jaxpile import sweeps

    result = sweeps.sweep("pour", "baxter", vary={"mu": [0.3, 0.6]}, seeds=1,
                         options={"n": 12, "release_height": 7.0, "speed_tolerance": 1e-3}, progress=False)
    assert [(r["mu"], r["seed"]) for r in result.rows] == [(0.3, 0), (0.6, 0)]
    for row in result.rows:
        assert row["in_play"] + row["lost"] == 12
        assert abs(row["force_balance"]) < 1e-3  # at rest: the substrate carries the heap's weight
        # the drop's dip measure (Smid-Novosad) on the heap's profile: <= 1 - 1 / the lower flank ratio,
        # equal when the two flank ratios agree, so it is consistent with the M ratio's mean
        assert row["central_dip"] <= 1.0 - 1.0 / row["m_ratio"] + 1e-12
        assert row["flank_over_centre"] > 0  # window means of the same profile (heap.flank_over_centre)
    summary = sweeps.summarise(result, "mu", "repose_mean")
    assert summary["x"] == [0.3, 0.6] and summary["count"][0] + summary["missing"][0] == 1
    with pytest.raises(InputError, match="unknown option"):
        sweeps.sweep("pour", vary={"mu": [0.3]}, seeds=1, options={"colour": "red"})
    with pytest.raises(InputError, match="unknown baxter parameter"):
        sweeps.sweep("pour", vary={"kn": [1.0]}, seeds=1, options={"n": 12})

