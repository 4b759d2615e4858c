"""jaxpile: a differentiable, vectorised 2D granular (DEM) simulator in JAX.

Importing jaxpile turns on float64 in JAX (`jax_enable_x64`): static force
analysis with stiff springs (mg / (k sigma) = 1e-4) needs it. Arrays created as
float32 stay float32, so large dynamic runs can still use single precision.
"""

import jax

jax.config.update("jax_enable_x64", True)

from jaxpile import analysis, boundaries, ensemble, fit, laws, protocols, sweep, theory  # noqa: E402
from jaxpile.boundaries import make_boundaries, set_wall  # noqa: E402
from jaxpile.errors import InputError, SimulationError  # noqa: E402
from jaxpile.simulate import RunInfo, Simulator, make_step, max_speed  # noqa: E402
from jaxpile.state import Boundaries, Contacts, Particles, SimState, make_particles  # noqa: E402

__version__ = "0.1.0"

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
