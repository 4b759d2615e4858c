"""Where the test suite's time goes: per test, its wall time, XLA's backend
compile time, JAX's tracing and lowering time, and how many distinct programs
it compiled.

    python tools/suite_profile.py                 # the whole suite, as `make test` runs it
    python tools/suite_profile.py tests/test_protocol_tilt.py -n 0
    python tools/suite_profile.py --json /tmp/profile.json -n 2 --dist loadscope  # not the committed file

runs pytest with this file as a plugin (each worker records its own tests) on a
fresh, empty compile cache, as CI's clean clone does, then prints the slowest
tests, modules and program names and writes benchmarks/results/<backend>/suite_profile.json.
A "distinct program" is one StableHLO module, debug information left out: the
same module compiled again (in the same worker or the other) is a "repeat",
which the persistent compile cache makes cheap.
"""

from __future__ import annotations

import collections
import hashlib
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

import pytest

_RECORD_DIR = "JAXPILE_SUITE_PROFILE_DIR"
_DUMP_DIR = "JAXPILE_SUITE_PROFILE_DUMP"  # where set: each step loop's StableHLO, named by its digest
_COMPILE = "/jax/core/compile/backend_compile_duration"
_TRACE = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration")


# ------------------------------------------------------------- the plugin
class _Recorder:
    """Per-test sums of JAX's compile events and the programs compiled."""

    def __init__(self):
        self.test = "<collection>"
        self.tests = collections.defaultdict(lambda: {"wall": 0.0, "compile": 0.0, "trace": 0.0, "compiles": 0})
        self.programs = []  # (test, program name, module hash, seconds)

    def on_event(self, event, seconds, **_):
        t = self.tests[self.test]
        if event == _COMPILE:
            t["compile"] += seconds
            t["compiles"] += 1
        elif event in _TRACE:
            t["trace"] += seconds

    def wrap_compiler(self):
        """Names and hashes each module JAX hands XLA (a private JAX function:
        where it has moved, the per-program table is left empty)."""
        try:
            from jax._src import compiler
        except ImportError:
            return
        original = getattr(compiler, "compile_or_get_cached", None)
        if original is None:
            return

        def compile_or_get_cached(backend, computation, *args, **kwargs):
            attrs = computation.operation.attributes
            name = str(attrs["sym_name"]).strip('"') if "sym_name" in attrs else "?"
            text = computation.operation.get_asm(enable_debug_info=False)
            t0 = time.perf_counter()
            out = original(backend, computation, *args, **kwargs)
            digest = hashlib.sha1(text.encode()).hexdigest()[:16]
            self.programs.append((self.test, name, digest, time.perf_counter() - t0, _signature(text)))
            if os.environ.get(_DUMP_DIR) and name == "jit__advance":  # to diff two step loops of the same shapes
                pathlib.Path(os.environ[_DUMP_DIR], f"{digest}.mlir").write_text(text)
            return out

        compiler.compile_or_get_cached = compile_or_get_cached


def _signature(text: str) -> str:
    """The argument shapes of a module's entry function: two programs with the
    same shapes and different hashes differ by what the function closes over
    (a law, a boundary, an option), not by the pile's size."""
    match = re.search(r"func\.func public @main\((.*?)\) ->", text)
    return " ".join(re.findall(r"tensor<([^>]*)>", match.group(1))) if match else ""


_recorder = None


def pytest_configure(config):
    global _recorder
    import jax.monitoring

    _recorder = _Recorder()
    jax.monitoring.register_event_duration_secs_listener(_recorder.on_event)
    _recorder.wrap_compiler()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """A test's wall time, its fixtures' set-up included (a module's shared
    pile counts in the module's first test)."""
    _recorder.test = item.nodeid
    t0 = time.perf_counter()
    yield
    _recorder.tests[item.nodeid]["wall"] += time.perf_counter() - t0


