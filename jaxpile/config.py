"""What jaxpile asks of JAX and XLA, set by one call: `jaxpile.configure()`.

`import jaxpile` changes nothing in JAX, XLA or the environment. The commands
(`jaxpile pile`, `sweep`, `fit`) call `configure` before anything runs, and a
script that calls it first, right after `import jaxpile`, runs exactly as they
do: the same seed gives the same result, bit for bit.

What it sets:

- **float64** (`jax_enable_x64`): static force analysis with stiff springs
  (mg / (k sigma) = 1e-4) needs it, and a pile in float64 is refused without it
  (`make_particles` says so in one line). Arrays made as float32 stay float32,
  so a large dynamic run can still use single precision.
- On a CPU, XLA settings that XLA reads once, when JAX first compiles (so call
  `configure` before any JAX computation; afterwards they are left as they are,
  with a warning):
  - 512-bit vectors (`--xla_cpu_prefer_vector_width=512`): XLA vectorises at
    256 bits by default even where the CPU has 512-bit registers; the step's
    kernels are elementwise over pairs and disks, so wider vectors pay (same
    arithmetic, same bits; docs/performance.md#vector-width);
  - XLA:CPU's multi-output fusion: one fusion computes a law's shared
    arithmetic once for the force, its two scatters and the new history, where
    XLA would otherwise copy it into each (the law runs three to five times a
    step without it; docs/performance.md#multi-output-fusion). It changes
    results at round-off, which a pile's dynamics then grow, hence one setting
    for commands and scripts. `multi_output_fusion=False` leaves it off: XLA's
    newer emitters abort the process compiling a multi-output fusion of some
    scatter-adds, such as those of the derivative of `jnp.interp` on traced
    values; a loss of your own that holds one needs it off (jaxpile's own
    losses hold none);
  - one XLA thread per process (`PJRT_NPROC=1`) unless `threads=True`: one
    small pile's kernels (a few microseconds each) cost more to split than they
    save (docs/performance.md#why-one-thread-per-pile-on-a-cpu); a batch's, or
    one pile's from about 2000 disks, are large enough. Threads never change results;
  - `host_devices=N` (or `JAXPILE_HOST_DEVICES=N` in the environment): the host
    split into N JAX devices, one core each, over which `Ensemble` and sweeps
    shard a batch. The device count changes results at round-off.

A setting already in the environment wins (`XLA_FLAGS`, `PJRT_NPROC`), and
`JAXPILE_MULTI_OUTPUT_FUSION=0` (or 1) decides the fusion for the commands too.
`settings()` is what is in force; every summary.json, sweep.json and fit.json
records it, and a resume or a comparison of runs made under other settings says so.
"""

from __future__ import annotations

import os
import warnings

import jax

_VECTOR_WIDTH = "--xla_cpu_prefer_vector_width=512"
_MULTI_OUTPUT_FUSION = "--xla_backend_extra_options=xla_cpu_use_multi_output_fusion"
_HOST_DEVICES_ENV = "JAXPILE_HOST_DEVICES"
_FUSION_ENV = "JAXPILE_MULTI_OUTPUT_FUSION"

RESULT_SETTINGS = ("float64", "multi_output_fusion", "fusion_emitters", "optimization_level", "devices")
"""The settings that change a run's numbers (at round-off, which dynamics grow):
two runs compare bit for bit only where these agree. Threads and the vector
width do not change them."""


def _flags() -> str:
    return os.environ.get("XLA_FLAGS", "")


def _add_flag(flag: str) -> None:
    os.environ["XLA_FLAGS"] = (_flags() + " " + flag).strip()


def backend_started() -> bool:
    """Whether JAX has made its backends (after which XLA_FLAGS, PJRT_NPROC and
    the host device count are read and fixed for the process)."""
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # where JAX has moved it: assume not, as a fresh process
        return False


def multi_output_fusion_on() -> bool:
    """Whether XLA_FLAGS asks XLA:CPU for its multi-output fusion (jaxpile's
    flag or a user's own xla_backend_extra_options holding the option)."""
    return "xla_cpu_use_multi_output_fusion" in _flags()


