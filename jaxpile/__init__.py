"""jaxpile: a differentiable, vectorised 2D granular (DEM) simulator in JAX.

    import jaxpile as jp
    jp.configure()     # float64 and the commands' XLA settings: call it first

`import jaxpile` changes nothing in JAX, XLA or the environment;
`jaxpile.configure()` sets what the commands set (float64, and on a CPU the XLA
settings that make a script's result for a seed the command's, bit for bit; see
`jaxpile.config`).
"""

from jaxpile.config import configure, settings  # noqa: E402

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
