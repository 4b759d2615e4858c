"""One line naming the machine a benchmark ran on (the README table's first column)."""

from __future__ import annotations

import os
import platform

import jax


def describe() -> str:
    """CPU model and core count, and the JAX backend with its device count and kind."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            model = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    device = jax.devices()[0]
    kind = "" if jax.default_backend() == "cpu" else f" {device.device_kind}"
    return f"{model}, {os.cpu_count()} cores; jax {jax.__version__} {jax.default_backend()} x{jax.device_count()}{kind}"