def pytest_sessionfinish(session):
    folder = os.environ.get(_RECORD_DIR)
    if not folder or _recorder is None:
        return
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    pathlib.Path(folder, f"{worker}.json").write_text(json.dumps(
        {"worker": worker, "tests": _recorder.tests, "programs": _recorder.programs}))


# ------------------------------------------------------------- the report
def summarise(records: list[dict], wall_seconds: float, top: int = 25) -> dict:
    tests, programs = {}, []
    for r in records:
        tests.update(r["tests"])
        programs += [(r["worker"], *p) for p in r["programs"]]
    first_seen, repeats, repeat_seconds = set(), 0, 0.0
    by_name = collections.defaultdict(lambda: {"compiles": 0, "seconds": 0.0, "distinct": set()})
    for worker, test, name, digest, seconds, *_ in programs:
        by_name[name]["compiles"] += 1
        by_name[name]["seconds"] += seconds
        by_name[name]["distinct"].add(digest)
        if digest in first_seen:
            repeats += 1
            repeat_seconds += seconds
        first_seen.add(digest)
    # the step loops by module: where a test's pile differs from every other test's, it pays a compile of its own
    steps = collections.defaultdict(lambda: {"compiles": 0, "seconds": 0.0, "distinct": set()})
    step_modules = collections.defaultdict(set)
    step_programs = {}  # digest -> where it was first compiled, its argument shapes, its seconds
    for worker, test, name, digest, seconds, *signature in programs:
        if name == "jit__advance" and digest not in step_programs:
            step_programs[digest] = {"test": test, "seconds": round(seconds, 2),
                                     "signature": signature[0] if signature else ""}
    for worker, test, name, digest, seconds, *_ in programs:
        if name == "jit__advance":
            module = test.split("::")[0]
            steps[module]["compiles"] += 1
            steps[module]["seconds"] += seconds
            steps[module]["distinct"].add(digest)
            step_modules[digest].add(module)
    modules = collections.defaultdict(lambda: {"wall": 0.0, "compile": 0.0, "trace": 0.0})
    for nodeid, t in tests.items():
        module = modules[nodeid.split("::")[0]]
        for key in module:
            module[key] += t[key]
    total = {key: sum(t[key] for t in tests.values()) for key in ("wall", "compile", "trace", "compiles")}
    return {
        "suite_wall_seconds": round(wall_seconds, 1),
        "worker_seconds": {k: round(v, 1) for k, v in total.items() if k != "compiles"},
        "backend_compiles": total["compiles"],
        "distinct_programs": len(first_seen),
        "repeated_programs": {"count": repeats, "seconds": round(repeat_seconds, 1)},
        "programs_by_name": [
            {"name": n, "compiles": v["compiles"], "distinct": len(v["distinct"]), "seconds": round(v["seconds"], 1)}
            for n, v in sorted(by_name.items(), key=lambda kv: -kv[1]["seconds"])[:top]],
        "step_programs_by_module": [
            {"module": m, "compiles": v["compiles"], "distinct": len(v["distinct"]),
             "own": sum(1 for d in v["distinct"] if len(step_modules[d]) == 1), "seconds": round(v["seconds"], 1)}
            for m, v in sorted(steps.items(), key=lambda kv: -kv[1]["seconds"])],
        # every distinct step loop, to see which piles differ only by what they close over
        "step_programs": sorted(step_programs.values(), key=lambda p: (p["signature"], p["test"])),
        "modules": [{"module": m, **{k: round(x, 1) for k, x in v.items()}}
                    for m, v in sorted(modules.items(), key=lambda kv: -kv[1]["wall"])],
        "slowest_tests": [{"test": n, "wall": round(t["wall"], 1), "compile": round(t["compile"], 1),
                           "trace": round(t["trace"], 1), "compiles": t["compiles"]}
                          for n, t in sorted(tests.items(), key=lambda kv: -kv[1]["wall"])[:top]],
        # time outside XLA's compile and JAX's tracing: running, and host round trips between runs
        "most_time_outside_compile": [
            {"test": n, "outside": round(t["wall"] - t["compile"] - t["trace"], 1), "wall": round(t["wall"], 1)}
            for n, t in sorted(tests.items(), key=lambda kv: kv[1]["compile"] + kv[1]["trace"] - kv[1]["wall"])
            if "test_notebooks.py" not in n][:top],  # a notebook compiles in its own kernel, out of view
    }


