"""Spheres against LAMMPS 29Sep2021 (`fix nve/sphere`: velocity Verlet, I = 2 m
r^2 / 5; walls `fix wall/gran`), each run in one LAMMPS `run` dumped every few
hundred steps and compared column by column (x, v, omega, F and the torque,
each component) with jaxpile's velocity Verlet (LAMMPS's half-step forces):

- a sphere launched sliding and spinning on a wall floor with `pair_style
  granular ... rolling sds` (`hooke.law(rolling="sds", pair_style="granular")`);
- two spheres in an oblique, spinning collision with `pair_style
  gran/hooke/history` (`hooke.law()`, the shear spring projected into the new
  tangent plane each step);
- 200 polydisperse spheres settling in a box of five walls with rolling sds.

The pile amplifies round-off while it collides; its bound stands beside
jaxpile against itself with one coordinate of one sphere moved by one ulp (in
the same test). Its run stops at 1500 steps: the normal force jumps at
contact onset (its damping part, m_eff gamma_n v_n, is not zero at zero
overlap), so a contact made one step earlier in one code than in the other
turns the 1e-10 of round-off into 0.1 in a force; measured, that first
happens between steps 1750 and 1800 of this pile.
"""

from __future__ import annotations

import numpy as np
import pytest

import jaxpile
from jaxpile.laws import hooke
from lammps_twin import LMP, differences, run_jaxpile, run_lammps
from test_rolling_lammps import granular_coefficients

pytestmark = pytest.mark.skipif(LMP is None, reason="LAMMPS (lmp) is not installed: apt-get install lammps")

PARAMS = dict(kn=1.0e5, kt=2.0e4, gamma_n=300.0, gamma_t=150.0, mu=0.5, k_roll=5.0e3, gamma_roll=2.0, mu_roll=0.2)
HISTORY = dict(kn=1.0e5, kt=2.0e4, gamma_n=300.0, gamma_t=150.0, mu=0.5)


def _num(x) -> str:
    return repr(float(x))


def granular(p=PARAMS) -> dict:
    model = granular_coefficients(p)
    return dict(pair=["pair_style granular", f"pair_coeff * * {model}"], wall=f"granular {model}")


def hooke_history(p=HISTORY) -> dict:
    coeffs = " ".join(_num(p[k]) for k in ("kn", "kt", "gamma_n", "gamma_t", "mu"))
    return dict(pair=[f"pair_style gran/hooke/history {coeffs} 1", "pair_coeff * *"], wall=f"hooke/history {coeffs} 1")


def boundaries(gravity, ground=None, sides=None, ends=None):
    """jaxpile's walls for LAMMPS's (a wall not asked for is off)."""
    b = jaxpile.make_boundaries(left=None if sides is None else sides[0], right=None if sides is None else sides[1],
                                front=None if ends is None else ends[0], back=None if ends is None else ends[1],
                                ground=0.0 if ground is None else ground, gravity=gravity, dim=3)
    return b if ground is not None else b.set(wall_active=b.wall_active.at[0].set(False))


def sphere_on_wall():
    mass, radius = 0.7, 0.5
    z = radius - mass / PARAMS["kn"]
    p = jaxpile.make_particles([[2.0, 3.0, z]], radius, mass=mass, velocity=[[1.5, 0.4, 0.0]],
                               angular_velocity=[[1.0, -2.0, 0.3]])
    return p, dict(ground=0.0), ((-5.0, 40.0), (-5.0, 20.0), (-1.0, 10.0))


def oblique_collision():
    p = jaxpile.make_particles([[0.0, 0.0, 0.0], [0.95, 0.3, 0.2]], [0.5, 0.45], mass=[1.0, 0.73],
                               velocity=[[0.4, 0.1, 0.0], [-0.5, -0.1, 0.05]],
                               angular_velocity=[[0.0, 3.0, -1.0], [2.0, 0.0, 1.5]])
    return p, dict(), ((-10.0, 10.0), (-10.0, 10.0), (-10.0, 10.0))


def sphere_pile(nudge=0.0, n=200, side=5.0):
    rng = np.random.default_rng(4)
    grid = np.stack(np.meshgrid(np.arange(4), np.arange(4), np.arange(13), indexing="ij"), -1).reshape(-1, 3)[:n]
    position = 0.62 + 1.22 * grid.astype(float)
    position[0, 0] += nudge
    radius = rng.uniform(0.4, 0.6, n)
    p = jaxpile.make_particles(position, radius, mass=8.0 * radius ** 3, velocity=rng.uniform(-0.1, 0.1, (n, 3)),
                               angular_velocity=rng.uniform(-0.5, 0.5, (n, 3)))
    return p, dict(ground=0.0, sides=(0.0, side), ends=(0.0, side)), ((-1.0, 6.0), (-1.0, 6.0), (-1.0, 18.0))


SETUPS = {  # set-up, model, law, steps, dump interval, dt, gravity, the largest difference / the column's scale
    "sphere-on-wall": dict(make=sphere_on_wall, model=granular, law=dict(rolling="sds", pair_style="granular"),
                           steps=4000, every=500, dt=2e-4, gravity=1.0, tol=1e-12),
    "oblique-collision": dict(make=oblique_collision, model=hooke_history, law={}, steps=800, every=10, dt=2e-4,
                              gravity=0.0, tol=1e-12),
    "pile": dict(make=sphere_pile, model=granular, law=dict(rolling="sds", pair_style="granular"), steps=1500,
                 every=250, dt=5e-4, gravity=5.0, tol=1e-10),
}


def _run_both(name, tmp_path, nudge=None):
    case = dict(SETUPS[name])
    make, model, law, tol = case.pop("make"), case.pop("model"), case.pop("law"), case.pop("tol")
    particles, walls, box = make()
    params = hooke.make_params(**(PARAMS if law else HISTORY))
    theirs = run_lammps(str(tmp_path), particles, box, **model(), **case, **walls)
    ours, strained = run_jaxpile(particles, boundaries(case["gravity"], **walls), law=hooke.law(**law),
                                 params=params, strained=3 if law else 0, **case)
    return particles, ours, theirs, strained, tol, case, walls, law, params


@pytest.mark.parametrize("name", list(SETUPS))
def test_spheres_match_lammps_to_round_off(name, tmp_path):
    """Measured, the largest difference over the columns relative to each
    column's scale: the sphere on a wall 9e-15, the collision 2e-13, the pile
    4e-12; the pile's spread against jaxpile with one ulp moved is checked
    beside it."""
    particles, ours, theirs, strained, tol, case, walls, law, params = _run_both(name, tmp_path)
    assert strained >= 3, "too few dumps with a spring strained: the set-up does not test the history"
    worst = differences(ours, theirs, ~np.asarray(particles.fixed))
    assert all(rel <= tol for _, rel in worst.values()), worst
    if name == "pile":  # the bound stands beside jaxpile's own sensitivity to one ulp
        nudged, _, _ = sphere_pile(nudge=np.spacing(0.62))
        again, _ = run_jaxpile(nudged, boundaries(case["gravity"], **walls), law=hooke.law(**law), params=params,
                               **case)
        spread = differences(ours, again, np.ones(particles.count, bool))
        assert max(rel for _, rel in spread.values()) > 0  # the ulp moved something
        assert max(rel for _, rel in worst.values()) <= max(100 * max(rel for _, rel in spread.values()), 1e-12)
