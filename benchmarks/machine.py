"""One line naming the machine a benchmark ran on (the first column of the benchmark table in docs/performance.md)."""

from __future__ import annotations

import os
import platform

import jax


def vector_isa(flags: set[str]) -> str | None:
    """The widest x86 vector instructions in a CPU's flags: "AVX-512", "AVX2",
    or None (another architecture, or flags unknown)."""
    if "avx512f" in flags:
        return "AVX-512"
    if "avx2" in flags:
        return "AVX2"
    return None


def details() -> dict:
    """CPU model, its widest vector instructions and core count, the JAX
    backend and its devices. The model alone does not name the machine: the
    same "AMD EPYC" VM ran the 45-layer lattice at 1.18e7 particle-steps/s with
    AVX-512 (XLA vectorises at 512 bits, `jaxpile/__init__.py`) and 4.0-4.8e6
    without it (2026-11-27), LAMMPS's Debian build 9.3e6 and 6.1-6.8e6."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as f:
            lines = f.read().splitlines()
        model = next(line.split(":", 1)[1].strip() for line in lines if line.startswith("model name"))
        flags = set(next((line.split(":", 1)[1].split() for line in lines if line.startswith("flags")), []))
    except (OSError, StopIteration):
        pass
    return {"processor": model, "vector_isa": vector_isa(flags), "cpu_count": os.cpu_count(),
            "jax_version": jax.__version__, "jax_backend": jax.default_backend(),
            "jax_device_count": jax.device_count(), "device_kind": jax.devices()[0].device_kind}


def describe() -> str:
    """`details` in one line."""
    d = details()
    kind = "" if d["jax_backend"] == "cpu" else f" {d['device_kind']}"
    isa = f" ({d['vector_isa']})" if d["vector_isa"] else ""
    return (f"{d['processor']}{isa}, {d['cpu_count']} cores; jax {d['jax_version']} {d['jax_backend']} "
            f"x{d['jax_device_count']}{kind}")
