"""`jaxpile sweep` for the 1992 piles and the 1993 flux (issue 18: every
protocol sweeps): each batched member against the protocol's own run.

In a module of their own so that the suite's workers (`--dist loadscope`,
one module per worker) run them beside test_ensemble.py's batches."""

import json

import pytest

from jaxpile.errors import InputError

LAW = "lee-herrmann"


def test_lattice_and_sloped_sweeps_vary_the_law_and_a_member_equals_the_protocol_run():
    """The 1992 static piles batched over a law parameter (deterministic piles:
    one seed): each member loads and relaxes as `lattice.relax` / `sloped.SPEC.run`."""
    from jaxpile import sweeps
    from jaxpile.protocols import sloped

    lat = sweeps.sweep("lattice", "hooke", vary={"kn": [5e3, 1e4]}, seeds=1,
                      options={"layers": 5, "ramp_steps": 500, "max_steps": 4000}, progress=False)
    assert [r["kn"] for r in lat.rows] == [5e3, 1e4] and all(r["pile_intact"] for r in lat.rows)
    assert all(r["max_rel_dev_normal"] < 0.01 for r in lat.rows)  # eq. 42 at rest
    slo = sweeps.sweep("sloped", "hooke", vary={"kn": [1e4]}, seeds=1,
                      options={"n": 20, "ramp_steps": 500, "max_steps": 4000}, progress=False)
    _, alone = sloped.SPEC.run("hooke", n=20, params={"kn": 1e4}, ramp_steps=500, max_steps=4000)
    row = slo.rows[0]
    # the member runs the single run's phases (ramp, then rest checked at chunk ends counted from the
    # ramp's end, 500 steps off the chunk grid from 0): the same stop, N to round-off
    assert row["at_rest"] and alone["at_rest"] and row["steps"] == alone["steps"]
    assert row["central_normal_rel_dev"] == pytest.approx(alone["central_normal_rel_dev"], rel=1e-9)
    with pytest.raises(InputError, match="unknown option"):
        sweeps.sweep("lattice", vary={"kn": [1e4]}, seeds=1, options={"width": 3})


def test_drop_sweep_members_are_the_dropped_piles_of_their_seeds():
    """1992 Fig. 20 over seeds in one batch: each member fills and relaxes as
    `drop.SPEC.run` with its seed (the same steps; the dip to round-off)."""
    from jaxpile import sweeps
    from jaxpile.protocols import drop

    result = sweeps.sweep("drop", "liffman", vary={"ks": [1e4]}, seeds=2, options={"n": 8, "relax_steps": 20000},
                         progress=False)
    for row in result.rows:
        _, alone = drop.SPEC.run("liffman", 8, seed=row["seed"], relax_steps=20000)
        assert row["all_inserted"] and row["steps"] == alone["steps"]
        assert row["central_dip"] == pytest.approx(alone["central_dip"], rel=1e-6, abs=1e-9)


def test_flux_sweep_members_feed_the_pile_as_the_flux_run():
    """1993 Fig. 5 batched: a member makes the insertions `flux.SPEC.run` makes with
    its seed, and its angle record gives the same steady mean (to round-off:
    the batch shares one neighbour capacity)."""
    from jaxpile import sweeps
    from jaxpile.protocols import flux

    options = {"width": 1.0, "max_time": 0.3}
    result = sweeps.sweep("flux", LAW, vary={"mu": [0.3]}, seeds=[1], options={"n": 6, **options}, progress=False)
    _, alone = flux.SPEC.run(LAW, 6, params={"mu": 0.3}, seed=1, **options)
    row = result.rows[0]
    assert row["inserted"] == alone["inserted"] and row["n_left"] == alone["n_left"]
    assert row["steady_mean"] == pytest.approx(alone["steady_mean"], rel=1e-3)


def test_a_set_up_has_the_same_shapes_for_every_seed():
    """A batch stacks its members' arrays, so a protocol's set-up, its disks
    and its protocol state, must have shapes that depend on its options alone.
    The flux floor lays as many of its drawn disks as fit (4 or 5 on W = 1)
    and pads the rest, and its surface columns come from the radius law, not
    the draws (at W = 4, seeds 0-11 drew 19, 20 or 21 by their mean)."""
    import jax

    from jaxpile.protocols import PROTOCOLS

    cases = [("drop", 20, {}), ("box", 40, {"width": 1.6, "height": 1.2}), ("flux", 6, {"width": 1.0}),
             ("flux", 50, {}), ("pour", 12, {"release_height": 8}), ("hopper", 60, {}),
             ("cone", 20, {})]
    for name, size, options in cases:
        spec = PROTOCOLS[name]
        shapes = set()
        for seed in range(12):
            p = spec.set_up(spec.default_law, size, seed=seed, **options)
            shapes.add(tuple(jax.numpy.shape(x) for x in jax.tree.leaves((p.particles, p.protocol_state))))
        assert len(shapes) == 1, (name, options, size)


