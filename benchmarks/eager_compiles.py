"""Small XLA programs compiled while piles are set up, run and measured.

Every jaxpile protocol compiles its step loop once per pile size; the host
code around it (making the particles, the lists, the contacts, reading the
overflow flags, measuring) should compile next to nothing else. In this JAX
`jnp.asarray` of a numpy array, `jnp.zeros` and every op run eagerly on a
concrete array compile a small program per new shape (with their tracing,
~10-40 ms each on 2 CPU cores). This runs three small protocols (a 1993 box,
a 1997 pour of 40 disks, a 1992 drop of 20), in one process, and counts the
compiles other than the step loop (`_advance`) and the pile's start, with the
jaxpile line that asked for each.

    python benchmarks/eager_compiles.py [--out FILE]
"""

from __future__ import annotations

import argparse
import collections
import time
import traceback

import jax

from machine import describe  # benchmarks/machine.py (scripts run from benchmarks/)

_COMPILE = "/jax/core/compile/backend_compile_duration"
_TRACE = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration")
_OWN = ("jit(_advance)", "jit(start)", "_advance", "start")


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    count, seconds, traced = collections.Counter(), collections.Counter(), collections.Counter()

    def on_event(event, secs, **kw):
        name = kw.get("fun_name", "?")
        if name in _OWN:
            return
        if event in _TRACE:  # tracing and lowering, before the compile they belong to
            traced[name.removeprefix("jit(").removesuffix(")")] += secs
        elif event == _COMPILE:
            frames = [f for f in traceback.extract_stack() if "/jaxpile/" in f.filename]
            site = f"{frames[-1].filename.split('jaxpile/')[-1]}:{frames[-1].name}" if frames else "-"
            count[(name, site)] += 1
            seconds[(name, site)] += secs

    jax.monitoring.register_event_duration_secs_listener(on_event)
    import jaxpile  # noqa: F401  (after the listener: nothing compiled is missed)
    from jaxpile.protocols import box, drop, pour

    t0 = time.perf_counter()
    box.run("lee-herrmann", width=2.0, height=2.0)
    pour.run("baxter", 40)
    drop.run("liffman", 20)
    wall = time.perf_counter() - t0
    rows = [{"program": name, "site": site, "compiles": count[(name, site)],
             "compile_seconds": seconds[(name, site)]} for name, site in sorted(count, key=lambda k: -seconds[k])]
    out = {"machine": describe(), "wall_seconds": wall, "compiles": sum(count.values()),
           "compile_seconds": sum(seconds.values()), "trace_and_lower_seconds": sum(traced.values()),
           "by_site": rows}
    print(f"box + pour + drop: {wall:.1f} s; {out['compiles']} programs besides the step loops and starts, "
          f"{out['compile_seconds']:.2f} s compiling + {out['trace_and_lower_seconds']:.2f} s tracing ({describe()})")
    for r in rows:
        print(f"  {r['compiles']:3d}  {r['compile_seconds']:5.2f} s  {r['program']:28s} {r['site']}")
    if args.out:
        from jaxpile import io

        io.write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
