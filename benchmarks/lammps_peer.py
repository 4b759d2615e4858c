"""LAMMPS as the reference peer of jaxpile's benchmarks: finding the binary,
writing inputs that pose the same problem as a jaxpile run, running them and
reading back loop times and per-disk forces.

How a jaxpile set-up maps onto LAMMPS (2D, `units lj`, `atom_style sphere`):

* `hooke` law: `pair_style gran/hooke/history kn kt gamma_n gamma_t mu 1`; the
  ground and side walls: `fix wall/gran hooke/history` with the `wall_*` values
  (`yplane` for the ground, `xplane` for the side walls: jaxpile's walls are the
  half-planes normal . x >= offset of `jaxpile.engine.boundaries`);
* velocity Verlet: `fix nve/sphere disc` (I = m r^2 / 2) with rotation, plain
  `fix nve` without (spins are never integrated and stay 0), and `fix enforce2d`;
* fixed disks: integrated with the rest but frozen with `fix freeze`, which
  zeroes their force (so velocity 0 keeps them in place) and makes pair gran use
  m_eff = m_i against them, as jaxpile does; in the pours, the pairs of two
  frozen particles are left out of the neighbour list (`neigh_modify exclude
  group base base`), as jaxpile leaves them out of its own;
* `simulate.gravity_ramp(R)`: `fix gravity` with the equal-style variable
  s(u) = u^2 (3 - 2u), u = min(step / R, 1), in one `run` for ramp and hold;
* masses are set with `set ... mass` after `read_data` (LAMMPS turns a data
  file's density into a mass with the sphere volume, even in 2D);
* spheres (the cone's pour, `dimension=3`): `dimension 3`, `boundary f f f`,
  `fix nve/sphere` (I = 2 m r^2 / 5), gravity along -z, no `enforce2d`.

Timings come from the "Loop time of T on P procs for N steps" lines of the log
(the integration only) and, separately, the whole process's wall time (start-up,
input parsing and set-up included).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

BINARY_ENV = "LAMMPS_BIN"
LOOP_LINE = re.compile(r"^Loop time of (\S+) on (\d+) procs for (\d+) steps with (\d+) atoms", re.M)
VERSION_LINE = re.compile(r"^LAMMPS \((.+?)\)", re.M)


# ------------------------------------------------------------------- binary
def find_binary() -> str | None:
    """The LAMMPS executable: `$LAMMPS_BIN`, else `lmp` (or lmp_serial, lmp_mpi) on the PATH."""
    env = os.environ.get(BINARY_ENV)
    if env:
        return shutil.which(env) or (env if os.access(env, os.X_OK) else None)
    for name in ("lmp", "lmp_serial", "lmp_mpi"):
        path = shutil.which(name)
        if path:
            return path
    return None


def mpi_launcher(binary: str, procs: int, workdir: str) -> tuple[list[str] | None, str]:
    """A working `mpirun -np procs` prefix and a note, or (None, why not).

    Tried with a one-line input: Open MPI refuses root without
    `--allow-run-as-root`, and more ranks than it counts as slots without
    `--oversubscribe`."""
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        return None, "mpirun not found"
    os.makedirs(workdir, exist_ok=True)
    probe = os.path.join(workdir, "probe.in")
    with open(probe, "w") as f:
        f.write("units lj\n")
    reason = ""
    for extra in ([], ["--allow-run-as-root", "--oversubscribe"]):
        cmd = [mpirun, *extra, "-np", str(procs)]
        try:
            done = subprocess.run([*cmd, binary, "-in", probe, "-log", "none", "-screen", "none"],
                                  cwd=workdir, capture_output=True, text=True, timeout=60)
        except (OSError, subprocess.TimeoutExpired) as err:
            reason = str(err)
            continue
        if done.returncode == 0:
            return cmd, " ".join(cmd[1:])
        reason = (done.stderr or done.stdout).strip().splitlines()[-1:] or [f"exit {done.returncode}"]
        reason = reason[0]
    return None, f"mpirun -np {procs} failed: {reason}"


# ---------------------------------------------------------------------- runs
@dataclass
class Run:
    """One LAMMPS process: its timings and where it ran."""

    workdir: str
    log: str
    wall_seconds: float = float("nan")
    loop_seconds: float = 0.0
    steps: int = 0
    procs: int = 1
    runs: int = 0
    atom_steps: float = 0.0
    version: str | None = None
    returncode: int | None = None
    error: str | None = None
    extra: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and self.error is None


def write_input(workdir: str, script: str, name: str = "in.lmp") -> str:
    os.makedirs(workdir, exist_ok=True)
    path = os.path.join(workdir, name)
    with open(path, "w") as f:
        f.write(script)
    return path


def start(binary: str, script: str, workdir: str, launcher: list[str] | None = None) -> tuple[subprocess.Popen, Run]:
    """Starts LAMMPS on `script` in `workdir` (created); `finish` waits for it."""
    path = write_input(workdir, script)
    log = os.path.join(workdir, "log.lammps")
    cmd = [*(launcher or []), binary, "-in", os.path.basename(path), "-log", "log.lammps", "-screen", "none"]
    run = Run(workdir=workdir, log=log)
    run.extra["t0"] = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=workdir, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, run


def finish(proc: subprocess.Popen, run: Run, timeout: float | None = None) -> Run:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        run.error = f"timed out after {timeout} s"
    run.wall_seconds = time.perf_counter() - run.extra.pop("t0")
    run.returncode = proc.returncode
    parse_log(run)
    if run.returncode != 0 and run.error is None:
        text = _read(run.log) + (out or "")
        errors = [line for line in text.splitlines() if "ERROR" in line]
        run.error = errors[-1] if errors else f"exit status {run.returncode}"
    return run


def run(binary: str, script: str, workdir: str, launcher: list[str] | None = None,
        timeout: float | None = None) -> Run:
    """Runs LAMMPS on `script` in `workdir` and waits: the `Run` with its timings."""
    return finish(*start(binary, script, workdir, launcher), timeout=timeout)


def run_concurrently(binary: str, jobs: list[tuple[str, str]], parallel: int = 2) -> tuple[list[Run], float]:
    """`(script, workdir)` jobs, at most `parallel` processes at a time.

    Returns the runs (in job order) and the wall time of the whole set."""
    t0 = time.perf_counter()
    pending = list(enumerate(jobs))
    active: list[tuple[int, subprocess.Popen, Run]] = []
    done: dict[int, Run] = {}
    while pending or active:
        while pending and len(active) < parallel:
            i, (script, workdir) = pending.pop(0)
            active.append((i, *start(binary, script, workdir)))
        for item in [a for a in active if a[1].poll() is not None]:
            active.remove(item)
            done[item[0]] = finish(item[1], item[2])
        time.sleep(0.002)
    return [done[i] for i in range(len(jobs))], time.perf_counter() - t0


def _read(path: str) -> str:
    try:
        with open(path, errors="replace") as f:
            return f.read()
    except OSError:
        return ""


def parse_log(run: Run) -> Run:
    """Fills the loop seconds and steps (summed over every `run` in the log), the
    process count and the version from the log header."""
    text = _read(run.log)
    loops = LOOP_LINE.findall(text)
    run.loop_seconds = sum(float(t) for t, *_ in loops)
    run.steps = sum(int(n) for _, _, n, _ in loops)
    run.runs = len(loops)
    run.atom_steps = sum(int(n) * int(a) for _, _, n, a in loops)  # disks x steps LAMMPS integrated
    if loops:
        run.procs = int(loops[0][1])
    match = VERSION_LINE.search(text)
    run.version = match.group(1) if match else None
    return run


def startup_seconds(binary: str, workdir: str, launcher: list[str] | None = None, repeat: int = 3) -> float:
    """Wall time of a LAMMPS process that reads a one-line input (process start-up
    alone): the median of `repeat` tries, as other work on the machine shifts it."""
    return float(np.median([run(binary, "units lj\n", workdir, launcher).wall_seconds for _ in range(repeat)]))


def open_race(workdir: str | None, prefix: str) -> tuple[str | None, str, str | None]:
    """`(binary, root, version)` of a race: the LAMMPS binary (None: jaxpile
    alone, said on stdout), the folder for its work files (`workdir`, or a
    new temporary one) and the LAMMPS version its log header gives."""
    binary = find_binary()
    root = workdir or tempfile.mkdtemp(prefix=prefix)
    os.makedirs(root, exist_ok=True)
    if binary is None:
        print(f"LAMMPS not found (no `lmp` on the PATH, ${BINARY_ENV} unset): jaxpile alone, LAMMPS fields null")
        return None, root, None
    version = run(binary, "units lj\n", os.path.join(root, "version")).version
    print(f"LAMMPS {version} ({binary}); work files in {root}")
    return binary, root, version


def run_cases(cases, chosen, args, binary: str | None, root: str, keep: bool) -> dict:
    """Runs each `(name, case)` of `cases` named in `chosen` (a case is
    `(args, binary, root) -> (result, table rows)`), removes `root` after
    unless `keep`, prints the table of rows, and returns `{"cases", "table",
    "total_seconds"}`."""
    out = {"cases": {}, "table": []}
    t0 = time.perf_counter()
    try:
        for name, case in cases:
            if name in chosen:
                out["cases"][name], rows = case(args, binary, root)
                out["table"] += rows
    finally:
        if not keep:
            shutil.rmtree(root, ignore_errors=True)
    out["total_seconds"] = time.perf_counter() - t0
    width = max([len(row["case"]) for row in out["table"]] + [4])
    print(f"\n{'case':{width}s} {'jaxpile':>9s} {'LAMMPS':>9s} {'ratio':>7s}")
    for row in out["table"]:
        lmp = "-" if row["lammps"] is None else f"{row['lammps']:.3g}"
        r = "-" if row["ratio"] is None else f"{row['ratio']:.3g}"
        print(f"{row['case']:{width}s} {row['jaxpile']:9.3g} {lmp:>9s} {r:>7s}")
    return out


# ------------------------------------------------------------------ files
def _num(x) -> str:
    # repr of a Python float round-trips; numpy scalars would print as np.float64(...)
    return repr(float(x))


def write_data(path: str, position, diameter, box) -> None:
    """A LAMMPS data file of disks or spheres (`Atoms # sphere`: id type diameter density x y z).

    Args:
      position: `[n, d]` centres (d = 2: disks in z = 0; d = 3: spheres); ids are 1..n in this order.
      diameter: `[n]`.
      box: ((xlo, xhi), (ylo, yhi)), and (zlo, zhi) for spheres.
    """
    position = np.asarray(position, float)
    diameter = np.broadcast_to(np.asarray(diameter, float), (len(position),))
    (xlo, xhi), (ylo, yhi), *z = box
    zlo, zhi = z[0] if z else (-0.5, 0.5)
    flat = np.zeros((len(position), 3))
    flat[:, :position.shape[1]] = position
    lines = ["jaxpile disks" if position.shape[1] == 2 else "jaxpile spheres", "", f"{len(position)} atoms",
             "1 atom types", "", f"{_num(xlo)} {_num(xhi)} xlo xhi", f"{_num(ylo)} {_num(yhi)} ylo yhi",
             f"{_num(zlo)} {_num(zhi)} zlo zhi", "", "Atoms # sphere", ""]
    # density 1: the mass is set afterwards with `set` (see the module notes)
    lines += [f"{i + 1} 1 {_num(d)} 1.0 {_num(x)} {_num(y)} {_num(zz)}" for i, ((x, y, zz), d) in
              enumerate(zip(flat, diameter))]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def mass_lines(mass, first_id: int = 1) -> list[str]:
    """`set` commands giving atoms first_id.. their masses (one line when all equal)."""
    mass = np.asarray(mass, float)
    if mass.size and np.all(mass == mass[0]):
        last = first_id + mass.size - 1
        return [f"set atom {first_id}*{last} mass {_num(mass[0])}"]
    return [f"set atom {first_id + i} mass {_num(m)}" for i, m in enumerate(mass)]


def read_dump(path: str, timestep: int | None = None) -> dict[str, np.ndarray]:
    """One snapshot of a `dump custom` file (the last, or the one at `timestep`),
    columns by name, sorted by id."""
    with open(path) as f:
        lines = f.read().splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith("ITEM: ATOMS")]
    steps = [int(lines[i + 1]) for i, line in enumerate(lines) if line.startswith("ITEM: TIMESTEP")]
    if timestep is not None:
        starts = [i for i, t in zip(starts, steps) if t == timestep]
    if not starts:
        raise ValueError(f"{path} holds no snapshot" + ("" if timestep is None else f" at step {timestep}") + ".")
    head = starts[-1]
    names = lines[head].split()[2:]
    rows = []
    for line in lines[head + 1:]:
        if line.startswith("ITEM:"):
            break
        if line.strip():
            rows.append(line.split())
    data = np.array(rows, float).reshape(len(rows), len(names))
    columns = {name: data[:, k] for k, name in enumerate(names)}
    order = np.argsort(columns["id"])
    return {name: col[order] for name, col in columns.items()}


# ---------------------------------------------------------------- commands
def hooke_coefficients(params) -> tuple[list[float], list[float]]:
    """(disk, wall) coefficient lists `kn kt gamma_n gamma_t mu` of jaxpile `hooke` params."""
    from jaxpile.laws import hooke

    names = ("kn", "kt", "gamma_n", "gamma_t", "mu")
    wall = hooke.wall_params(params)
    return [float(getattr(params, k)) for k in names], [float(getattr(wall, k)) for k in names]


def wall_lines(boundaries, wall_coefficients: list[float], ground_fix: str = "ground") -> list[str]:
    """`fix wall/gran` commands for jaxpile's active walls, read from their
    normals (a boundaries object may hold the ground alone, or the ground and
    two side-wall slots): the floor (normal +y) as a `yplane` fix with
    `contacts`, for the ground forces, and the side walls (normals +-x) as one
    `xplane` fix."""
    active = np.asarray(boundaries.wall_active, bool)
    normal = np.asarray(boundaries.wall_normal, float)
    offset = np.asarray(boundaries.wall_offset, float)
    coeffs = " ".join(_num(c) for c in wall_coefficients)
    floor, lo, hi = None, "NULL", "NULL"
    for on, (nx, ny), c in zip(active, normal, offset):
        if not on:
            continue
        if (nx, ny) == (0.0, 1.0):
            floor = c
        elif (nx, ny) == (1.0, 0.0):
            lo = _num(c)
        elif (nx, ny) == (-1.0, 0.0):
            hi = _num(-c)  # -x >= c: the wall stands at x = -c
        else:
            raise ValueError(f"LAMMPS wall/gran planes are axis-aligned; got a wall with normal ({nx}, {ny}).")
    lines = []
    if floor is not None:
        lines.append(f"fix {ground_fix} all wall/gran hooke/history {coeffs} 1 yplane {_num(floor)} NULL contacts")
    if (lo, hi) != ("NULL", "NULL"):
        lines.append(f"fix sides all wall/gran hooke/history {coeffs} 1 xplane {lo} {hi}")
    return lines


def _header(data_file: str, params, rotation: bool, skin: float, dimension: int = 2) -> list[str]:
    disk, _ = hooke_coefficients(params)
    return [
        "units lj",
        f"dimension {int(dimension)}",
        "atom_style sphere",
        "atom_modify map array",  # `set atom ID` on atoms created later
        "boundary f f p" if dimension == 2 else "boundary f f f",
        "comm_modify vel yes",  # granular pairs need the ghosts' velocities
        f"read_data {data_file}",
        f"neighbor {_num(skin)} bin",
        "neigh_modify delay 0 every 1 check yes",
        f"pair_style gran/hooke/history {' '.join(_num(c) for c in disk)} 1",
        "pair_coeff * *",
    ]


def _integrator(rotation: bool, dimension: int = 2) -> str:
    if not rotation:
        return "fix move all nve"
    return "fix move all nve/sphere disc" if dimension == 2 else "fix move all nve/sphere"


def _gravity(boundaries, magnitude: str) -> str:
    g = np.asarray(boundaries.gravity, float)
    norm = float(np.linalg.norm(g))
    direction = g / norm if norm > 0 else np.array([0.0, -1.0])
    return f"fix grav all gravity {magnitude} vector {_num(direction[0])} {_num(direction[1])} 0.0"


def ramp_pile_script(data_file: str, *, params, boundaries, mass, dt: float, ramp_steps: int, hold_steps: int,
                     rotation: bool, dump_file: str, skin: float = 0.2) -> str:
    """A pile loaded by jaxpile's `gravity_ramp(ramp_steps)`, then held at full
    gravity for `hold_steps`, then dumped with its ground forces to `dump_file`
    (`f_ground[1..3]`: contact flag, wall force x, y on the disk); positions
    and velocities every `ramp_steps` steps go to `ramp.dump`."""
    g = float(np.linalg.norm(np.asarray(boundaries.gravity, float)))
    _, wall = hooke_coefficients(params)
    lines = _header(data_file, params, rotation, skin) + mass_lines(mass)
    lines += wall_lines(boundaries, wall)
    lines += [
        _integrator(rotation),
        "fix flat all enforce2d",
        # u = min(step / R, 1) (LAMMPS has no min(); a comparison is 0 or 1). One run for
        # ramp and hold: a second `run` would re-evaluate the damping forces at its set-up
        # with the full-step velocities (a step uses the half-step ones), and that kick,
        # small as it is, grew to 3% of the 45-layer pile's base forces (5000 + 5000 steps)
        f'variable u equal "(step<{int(ramp_steps)})*step/{int(ramp_steps)}+(step>={int(ramp_steps)})"',
        f'variable g equal "{_num(g)}*v_u*v_u*(3.0-2.0*v_u)"',  # the C1 smoothstep of gravity_ramp
        _gravity(boundaries, "v_g"),
        f"timestep {_num(dt)}",
        "thermo 0",
        # positions every ramp_steps steps: the state at the ramp's end, before the
        # pile's sensitivity to round-off has had time to grow
        f"dump ramp all custom {int(ramp_steps)} ramp.dump id x y vx vy",
        "dump_modify ramp format float %.17g sort id",
        f"run {int(ramp_steps) + int(hold_steps)}",
        "undump ramp",
        f"dump out all custom 1 {dump_file} id mass radius x y vx vy fx fy f_ground[1] f_ground[2] f_ground[3]",
        "dump_modify out format float %.17g sort id",
        "run 0",
    ]
    return "\n".join(lines) + "\n"


def ground_forces(dump: dict[str, np.ndarray], gravity: float = 1.0):
    """(x, N, H) of the disks touching the ground, sorted by x, in mg, with
    jaxpile's conventions (`analysis.base_forces`): N the ground's upward force
    on the disk, H the horizontal force the disk exerts on the ground."""
    touching = dump["f_ground[1]"] > 0
    unit = float(np.mean(dump["mass"])) * gravity  # jaxpile's force unit: the mean mass times g
    x = dump["x"][touching]
    order = np.argsort(x)
    return x[order], dump["f_ground[3]"][touching][order] / unit, -dump["f_ground[2]"][touching][order] / unit


def pour_script(data_file: str, *, params, rotation: bool, mass, fixed_ids: int, releases, interval: int,
                settle_steps: int, dt: float, gravity: float, dump_file: str, setup_each: bool = True,
                skin: float = 0.2, dimension: int = 2) -> str:
    """jaxpile's pour (`protocols.pour`, or the cone's in 3D) replayed: disks
    or spheres created one by one.

    The data file holds the substrate or plate (ids 1..fixed_ids, frozen).
    Particle k of `releases` (x, y, vx, vy, diameter, mass; in 3D x, y, z, vx,
    vy, vz, diameter, mass) is created at step k * interval at its release
    point with its release velocity, then the run goes on for `interval`
    steps; after the last one, `settle_steps` more. Gravity is along -y (2D)
    or -z (3D). A particle that leaves the box (below jaxpile's `lost_below`)
    is deleted, as jaxpile parks it (`thermo_modify lost ignore`).

    Args:
      setup_each: `pre yes` on every segment (the set-up LAMMPS asks for when
        atoms were added between runs); False runs `pre no`, which skips the
        neighbour build and relies on the next distance check to pick the new
        particle up.
    """
    lines = _header(data_file, params, rotation, skin, dimension) + mass_lines(mass)
    down = "0.0 -1.0 0.0" if dimension == 2 else "0.0 0.0 -1.0"
    lines += [
        f"group base id 1:{int(fixed_ids)}",
        # two frozen particles exert nothing on each other: no pair for them, as jaxpile lists none
        "neigh_modify exclude group base base",
        _integrator(rotation, dimension),
        *(["fix flat all enforce2d"] if dimension == 2 else []),
        f"fix grav all gravity {_num(gravity)} vector {down}",
        "fix frozen base freeze",  # after gravity: zeroes the substrate's force
        f"timestep {_num(dt)}",
        "thermo 0",
        "thermo_modify lost ignore",
    ]
    pre = "yes" if setup_each else "no"
    for k, release in enumerate(releases):
        ident = int(fixed_ids) + k + 1  # create_atoms gives the next id
        if dimension == 2:
            x, y, vx, vy, d, m = release
            z, vz = 0.0, None
        else:
            x, y, z, vx, vy, vz, d, m = release
        speed = f"vx {_num(vx)} vy {_num(vy)}" + ("" if vz is None else f" vz {_num(vz)}")
        lines += [f"create_atoms 1 single {_num(x)} {_num(y)} {_num(z)} units box",
                  f"set atom {ident} diameter {_num(d)} mass {_num(m)} {speed}",
                  f"run {int(interval)} pre {'yes' if k == 0 else pre} post no"]
    columns = "id mass radius x y vx vy" if dimension == 2 else "id mass radius x y z vx vy vz"
    lines += [f"run {int(settle_steps)} pre {pre} post no",
              f"dump out all custom 1 {dump_file} {columns}",
              "dump_modify out format float %.17g sort id",
              "run 0"]
    return "\n".join(lines) + "\n"
