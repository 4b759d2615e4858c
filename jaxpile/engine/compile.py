"""XLA compile options by kind of program.

Derivative programs (a gradient or Jacobian through a rollout) compile with
XLA:CPU's older fusion emitters, where a forward run keeps XLA's default:
the newer emitters make the forward step faster and its derivatives slower
(measured, 55-disk frictional pile, 1000 steps, one CPU thread: forward 9.5
against 13.0 ms; checkpointed reverse 72 against 61 ms; forward mode over
three parameters 80 against 47 ms; `benchmarks/gradient_cost.py`). The
option exists on the CPU backend only, and a flag the user set in XLA_FLAGS
wins.
"""

from __future__ import annotations

import os

import jax

_FLAG = "xla_cpu_use_fusion_emitters"


def derivative_options() -> dict:
    """`compiler_options` for `jax.jit` of a derivative program: the older
    fusion emitters on a CPU, nothing elsewhere or when XLA_FLAGS sets them."""
    if jax.default_backend() != "cpu" or _FLAG in os.environ.get("XLA_FLAGS", ""):
        return {}
    return {_FLAG: False}


def jit_derivative(fn, **kwargs):
    """`jax.jit(fn)` compiled with `derivative_options()`."""
    return jax.jit(fn, compiler_options=derivative_options() or None, **kwargs)


__all__ = ["derivative_options", "jit_derivative"]
