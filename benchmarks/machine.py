"""One line naming the machine a benchmark ran on (the README table's first column)."""

from __future__ import annotations

import os
import platform

import jax


def details() -> dict:
    """CPU model and core count, the JAX backend and its devices."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            model = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"processor": model, "cpu_count": os.cpu_count(), "jax_version": jax.__version__,
            "jax_backend": jax.default_backend(), "jax_device_count": jax.device_count(),
            "device_kind": jax.devices()[0].device_kind}


def describe() -> str:
    """`details` in one line."""
    d = details()
    kind = "" if d["jax_backend"] == "cpu" else f" {d['device_kind']}"
    return (f"{d['processor']}, {d['cpu_count']} cores; jax {d['jax_version']} {d['jax_backend']} "
            f"x{d['jax_device_count']}{kind}")
