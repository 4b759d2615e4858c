"""Results other programs open: extended XYZ frames (OVITO, ASE), LAMMPS
`dump custom` frames (OVITO; LAMMPS `read_dump`, `rerun`) and the
contact-force network as a per-contact table.

Extended XYZ: one frame is a count line, a comment line of `key=value` pairs
(`Properties` names the columns, `Lattice` the box, `Time` and `Step`), then
one line per disk. jaxpile writes 2D disks in 3D columns (z = 0) because the
readers expect three components:

  species (X)  pos(x y z)  radius  velo(vx vy vz)  omega(z)  force(fx fy fz)  active

and spheres with the spin vector, omega(x y z).

`force` is the total force on the disk at its last step (contacts + gravity).
Parked disks (not yet poured) are written with `active` = 0 so every frame of a
trajectory has the same rows; filter on it in OVITO (Expression selection
`active == 0`, Delete selected). A trajectory is frames appended to one file:
`with export.trajectory(path, every): ...` records one through any run, a
protocol's included (CLI: `--trajectory-every STEPS`).

The contact table (CSV) has one row per disk-disk contact, i < j, with the
normal and tangential force magnitudes in mg (`analysis.contact_network`),
and the ground and wall contacts with j = -1 - wall index (`analysis.wall_partner`).
"""

from __future__ import annotations

import os

import numpy as np

from jaxpile.errors import InputError
from jaxpile.io import atomic_write
from jaxpile.engine.state import SimState

PROPERTIES = "species:S:1:pos:R:3:radius:R:1:velo:R:3:omega:R:1:force:R:3:active:I:1"
COLUMNS = ("pos", 3), ("radius", 1), ("velo", 3), ("omega", 1), ("force", 3), ("active", 1)
PROPERTIES_3D = "species:S:1:pos:R:3:radius:R:1:velo:R:3:omega:R:3:force:R:3:active:I:1"
COLUMNS_3D = ("pos", 3), ("radius", 1), ("velo", 3), ("omega", 3), ("force", 3), ("active", 1)
"""Spheres: the same columns with the spin vector."""


def _table(state: SimState):
    """`(rows, active, lo, hi)`: the per-disk columns both formats write (pos xyz,
    radius, velocity xyz, spin z, force xyz; z = 0), the active flags, and the
    corners of the disks' bounding box (plain floats: the repr of a numpy
    scalar is "np.float64(...)")."""
    p = state.particles
    pos = np.asarray(p.position, float)
    n, d = pos.shape
    reach = float(np.asarray(p.radius).max()) if n else 0.5
    lo = pos.min(0) - reach if n else np.zeros(d)
    hi = np.maximum(pos.max(0) + reach if n else np.ones(d), lo + 1e-12)
    zero = np.zeros((n, 1))
    if d == 3:  # spheres: every column as it is, the spin a vector
        table = np.hstack([pos, np.asarray(p.radius, float)[:, None], np.asarray(p.velocity, float),
                           np.asarray(p.angular_velocity, float), np.asarray(p.force, float)])
    else:
        table = np.hstack([pos, zero, np.asarray(p.radius, float)[:, None], np.asarray(p.velocity, float), zero,
                           np.asarray(p.angular_velocity, float)[:, None], np.asarray(p.force, float), zero])
    rows = [" ".join(repr(float(v)) for v in row) for row in table]
    return rows, np.asarray(p.active).astype(int), [float(v) for v in lo], [float(v) for v in hi]


def frame_text(state: SimState, time: float | None = None) -> str:
    """One extended-XYZ frame of `state`."""
    rows, active, lo, hi = _table(state)
    size = [h - l for h, l in zip(hi, lo)]
    spheres = len(size) == 3
    depth, bottom = (size[2], lo[2]) if spheres else (1.0, -0.5)
    header = (f'Lattice="{size[0]!r} 0.0 0.0 0.0 {size[1]!r} 0.0 0.0 0.0 {depth!r}" '
              f'Origin="{lo[0]!r} {lo[1]!r} {bottom!r}" '
              f'Properties={PROPERTIES_3D if spheres else PROPERTIES} Step={int(state.step)} pbc="F F F"'
              + ("" if time is None else f" Time={float(time)!r}"))
    lines = [f"X {row} {a}" for row, a in zip(rows, active)]
    return f"{len(rows)}\n{header}\n" + "\n".join(lines) + ("\n" if lines else "")


def write_xyz(path, state: SimState, *, time: float | None = None, append: bool = False) -> None:
    """Writes (or appends, for a trajectory) one frame of `state` to `path`."""
    _write(path, frame_text(state, time), append)


