"""Liffman, Chan & Hughes 1992 Fig. 20: a pile built by dropping disks one at a
time from 2 sigma above its highest point, every insertion made by the driver
inside the compiled loop. Small piles (20 disks) with hooke (frictionless disks,
wall_mu = 1) and the paper's own liffman law: every disk goes in, none is lost,
the pile ends at rest as a heap (not a flat layer, not a column), and its base
carries its weight (measured to 1e-9)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile import analysis
from jaxpile.errors import InputError
from jaxpile.protocols import drop
from jaxpile.engine.simulate import Simulator
from jaxpile.measure import heap

N = 20
RUN = dict(speed_tolerance=1e-6, relax_steps=200_000)


@pytest.fixture(scope="module")
def hooke_pile():
    return drop.SPEC.run("hooke", N, seed=0, **RUN)


@pytest.fixture(scope="module")
def liffman_pile():
    return drop.SPEC.run("liffman", N, seed=1, **RUN)


# ------------------------------------------------------------------ set-up
def test_protocol_parks_every_disk_apart_and_inactive():
    p = drop.SPEC.set_up("liffman", 50, seed=3)
    assert p.particles.count == 50
    assert not np.asarray(p.particles.active).any()
    pos = np.asarray(p.particles.position)
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() >= drop.PARK_SPACING - 1e-9  # > 2 diameters: parked disks never meet
    # parked above any 50-disk close-packed pile (a 60-deg one is ~6.6 high) plus the drop
    assert pos[:, 1].min() > 10.0
    assert 0 < pos[:, 0].min() and pos[:, 0].max() < p.box[0] and pos[:, 1].max() < p.box[1]
    x = np.asarray(p.protocol_state.drop_x)
    assert np.all(np.abs(x - p.info["axis_x"]) <= 0.1 + 1e-12) and x.std() > 0.01


def test_seeds_give_different_drops_and_zero_jitter_drops_on_the_axis():
    a, b = (np.asarray(drop.SPEC.set_up("liffman", 20, seed=s).protocol_state.drop_x) for s in (0, 1))
    assert not np.allclose(a, b)
    np.testing.assert_array_equal(a, np.asarray(drop.SPEC.set_up("liffman", 20, seed=0).protocol_state.drop_x))
    flat = drop.SPEC.set_up("liffman", 20, jitter=0.0)
    np.testing.assert_array_equal(np.asarray(flat.protocol_state.drop_x), flat.info["axis_x"])


def test_bad_inputs_raise_input_error():
    for kwargs in (dict(n=0), dict(n=2.5), dict(n=10, jitter=-0.1), dict(n=10, drop_height=0.0),
                   dict(n=10, settle_speed=-1.0), dict(n=10, quiet_time=5.0, max_interval=1.0),
                   dict(n=10, dt=0.0)):
        with pytest.raises(InputError):
            drop.SPEC.set_up("liffman", **kwargs)
    with pytest.raises(InputError):
        drop.SPEC.run("no-such-law", 5)
    with pytest.raises(InputError, match="max_interval"):  # the options refuse it before any set-up
        drop.DropOptions(quiet_time=1.0, max_interval=1.0)
    empty = analysis.BaseForces(x=np.array([]), normal=np.array([]), horizontal=np.array([]),
                                particle=np.array([], int))
    with pytest.raises(InputError):
        heap.normal_profile(empty)


def test_the_spec_simulator_takes_its_driver_and_hard_collisions_from_the_options():
    """The simulator is built from the options alone (the driver's constants
    are the same for every seed and every n): its driver is the set-up's (one
    batch of set-ups runs on it), with the options' hard collisions."""
    from jaxpile.engine.collisions import HardCollisions

    o = drop.DropOptions(n=5, quiet_time=0.05, max_interval=0.5, hard_collisions=HardCollisions(0.6, 0.3))
    sim = drop.SPEC.simulator(o, law="hooke", dt=1e-3)
    p = drop.setup(o.replace(n=7), law="hooke", seed=4, dt=1e-3)
    assert sim.driver is p.driver and sim.hard_collisions == HardCollisions(0.6, 0.3) and sim.chunk_steps == 1000
    assert p.info["quiet_steps"] == 50 and p.info["max_interval_steps"] == 500 and p.info["dt"] == 1e-3


