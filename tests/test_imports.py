"""`import jaxpile` changes nothing in JAX, XLA or the environment and loads
only the jax-md modules it uses, leaving no package of its own in
`sys.modules` (jaxpile/_jax_md.py); `jaxpile.configure()`
sets what the commands set (a script that calls it gets the commands'
numbers for the same seed, bit for bit: tests/test_readme.py runs a sweep both
ways)."""

import os
import subprocess
import sys

XLA_THREADS = ("def xla_threads():\n"
               "    import glob, jax\n"
               "    jax.numpy.zeros(1).block_until_ready()\n"
               "    return sum(open(f).read().startswith('tf_XLAEigen') for f in glob.glob('/proc/self/task/*/comm'))\n")
"""Code that counts the threads of XLA's CPU client (made by the first JAX operation)."""

OURS = ("XLA_FLAGS", "PJRT_NPROC", "JAXPILE_MULTI_OUTPUT_FUSION", "JAXPILE_HOST_DEVICES")


def clean_env(**extra) -> dict:
    """The environment without the suite's XLA settings (tests/conftest.py), as a user's shell has it.

    An instruction set the suite was told to compile for (`--xla_cpu_max_isa`,
    `make test-isa`) stays: it stands for the user's CPU, not a setting of ours
    (unless `extra` gives XLA_FLAGS of its own: then those are the user's, as given)."""
    env = {k: v for k, v in os.environ.items() if k not in OURS} | extra
    isa = [t for t in os.environ.get("XLA_FLAGS", "").split() if t.startswith("--xla_cpu_max_isa=")]
    if isa and "XLA_FLAGS" not in extra:
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + isa[-1]).strip()
    return env


def python(code, env, *args):
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    return done


def test_import_changes_nothing_and_configure_sets_float64_and_the_commands_xla_settings():
    code = ("import os, sys, warnings, jax\n"
            "env, x64 = dict(os.environ), jax.config.jax_enable_x64\n"
            "import jaxpile\n"
            "assert dict(os.environ) == env and jax.config.jax_enable_x64 == x64 == False\n"
            "loaded = sorted(m for m in sys.modules if m.startswith('jax_md'))\n"
            "assert 'jax_md.energy' not in loaded and 'jax_md.rigid_body' not in loaded, loaded\n"
            # jax-md's own modules, run as written; no stand-in package of jaxpile's
            "assert 'jax_md' not in sys.modules and 'jax_md.partition' in loaded, loaded\n"
            "assert all(os.path.join('jax_md', m.split('.')[1] + '.py') in sys.modules[m].__file__ for m in loaded), loaded\n"
            # and starts no XLA backend: threads, host devices and jax.distributed are still the user's to set
            "from jax._src import xla_bridge\n"
            "assert not xla_bridge.backends_are_initialized()\n"
            # a float64 pile without float64 is refused in one line (before JAX starts)
            "try:\n"
            "    jaxpile.make_particles([[0.0, 0.5]], 0.5)\n"
            "    raise SystemExit('float64 particles were made without float64')\n"
            "except jaxpile.InputError as e:\n"
            "    assert 'jaxpile.configure()' in str(e), e\n"
            "import numpy as np\n"
            # a second call before JAX runs replaces the first's choices (never the user's own)
            "s = jaxpile.configure(multi_output_fusion=False, threads=True)\n"
            "assert not s['multi_output_fusion'] and 'PJRT_NPROC' not in os.environ, (s, os.environ.get('XLA_FLAGS'))\n"
            "s = jaxpile.configure()\n"
            "assert jax.config.jax_enable_x64 and s['float64'] and s['multi_output_fusion'] and s['vector_width'] == 512\n"
            "assert '--xla_cpu_prefer_vector_width=512' in os.environ['XLA_FLAGS'], os.environ['XLA_FLAGS']\n"
            "assert 'xla_cpu_use_multi_output_fusion' in os.environ['XLA_FLAGS'], os.environ['XLA_FLAGS']\n"
            # one XLA thread for a pile's small kernels (88 vs 119 us a lattice step on 2 cores)
            f"{XLA_THREADS}assert xla_threads() == 1 and jaxpile.settings()['xla_threads'] == 1, xla_threads()\n"
            "assert jaxpile.make_particles([[0.0, 0.5]], 0.5).position.dtype == np.float64\n"
            "assert jaxpile.make_particles(np.float32([[0.0, 0.5]]), 0.5).position.dtype == np.float32\n"
            # once JAX has run, XLA's settings cannot change: said, not silently ignored
            "with warnings.catch_warnings(record=True) as caught:\n"
            "    warnings.simplefilter('always')\n"
            "    jaxpile.configure(host_devices=2)\n"
            "assert any('after JAX had run' in str(w.message) for w in caught), [str(w.message) for w in caught]\n"
            # and jax-md stays whole for a user who imports it after jaxpile
            "import jax_md\n"
            "assert callable(jax_md.energy.soft_sphere) and callable(jax_md.simulate.nve)\n"
            "from jaxpile.engine import state\n"
            "assert jax_md.partition.NeighborList is state.partition.NeighborList  # one class for both\n"
            "from jax_md import quantity\n"
            "assert callable(quantity.force)\n")
    python(code, clean_env())


