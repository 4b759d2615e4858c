"""jaxpile: a differentiable, vectorised 2D granular (DEM) simulator in JAX.

Importing jaxpile turns on float64 in JAX (`jax_enable_x64`): static force
analysis with stiff springs (mg / (k sigma) = 1e-4) needs it. Arrays created as
float32 stay float32, so large dynamic runs can still use single precision.

On a CPU, one pile runs on one core: jaxpile sets `PJRT_NPROC=1` (unless the
environment sets it), which gives XLA's CPU client one thread for the work
inside a step. The step's kernels are small (a few microseconds each), and
splitting them over threads costs more than it saves (measured:
docs/performance.md#why-one-thread-per-pile-on-a-cpu).

A batch uses the cores another way: `JAXPILE_HOST_DEVICES=N` in the
environment splits the host into N JAX devices before anything runs
(`jax_num_cpu_devices`), and `Ensemble` and `jaxpile sweep` shard a batch over
them, one core each (a single pile in such a process is slower). Without it,
`jaxpile sweep` and `jaxpile fit`, which run batches, give XLA back its own
thread count: a batch's kernels are large enough to split. So are one large
pile's from about 2000 disks, and `jaxpile pile --n N` gives XLA its threads
for N >= 2000 (`cli.THREADED_PILE_DISKS`); from Python, set `PJRT_NPROC` to
the core count before `import jaxpile` for such a pile.
Threads never change results (the same rows bit for bit); the device count
does, at round-off, so it is the user's choice.
"""

import os as _os
import warnings as _warnings

# XLA on a CPU vectorises at 256 bits by default even where the CPU has 512-bit
# registers (AVX-512); the step's kernels are elementwise over pairs and disks,
# so wider vectors pay (measured: docs/performance.md#vector-width). Same
# arithmetic, same results bit for bit; CPUs without AVX-512 ignore it. Read
# when JAX first compiles, so a flag the user set wins and a JAX already
# compiling before `import jaxpile` keeps its own.
if "xla_cpu_prefer_vector_width" not in _os.environ.get("XLA_FLAGS", ""):
    _os.environ["XLA_FLAGS"] = (_os.environ.get("XLA_FLAGS", "") + " --xla_cpu_prefer_vector_width=512").strip()

# XLA:CPU fuses a producer into each of its consumers, copying it, unless its
# multi-output fusion is on: then one fusion computes a shared chain once and
# writes every output it feeds. A contact law's arithmetic feeds the force, its
# two scatters and the new history, so without it the law runs three to five
# times a step (measured: docs/performance.md#multi-output-fusion).
# It is not on by default in Python: XLA's newer fusion emitters abort the
# process ("Check failed: GetNumDims() == other.GetNumResults()") on a
# multi-output fusion of some scatter-adds, such as the two that the
# derivative of `jnp.interp` makes, and a user's own loss may hold one. jaxpile's
# own losses hold none (`fit.profile_loss` reads a profile by a select, not
# `jnp.interp`), so the commands turn it on: `jaxpile pile`, `sweep` and `fit`
# (`use_multi_output_fusion`), and a derivative program then compiles with the
# newer emitters too (`engine.compile`: with the older ones the fusion makes a
# reverse gradient far slower). JAXPILE_MULTI_OUTPUT_FUSION=1 turns it on for a
# whole process, =0 keeps it off, commands included. A user's own
# xla_backend_extra_options wins.
_MULTI_OUTPUT_FUSION_FLAG = "--xla_backend_extra_options=xla_cpu_use_multi_output_fusion"


def multi_output_fusion_on() -> bool:
    """Whether XLA_FLAGS asks XLA:CPU for its multi-output fusion (jaxpile's
    flag or a user's own xla_backend_extra_options holding the option)."""
    return "xla_cpu_use_multi_output_fusion" in _os.environ.get("XLA_FLAGS", "")


def use_multi_output_fusion() -> bool:
    """Turns XLA:CPU's multi-output fusion on for this process (see above),
    unless JAXPILE_MULTI_OUTPUT_FUSION=0 or XLA_FLAGS already sets
    xla_backend_extra_options. Read when JAX first compiles: call it before any
    JAX computation. Returns whether the flag is in XLA_FLAGS now."""
    if multi_output_fusion_on():
        return True
    flags = _os.environ.get("XLA_FLAGS", "")
    if _os.environ.get("JAXPILE_MULTI_OUTPUT_FUSION") == "0" or "xla_backend_extra_options" in flags:
        return False
    _os.environ["XLA_FLAGS"] = (flags + " " + _MULTI_OUTPUT_FUSION_FLAG).strip()
    return True


if _os.environ.get("JAXPILE_MULTI_OUTPUT_FUSION") == "1":
    use_multi_output_fusion()

# One thread for XLA's CPU client (see the docstring; read when the CPU client
# is made, so a value the user set wins and a JAX already running keeps its own).
_ONE_THREAD_BY_DEFAULT = "PJRT_NPROC" not in _os.environ
_os.environ.setdefault("PJRT_NPROC", "1")


def use_xla_threads() -> bool:
    """Gives XLA's CPU client its own thread count where `import jaxpile` set
    one thread (the user had not set PJRT_NPROC): a batch's kernels, or one
    large pile's, are large enough to split. Read when JAX makes its CPU client,
    so it only acts before JAX has run anything; threads do not change results.
    Returns whether it acted."""
    global _ONE_THREAD_BY_DEFAULT
    if not _ONE_THREAD_BY_DEFAULT or _os.environ.get("PJRT_NPROC") != "1":
        return False
    del _os.environ["PJRT_NPROC"]
    _ONE_THREAD_BY_DEFAULT = False
    return True


import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
if _os.environ.get("JAXPILE_HOST_DEVICES"):
    try:
        jax.config.update("jax_num_cpu_devices", int(_os.environ["JAXPILE_HOST_DEVICES"]))
    except (RuntimeError, ValueError) as _error:  # JAX already running, or not a number: say so, carry on
        _warnings.warn(f"JAXPILE_HOST_DEVICES={_os.environ['JAXPILE_HOST_DEVICES']!r} ignored: {_error}",
                       stacklevel=2)

from jaxpile.engine import _jax_md  # noqa: E402

_jax_md.register()  # jax-md's neighbour lists without the rest of jax-md's slow import (see _jax_md)

from jaxpile import fit, laws, protocols, sweep  # noqa: E402
from jaxpile.measure import analysis, theory
from jaxpile.engine import boundaries, ensemble
from jaxpile.engine.boundaries import make_boundaries, set_wall  # noqa: E402
from jaxpile.errors import InputError, SimulationError  # noqa: E402
from jaxpile.engine.simulate import RunInfo, Simulator, make_step, max_speed  # noqa: E402
from jaxpile.engine.state import Boundaries, Contacts, Particles, SimState, make_particles  # noqa: E402

from jaxpile._version import __version__  # noqa: E402

__all__ = [
    "Boundaries",
    "Contacts",
    "InputError",
    "Particles",
    "RunInfo",
    "SimState",
    "SimulationError",
    "Simulator",
    "analysis",
    "boundaries",
    "ensemble",
    "fit",
    "laws",
    "make_boundaries",
    "make_particles",
    "make_step",
    "max_speed",
    "protocols",
    "set_wall",
    "sweep",
    "theory",
]
