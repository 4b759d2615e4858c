"""Rolling resistance against LAMMPS 29Sep2021: `pair_style granular hooke kn
gamma_n damping mass_velocity tangential linear_history kt gamma_t/gamma_n mu
rolling sds k_roll gamma_roll mu_roll`, its walls `fix wall/gran granular` with
the same coefficients, `fix nve/sphere disc` (velocity Verlet, I = m r^2 / 2)
and `fix enforce2d`, against jaxpile's `hooke.law(rolling="sds",
pair_style="granular")` with velocity Verlet (LAMMPS's half-step forces).

Three set-ups, each run in one LAMMPS `run` (a second `run` would re-evaluate
the forces at its set-up with the full-step velocities) and dumped every few
hundred steps: a disk rolling on a wall floor (launched sliding with backspin,
so the rolling slider slips before it sticks), a disk rolling over a row of fixed
disks (`fix freeze`: LAMMPS then takes m_eff = m_i against them, as jaxpile
does), and a pile of 20 polydisperse disks dropped into a box (floor and side
walls). Positions, velocities, spins, forces and torques agree to round-off
(the pile's round-off grows as it collides; its bound is set against jaxpile's
own spread when one disk is moved by one ulp, measured once: see the test).

The LAMMPS inputs are written by `lammps_twin.py` (benchmarks/lammps_peer.py
does the same for `gran/hooke/history`).
"""

from __future__ import annotations

import numpy as np
import pytest

import jaxpile
from jaxpile.laws import hooke
from lammps_twin import LMP, differences, pile, run_jaxpile, run_lammps, walls

pytestmark = pytest.mark.skipif(LMP is None, reason="LAMMPS (lmp) is not installed: apt-get install lammps")

PARAMS = dict(kn=1.0e5, kt=2.0e4, gamma_n=300.0, gamma_t=150.0, mu=0.5, k_roll=5.0e3, gamma_roll=2.0, mu_roll=0.2)


def _num(x) -> str:
    return repr(float(x))


def granular_coefficients(p) -> str:
    """The `pair_coeff` / `fix wall/gran granular` model of jaxpile hooke params:
    LAMMPS's tangential damping is a multiple of the normal one."""
    return (f"hooke {_num(p['kn'])} {_num(p['gamma_n'])} damping mass_velocity "
            f"tangential linear_history {_num(p['kt'])} {_num(p['gamma_t'] / p['gamma_n'])} {_num(p['mu'])} "
            f"rolling sds {_num(p['k_roll'])} {_num(p['gamma_roll'])} {_num(p['mu_roll'])}")


# ------------------------------------------------------------------------ set-ups
def disk_on_wall():
    """A disk launched sliding and spinning backwards on a wall floor (slides,
    then rolls, slowed by the rolling torque)."""
    mass, radius, g = 0.7, 0.5, 1.0
    y = radius - mass * g / PARAMS["kn"]
    particles = jaxpile.make_particles([[2.0, y]], radius, mass=mass, velocity=[[1.5, 0.0]], angular_velocity=[-2.0])
    return particles, dict(ground=0.0), ((-5.0, 40.0), (-5.0, 10.0))


ROW_GRAVITY = 4.0


def disk_on_row():
    """A disk rolling over a row of touching fixed disks: contacts made and broken,
    the normal turning as it goes (the spring's frame rotation and the arm
    r - delta/2 of pair granular), partners of another radius (R_eff)."""
    row = [[0.9 * k, 0.0] for k in range(30)]
    radius = [0.45] * 30 + [0.55]
    height = np.sqrt(1.0 - 0.45 ** 2)  # resting in the dip between disks 2 and 3
    top = [[0.9 * 2 + 0.45, height - 0.9 * ROW_GRAVITY / (2 * PARAMS["kn"] * height) / height]]
    mass = [1.0] * 30 + [0.9]
    velocity = [[0.0, 0.0]] * 30 + [[0.6, 0.0]]
    spin = [0.0] * 30 + [-1.0]
    particles = jaxpile.make_particles(row + top, np.array(radius), mass=np.array(mass), velocity=velocity,
                                       angular_velocity=spin, fixed=[True] * 30 + [False])
    return particles, dict(), ((-5.0, 35.0), (-5.0, 10.0))


SETUPS = {  # set-up, steps, dump interval, dt, gravity, and the largest difference / the column's scale allowed
    "disk-on-wall": dict(make=disk_on_wall, steps=4000, every=500, dt=2e-4, gravity=1.0, tol=1e-12),
    "disk-on-row": dict(make=disk_on_row, steps=6000, every=250, dt=2e-4, gravity=ROW_GRAVITY, tol=1e-10),
    "pile": dict(make=pile, steps=4000, every=500, dt=5e-4, gravity=5.0, tol=1e-8),
}


@pytest.mark.parametrize("name", list(SETUPS))
def test_rolling_sds_matches_lammps_pair_granular_to_round_off(name, tmp_path):
    """LAMMPS `pair_style granular ... rolling sds` (and `fix wall/gran granular`)
    against `hooke.law(rolling="sds", pair_style="granular")`: x, y, v, omega, F
    and the torque of every moving disk at every dump, relative to the column's
    largest magnitude over the run. Measured: disk on a wall <= 2e-16, disk on
    a row of fixed disks <= 6e-12, the pile <= 2e-10 (in F_x; 1e-11 in the
    spins) over 4000 steps, where jaxpile against itself with one coordinate of
    one disk moved by one ulp differs by 2e-11 (F_x) and 1e-11 (spins): the
    pile amplifies round-off, by ~x10 per 500 steps while it collides."""
    case = dict(SETUPS[name])
    make, tol = case.pop("make"), case.pop("tol")
    particles, wall_positions, box = make()
    theirs = run_lammps(str(tmp_path), particles, box, model=granular_coefficients(PARAMS), **case, **wall_positions)
    ours, loaded = run_jaxpile(particles, walls(case["gravity"], **wall_positions),
                               law=hooke.law(rolling="sds", pair_style="granular"), params=hooke.make_params(**PARAMS),
                               strained=2, **case)
    assert loaded >= 3, "too few dumps with a rolling spring strained: the set-up does not test rolling"
    worst = differences(ours, theirs, ~np.asarray(particles.fixed))
    assert all(rel <= tol for _, rel in worst.values()), worst
