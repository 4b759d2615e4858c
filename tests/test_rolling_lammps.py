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

The LAMMPS inputs are written here (benchmarks/lammps_peer.py does the same for
`gran/hooke/history`; these helpers are this file's own).
"""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest

import jaxpile
from jaxpile.engine.simulate import Simulator
from jaxpile.laws import hooke

LMP = shutil.which("lmp")
pytestmark = pytest.mark.skipif(LMP is None, reason="LAMMPS (lmp) is not installed: apt-get install lammps")

PARAMS = dict(kn=1.0e5, kt=2.0e4, gamma_n=300.0, gamma_t=150.0, mu=0.5, k_roll=5.0e3, gamma_roll=2.0, mu_roll=0.2)
COLUMNS = ("x", "y", "vx", "vy", "omegaz", "fx", "fy", "tqz")


def _num(x) -> str:
    return repr(float(x))


def write_data(path, position, radius, box) -> None:
    """A LAMMPS data file of disks (`Atoms # sphere`: id type diameter density x y z);
    masses are set in the input (`set atom`)."""
    (xlo, xhi), (ylo, yhi) = box
    lines = ["jaxpile rolling twin", "", f"{len(position)} atoms", "1 atom types", "",
             f"{_num(xlo)} {_num(xhi)} xlo xhi", f"{_num(ylo)} {_num(yhi)} ylo yhi", "-0.5 0.5 zlo zhi",
             "", "Atoms # sphere", ""]
    lines += [f"{i + 1} 1 {_num(2 * r)} 1.0 {_num(x)} {_num(y)} 0.0" for i, ((x, y), r) in
              enumerate(zip(np.asarray(position, float), np.asarray(radius, float)))]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def granular_coefficients(p) -> str:
    """The `pair_coeff` / `fix wall/gran granular` model of jaxpile hooke params:
    LAMMPS's tangential damping is a multiple of the normal one."""
    return (f"hooke {_num(p['kn'])} {_num(p['gamma_n'])} damping mass_velocity "
            f"tangential linear_history {_num(p['kt'])} {_num(p['gamma_t'] / p['gamma_n'])} {_num(p['mu'])} "
            f"rolling sds {_num(p['k_roll'])} {_num(p['gamma_roll'])} {_num(p['mu_roll'])}")


def lammps_script(particles, *, params, dt, steps, every, gravity, ground=None, sides=None, skin=0.3) -> str:
    """The input: masses, velocities and spins set per atom, fixed disks frozen,
    walls (`ground`: the floor's y; `sides`: (left x, right x)), one `run` of
    `steps`, dumped every `every` steps."""
    model = granular_coefficients(params)
    mass = np.asarray(particles.mass, float)
    velocity = np.asarray(particles.velocity, float)
    spin = np.asarray(particles.angular_velocity, float)
    fixed = np.flatnonzero(np.asarray(particles.fixed))
    lines = ["units lj", "dimension 2", "atom_style sphere", "atom_modify map array", "boundary f f p",
             "comm_modify vel yes", "read_data disks.data"]
    lines += [f"set atom {i + 1} mass {_num(m)} vx {_num(v[0])} vy {_num(v[1])} omega 0.0 0.0 {_num(w)}"
              for i, (m, v, w) in enumerate(zip(mass, velocity, spin))]
    lines += [f"neighbor {_num(skin)} bin", "neigh_modify delay 0 every 1 check yes",
              "pair_style granular", f"pair_coeff * * {model}"]
    if ground is not None:
        lines.append(f"fix ground all wall/gran granular {model} yplane {_num(ground)} NULL")
    if sides is not None:
        lines.append(f"fix sides all wall/gran granular {model} xplane {_num(sides[0])} {_num(sides[1])}")
    lines += ["fix move all nve/sphere disc", "fix flat all enforce2d",
              f"fix grav all gravity {_num(gravity)} vector 0.0 -1.0 0.0"]
    if len(fixed):  # after gravity: zeroes the fixed disks' force, and pair granular takes m_eff = m_i against them
        lines += [f"group base id {' '.join(str(i + 1) for i in fixed)}", "fix frozen base freeze"]
    lines += [f"timestep {_num(dt)}", "thermo 0",
              f"dump out all custom {int(every)} out.dump id {' '.join(COLUMNS)}",
              "dump_modify out format float %.17g sort id", f"run {int(steps)}"]
    return "\n".join(lines) + "\n"


def read_snapshots(path) -> dict[int, dict]:
    """Every snapshot of a `dump custom` file by time step: columns by name, sorted by id."""
    with open(path) as f:
        lines = f.read().splitlines()
    out = {}
    for i, line in enumerate(lines):
        if not line.startswith("ITEM: ATOMS"):
            continue
        step = int(lines[lines.index("ITEM: TIMESTEP", max(0, i - 9)) + 1])
        names = line.split()[2:]
        rows = []
        for row in lines[i + 1:]:
            if row.startswith("ITEM:"):
                break
            rows.append(row.split())
        rows = np.array(rows, float)
        order = np.argsort(rows[:, names.index("id")])
        out[step] = {name: rows[order, k] for k, name in enumerate(names)}
    return out


def run_lammps(workdir, particles, box, **kwargs) -> dict[int, dict]:
    os.makedirs(workdir, exist_ok=True)
    write_data(os.path.join(workdir, "disks.data"), particles.position, particles.radius, box)
    with open(os.path.join(workdir, "in.lmp"), "w") as f:
        f.write(lammps_script(particles, **kwargs))
    done = subprocess.run([LMP, "-in", "in.lmp", "-log", "log.lammps", "-screen", "none"], cwd=workdir,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, (done.stdout + done.stderr)[-2000:]
    return read_snapshots(os.path.join(workdir, "out.dump"))


def run_jaxpile(particles, boundaries, *, params, dt, steps, every, **_) -> tuple[dict[int, dict], int]:
    """Snapshots every `every` steps, and how many of them had a rolling spring
    strained (some pair or wall history's psi nonzero)."""
    law = hooke.law(rolling="sds", pair_style="granular")
    p = hooke.make_params(**params)
    sim = Simulator(law, dt=dt, skin=0.3, chunk_steps=every)
    state = sim.init(p, particles, boundaries)
    out, rolling = {}, 0
    for k in range(0, steps + 1, every):
        if k:
            state = sim.run(p, state, every, progress=False)
        q = state.particles
        out[k] = dict(x=q.position[:, 0], y=q.position[:, 1], vx=q.velocity[:, 0], vy=q.velocity[:, 1],
                      omegaz=q.angular_velocity, fx=q.force[:, 0], fy=q.force[:, 1], tqz=q.torque)
        rolling += bool(np.any(np.asarray(state.contacts.history)[:, 2] != 0)
                        or np.any(np.asarray(state.contacts.wall_history)[..., 2] != 0))
    return out, rolling


def differences(ours: dict[int, dict], theirs: dict[int, dict], moving) -> dict:
    """Per column, over the moving disks and every snapshot: (max abs difference,
    that / the column's largest magnitude over the run)."""
    assert sorted(ours) == sorted(theirs)
    out = {}
    for name in COLUMNS:
        a = np.stack([np.asarray(ours[step][name], float)[moving] for step in sorted(ours)])
        b = np.stack([np.asarray(theirs[step][name], float)[moving] for step in sorted(ours)])
        worst = float(np.max(np.abs(a - b)))
        out[name] = (worst, worst / max(float(np.max(np.abs(b))), 1e-300))
    return out


def walls(gravity, ground=None, sides=None):
    """jaxpile boundaries with LAMMPS's walls (`ground`: the floor's y; `sides`:
    the side walls' x) and gravity; a wall not asked for is off."""
    if sides is not None:
        return jaxpile.make_boundaries(left=sides[0], right=sides[1], ground=ground, gravity=gravity)
    floor = jaxpile.make_boundaries(ground=0.0 if ground is None else ground, gravity=gravity, sides=False)
    return floor if ground is not None else floor.set(wall_active=np.array([False]))


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


def pile(n=20, seed=3, nudge=0.0):
    """20 disks of radii 0.4-0.6 on a grid in a box 6 wide, 0.02 apart at most
    where they are largest, with small random velocities and spins, settling
    onto the floor and into each other: a small pile."""
    rng = np.random.default_rng(seed)
    columns = 5
    position = np.array([[0.62 + 1.22 * (k % columns), 0.61 + 1.22 * (k // columns)] for k in range(n)])
    position[0, 0] += nudge
    radius = rng.uniform(0.4, 0.6, n)
    mass = 4.0 * radius ** 2  # mass 1 at diameter 1
    velocity = rng.uniform(-0.1, 0.1, (n, 2))
    spin = rng.uniform(-0.5, 0.5, n)
    particles = jaxpile.make_particles(position, radius, mass=mass, velocity=velocity, angular_velocity=spin)
    return particles, dict(ground=0.0, sides=(0.0, 6.12)), ((-1.0, 7.2), (-1.0, 12.0))


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
    theirs = run_lammps(str(tmp_path), particles, box, params=PARAMS, **case, **wall_positions)
    ours, loaded = run_jaxpile(particles, walls(case["gravity"], **wall_positions), params=PARAMS, **case)
    assert loaded >= 3, "too few dumps with a rolling spring strained: the set-up does not test rolling"
    worst = differences(ours, theirs, ~np.asarray(particles.fixed))
    assert all(rel <= tol for _, rel in worst.values()), worst
