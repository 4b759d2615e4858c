"""XLA compile options by kind of program.

Programs a pile runs once (its start, the contact forces a measurement reads)
compile at LLVM level 0 when the pile is small (`ONE_OFF_MAX_DISKS`): their
compile time is then most of their cost.

Derivative programs (a gradient or Jacobian through a rollout) compile with
XLA:CPU's older fusion emitters, where a forward run keeps XLA's default:
the newer emitters make the forward step faster and its derivatives slower.
With XLA:CPU's multi-output fusion on (`jaxpile.configure`, as
`jaxpile pile`, `sweep` and `fit` run) the newer emitters are the faster for
derivatives too and the older ones make a reverse gradient many times slower,
so derivatives keep XLA's default there (measured:
docs/choices.md#fusion-emitters-for-derivatives). The option exists on the
CPU backend only, and a flag the user set in XLA_FLAGS wins.
"""

from __future__ import annotations

import os

import jax

_FLAG = "xla_cpu_use_fusion_emitters"
_MULTI_OUTPUT_FUSION = "xla_cpu_use_multi_output_fusion"  # as jaxpile.config.multi_output_fusion_on reads it (the
# engine imports nothing from the package's top, tests/test_layers.py)


def derivative_options() -> dict:
    """`compiler_options` for `jax.jit` of a derivative program: the older
    fusion emitters on a CPU without multi-output fusion; nothing with it,
    elsewhere, or when XLA_FLAGS sets them."""
    flags = os.environ.get("XLA_FLAGS", "")
    if jax.default_backend() != "cpu" or _FLAG in flags or _MULTI_OUTPUT_FUSION in flags:
        return {}
    return {_FLAG: False}


def jit_derivative(fn, **kwargs):
    """`jax.jit(fn)` compiled with `derivative_options()`."""
    return jax.jit(fn, compiler_options=derivative_options() or None, **kwargs)


ONE_OFF_MAX_DISKS = 2_000
"""Programs a pile runs once (its start: the forces at t = 0 and the
integrator's preparation; the contact forces a measurement reads) compile at
LLVM optimisation level 0 for piles of up to this many disks: up to here a
call's slower run costs less than the compile time it saves (measured:
docs/choices.md#one-off-programs-at-optimisation-level-0). Level 0 can
round differently from the default in the last bit (the 36-disk agitated
pile's start forces: up to 6e-15 relative, `tests/test_engine.py`); a pile and
an ensemble member of the same size start at the same level (`Ensemble.init`
picks by the member's disks), so a member still starts exactly as it does
alone; a batch's start then runs at level 0 over all its members' disks,
which for a large batch costs more than the compile it saves (estimated on
the same page)."""

_LEVEL = "xla_backend_optimization_level"


def one_off_options(disks: int) -> dict | None:
    """`compiler_options` for a program run once per pile (see
    `ONE_OFF_MAX_DISKS`): level 0 up to that size on a CPU (measured there
    only), else (or when XLA_FLAGS sets the level) XLA's default."""
    if disks > ONE_OFF_MAX_DISKS or jax.default_backend() != "cpu" or _LEVEL in os.environ.get("XLA_FLAGS", ""):
        return None
    return {_LEVEL: 0}


def jit_one_off(fn, **kwargs):
    """`fn` jitted as `one_off_options` says, called as `run(disks, *args)`
    with the pile's disk count first; `run.program(disks, *args)` is the
    jitted function it calls. Under a trace (inside another jit, a grad) it
    is XLA's default jit: compile options belong to the outermost program only."""
    large = jax.jit(fn, **kwargs)
    small = []  # made at the first small pile: deciding needs the backend, which import must not start

    def program(disks: int, *args):
        if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(args)):
            return large
        options = one_off_options(disks)
        if options is None:
            return large
        if not small:
            small.append(jax.jit(fn, compiler_options=options, **kwargs))
        return small[0]

    def run(disks: int, *args):
        return program(disks, *args)(*args)

    run.program = program
    return run


__all__ = ["ONE_OFF_MAX_DISKS", "derivative_options", "jit_derivative", "jit_one_off", "one_off_options"]
