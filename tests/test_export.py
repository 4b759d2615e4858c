"""Export: extended XYZ frames and the contact table re-read to what was written."""

import numpy as np
import pytest

from jaxpile import analysis, export, io
from jaxpile.errors import InputError
from jaxpile.laws import hooke
from jaxpile.protocols import lattice
from jaxpile.simulate import Simulator, gravity_ramp


@pytest.fixture(scope="module")
def loaded_pile():
    """A 4-layer lattice pile with friction and spin, loaded and still moving a little."""
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3, wall_mu=1.0)
    sim = Simulator(hooke.law(rotation=True), 1e-3, schedule=gravity_ramp(300))
    particles, boundaries = lattice.equilateral_pile(4)
    particles = particles.set(angular_velocity=particles.angular_velocity.at[3].set(0.7))
    state = sim.run(params, sim.init(params, particles, boundaries), 500, progress=False)
    return sim, params, state


def test_xyz_trajectory_rereads_every_column_of_every_frame(loaded_pile, tmp_path):
    sim, params, state = loaded_pile
    later = sim.run(params, state, 50, progress=False)
    path = tmp_path / "traj.xyz"
    export.write_xyz(path, state, time=0.5)
    export.write_xyz(path, later, time=0.55, append=True)
    frames = export.read_xyz(path)
    assert [f["step"] for f in frames] == [500, 550] and frames[1]["time"] == 0.55
    for frame, s in zip(frames, (state, later)):
        p = s.particles
        np.testing.assert_array_equal(frame["pos"][:, :2], np.asarray(p.position))  # repr: exact round trip
        np.testing.assert_array_equal(frame["pos"][:, 2], 0.0)
        np.testing.assert_array_equal(frame["radius"], np.asarray(p.radius))
        np.testing.assert_array_equal(frame["velo"][:, :2], np.asarray(p.velocity))
        np.testing.assert_array_equal(frame["omega"], np.asarray(p.angular_velocity))
        np.testing.assert_array_equal(frame["force"][:, :2], np.asarray(p.force))
        assert frame["active"].all()
    assert np.abs(frames[0]["omega"]).max() > 0  # spins are written, not zeros
    # the header OVITO reads: columns, box and no periodicity
    header = path.read_text().splitlines()[1]
    assert f"Properties={export.PROPERTIES}" in header and 'pbc="F F F"' in header
    fields = dict(export._pairs(header))
    cell = [float(v) for v in fields["Lattice"].split()]  # 9 plain numbers (ASE and OVITO insist)
    assert len(cell) == 9 and cell[0] > 0 and cell[4] > 0
    assert len([float(v) for v in fields["Origin"].split()]) == 3


def test_contact_table_has_each_contact_once_with_the_network_forces(loaded_pile, tmp_path):
    sim, params, state = loaded_pile
    written = export.write_contacts(tmp_path / "contacts.csv", sim, params, state)
    table = io.read_csv(tmp_path / "contacts.csv")
    assert set(table) == {"i", "j", "normal", "tangential"}
    for k in table:
        np.testing.assert_allclose(table[k], written[k], rtol=1e-9)
    disks = table["j"] >= 0
    assert np.all(table["i"][disks] < table["j"][disks])  # each pair once
    net = analysis.contact_network(sim, params, state)
    assert disks.sum() == len(net.i)
    ground = table["j"] == analysis.wall_partner(0)
    base = analysis.base_forces(sim, params, state)
    assert ground.sum() == len(base.x) == 4
    # the ground rows carry the base load: their normals sum to the weight's share the ground holds
    np.testing.assert_allclose(np.sort(table["normal"][ground]), np.sort(base.normal), rtol=1e-9)


def test_reading_something_else_is_a_clear_error(tmp_path):
    (tmp_path / "other.xyz").write_text("2\nProperties=species:S:1:pos:R:3\nH 0 0 0\nH 1 0 0\n")
    with pytest.raises(InputError, match="not a jaxpile frame"):
        export.read_xyz(tmp_path / "other.xyz")
    with pytest.raises(InputError, match="no such file"):
        export.read_xyz(tmp_path / "missing.xyz")