def _print(summary: dict) -> None:
    w = summary["worker_seconds"]
    print(f"suite: {summary['suite_wall_seconds']:.0f} s wall; worker time {w['wall']:.0f} s, of it "
          f"backend compile {w['compile']:.0f} s ({w['compile'] / w['wall']:.0%}), tracing and lowering "
          f"{w['trace']:.0f} s ({w['trace'] / w['wall']:.0%})")
    r = summary["repeated_programs"]
    print(f"{summary['backend_compiles']} compiles of {summary['distinct_programs']} distinct programs; "
          f"repeats: {r['count']}, {r['seconds']:.0f} s")
    print("\nprogram              compiles distinct  seconds")
    for p in summary["programs_by_name"][:12]:
        print(f"{p['name'][:20]:20s} {p['compiles']:8d} {p['distinct']:8d} {p['seconds']:8.1f}")
    print("\nstep loops (jit__advance) by module: compiles, distinct, its own alone, seconds")
    for p in summary["step_programs_by_module"][:15]:
        print(f"{p['compiles']:4d} {p['distinct']:4d} {p['own']:4d} {p['seconds']:7.1f}  {p['module']}")
    print("\n  wall compile trace  test")
    for t in summary["slowest_tests"]:
        print(f"{t['wall']:6.1f} {t['compile']:7.1f} {t['trace']:5.1f}  {t['test']}")
    print("\n  outside compile and tracing (running, host round trips)")
    for t in summary["most_time_outside_compile"][:12]:
        print(f"{t['outside']:6.1f} of {t['wall']:5.1f}  {t['test']}")


def main(argv: list[str]) -> int:
    root = pathlib.Path(__file__).resolve().parent.parent
    out = None  # `--json PATH` first: a partial profile that leaves the committed one (the suite's order) alone
    if argv[:1] == ["--json"]:
        out, argv = pathlib.Path(argv[1]).resolve(), argv[2:]
    jobs = min(4, os.cpu_count() or 2)
    args = argv or ["-n", str(jobs), "--dist", "loadscope", "--no-loadscope-reorder"]  # as `make test`
    with tempfile.TemporaryDirectory() as records, tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, **{_RECORD_DIR: records, "JAX_COMPILATION_CACHE_DIR": cache})
        # tools/ for this plugin (`-p suite_profile`); benchmarks/ and the root as before the move
        env["PYTHONPATH"] = os.pathsep.join([str(root / "tools"), str(root / "benchmarks"), str(root),
                                             env.get("PYTHONPATH", "")])
        t0 = time.perf_counter()
        rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "suite_profile", "-p", "no:cacheprovider",
                              *args], cwd=root, env=env)
        wall = time.perf_counter() - t0
        records = [json.loads(p.read_text()) for p in sorted(pathlib.Path(records).glob("*.json"))]
    if not records:
        print("no test recorded (pytest failed to start?)", file=sys.stderr)
        return rc or 1
    summary = summarise(records, wall)
    summary["pytest_args"] = args
    summary["pytest_exit_code"] = rc
    _print(summary)
    import jax

    from jaxpile.io import write_json
    sys.path.insert(0, str(root / "benchmarks"))
    from machine import details  # benchmarks/machine.py

    summary["machine"] = details()
    out = out or root / "benchmarks" / "results" / jax.default_backend() / "suite_profile.json"
    write_json(out, summary)
    print(f"\nwrote {out}")
    return rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