def test_threads_for_a_batch_and_what_the_user_set_wins():
    """`configure(threads=True)` (sweeps, fits, large piles) gives XLA its own
    thread count; a thread count, vector width or fusion the user set is kept."""
    batch = (f"import os, jaxpile\njaxpile.configure(threads=True)\n{XLA_THREADS}"
             "assert xla_threads() == len(os.sched_getaffinity(0)), xla_threads()\n")
    user = (f"import os, jaxpile\ns = jaxpile.configure()\n{XLA_THREADS}"
            "assert os.environ['PJRT_NPROC'] == '3' and xla_threads() == 3, xla_threads()\n"
            "assert os.environ['XLA_FLAGS'] == '--xla_cpu_prefer_vector_width=256', os.environ['XLA_FLAGS']\n"
            "assert s['vector_width'] == 256 and not s['multi_output_fusion'], s\n")
    python(batch, clean_env())
    python(user, clean_env(PJRT_NPROC="3", XLA_FLAGS="--xla_cpu_prefer_vector_width=256",
                           JAXPILE_MULTI_OUTPUT_FUSION="0"))


def test_pile_gives_a_large_pile_xla_s_threads_and_keeps_one_for_the_papers_sizes(tmp_path):
    """`jaxpile pile` reads the size it is asked for before JAX starts: from
    THREADED_PILE_DISKS disks XLA gets its threads (a dry run is enough to see it)."""
    code = ("import os, sys, jaxpile\n"
            "from jaxpile import cli\n"
            "assert cli.main(['pile', '--protocol', 'box', '--n', sys.argv[1], '--out', sys.argv[2], '--dry-run']) == 0\n"
            f"{XLA_THREADS}"
            "print('threads', xla_threads(), os.environ.get('PJRT_NPROC'))\n")
    env = {k: v for k, v in os.environ.items() if k != "PJRT_NPROC"}
    for disks, expect in ((100, "threads 1 1"), (3000, f"threads {len(os.sched_getaffinity(0))} None")):
        done = subprocess.run([sys.executable, "-c", code, str(disks), str(tmp_path / "run")], capture_output=True, text=True, timeout=300,
                              env=env)
        assert done.returncode == 0, done.stderr[-2000:]
        assert done.stdout.strip().splitlines()[-1] == expect, done.stdout


def test_a_pathwise_fit_keeps_one_thread_and_an_ensemble_fit_runs_batches():
    """`fit` gives XLA its threads only for the ensemble estimators (batches);
    the pathwise gradient through one pile is faster on one thread."""
    from argparse import Namespace

    from jaxpile.cli import fit_runs_batches

    args = dict(estimator=None, truth=None, target="profile.csv", resume=None, protocol="lattice")
    assert not fit_runs_batches(Namespace(**args))
    assert fit_runs_batches(Namespace(**{**args, "protocol": "pour"}))  # a random pile: its ensemble mean
    assert fit_runs_batches(Namespace(**{**args, "target": "target.json"}))
    assert fit_runs_batches(Namespace(**{**args, "truth": ["mu=0.3"]}))
    assert fit_runs_batches(Namespace(**{**args, "estimator": "smoothing"}))
    assert not fit_runs_batches(Namespace(**{**args, "estimator": "pathwise", "target": "target.json"}))


SETTLING_PILE = """
import json, os
import jax.numpy as jnp, numpy as np
import jaxpile
from jaxpile.laws import hooke
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator

jaxpile.configure()
particles, boundaries = lattice.equilateral_pile(6)
rng = np.random.default_rng(0)  # sliding and spinning contacts while it settles
particles = particles.set(velocity=jnp.asarray(rng.normal(0, 0.2, (particles.count, 2))),
                          angular_velocity=jnp.asarray(rng.normal(0, 1.0, particles.count)))
params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3, wall_mu=0.5)
sim = Simulator(hooke.law(rotation=True), dt=5e-4, skin=0.1)
state = sim.run(params, sim.init(params, particles, boundaries), 300, progress=False)
print(json.dumps({"flags": os.environ["XLA_FLAGS"], "position": np.asarray(state.particles.position).tolist(),
                  "base": np.asarray(sim.contact_forces(params, state).wall.normal[:, 0]).tolist()}))
"""


