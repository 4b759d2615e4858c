"""What a command sets in JAX and XLA before JAX runs anything:
`jaxpile.configure()` (float64 and XLA's settings, with XLA's own thread count
for batches and large piles, one thread for a small pile), and the on-disk
cache of compiled programs."""

from __future__ import annotations

import importlib.util
import os

import jaxpile
from jaxpile.cli.fit import fit_runs_batches

THREADED_PILE_DISKS = 2000
"""From this many disks one pile's kernels are large enough to split over
XLA's threads (docs/choices.md, "The command line")."""


def pile_disks(args) -> int | None:
    """The disk count a `pile` command asks for, read from its size flag before
    anything runs (None: the protocol's default size, the paper's)."""
    if getattr(args, "layers", None) is not None:
        from jaxpile.protocols.lattice import pile_count

        return pile_count(int(args.layers))
    return None if getattr(args, "n", None) is None else int(args.n)


def wants_xla_threads(args) -> bool:
    """Whether a command runs work whose kernels are large enough to split over
    XLA's threads: a sweep, an ensemble fit, a pile of `THREADED_PILE_DISKS` or more."""
    return (args.command == "sweep" or (args.command == "fit" and fit_runs_batches(args))
            or (args.command == "pile" and (pile_disks(args) or 0) >= THREADED_PILE_DISKS))


def configure_for(args) -> dict:
    """`jaxpile.configure()` as the command needs it, before JAX runs anything:
    float64, and on a CPU XLA's settings, with XLA's own thread count for work
    large enough to split (`wants_xla_threads`). Returns the settings in force,
    which the command's outputs record."""
    return jaxpile.configure(threads=wants_xla_threads(args))


def join_processes(args) -> tuple[int, int]:
    """`--distributed`: this process joins the run's others
    (`jaxpile.distributed.initialize`) before JAX computes anything. Returns
    `(process index, process count)`."""
    from jaxpile import distributed
    from jaxpile.errors import InputError

    if args.command == "fit" and not fit_runs_batches(args):
        raise InputError("--distributed shares an ensemble fit's batches over processes; a pathwise fit is one "
                         "pile: run it without --distributed.")
    if args.command == "fit" and getattr(args, "estimator", None) == "truncated":
        raise InputError("--distributed shares an ensemble fit's batches over processes; the truncated "
                         "estimator's rollouts are not batches of a sweep: run it without --distributed.")
    index, count = distributed.initialize()
    print(f"jaxpile: process {index} of {count}", flush=True)
    return index, count


COMPILE_CACHE_ENV = "JAXPILE_COMPILE_CACHE"
COMPILE_CACHE_MAX_BYTES = 2 * 1024**3


def compile_cache_dir(environ, configured: str | None = None) -> str | None:
    """Where `use_compile_cache` keeps compiled programs: `$JAXPILE_COMPILE_CACHE`,
    else the folder JAX is already configured with (`JAX_COMPILATION_CACHE_DIR`),
    else `$XDG_CACHE_HOME/jaxpile/xla` (`~/.cache/jaxpile/xla`); None when
    `JAXPILE_COMPILE_CACHE` is off, 0, no or false."""
    setting = environ.get(COMPILE_CACHE_ENV, "")
    if setting.lower() in ("0", "off", "no", "false"):
        return None
    if setting:
        return setting
    if configured:
        return configured
    home = environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(home, "jaxpile", "xla")


def use_compile_cache() -> str | None:
    """Keeps XLA's compiled programs on disk between commands (JAX's
    persistent compilation cache), so a command that runs what an earlier one
    compiled skips most of its compiling (docs/choices.md, "The command line").

    The folder is `compile_cache_dir`'s, at most `COMPILE_CACHE_MAX_BYTES`, the
    least recently used programs evicted first; `JAXPILE_COMPILE_CACHE=off`
    turns it off. Results do not depend on it. Returns the folder, or None
    (off, or not writable: the command runs without)."""
    import jax

    path = compile_cache_dir(os.environ, jax.config.jax_compilation_cache_dir)
    if path is None:
        return None
    if path == jax.config.jax_compilation_cache_dir:
        return path  # JAX's own setting (or the test suite's): as it was set
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return None
    if not os.access(path, os.W_OK | os.X_OK):
        return None
    jax.config.update("jax_compilation_cache_dir", path)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)  # the step loops, not small helpers
    if "JAX_COMPILATION_CACHE_MAX_SIZE" not in os.environ and importlib.util.find_spec("filelock"):
        jax.config.update("jax_compilation_cache_max_size", COMPILE_CACHE_MAX_BYTES)  # JAX locks with filelock
    return path
