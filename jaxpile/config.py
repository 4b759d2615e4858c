"""What jaxpile asks of JAX and XLA, set by one call: `jaxpile.configure()`.

`import jaxpile` changes nothing in JAX, XLA or the environment. The commands
(`jaxpile pile`, `sweep`, `fit`) call `configure` before anything runs, and a
script that calls it first, right after `import jaxpile`, runs exactly as they
do: the same seed gives the same result, bit for bit.

What it sets:

- **float64** (`jax_enable_x64`): static force analysis with stiff springs
  (mg / (k sigma) = 1e-4) needs it, and a pile in float64 is refused without it
  (`make_particles` says so in one line). Arrays made as float32 stay float32.
- On a CPU, XLA settings that XLA reads once, when JAX first compiles (so call
  `configure` before any JAX computation; afterwards they are left as they are,
  with a warning):
  - 512-bit vectors (`--xla_cpu_prefer_vector_width=512`, XLA's default being
    256 bits even on 512-bit CPUs): the step's kernels are elementwise over pairs
    and disks, so wider vectors pay, with the same bits
    (docs/choices.md#vector-width);
  - XLA:CPU's multi-output fusion: one fusion computes a law's shared arithmetic
    once for the force, its two scatters and the new history, where XLA would
    otherwise repeat it in each (docs/choices.md#multi-output-fusion). It moves
    results at round-off, hence one setting for commands and scripts.
    `multi_output_fusion=False` leaves it off, as a loss of your own needs if it
    holds scatter-adds such as the derivative of `jnp.interp` on traced values
    (XLA's newer emitters abort compiling them fused; jaxpile's losses hold none);
  - one XLA thread per process (`PJRT_NPROC=1`) unless `threads=True`: a small
    pile's kernels cost more to split than they save; a batch's, or one pile's
    from about 2000 disks, are large enough
    (docs/choices.md#why-one-thread-per-pile-on-a-cpu). Threads never change results;
  - `host_devices=N` (or `JAXPILE_HOST_DEVICES=N`): the host split into N JAX
    devices, one core each, over which `Ensemble` and sweeps shard a batch. The
    device count changes results at round-off.

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
    fusion = {"0": False, "1": True}.get(os.environ.get(_FUSION_ENV, ""), multi_output_fusion)
    devices = host_devices if host_devices is not None else os.environ.get(_HOST_DEVICES_ENV)
    if backend_started():
        asked = _would_set(fusion, threads)
        differ = [name for name, value in asked.items() if value != _in_force(name)]
        if devices is not None and str(devices).strip() != str(jax.device_count()):
            differ.append("host_devices")
        if differ:
            warnings.warn(f"jaxpile.configure() came after JAX had run: {', '.join(differ)} stay as JAX set them "
                          "(call it right after `import jaxpile`)"
                          + ("; float64 is on." if float64 else "."), stacklevel=2)
        return settings()
    _undo_ours()  # a call before JAX runs replaces an earlier call's choices (never the user's own)
    asked = _would_set(fusion, threads)
    if asked["vector_width"] and "xla_cpu_prefer_vector_width" not in _flags():
        _add_flag(_VECTOR_WIDTH)
        _OURS["flags"].append(_VECTOR_WIDTH)
    if asked["multi_output_fusion"] and "xla_backend_extra_options" not in _flags():
        _add_flag(_MULTI_OUTPUT_FUSION)
        _OURS["flags"].append(_MULTI_OUTPUT_FUSION)
    if asked["one_thread"] and "PJRT_NPROC" not in os.environ:
        os.environ["PJRT_NPROC"] = "1"
        _OURS["nproc"] = True
    if devices is not None:
        try:
            count = int(devices)
            if count < 1:
                raise ValueError("not a positive count")
            jax.config.update("jax_num_cpu_devices", count)
        except (RuntimeError, ValueError) as error:  # not a number, or JAX already running: say so, carry on
            warnings.warn(f"host_devices={devices!r} ignored: {error}", stacklevel=2)
    return settings()


_OURS = {"flags": [], "nproc": False}
"""What configure itself put in the environment, which a later call (before JAX runs) may take back."""


def _undo_ours() -> None:
    for flag in _OURS["flags"]:
        os.environ["XLA_FLAGS"] = " ".join(t for t in _flags().split() if t != flag)
    if _OURS["nproc"] and os.environ.get("PJRT_NPROC") == "1":
        del os.environ["PJRT_NPROC"]
    _OURS.update(flags=[], nproc=False)


def _would_set(fusion: bool, threads: bool) -> dict:
    """What a call asks for, where the user's environment does not decide it."""
    user_flags = " ".join(t for t in _flags().split() if t not in _OURS["flags"])
    return {"vector_width": True if "xla_cpu_prefer_vector_width" not in user_flags else _in_force("vector_width"),
            "multi_output_fusion": fusion if "xla_backend_extra_options" not in user_flags
            else _in_force("multi_output_fusion"),
            "one_thread": (not threads) if ("PJRT_NPROC" not in os.environ or _OURS["nproc"])
            else _in_force("one_thread")}


def _in_force(name: str):
    if name == "vector_width":
        return "xla_cpu_prefer_vector_width" in _flags()
    if name == "multi_output_fusion":
        return multi_output_fusion_on()
    return os.environ.get("PJRT_NPROC") == "1"


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
    def number(text):
        try:
            return None if text is None else int(text)
        except ValueError:  # as the environment has it, when it is not a count
            return text

    return {
        "float64": bool(jax.config.jax_enable_x64),
        "multi_output_fusion": multi_output_fusion_on(),
        "fusion_emitters": emitters is None or emitters.lower() not in ("false", "0"),
        "optimization_level": number(level),
        "vector_width": number(width),
        "xla_threads": number(threads),
        "devices": jax.device_count() if backend_started() else None,
    }


def differences(recorded: dict | None, current: dict | None = None, *, batch: bool = False) -> list[str]:
    """The result-changing settings (`RESULT_SETTINGS`) in which a run's
    recorded settings differ from `current` (default: `settings()`), as
    'name: recorded -> current'; empty when they agree or a record lacks them.
    The device count changes only a sharded batch's numbers: compared when
    `batch`."""
    if not recorded:
        return []
    current = settings() if current is None else current
    names = [k for k in RESULT_SETTINGS if batch or k != "devices"]
    return [f"{k}: {recorded[k]} -> {current[k]}" for k in names
            if k in recorded and k in current and recorded[k] != current[k]
            and not (k == "devices" and None in (recorded[k], current[k]))]


__all__ = ["RESULT_SETTINGS", "backend_started", "configure", "differences", "multi_output_fusion_on", "settings"]
