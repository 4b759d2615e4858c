"""The `jaxpile` command.

    jaxpile pile --protocol lattice --layers 45 --law hooke --out DIR [--set NAME=VALUE ...]
    jaxpile pile --protocol sloped --slope 45 --n 360 --out DIR
    jaxpile pile --protocol drop | box | tilt | flux | pour [--n N] [--option NAME=VALUE ...] --out DIR
    jaxpile pile|sweep ... --checkpoint-every STEPS --out DIR;  jaxpile pile|sweep --resume DIR
    jaxpile show DIR [--out DIR2] [--checkpoint]   (a pile run, a checkpoint, a sweep or a fit)
    jaxpile compare DIR [DIR ...]
    jaxpile sweep --protocol box --law lee-herrmann --mu 0.05,0.1,0.2 --seeds 16 --out DIR
    jaxpile fit --target FILE|smid-novosad --protocol lattice|pour --law hooke --params mu,kt --out DIR
    jaxpile fit --protocol box|pour|drop|lattice|sloped|flux --params mu --truth mu=0.273 --set mu=0.19
                --ensemble 16 [--estimator central|smoothing|truncated] --out DIR   (ensemble fits; --resume)

Every protocol writes summary.json (the set-up and the protocol's measurements),
base_forces.csv, contacts.csv (the force network), state.npz, final.xyz
(extended XYZ), pile.png and profile.png; box and tilt add
energy.png (kinetic energy per disk, Lee & Herrmann 1993 Fig. 1(b)), flux adds
angles.png (Fig. 5) and pour adds heap_profile.png (the binned base force of
Baxter et al. 1997). A sweep writes sweep.csv (one row per member), sweep.png
(mean +- standard error against the varied parameter, theory overlaid) and
sweep.json (the set-up, timings and the per-value summaries). A fit writes
fit.json (the fitted values, the loss history, the profiles before and after)
and fit.png (loss curve; target, before and after); an ensemble fit adds the
95 % interval to fit.json, target.json (the target's statistics and piles)
and fit_checkpoint.json (the history, written every iteration).

The package, one idea a module: `parser` (the argument parser), `protocol_flags`
(a protocol's options as flags), `flag_ranges` (the numeric flags' ranges),
`parsing` (flag text into values), `xla_settings` (`jaxpile.configure` for the
command, the compile cache), `run_folder` (the output folder, checkpoints, resuming), `dry_run`;
one module a command: `pile` (with `pile_outputs`), `sweep`, `fit` (with
`ensemble_fit`), `show`, `compare`.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings

from jaxpile.cli.compare import compare_table
from jaxpile.cli.fit import fit_runs_batches, run_fit
from jaxpile.cli.flag_ranges import FLAG_RANGES, check_flags, ranges_markdown
from jaxpile.cli.parser import build_parser, sweep_protocols
from jaxpile.cli.pile import run_protocol
from jaxpile.cli.protocol_flags import merge_protocol_flags, protocol_flags
from jaxpile.cli.run_folder import check_out_folder, in_use, recorded_command, resume_argv
from jaxpile.cli.sweep import run_sweep
from jaxpile.cli.xla_settings import (
    THREADED_PILE_DISKS,
    compile_cache_dir,
    configure_for,
    join_processes,
    use_compile_cache,
    wants_xla_threads,
)
from jaxpile import distributed
from jaxpile.errors import InputError, SimulationError


def main(argv=None) -> int:
    """`jaxpile ARGS`: parses the command line, sets up JAX for the command,
    runs it, and returns the exit status (2 with one line for a refusal)."""
    with warnings.catch_warnings():
        shown = warnings.showwarning

        def one_line(message, category, filename, lineno, file=None, line=None):
            """jaxpile's own warnings as one line on stdout (stderr holds refusals alone)."""
            if issubclass(category, UserWarning) and os.sep + "jaxpile" + os.sep in filename:
                print(f"jaxpile: warning: {message}", flush=True)
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.showwarning = one_line
        return _main(argv)


def _main(argv) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    os.environ.setdefault("MPLBACKEND", "Agg")  # figures go to files; never open a window
    args = None  # until the flags are parsed
    try:
        argv = [t for a in argv for t in (a.split("=", 1) if a.startswith("--resume=") else [a])]
        if argv[:1] in (["pile"], ["sweep"]) and "--resume" in argv:
            argv = resume_argv(argv)
        args = build_parser(argv).parse_args(argv)
        merge_protocol_flags(args)
        if args.command in ("pile", "sweep"):
            args.argv = recorded_command(argv)
            if args.resume is not None:
                args.out = args.resume  # the run goes on where it is now, even if its folder was moved
        check_flags(args)
        configure_for(args)
        if getattr(args, "distributed", False):
            join_processes(args)
        use_compile_cache()
        if getattr(args, "out", None) is not None:
            check_out_folder(args.out)
        holds = (args.command in ("pile", "sweep", "fit") and getattr(args, "out", None) is not None
                 and not getattr(args, "dry_run", False))
        with in_use(args.out, argv) if holds else contextlib.nullcontext():
            _run(args)
    except (InputError, SimulationError) as err:
        print(f"jaxpile: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # the file system said no mid-run (disk full, a folder removed): one line, not a traceback
        where = f"{err.filename}: " if err.filename else ""
        print(f"jaxpile: error: {where}{err.strerror or err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: one line saying what is saved, not JAX's traceback
        print(f"jaxpile: interrupted{_what_resumes(args)}", file=sys.stderr)
        return 130
    return 0


def _what_resumes(args) -> str:
    """What an interrupted command leaves to resume from, as the end of its one line."""
    command, out = getattr(args, "command", None), getattr(args, "out", None)
    if command not in ("pile", "sweep", "fit") or out is None or getattr(args, "dry_run", False):
        return ""
    from jaxpile.engine import checkpoint

    if command == "fit":
        saved = os.path.exists(os.path.join(distributed.folder_of(out), "fit_checkpoint.json"))
        return (f"; the same command with --resume continues the fit from {out}" if saved else
                "; the fit saved nothing to resume (an ensemble fit saves after each iteration)")
    if checkpoint.in_folder(distributed.folder_of(out)) is not None:
        return f"; `jaxpile {command} --resume {out}` continues from its last checkpoint"
    return "; nothing was saved to resume (--checkpoint-every STEPS saves a run as it goes)"


def _run(args) -> None:
    """The command itself, once its flags are checked."""
    if args.command == "pile":
        run_protocol(args)
    elif args.command == "show":
        from jaxpile.cli.show import show

        out = args.out or os.path.join(args.dir, "shown")  # never over the run's own figures
        written = show(args.dir, out, checkpoint=args.checkpoint)
        print(f"jaxpile: wrote {out}/" + ", ".join(written))
    elif args.command == "compare":
        print(compare_table(args.dirs))
    elif args.command == "sweep":
        run_sweep(args)
    elif args.command == "fit":
        run_fit(args)


__all__ = [
    "FLAG_RANGES",
    "THREADED_PILE_DISKS",
    "build_parser",
    "compare_table",
    "compile_cache_dir",
    "configure_for",
    "join_processes",
    "fit_runs_batches",
    "main",
    "merge_protocol_flags",
    "protocol_flags",
    "ranges_markdown",
    "run_fit",
    "run_protocol",
    "run_sweep",
    "sweep_protocols",
    "use_compile_cache",
]


if __name__ == "__main__":
    sys.exit(main())