FLUX_BATCH = """
import json, sys
import jaxpile
settings = jaxpile.configure()
import jax, numpy as np
from jaxpile.engine.ensemble import Ensemble
from jaxpile.protocols import flux

law, spec = "lee-herrmann", flux.SPEC
setups = [spec.set_up(law, 4, seed=seed, width=1.0) for seed in range(4)]
_, _, params = spec.law_and_params(law, None, None, None, {})
sim = spec.simulator(spec.make_options({"insertions": 4, "width": 1.0}), law=law, dt=spec.default_dt(law),
                     rotation=None, integrator=None, chunk_steps=None, law_options={})
ends = {}
for sequential in (False, True):
    ens = Ensemble(sim, sequential=sequential)
    ends[sequential] = ens.run([params] * 4, ens.init([params] * 4, setups), 8000, progress=False)
same = all(np.array_equal(np.asarray(a), np.asarray(b))
           for a, b in zip(jax.tree.leaves(ends[False]), jax.tree.leaves(ends[True])))
print(json.dumps({"fusion": settings["multi_output_fusion"], "same": same, "laid": [p.info["n_base"] for p in setups],
                  "inserted": np.asarray(ends[True].protocol_state.inserted).tolist()}))
"""
"""Four flux piles as one batch, side by side and one after another, as a user's script runs them."""


def test_a_batch_of_flux_piles_runs_side_by_side_under_the_commands_settings():
    """A batch of flux piles in a user's environment (`jaxpile.configure()`:
    XLA:CPU's multi-output fusion on, as every command runs; the suite itself
    runs without it), their floors holding different numbers of disks: side
    by side (vmapped, as on a GPU or sharded) it compiles, where XLA aborted
    while the driver recorded each insertion by two scatters at one index, and
    it ends bit for bit as one after another (`Batch.sequential`, the CPU's
    way), though the insertion branch is a select in one and a cond in the other."""
    from test_imports import clean_env, python

    out = json.loads(python(FLUX_BATCH, clean_env()).stdout.strip().splitlines()[-1])
    assert out["fusion"] and len(set(out["laid"])) == 2, out  # 4 or 5 disks laid on the floor
    assert all(k >= 2 for k in out["inserted"]) and out["same"], out


def test_tilt_sweep_runs_two_stages_and_a_member_equals_the_tilt_run(tmp_path):
    """1993 Fig. 4 batched: each member builds its box pile (stage 1), then is
    tilted from where its pile settled, contact history kept (stage 2); its
    theta_T, theta_R and last step are those of `tilt.SPEC.run` with its seed.
    Resumed from a save in the middle of the tilt, the sweep ends with the
    same rows (the tilt's start steps and the pile's theta_R come from the file)."""
    from jaxpile import sweeps
    from jaxpile.engine import checkpoint
    from jaxpile.protocols import tilt

    options = {"width": 1.2, "height": 1.2, "rate_degrees": 0.01}
    result = sweeps.sweep("tilt", LAW, vary={"mu": [0.3]}, seeds=[1], options=options, progress=False,
                         checkpoint=(str(tmp_path / "ck-{step}.npz"), 500))
    state, alone = tilt.SPEC.run(LAW, params={"mu": 0.3}, rate_degrees=0.01, seed=1,
                                 pile_options={"width": 1.2, "height": 1.2})
    row = result.rows[0]
    assert row["moved"] and alone["moved"] and row["box_settled"]
    assert row["theta_t"] == pytest.approx(alone["theta_t"], abs=1e-9)
    assert row["theta_r"] == pytest.approx(alone["theta_r"], rel=1e-6)
    assert row["steps"] == int(state.step)
    assert row["theta_ms_theory"] == pytest.approx(alone["theta_ms_theory"])
    saves = sorted(tmp_path.glob("ck-*.npz"), key=lambda f: int(f.stem[3:]))
    tilting = [f for f in saves if checkpoint.read_metadata(f)["extra"]["stage"] == 1]
    assert len(tilting) >= 2 and any(checkpoint.read_metadata(f)["extra"]["stage"] == 0 for f in saves)
    resumed = sweeps.sweep("tilt", LAW, vary={"mu": [0.3]}, seeds=[1], options=options, progress=False,
                          resume=str(tilting[len(tilting) // 2]))
    assert json.dumps(resumed.rows) == json.dumps(result.rows)  # equal, NaN theory included


def test_the_command_line_offers_every_sweepable_protocol():
    from jaxpile import cli
    from jaxpile.protocols import PROTOCOLS

    assert sorted(cli.sweep_protocols()) == sorted(PROTOCOLS)  # every registered spec runs as a batch