def test_multi_output_fusion_gives_the_same_pile():
    """XLA:CPU's multi-output fusion as `jaxpile pile` runs (XLA's default
    emitters, JAXPILE_MULTI_OUTPUT_FUSION=1 for a whole process) against the
    suite's configuration (older emitters, no multi-output fusion;
    tests/conftest.py): a settling frictional pile with spinning disks agrees to
    round-off, positions and base forces."""
    import json

    import numpy as np

    runs = {}
    on = clean_env()  # jaxpile.configure() as a user calls it: the fusion on
    for name, env in (("on", on), ("suite", dict(os.environ))):
        done = subprocess.run([sys.executable, "-c", SETTLING_PILE], capture_output=True, text=True, timeout=300,
                              env=env)
        assert done.returncode == 0, done.stderr[-2000:]
        runs[name] = json.loads(done.stdout.strip().splitlines()[-1])
    assert "xla_cpu_use_multi_output_fusion" in runs["on"]["flags"]
    assert "xla_cpu_use_multi_output_fusion" not in runs["suite"]["flags"]
    a, b = np.asarray(runs["on"]["position"]), np.asarray(runs["suite"]["position"])
    assert np.max(np.abs(a - b)) < 1e-10, np.max(np.abs(a - b))
    a, b = np.asarray(runs["on"]["base"]), np.asarray(runs["suite"]["base"])
    assert np.sum(b) > 0 and np.max(np.abs(a - b)) < 1e-8 * np.max(b), np.max(np.abs(a - b))


def test_pile_sweep_and_fit_turn_multi_output_fusion_on_unless_the_user_says_0(tmp_path):
    """The commands turn XLA:CPU's multi-output fusion on (a law computed once
    a step), and a derivative program then keeps XLA's newer emitters
    (`engine.compile`: the older ones make a reverse gradient ~20x slower with
    the fusion); none does under JAXPILE_MULTI_OUTPUT_FUSION=0, where
    derivatives take the older emitters. The fit below stops at its input
    check, after the command has chosen."""
    code = ("import os, sys, jaxpile\n"
            "from jaxpile import cli\n"
            "from jaxpile.engine import compile\n"
            "code = cli.main(sys.argv[1:])\n"
            "print('fusion', 'xla_cpu_use_multi_output_fusion' in os.environ.get('XLA_FLAGS', ''), code,\n"
            "      'derivative', compile.derivative_options())\n")
    unset = {k: v for k, v in os.environ.items() if k not in ("JAXPILE_MULTI_OUTPUT_FUSION", "XLA_FLAGS")}
    pile = ["pile", "--protocol", "box", "--n", "50", "--dry-run", "--out", str(tmp_path / "pile")]
    sweep = ["sweep", "--protocol", "box", "--n", "50", "--mu", "0.1,0.2", "--seeds", "1", "--dry-run",
             "--out", str(tmp_path / "sweep")]
    fit = ["fit", "--target", "smid-novosad", "--params", "not_a_parameter", "--out", str(tmp_path / "fit")]
    on, off = "derivative {}", "derivative {'xla_cpu_use_fusion_emitters': False}"
    for argv, env, expect in ((pile, unset, ("fusion True 0", on)), (sweep, unset, ("fusion True 0", on)),
                              (fit, unset, ("fusion True 2", on)),
                              (pile, unset | {"JAXPILE_MULTI_OUTPUT_FUSION": "0"}, ("fusion False 0", off))):
        done = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=300, env=env)
        assert done.returncode == 0 and all(e in done.stdout for e in expect), (argv, done.stdout[-500:],
                                                                                done.stderr[-1500:])