def configure(*, float64: bool = True, multi_output_fusion: bool = True, threads: bool = False,
              host_devices: int | None = None) -> dict:
    """Sets what the commands set (see the module's docstring) and returns `settings()`.

    Call it right after `import jaxpile`, before any JAX computation: XLA reads
    its flags when it first compiles. Called later, the float64 switch still
    applies (to arrays made after it) and the XLA settings are left as JAX
    already has them, with a warning.

        import jaxpile as jp
        jp.configure()          # float64, and the commands' XLA settings

    Args:
      float64: turn on JAX's float64 (`jax_enable_x64`).
      multi_output_fusion: XLA:CPU's multi-output fusion (off: a loss of your
        own that holds `jnp.interp`'s derivative). `JAXPILE_MULTI_OUTPUT_FUSION`
        in the environment (0 or 1) wins.
      threads: XLA's own thread count on a CPU instead of one thread
        (a batch, or one pile of ~2000 disks or more). `PJRT_NPROC` in the environment wins.
      host_devices: split the host into this many JAX devices (default:
        `JAXPILE_HOST_DEVICES`, else one).
    """
    if float64:
        jax.config.update("jax_enable_x64", True)
    wanted = {"vector_width": "xla_cpu_prefer_vector_width" not in _flags()}
    fusion = {"0": False, "1": True}.get(os.environ.get(_FUSION_ENV, ""), multi_output_fusion)
    wanted["fusion"] = fusion and not multi_output_fusion_on() and "xla_backend_extra_options" not in _flags()
    wanted["one_thread"] = not threads and "PJRT_NPROC" not in os.environ
    devices = host_devices if host_devices is not None else os.environ.get(_HOST_DEVICES_ENV)
    if not any(wanted.values()) and devices is None:
        return settings()
    if backend_started():
        if any(wanted.values()) or devices is not None:
            warnings.warn("jaxpile.configure() came after JAX had run: XLA's flags, its thread count and the host "
                          "devices stay as JAX set them (call it right after `import jaxpile`); float64 is on.",
                          stacklevel=2)
        return settings()
    if wanted["vector_width"]:
        _add_flag(_VECTOR_WIDTH)
    if wanted["fusion"]:
        _add_flag(_MULTI_OUTPUT_FUSION)
    if wanted["one_thread"]:
        os.environ["PJRT_NPROC"] = "1"
    if devices is not None:
        try:
            count = int(devices)
            if count < 1:
                raise ValueError("not a positive count")
            jax.config.update("jax_num_cpu_devices", count)
        except (RuntimeError, ValueError) as error:  # not a number, or JAX already running: say so, carry on
            warnings.warn(f"host_devices={devices!r} ignored: {error}", stacklevel=2)
    return settings()


def _flag_value(name: str) -> str | None:
    """The value of `--name=value` in XLA_FLAGS (the last one), or None."""
    value = None
    for token in _flags().split():
        if token.startswith(f"--{name}="):
            value = token.split("=", 1)[1]
    return value


def settings() -> dict:
    """The settings in force, as runs record them: float64, XLA:CPU's
    multi-output fusion, whether it uses its newer fusion emitters, its
    optimisation level (None: XLA's default), the vector width, the XLA thread
    count (None: XLA's own), and the JAX device count once JAX has started
    (None before: counting would start it)."""
    emitters = _flag_value("xla_cpu_use_fusion_emitters")
    level = _flag_value("xla_backend_optimization_level")
    width = _flag_value("xla_cpu_prefer_vector_width")
    threads = os.environ.get("PJRT_NPROC")
    return {
        "float64": bool(jax.config.jax_enable_x64),
        "multi_output_fusion": multi_output_fusion_on(),
        "fusion_emitters": emitters is None or emitters.lower() not in ("false", "0"),
        "optimization_level": None if level is None else int(level),
        "vector_width": None if width is None else int(width),
        "xla_threads": None if threads is None else int(threads),
        "devices": jax.device_count() if backend_started() else None,
    }


def differences(recorded: dict | None, current: dict | None = None) -> list[str]:
    """The result-changing settings (`RESULT_SETTINGS`) in which a run's
    recorded settings differ from `current` (default: `settings()`), as
    'name: recorded -> current'; empty when they agree or the record has none."""
    if not recorded:
        return []
    current = settings() if current is None else current
    return [f"{k}: {recorded[k]} -> {current.get(k)}" for k in RESULT_SETTINGS
            if k in recorded and recorded[k] != current.get(k)
            and not (k == "devices" and None in (recorded[k], current.get(k)))]


__all__ = ["RESULT_SETTINGS", "backend_started", "configure", "differences", "multi_output_fusion_on", "settings"]