def read_xyz(path) -> list[dict]:
    """The frames of an extended-XYZ file written by `write_xyz`: each a dict of
    numpy columns (`pos` `[n, 3]`, `radius`, `velo`, `omega`, `force`, `active`)
    plus `step` and `time`."""
    if not os.path.exists(path):
        raise InputError(f"no such file: {path}")
    frames = []
    with open(path) as f:
        lines = f.read().splitlines()
    k = 0
    while k < len(lines):
        try:
            n = int(lines[k])
        except ValueError as e:
            raise InputError(f"{path}, line {k + 1}: expected a particle count, got {lines[k]!r}.") from e
        header = dict(_pairs(lines[k + 1]))
        if header.get("Properties") not in (PROPERTIES, PROPERTIES_3D):
            raise InputError(f"{path}, line {k + 2}: not a jaxpile frame (Properties={header.get('Properties')}).")
        columns = COLUMNS if header["Properties"] == PROPERTIES else COLUMNS_3D
        body = [line.split()[1:] for line in lines[k + 2:k + 2 + n]]
        data = np.asarray(body, float).reshape(n, sum(width for _, width in columns))
        frame, col = {}, 0
        for name, width in columns:
            frame[name] = data[:, col:col + width] if width > 1 else data[:, col]
            col += width
        frame["active"] = frame["active"].astype(bool)
        frame["step"] = int(header["Step"])
        frame["time"] = float(header["Time"]) if "Time" in header else None
        frames.append(frame)
        k += 2 + n
    return frames


DUMP_COLUMNS = "id type x y z radius vx vy vz omegaz fx fy fz active"
DUMP_COLUMNS_3D = "id type x y z radius vx vy vz omegax omegay omegaz fx fy fz active"


def dump_text(state: SimState) -> str:
    """One LAMMPS `dump custom` frame of `state` (what OVITO opens and LAMMPS's
    `read_dump` / `rerun` read): ids from 1, type 1, z = 0, and the box of the
    disks (`ff ff pp`, non-periodic in the plane)."""
    rows, active, lo, hi = _table(state)
    spheres = len(lo) == 3
    z = f"ff\n{lo[0]!r} {hi[0]!r}\n{lo[1]!r} {hi[1]!r}\n{lo[2]!r} {hi[2]!r}" if spheres else \
        f"pp\n{lo[0]!r} {hi[0]!r}\n{lo[1]!r} {hi[1]!r}\n-0.5 0.5"
    head = (f"ITEM: TIMESTEP\n{int(state.step)}\nITEM: NUMBER OF ATOMS\n{len(rows)}\n"
            f"ITEM: BOX BOUNDS ff ff {z}\nITEM: ATOMS {DUMP_COLUMNS_3D if spheres else DUMP_COLUMNS}\n")
    lines = [f"{k + 1} 1 {row} {a}" for k, (row, a) in enumerate(zip(rows, active))]
    return head + "\n".join(lines) + ("\n" if lines else "")


def write_lammps_dump(path, state: SimState, *, append: bool = False) -> None:
    """Writes (or appends, for a trajectory) one `dump custom` frame of `state`."""
    _write(path, dump_text(state), append)


def read_lammps_dump(path) -> list[dict]:
    """The frames of a dump written by `write_lammps_dump`, as `read_xyz` gives
    them (`pos` `[n, 3]`, `radius`, `velo`, `omega`, `force`, `active`, `step`)."""
    frames = []
    for step, text in _frames(path):
        lines = text.splitlines()
        if lines[8].split()[2:] != DUMP_COLUMNS.split():
            raise InputError(f"{path}: a frame with columns {lines[8]!r}; jaxpile writes {DUMP_COLUMNS!r}.")
        n = int(lines[3])
        data = np.asarray([line.split() for line in lines[9:9 + n]], float).reshape(n, 14)
        frames.append({"pos": data[:, 2:5], "radius": data[:, 5], "velo": data[:, 6:9], "omega": data[:, 9],
                       "force": data[:, 10:13], "active": data[:, 13].astype(bool), "step": step, "time": None})
    return frames


def _write(path, text: str, append: bool) -> None:
    if append:
        with open(path, "a") as f:
            f.write(text)
    else:
        atomic_write(path, lambda f: f.write(text), text=True)


def _is_dump(path) -> bool:
    return str(path).endswith((".lammpstrj", ".dump"))


