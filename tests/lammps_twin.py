"""The LAMMPS twin's machinery, shared by the tests that run real LAMMPS
29Sep2021 against jaxpile (`test_rolling_lammps.py`, `test_granular_lammps.py`):
a data file of disks, an input of `pair_style granular` with its walls
(`fix wall/gran granular`), `fix nve/sphere disc` (velocity Verlet, I = m r^2 /
2) and `fix enforce2d`, one `run` dumped every few hundred steps (a second
`run` would re-evaluate the forces at its set-up with the full-step
velocities), and the same set-up run by jaxpile with velocity Verlet (LAMMPS's
half-step forces), compared column by column.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np

import jaxpile
from jaxpile.engine.simulate import Simulator

LMP = shutil.which("lmp")
COLUMNS = ("x", "y", "vx", "vy", "omegaz", "fx", "fy", "tqz")
COLUMNS_3D = ("x", "y", "z", "vx", "vy", "vz", "omegax", "omegay", "omegaz", "fx", "fy", "fz", "tqx", "tqy", "tqz")
"""The dumped columns, disks and spheres."""


def _num(x) -> str:
    return repr(float(x))


def write_data(path, position, radius, box) -> None:
    """A LAMMPS data file of disks or spheres (`Atoms # sphere`: id type
    diameter density x y z); masses are set in the input (`set atom`). `box`
    holds (lo, hi) per axis; disks lie in z = 0 of a slab -0.5..0.5."""
    position = np.asarray(position, float)
    (xlo, xhi), (ylo, yhi), *z = box
    zlo, zhi = z[0] if z else (-0.5, 0.5)
    lines = ["jaxpile rolling twin", "", f"{len(position)} atoms", "1 atom types", "",
             f"{_num(xlo)} {_num(xhi)} xlo xhi", f"{_num(ylo)} {_num(yhi)} ylo yhi", f"{_num(zlo)} {_num(zhi)} zlo zhi",
             "", "Atoms # sphere", ""]
    if position.shape[1] == 2:
        lines += [f"{i + 1} 1 {_num(2 * r)} 1.0 {_num(x)} {_num(y)} 0.0" for i, ((x, y), r) in
                  enumerate(zip(position, np.asarray(radius, float)))]
    else:
        lines += [f"{i + 1} 1 {_num(2 * r)} 1.0 {_num(x)} {_num(y)} {_num(z)}" for i, ((x, y, z), r) in
                  enumerate(zip(position, np.asarray(radius, float)))]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def lammps_script(particles, *, model, dt, steps, every, gravity, ground=None, sides=None, skin=0.3) -> str:
    """The input: `pair_style granular` with `pair_coeff * * model` and its walls
    `fix wall/gran granular model` (`ground`: the floor's y; `sides`: (left x,
    right x)), masses, velocities and spins set per atom, fixed disks frozen,
    one `run` of `steps`, dumped every `every` steps."""
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


def lammps_script_3d(particles, *, pair, dt, steps, every, gravity, wall=None, ground=None, sides=None,
                     ends=None, skin=0.3) -> str:
    """The spheres' input: `pair` (a `pair_style` line and its `pair_coeff`),
    walls `fix wall/gran <wall>` (`ground`: the floor's z; `sides`: x planes;
    `ends`: y planes), `fix nve/sphere` (I = 2 m r^2 / 5), gravity along -z,
    masses, velocities and spins per atom, one `run` dumped every `every` steps."""
    mass = np.asarray(particles.mass, float)
    velocity = np.asarray(particles.velocity, float)
    spin = np.asarray(particles.angular_velocity, float)
    lines = ["units lj", "dimension 3", "atom_style sphere", "atom_modify map array", "boundary f f f",
             "comm_modify vel yes", "read_data disks.data"]
    lines += [f"set atom {i + 1} mass {_num(m)} vx {_num(v[0])} vy {_num(v[1])} vz {_num(v[2])} "
              f"omega {_num(w[0])} {_num(w[1])} {_num(w[2])}" for i, (m, v, w) in enumerate(zip(mass, velocity, spin))]
    lines += [f"neighbor {_num(skin)} bin", "neigh_modify delay 0 every 1 check yes", *pair]
    for name, plane, where in (("ground", "zplane", None if ground is None else (ground, None)),
                               ("sides", "xplane", sides), ("ends", "yplane", ends)):
        if where is not None:
            lo, hi = ("NULL" if v is None else _num(v) for v in where)
            lines.append(f"fix {name} all wall/gran {wall} {plane} {lo} {hi}")
    lines += ["fix move all nve/sphere", f"fix grav all gravity {_num(gravity)} vector 0.0 0.0 -1.0",
              f"timestep {_num(dt)}", "thermo 0",
              f"dump out all custom {int(every)} out.dump id {' '.join(COLUMNS_3D)}",
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
    script = lammps_script if particles.dim == 2 else lammps_script_3d
    with open(os.path.join(workdir, "in.lmp"), "w") as f:
        f.write(script(particles, **kwargs))
    done = subprocess.run([LMP, "-in", "in.lmp", "-log", "log.lammps", "-screen", "none"], cwd=workdir,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, (done.stdout + done.stderr)[-2000:]
    return read_snapshots(os.path.join(workdir, "out.dump"))


def run_jaxpile(particles, boundaries, *, law, params, dt, steps, every, strained=0, **_) -> tuple[dict[int, dict], int]:
    """Snapshots every `every` steps of `law` at `params`, and how many of them
    had the history entry `strained` nonzero in some pair or wall contact (a
    spring under strain)."""
    p = params
    sim = Simulator(law, dt=dt, skin=0.3, chunk_steps=every)
    state = sim.init(p, particles, boundaries)
    out, rolling = {}, 0
    for k in range(0, steps + 1, every):
        if k:
            state = sim.run(p, state, every, progress=False)
        q = state.particles
        if q.dim == 2:
            out[k] = dict(x=q.position[:, 0], y=q.position[:, 1], vx=q.velocity[:, 0], vy=q.velocity[:, 1],
                          omegaz=q.angular_velocity, fx=q.force[:, 0], fy=q.force[:, 1], tqz=q.torque)
        else:
            fields = (("", q.position), ("v", q.velocity), ("omega", q.angular_velocity), ("f", q.force),
                      ("tq", q.torque))
            out[k] = {prefix + axis if prefix else axis: np.asarray(a)[:, c]
                      for prefix, a in fields for c, axis in enumerate("xyz")}
        rolling += bool(np.any(np.asarray(state.contacts.history)[:, strained] != 0)
                        or np.any(np.asarray(state.contacts.wall_history)[..., strained] != 0))
    return out, rolling


def differences(ours: dict[int, dict], theirs: dict[int, dict], moving) -> dict:
    """Per column, over the moving disks and every snapshot: (max abs difference,
    that / the column's largest magnitude over the run)."""
    assert sorted(ours) == sorted(theirs)
    out = {}
    for name in (COLUMNS if "z" not in next(iter(ours.values())) else COLUMNS_3D):
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