# ------------------------------------------------------------ the driver rule
@pytest.fixture(scope="module")
def one_disk_down():
    """A 3-disk drop protocol with disk 0 resting on the ground, as a state."""
    p = drop.SPEC.set_up("hooke", 3, seed=0, quiet_time=0.25, max_interval=10.0)
    _, law, params = drop.law_and_params("hooke")
    sim = Simulator(law, 1e-3, driver=p.driver)
    state = sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)
    part = state.particles
    part = part.set(position=part.position.at[0].set(jnp.array([p.info["axis_x"], 0.5])),
                    active=part.active.at[0].set(True))
    ps = state.protocol_state._replace(inserted=jnp.int32(1), last_insert=jnp.int32(0), quiet_steps=jnp.int32(0))
    return p, state.set(particles=part, protocol_state=ps, step=jnp.int32(1000))


def test_driver_waits_while_the_pile_moves(one_disk_down):
    p, state = one_disk_down
    push = state.particles.velocity.at[0].set(jnp.array([0.2, 0.0]))
    moving = state.set(particles=state.particles.set(velocity=push),
                       protocol_state=state.protocol_state._replace(quiet_steps=jnp.int32(p.info["quiet_steps"])))
    after = p.driver(moving)
    assert np.asarray(after.particles.active).tolist() == [True, False, False]
    assert int(after.protocol_state.quiet_steps) == 0  # the quiet count starts again


def test_driver_drops_the_next_disk_two_diameters_above_the_top_once_settled(one_disk_down):
    p, state = one_disk_down
    almost = state.set(protocol_state=state.protocol_state._replace(quiet_steps=jnp.int32(p.info["quiet_steps"] - 2)))
    once = p.driver(almost)
    assert np.asarray(once.particles.active).tolist() == [True, False, False]  # not yet: quiet for too short
    twice = p.driver(once)
    assert np.asarray(twice.particles.active).tolist() == [True, True, False]
    x, y = np.asarray(twice.particles.position[1])
    assert x == pytest.approx(float(p.protocol_state.drop_x[1]))
    assert y == pytest.approx(1.0 + 2.0 + 0.5)  # top of disk 0, the 2-sigma gap, the radius
    assert np.all(np.asarray(twice.particles.velocity[1]) == 0)
    ps = twice.protocol_state
    assert int(ps.inserted) == 2 and int(ps.forced) == 0 and int(ps.last_insert) == 1000


def test_driver_drops_anyway_after_max_interval(one_disk_down):
    p, state = one_disk_down
    late = state.set(step=jnp.int32(p.info["max_interval_steps"]),
                     particles=state.particles.set(velocity=state.particles.velocity.at[0].set(jnp.array([0.2, 0.0]))))
    after = p.driver(late)
    assert np.asarray(after.particles.active).tolist() == [True, True, False]
    assert int(after.protocol_state.forced) == 1


# ------------------------------------------------------------ whole runs
@pytest.mark.parametrize("pile", ["hooke_pile", "liffman_pile"])
def test_every_disk_is_dropped_once_and_the_pile_rests(pile, request):
    state, m = request.getfixturevalue(pile)
    assert state.particles.count == N
    assert m["all_inserted"] and m["n_particles"] == N == int(state.protocol_state.inserted)
    # most drops waited for the pile to settle. Some outlast max_interval: a
    # frictionless disk rattling in a pocket (only normal damping acts on it), or
    # liffman's base disks sliding out against 0.1 mg of friction (measured:
    # hooke 2 of 20, liffman 5 of 20)
    assert m["forced_drops"] < N // 2
    assert m["phases"]["fill"] / N > 2000  # at least the 2-sigma fall (2 sqrt(sigma/g) = 2000 steps)
    assert m["at_rest"] and m["final_max_speed"] < 1e-6
    pos = np.asarray(state.particles.position)
    assert np.all(pos[:, 1] > 0.45)  # nothing fell through the ground
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() > 0.99