def test_the_engine_imports_no_protocol_and_no_module_of_it_imports_itself_back():
    """Issue 18: the engine (state, neighbours, blocks, batches, checkpoints,
    the simulator and the batched runner) is read at import time without the
    protocol layer, and its top-level imports form no circle (the old one:
    checkpoint -> ensemble -> simulate -> checkpoint)."""
    import ast
    import pathlib

    root = pathlib.Path(__file__).parent.parent / "jaxpile"
    engine = ["state", "neighbors", "blocks", "batch", "checkpoint", "simulate", "ensemble", "interactions",
              "integrators", "collisions", "boundaries", "io", "errors"]

    def imports(name):
        """jaxpile modules imported at a module's top level, or inside its functions (lazy)."""
        path = root / "engine" / f"{name}.py"  # the engine's package (issue 18's layout); io, errors at the top
        tree = ast.parse((path if path.exists() else root / f"{name}.py").read_text())
        top, lazy = set(), set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("jaxpile"):
                found = {node.module} | {f"{node.module}.{a.name}" for a in node.names}
            elif isinstance(node, ast.Import):
                found = {a.name for a in node.names if a.name.startswith("jaxpile")}
            else:
                continue
            # jaxpile.engine.simulate -> simulate: the module, not its package
            found = {f.split(".")[2] if f.split(".")[1] == "engine" and f.count(".") >= 2 else f.split(".")[1]
                     for f in found if f.count(".") >= 1}
            (top if node in tree.body else lazy).update(found)
        return top, lazy

    graph = {}
    for name in engine:
        top, lazy = imports(name)
        assert "protocols" not in top, f"jaxpile.{name} imports the protocol layer at import time"
        graph[name] = {m for m in top | lazy if m in engine and m != name}

    def reaches(start, goal, seen=()):
        return any(m == goal or (m not in seen and reaches(m, goal, seen + (m,))) for m in graph[start])

    circles = [name for name in engine if reaches(name, name)]
    assert not circles, f"import circles through {circles}: {graph}"


def _code_lines(path) -> int:
    """Lines of code in a module: blank lines, comments and docstrings (the
    module's, its classes' and functions', and the strings documenting an
    assignment) not counted."""
    import ast

    source = path.read_text()
    tree = ast.parse(source)
    doc = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if not isinstance(body, list):
            continue
        for k, statement in enumerate(body):
            is_string = (isinstance(statement, ast.Expr) and isinstance(statement.value, ast.Constant)
                         and isinstance(statement.value.value, str))
            documents = k == 0 or isinstance(body[k - 1], (ast.Assign, ast.AnnAssign))
            if is_string and documents:
                doc.update(range(statement.lineno, statement.end_lineno + 1))
    return sum(1 for i, line in enumerate(source.splitlines(), 1)
               if line.strip() and not line.strip().startswith("#") and i not in doc)


def test_no_protocol_module_holds_more_than_300_lines_of_code():
    """Issue 18: a protocol module holds its set-up, driver and declaration;
    measurements, shared geometry and plumbing live elsewhere. The paper notes
    in its docstrings are not counted: they belong beside the code they explain."""
    import pathlib

    folder = pathlib.Path(__file__).parent.parent / "jaxpile" / "protocols"
    sizes = {path.name: _code_lines(path) for path in sorted(folder.glob("*.py"))}
    assert len(sizes) >= 10 and sizes["pour.py"] > 100, sizes  # the count sees code
    assert {name: n for name, n in sizes.items() if n > 300} == {}, sizes


def test_jaxpile_run_reaches_the_force_kernel_in_the_12_calls_the_layout_page_lists(monkeypatch):
    """The path from `jaxpile.run` to the law's kernel, traced on a 3-layer
    lattice, is the one docs/layout.md tabulates, and is at most 12 calls."""
    import re
    import traceback

    import jaxpile
    from jaxpile.engine import interactions

    kernel_over, seen = interactions._kernel_over, []
    package = os.path.dirname(jaxpile.__file__) + os.sep

    def spy(law, *layout):
        kernel = kernel_over(law, *layout)

        def traced(*args):
            stack = traceback.extract_stack()
            if not seen and any(frame.name == "run_chunks" for frame in stack):
                seen.append([frame.name for frame in stack if frame.filename.startswith(package)])
            return kernel(*args)

        return traced

    monkeypatch.setattr(interactions, "_kernel_over", spy)
    jaxpile.run("lattice", "hooke", 3, params={"mu": 0.3}, ramp_steps=200, max_steps=400)
    path = seen[0]
    # the compile helpers hand the chunk its jitted advance; at run time the chunk calls it directly
    path = [name for name in path[path.index("run"):] if name not in ("_compiled_advance", "compiled_for")]
    page = open(os.path.join(os.path.dirname(__file__), "..", "docs", "layout.md")).read()
    listed = re.findall(r"^\| (\d+) \| `([^`]+)`", page, re.M)
    names = [call.split(".")[-1] for _, call in listed]
    assert path[1:] == names[:-1] and names[-1] == "pair_force", (path, names)  # the law's kernel last
    assert [int(k) for k, _ in listed] == list(range(1, len(listed) + 1)) and len(listed) <= 12
