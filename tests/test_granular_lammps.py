"""`jaxpile.laws.granular` against LAMMPS 29Sep2021's `pair_style granular`
(and `fix wall/gran granular` with the same model), each sub-model in at
least one composition written as its `pair_coeff` line and read by
`granular.parse`: oblique collisions of spinning disks of unlike radii, and
a polydisperse pile settling in a box with walls (`lammps_twin.py` runs both
codes). The single-contact laws' closed forms are in `test_granular.py`.
"""

from __future__ import annotations

import numpy as np
import pytest

import jaxpile
from jaxpile.laws import granular
from lammps_twin import LMP, differences, pile, run_jaxpile, run_lammps, walls

pytestmark = pytest.mark.skipif(LMP is None, reason="LAMMPS (lmp) is not installed: apt-get install lammps")

MODELS = {  # every normal, damping and tangential model at least once, rolling sds and limit_damping
    "hooke-velocity-nohistory": "hooke 1e5 100.0 damping velocity tangential linear_nohistory 0.5 0.4",
    "hertz-viscoelastic-linear": "hertz 2e6 5000.0 damping viscoelastic tangential linear_history 3e4 0.5 0.4",
    "material-tsuji-mindlin": "hertz/material 3e6 0.5 0.3 damping tsuji tangential mindlin NULL 1.0 0.4",
    "material-mass-mindlin-sds": ("hertz/material 3e6 150.0 0.25 damping mass_velocity tangential mindlin 4e5 0.5 "
                                  "0.4 rolling sds 5e3 2.0 0.2"),
    "hertz-tsuji-nohistory": "hertz 2e6 0.7 damping tsuji tangential linear_nohistory 1.0 0.4",
    "jkr-viscoelastic-rescale": "jkr 3e6 5000.0 0.3 0.5 damping viscoelastic tangential mindlin_rescale NULL 1.0 0.4",
    "jkr-tsuji-force": "jkr 3e6 0.5 0.3 0.5 damping tsuji tangential mindlin/force NULL 1.0 0.4",
    "material-velocity-rescale-force-sds": ("hertz/material 3e6 50.0 0.3 damping velocity tangential "
                                            "mindlin_rescale/force 4e5 0.5 0.4 rolling sds 5e3 2.0 0.2"),
    "hooke-mass-linear-limit": ("hooke 1e5 20.0 damping mass_velocity tangential linear_history 3e4 0.5 0.4 "
                                "limit_damping"),
    # frictionless: LAMMPS 29Sep2021's dmt friction cap reads a variable only jkr sets (granular's W3)
    "dmt-viscoelastic-frictionless": "dmt 3e6 5000.0 0.25 0.3 damping viscoelastic tangential linear_nohistory 1.0 0.0",
}


def collisions():
    """Four pairs far apart, each disk of its own radius and mass, closing
    obliquely (an impact parameter of a third of the radii) with spins, just
    apart at the start: they collide, slide or stick, and fly apart."""
    rng = np.random.default_rng(11)
    position, radius, mass, velocity, spin = [], [], [], [], []
    for k in range(4):
        r1, r2 = rng.uniform(0.35, 0.6, 2)
        angle = rng.uniform(0, 2 * np.pi)
        n = np.array([np.cos(angle), np.sin(angle)])
        t = np.array([-n[1], n[0]])
        centre = np.array([5.0 * k, 0.0])
        position += [centre, centre + (r1 + r2 + 1e-3) * n]
        radius += [r1, r2]
        mass += list(4.0 * np.array([r1, r2]) ** 2)
        closing = rng.uniform(0.5, 1.5)
        velocity += [closing * (0.8 * n + 0.6 * t), -closing * (0.8 * n - 0.2 * t)]
        spin += list(rng.uniform(-3, 3, 2))
    particles = jaxpile.make_particles(np.array(position), np.array(radius), mass=np.array(mass),
                                       velocity=np.array(velocity), angular_velocity=np.array(spin))
    return particles, dict(), ((-5.0, 25.0), (-8.0, 8.0))


SETUPS = {  # set-up, steps, dump interval, dt, gravity, and the largest difference / the column's scale allowed
    "collisions": dict(make=collisions, steps=600, every=20, dt=5e-5, gravity=0.0, tol=1e-12),
    "pile": dict(make=pile, steps=4000, every=500, dt=2e-4, gravity=5.0, tol=1e-9),
}


@pytest.mark.parametrize("setup", list(SETUPS))
@pytest.mark.parametrize("name", list(MODELS))
def test_each_granular_sub_model_matches_lammps_pair_granular_to_round_off(name, setup, tmp_path):
    """Positions, velocities, spins, forces and torques of every disk at every
    dump, relative to the column's largest magnitude over the run: the
    collisions to 1e-12; the pile, which amplifies round-off while it
    collides, to 1e-9. Measured once on the pile (4000 steps), LAMMPS against
    jaxpile and, beside it, jaxpile against itself with one coordinate of one
    disk moved by one ulp: hooke-velocity-nohistory 2.8e-11 (1.2e-13),
    hertz-viscoelastic-linear 1.7e-12 (5.3e-13), material-tsuji-mindlin
    1.4e-10 (3.9e-13), material-mass-mindlin-sds 1.3e-11 (2.3e-13),
    hertz-tsuji-nohistory 9.8e-11 (1.7e-13), jkr-viscoelastic-rescale
    1.1e-11, jkr-tsuji-force 7.1e-12, material-velocity-rescale-force-sds
    1.0e-11, hooke-mass-linear-limit 4.7e-12, dmt-viscoelastic-frictionless
    5.7e-13: LAMMPS's order of summation
    differs at every contact of every step, not once, and the pile amplifies
    it; the collisions, which do not, agree to 1e-12 in every model."""
    case = dict(SETUPS[setup])
    make, tol = case.pop("make"), case.pop("tol")
    model, params = granular.parse(MODELS[name])
    law = granular.law(model)
    particles, wall_positions, box = make()
    theirs = run_lammps(str(tmp_path), particles, box, model=MODELS[name], **case, **wall_positions)
    boundaries = walls(case["gravity"], **wall_positions)
    ours, strained = run_jaxpile(particles, boundaries, law=law, params=params, **case)
    worst = differences(ours, theirs, ~np.asarray(particles.fixed))
    if tol is None:
        x = np.asarray(particles.position).copy()
        x[0, 0] = np.nextafter(x[0, 0], np.inf)
        nudged, _ = run_jaxpile(particles.set(position=x), boundaries, law=law, params=params, **case)
        spread = differences(nudged, ours, ~np.asarray(particles.fixed))
        tol = min(1e-8, max(1e-12, 10 * max(rel for _, rel in spread.values())))
    if model.tangential != "linear_nohistory":
        assert strained >= 2, "too few dumps with a tangential spring strained: the set-up does not test it"
    assert all(rel <= tol for _, rel in worst.values()), (worst, tol)