def _frames(path):
    """`(step, text)` of each frame of an extended-XYZ file or a LAMMPS dump."""
    if not os.path.exists(path):
        raise InputError(f"no such file: {path}")
    with open(path) as f:
        lines = f.read().splitlines(keepends=True)
    k = 0
    while k < len(lines):
        try:
            if _is_dump(path):
                n, step, size = int(lines[k + 3]), int(lines[k + 1]), 9 + int(lines[k + 3])
            else:
                n = int(lines[k])
                step, size = int(dict(_pairs(lines[k + 1].strip()))["Step"]), 2 + n
        except (ValueError, IndexError, KeyError) as e:
            raise InputError(f"{path}, line {k + 1}: not a frame jaxpile wrote ({e}).") from e
        yield step, "".join(lines[k:k + size])
        k += size


class Trajectory:
    """Appends a frame to an extended-XYZ file at step 0 and at the first chunk
    boundary at or past each multiple of `every` steps (see `trajectory`)."""

    def __init__(self, path, every: int, resume_step: int | None = None):
        if int(every) != every or every < 1:
            raise InputError(f"the trajectory interval must be a whole number of steps >= 1; got {every!r}.")
        self.path, self.every, self.frames = str(path), int(every), 0
        self.last = None  # step of the last frame written
        if resume_step is None:
            if os.path.exists(self.path):
                os.remove(self.path)
        else:  # frames written after the checkpoint, before the run stopped, are written again
            self.frames = truncate(self.path, resume_step) if os.path.exists(self.path) else 0
            self.last = int(resume_step)

    def __call__(self, state: SimState, dt: float) -> None:
        step = int(state.step)
        if self.last is not None and step <= self.last:
            return  # already written: the next phase starts where the last ended
        if self.last is None or step // self.every > self.last // self.every:
            if _is_dump(self.path):
                write_lammps_dump(self.path, state, append=True)
            else:
                write_xyz(self.path, state, time=step * dt, append=True)
            self.last, self.frames = step, self.frames + 1


def trajectory(path, every: int, *, resume_step: int | None = None):
    """A context manager: every run inside it appends frames to `path`
    (`Trajectory`), through a protocol's own runs (`simulate.observing`).

    Args:
      path: the `.xyz` file, or a LAMMPS dump (`.lammpstrj` or `.dump`);
        replaced, unless resuming.
      every: steps between frames (at chunk boundaries: a frame is written at
        the first boundary at or past each multiple).
      resume_step: the step a resumed run continues from: frames after it
        (written before the run was stopped) are dropped, and the resumed run
        appends the same frames the uninterrupted run would have.

    Example:
      >>> with export.trajectory("out/trajectory.xyz", 1000):            # doctest: +SKIP
      ...     state, m = box.run("hooke", width=1.6, height=1.6)
    """
    from jaxpile.engine.simulate import observing

    return observing(Trajectory(path, every, resume_step))


def truncate(path, step: int) -> int:
    """Keeps the frames of a trajectory (extended XYZ or LAMMPS dump) up to
    `step`, atomically; returns how many."""
    kept = [text for frame_step, text in _frames(path) if frame_step <= step]
    atomic_write(path, lambda f: f.write("".join(kept)), text=True)
    return len(kept)


def _pairs(comment: str):
    """key=value pairs of an extended-XYZ comment line (values may be quoted)."""
    i = 0
    while i < len(comment):
        while i < len(comment) and comment[i] == " ":
            i += 1
        eq = comment.find("=", i)
        if eq < 0:
            return
        key = comment[i:eq]
        if eq + 1 < len(comment) and comment[eq + 1] == '"':
            end = comment.index('"', eq + 2)
            yield key, comment[eq + 2:end]
            i = end + 1
        else:
            end = comment.find(" ", eq)
            end = len(comment) if end < 0 else end
            yield key, comment[eq + 1:end]
            i = end


def write_contacts(path, sim, params, state: SimState) -> dict:
    """The contact-force table: disk-disk contacts (i < j) and wall contacts
    (j = -1 - wall), with normal and tangential magnitudes in mg. Returns the columns."""
    from jaxpile.measure import analysis
    from jaxpile.io import write_csv

    net = analysis.contact_network(sim, params, state)
    cf = sim.contact_forces(params, state)
    touching = np.asarray(cf.wall.in_contact)
    wi, ww = np.nonzero(touching)
    normals = np.asarray(state.boundaries.wall_normal)[ww]
    f = np.asarray(cf.wall.force)[wi, ww]
    unit = analysis.force_unit(state)
    columns = {
        "i": np.concatenate([net.i, wi]),
        "j": np.concatenate([net.j, [analysis.wall_partner(w) for w in ww]]),
        "normal": np.concatenate([net.normal, np.sum(f * normals, axis=1) / unit]),
        "tangential": np.concatenate([net.tangential,
                                      np.abs(f[:, 0] * normals[:, 1] - f[:, 1] * normals[:, 0]) / unit]),
    }
    write_csv(path, columns)
    return columns
