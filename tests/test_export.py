"""Export: extended XYZ frames and the contact table re-read to what was written."""

import shutil
import subprocess

import numpy as np
import pytest

from jaxpile import analysis, export, io
from jaxpile.errors import InputError
from jaxpile.laws import hooke
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator, gravity_ramp


@pytest.fixture(scope="module")
def loaded_pile():
    """A 4-layer lattice pile with friction and spin, loaded and still moving a little."""
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3, wall_mu=1.0)
    sim = Simulator(hooke.law(rotation=True), 1e-3, schedule=gravity_ramp(300))
    particles, boundaries = lattice.equilateral_pile(4)
    particles = particles.set(angular_velocity=particles.angular_velocity.at[3].set(0.7))
    state = sim.run(params, sim.init(params, particles, boundaries), 500, progress=False)
    return sim, params, state


FORMATS = {
    "xyz": ("traj.xyz", lambda path, s, t, append: export.write_xyz(path, s, time=t, append=append), export.read_xyz),
    "lammps": ("traj.lammpstrj", lambda path, s, t, append: export.write_lammps_dump(path, s, append=append),
               export.read_lammps_dump),
}


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_trajectory_rereads_every_column_of_every_frame(loaded_pile, tmp_path, fmt):
    sim, params, state = loaded_pile
    name, write, read = FORMATS[fmt]
    later = sim.run(params, state, 50, progress=False)
    path = tmp_path / name
    write(path, state, 0.5, False)
    write(path, later, 0.55, True)
    frames = read(path)
    assert [f["step"] for f in frames] == [500, 550]
    assert frames[1]["time"] == (0.55 if fmt == "xyz" else None)  # a dump frame has its step alone
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
    if fmt == "lammps":  # the items LAMMPS's read_dump and OVITO look for, in LAMMPS's order
        lines = path.read_text().splitlines()
        assert lines[0] == "ITEM: TIMESTEP" and lines[2] == "ITEM: NUMBER OF ATOMS" and lines[3] == "10"
        assert lines[4] == "ITEM: BOX BOUNDS ff ff pp" and lines[8] == f"ITEM: ATOMS {export.DUMP_COLUMNS}"
        lo, hi = (float(v) for v in lines[5].split())
        assert lo < frames[0]["pos"][:, 0].min() and hi > frames[0]["pos"][:, 0].max()
        return
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
    (tmp_path / "other.lammpstrj").write_text("ITEM: TIMESTEP\n0\nITEM: NUMBER OF ATOMS\n1\nITEM: BOX BOUNDS ff ff pp\n"
                                              "0 1\n0 1\n0 1\nITEM: ATOMS id type x y z\n1 1 0.5 0.5 0\n")
    with pytest.raises(InputError, match="jaxpile writes"):
        export.read_lammps_dump(tmp_path / "other.lammpstrj")


@pytest.mark.skipif(shutil.which("lmp") is None, reason="LAMMPS (lmp) is not installed")
def test_lammps_reads_the_dump_back_exactly(loaded_pile, tmp_path):
    """LAMMPS's own read_dump takes the frame, and its write_dump gives the same numbers."""
    _, _, state = loaded_pile
    export.write_lammps_dump(tmp_path / "t.lammpstrj", state)
    (tmp_path / "in.read").write_text(
        "units lj\natom_style sphere\ndimension 2\nboundary f f p\nregion box block -1 20 -1 20 -0.5 0.5\n"
        "create_box 1 box\nread_dump t.lammpstrj 500 x y vx vy box yes add yes\n"
        "write_dump all custom out.dump id x y vx vy modify sort id format float %.17g\n")
    subprocess.run(["lmp", "-in", "in.read", "-log", "none", "-screen", "none"], cwd=tmp_path, check=True)
    back = np.loadtxt(tmp_path / "out.dump", skiprows=9)
    np.testing.assert_array_equal(back[:, 1:3], np.asarray(state.particles.position))
    np.testing.assert_array_equal(back[:, 3:5], np.asarray(state.particles.velocity))