@pytest.mark.parametrize("pile", ["hooke_pile", "liffman_pile"])
def test_base_carries_the_weight_and_the_pile_is_a_heap(pile, request):
    state, m = request.getfixturevalue(pile)
    assert abs(m["weight_balance"]) < 1e-4
    assert sum(m["profile_normal"]) == pytest.approx(m["total_normal"], rel=1e-12)
    assert max(m["profile_normalised"]) == 1.0
    # a heap: some disks on the ground, some above, not a column and not one layer
    assert 3 <= m["base_contacts"] < N
    assert 1.5 < m["height"] < N / 2
    assert np.isfinite(m["central_dip"]) and isinstance(m["has_central_dip"], bool)


def test_the_drop_declares_the_columns_of_its_rows(tmp_path, capsys):
    """`drop.ROW_COLUMNS`: a sweep row holds exactly those columns (besides the
    sweep's own and the point's), so an ensemble fit refuses a statistic the
    drop does not measure before a pile is dropped (the pour's dip_below_flanks)."""
    from jaxpile import batches, cli, sweeps

    result = sweeps.sweep("drop", "hooke", vary={"mu": [0.3]}, seeds=1, options={"n": 6, **RUN}, progress=False)
    (member,) = result.rows
    assert set(member) - set(batches.MEMBER_COLUMNS) - {"mu"} == set(drop.ROW_COLUMNS)
    assert cli.main(["fit", "--protocol", "drop", "--params", "mu_roll", "--target", "smid-novosad", "--estimator",
                     "central", "--statistics", "dip_below_flanks", "--dry-run", "--out", str(tmp_path)]) == 2
    assert "no column 'dip_below_flanks'" in capsys.readouterr().err


def test_drops_with_different_seeds_build_different_piles():
    """The paper's piles are 'random' and differ; here the seed sets the jitter.
    The first few drops (12000 steps) already differ, and a seed repeats itself."""
    _, law, params = drop.law_and_params("hooke")
    sim = None
    final = []
    for seed in (0, 5, 5):
        p = drop.SPEC.set_up("hooke", 5, seed=seed)
        sim = sim or Simulator(law, drop.SETTING["dt"], driver=p.driver, chunk_steps=4000)
        state = sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)
        state = sim.run(params, state, 12_000, progress=False)
        assert int(state.protocol_state.inserted) >= 2
        final.append(np.asarray(state.particles.position))
    assert not np.allclose(final[0], final[1], atol=1e-3)
    np.testing.assert_array_equal(final[1], final[2])


def test_a_drop_run_on_blocks_of_its_dropped_disks_is_bit_identical_to_the_full_run():
    """With `in_play=drop.make_in_play(quiet_steps)` each chunk runs on the
    block of leading disks that holds every disk droppable by its end
    (`jaxpile.engine.blocks`): here 64 of 128 disks throughout. Same arithmetic in the
    same order, so the same state bit for bit as carrying every parked disk."""
    p = drop.SPEC.set_up("hooke", 128, seed=2, dt=1e-3, quiet_time=0.05, max_interval=0.5)
    _, law, params = drop.law_and_params("hooke", {"mu": 0.5})
    in_play = drop.make_in_play(p.info["quiet_steps"])
    states = {}
    for blocked in (True, False):
        sim = Simulator(law, 1e-3, driver=p.driver, chunk_steps=250,
                        in_play=in_play if blocked else None)
        state = sim.init(params, p.particles, p.boundaries, box=p.box, protocol_state=p.protocol_state)
        if blocked:
            assert jaxpile.engine.blocks.block_size(in_play(state, 250), state.particles.count) == 64
        states[blocked] = sim.run(params, state, 2000, progress=False)
    a, b = states[True], states[False]
    assert int(a.protocol_state.inserted) >= 3
    for x, y in zip(jax.tree.leaves(a.particles), jax.tree.leaves(b.particles)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    np.testing.assert_array_equal(a.contacts.history, b.contacts.history)
    np.testing.assert_array_equal(a.contacts.wall_history, b.contacts.wall_history)
    assert int(a.protocol_state.inserted) == int(b.protocol_state.inserted)
