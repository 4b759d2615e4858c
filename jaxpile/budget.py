"""Will a run fit in this machine's memory? An estimate made before anything
is allocated, so that a run too big is refused at once, with both numbers.

The estimate is per disk and linear in the disk count: the state (positions,
velocities, the contact history, the neighbour list) plus XLA's temporaries of
the compiled step, as `benchmarks/scaling.py` measures them (`make bench`;
`compiled.memory_analysis()`), flat in N (measured:
docs/choices.md#memory-per-disk). We add a quarter for
what the measurement does not see (the neighbour list re-allocated larger, the
host-side set-up and measurement arrays) and a fixed allowance for JAX itself.
"""

from __future__ import annotations

import math
import numbers
import os

from jaxpile.errors import InputError

MEASURED_BYTES_PER_DISK = {"float64": 258 + 995, "float32": 154 + 879}
"""State + XLA temporaries per disk, the largest of `make bench`'s scaling rows
(docs/choices.md#memory-per-disk)."""

HEADROOM = 1.25
"""Factor on the measured figure for what it does not see (a larger re-allocated
list, host copies of the set-up and of the results)."""

HOST_BYTES_PER_DISK = 300
"""Host-side arrays per disk: the numpy set-up, the measurements' copies."""

FIXED_BYTES = 600 * 2**20
"""JAX, XLA and the compiled programs themselves, independent of the disk count."""

USABLE_FRACTION = 0.85
"""The share of the available memory a run may plan to use."""


def _precision_name(precision) -> str:
    name = getattr(precision, "__name__", None) or getattr(precision, "name", None) or str(precision)
    name = str(name).replace("jnp.", "").replace("numpy.", "")
    if name not in MEASURED_BYTES_PER_DISK:
        raise InputError(f"precision must be float32 or float64; got {precision!r}.")
    return name


def bytes_per_disk(precision="float64") -> float:
    """Estimated bytes per disk of a run in `precision` (see the module docstring)."""
    return MEASURED_BYTES_PER_DISK[_precision_name(precision)] * HEADROOM + HOST_BYTES_PER_DISK


def estimate(disks: int, precision="float64", batch: int = 1) -> int:
    """Estimated peak memory (bytes) of a run of `batch` piles of `disks` disks."""
    return int(FIXED_BYTES + int(batch) * int(disks) * bytes_per_disk(precision))


def available() -> tuple[int, str]:
    """`(bytes, where)`: the memory a run may use on the default device: a GPU's
    free memory from its own statistics, else the host's available memory
    (`MemAvailable` in /proc/meminfo, or the free physical pages)."""
    try:
        import jax

        device = jax.devices()[0]
        if device.platform != "cpu":
            stats = device.memory_stats() or {}
            if "bytes_limit" in stats:
                return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0)), f"{device.device_kind} memory"
    except Exception:  # no backend yet or no statistics: fall back to the host
        pass
    return host_available()


def host_available() -> tuple[int, str]:
    """`(bytes, where)`: the host's available memory (what numpy may allocate):
    `MemAvailable` in /proc/meminfo, or the free physical pages."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024, "available host memory"
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"), "free host memory"
    except (ValueError, OSError, AttributeError):
        return 2**63 - 1, "memory (unknown on this system)"


def _size(b: float) -> str:
    for unit, scale in (("TB", 2**40), ("GB", 2**30), ("MB", 2**20), ("kB", 2**10)):
        if b >= scale:
            return f"{b / scale:.1f} {unit}"
    return f"{b:.0f} B"


def largest(precision="float64", batch: int = 1, memory: int | None = None) -> int:
    """The largest disk count per pile whose estimate fits `memory` (default: available())."""
    memory = available()[0] if memory is None else memory
    room = USABLE_FRACTION * memory - FIXED_BYTES
    return max(0, int(room // (int(batch) * bytes_per_disk(precision))))


def check(disks, precision="float64", batch: int = 1, what: str = "the run") -> int:
    """Raises `InputError`, before anything is allocated, when `batch` piles of
    `disks` disks would not fit in this machine's memory; returns the estimate.

    The message names the estimate, the memory there is and the largest disk
    count that would fit."""
    if not (isinstance(disks, numbers.Real) and math.isfinite(disks)):  # numpy integers too
        return 0  # not a count: the set-up's own validation says so
    need = estimate(int(disks), precision, batch)
    memory, where = available()
    if need > USABLE_FRACTION * memory:
        fit = largest(precision, batch, memory)
        members = f"{batch} x " if batch > 1 else ""
        raise InputError(
            f"{what} of {members}{int(disks):,} disks ({_precision_name(precision)}) needs about {_size(need)} "
            f"(~{bytes_per_disk(precision) / 1024:.1f} kB per disk: state, neighbour list, XLA temporaries); "
            f"this machine has {_size(memory)} of {where}. At most {fit:,} disks"
            f"{' per member' if batch > 1 else ''} would fit.")
    return need


def check_host(need: float, what: str, advice: str = "") -> None:
    """Raises `InputError`, before anything is allocated, when a host array of
    about `need` bytes (`what`) would not fit in the host's memory; `advice`
    says how to make it smaller."""
    memory, where = host_available()
    if not need <= USABLE_FRACTION * memory:  # NaN or inf too
        size = f"about {_size(need)}" if math.isfinite(need) else "more memory than can be counted"
        raise InputError(f"{what} needs {size}; this machine has {_size(memory)} of {where}."
                         f"{' ' + advice if advice else ''}")


def describe(disks: int, precision="float64", batch: int = 1) -> str:
    """One line for `--dry-run`: the estimate against the memory there is."""
    memory, where = available()
    need = estimate(disks, precision, batch)
    return (f"memory: about {_size(need)} needed ({bytes_per_disk(precision) / 1024:.1f} kB per disk), "
            f"{_size(memory)} of {where}; at most {largest(precision, batch, memory):,} disks"
            f"{' per member' if batch > 1 else ''} would fit")
