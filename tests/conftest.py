"""Shared fixtures: small piles and simulators compiled once per session.

XLA's compiled programs are also kept on disk (JAX's persistent compilation
cache, in .pytest_cache/jax-compile unless JAX_COMPILATION_CACHE_DIR is set):
the test workers, the notebook kernels and the CLI subprocesses the suite
starts compile many of the same step functions, and on 2 cores compiling is
most of the suite's time. Set here, before jax is imported, so every process
the suite starts inherits it.
"""

import json
import os
import pathlib

os.environ.setdefault("JAX_COMPILATION_CACHE_DIR",
                      str(pathlib.Path(__file__).resolve().parent.parent / ".pytest_cache" / "jax-compile"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")
# XLA:CPU's older (non-MLIR) fusion emitters compile a step loop ~35 % faster (the
# box's: 6.7 -> 4.4 s) and run it ~20 % slower (the 45-layer lattice: 11.4 -> 9.0
# M particle-steps/s, same run). The suite's piles are small and its time is mostly
# compiling, so it takes them; commands and benchmarks keep XLA's defaults. Set
# before any computation initialises the backend (which reads XLA_FLAGS once).
if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()
# XLA:CPU's multi-output fusion, which `jaxpile pile`, `sweep` and `fit` turn on,
# stays off in the suite, commands included, as in the Python API by default (a
# user's own loss may hold the pattern it aborts on); tests/test_imports.py runs a
# pile both ways.
os.environ.setdefault("JAXPILE_MULTI_OUTPUT_FUSION", "0")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

# in case a plugin imported jax before the environment was set
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs",
                  float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))

import jaxpile  # noqa: E402

jaxpile.configure()  # float64, one XLA thread, 512-bit vectors; the fusion as set above
from jaxpile.laws import hooke
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator, gravity_ramp


LATTICE_LAYERS = 12


@pytest.fixture(scope="session")
def lattice_setting():
    return lattice.PAPER_SETTING


@pytest.fixture(scope="session")
def relaxed_lattice(lattice_setting):
    """The 12-layer 1992 pile relaxed with the paper's setting (hooke law)."""
    s = lattice_setting
    params = hooke.make_params(**s["params"]["hooke"])
    law = hooke.law(rotation=False)
    particles, boundaries = lattice.equilateral_pile(LATTICE_LAYERS)
    ramp = 5_000
    sim = Simulator(law, s["dt"], schedule=gravity_ramp(ramp), chunk_steps=2000)
    state = sim.init(params, particles, boundaries)
    # stricter than the CLI's rest tolerance, so the force balance is checked to 1e-6
    state, info = lattice.relax(sim, params, state, ramp_steps=ramp, speed_tolerance=1e-7,
                                max_steps=300_000, progress=False)
    return sim, params, state, info


def random_disks(n, seed=0, box=6.0, radius=(0.4, 0.5), overlap=0.02):
    """n disks scattered in a box, pushed apart until overlaps are at most a few
    per cent (a quick random-sequential placement with a small allowed overlap)."""
    rng = np.random.default_rng(seed)
    pos, rad = [], []
    while len(pos) < n:
        r = rng.uniform(*radius)
        p = rng.uniform([r, r], [box - r, box - r])
        if all(np.linalg.norm(p - q) > (r + s) * (1 - overlap) for q, s in zip(pos, rad)):
            pos.append(p)
            rad.append(r)
    return np.array(pos), np.array(rad)


PROFILE = pathlib.Path(__file__).resolve().parent.parent / "benchmarks" / "results" / "cpu" / "suite_profile.json"


def _scope_seconds(scopes: list[str]) -> dict[str, float]:
    """Each scheduling scope's seconds in the committed suite profile
    (`benchmarks/suite_profile.py`): a module's, or for a test class (the
    notebooks) its test's, else its module's shared out; scopes it does not
    know get the median."""
    try:
        profile = json.loads(PROFILE.read_text())
        seconds = {m["module"]: float(m["wall"]) for m in profile.get("modules", [])}
        for t in profile.get("slowest_tests", []):
            if t["test"].count("::") == 2:  # a test class: its own scope, no longer part of its module's
                scope, module = t["test"].rsplit("::", 1)[0], t["test"].split("::")[0]
                seconds[scope] = seconds.get(scope, 0.0) + float(t["wall"])
                seconds[module] = max(0.0, seconds.get(module, 0.0) - float(t["wall"]))
    except Exception:  # no profile, or not one this reads: collection order, as written
        return {}
    per_module = {}
    for scope in scopes:
        per_module[scope.split("::")[0]] = per_module.get(scope.split("::")[0], 0) + 1
    known = sorted(seconds.values()) or [0.0]
    median = known[len(known) // 2]

    def cost(scope):
        module = scope.split("::")[0]
        if scope in seconds:
            return seconds[scope]
        return seconds[module] / per_module[module] if module in seconds else median

    return {scope: cost(scope) for scope in scopes}


def pytest_collection_modifyitems(config, items):
    """The costliest scopes first (pytest-xdist's `--dist loadscope` sends each
    module, or test class, to one worker, in this order: `make test` passes
    `--no-loadscope-reorder`, which would otherwise order them by their count of
    tests and leave the notebooks, one test each and about a minute, to the
    end). Longest first leaves the workers short scopes to even out at the
    end. Costs come from the committed suite profile; each scope's own
    tests keep their order."""
    scope_of = [item.nodeid.rsplit("::", 1)[0] for item in items]  # xdist's own split
    first = {}
    for i, scope in enumerate(scope_of):
        first.setdefault(scope, i)
    seconds = _scope_seconds(list(first))
    order = sorted(range(len(items)), key=lambda i: (-seconds.get(scope_of[i], 0.0), first[scope_of[i]], i))
    items[:] = [items[i] for i in order]
