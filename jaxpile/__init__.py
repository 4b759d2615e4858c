"""jaxpile: a differentiable, vectorised 2D granular (DEM) simulator in JAX.

    import jaxpile as jp
    jp.configure()                                   # float64 and the commands' XLA settings: first

    pile = jp.run("lattice", "hooke", 6)             # a protocol's pile, run to its end and measured
    base = jp.base_forces(pile.simulator, pile.params, pile.state)      # eagerly or under jax.grad
    rows = jp.sweep("box", vary={"mu": [0.1, 0.3]}, seeds=4)            # one batched run
    jp.summarise(rows, "mu", "repose_cumulative_parabola")              # mean +- s.e. per mu
    result = jp.calibrate("pour", "heap.csv", "mu", options={"n": 100})  # a law fitted to a measurement

`import jaxpile` changes nothing in JAX, XLA or the environment, and puts
nothing in `sys.modules` but its own modules and the libraries it imports
(jax-md's modules without its package `__init__`: `jaxpile._jax_md`);
`jaxpile.configure()` sets what the commands set (float64, and on a CPU the XLA
settings that make a script's result for a seed the command's, bit for bit; see
`jaxpile.config`). The modules behind these names: `protocols` (the papers'
piles, one spec each), `sweeps` (a sweep study), `batches` (the batch runner),
`fit` (gradients and fits), `laws`, `measure`, `engine` (state, simulator,
ensembles), and `io`, `plot`, `export`, `distributed`, `cli`.

The public API is `__all__` here and, in each public module, its `__all__`
(or, where it has none, its own names without a leading underscore); a
public package's modules are public where its `__all__` names them. The
rest (`jaxpile.engine.loop`, `jaxpile.protocols.stages`, ...) is internal and
may change. Benchmarks, notebooks, docs and README use the public API only
(`tests/test_public_api.py`).
"""

from jaxpile.config import configure, settings  # noqa: E402

from jaxpile import fit, laws, protocols, sweeps  # noqa: E402
from jaxpile.engine import boundaries, ensemble  # noqa: E402
from jaxpile.engine.boundaries import make_boundaries, set_wall  # noqa: E402
from jaxpile.engine.simulate import RunInfo, Simulator, make_step, max_speed  # noqa: E402
from jaxpile.engine.state import Boundaries, Contacts, Particles, SimState, make_particles  # noqa: E402
from jaxpile.errors import InputError, SimulationError  # noqa: E402
from jaxpile.fit.calibrate import calibrate  # noqa: E402
from jaxpile.measure import analysis, theory  # noqa: E402
from jaxpile.measure.forces import base_forces  # noqa: E402
from jaxpile.protocols import run  # noqa: E402
from jaxpile.protocols.running import PileRun  # noqa: E402
from jaxpile.sweeps import SweepResult, summarise, sweep  # noqa: E402

from jaxpile._version import __version__  # noqa: E402

__all__ = [
    # set-up, and the four things a newcomer does
    "configure",
    "settings",
    "run",
    "PileRun",
    "base_forces",
    "sweep",
    "SweepResult",
    "summarise",
    "fit",
    "calibrate",
    # by hand: particles, boundaries, a simulator, batches
    "Boundaries",
    "Contacts",
    "InputError",
    "Particles",
    "RunInfo",
    "SimState",
    "SimulationError",
    "Simulator",
    "make_boundaries",
    "make_particles",
    "make_step",
    "max_speed",
    "set_wall",
    # the modules; in the subpackages, the names their own __all__ lists (tests/test_public_api.py)
    "analysis",
    "batches",
    "boundaries",
    "cli",
    "distributed",
    "engine",
    "ensemble",
    "export",
    "io",
    "laws",
    "measure",
    "plot",
    "protocols",
    "sweeps",
    "theory",
]
