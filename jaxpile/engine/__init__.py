"""The simulation engine: state pytrees, boundaries, neighbour lists, pair
interactions, hard collisions, integrators, the compiled step and its runs
(`Simulator`), checkpoints and batched ensembles. It knows nothing of the
papers' protocols.

Its public names are those below: the modules `boundaries`, `checkpoint`,
`collisions` and `ensemble`, and the step, the state and its runs; the rest
(neighbour lists, pair lists, the chunk loop, compilation) is internal.
"""

from jaxpile.engine import boundaries, checkpoint, collisions, ensemble
from jaxpile.engine.boundaries import GROUND, LEFT_WALL, RIGHT_WALL, make_boundaries, set_wall
from jaxpile.engine.collisions import HardCollisions
from jaxpile.engine.ensemble import Ensemble
from jaxpile.engine.simulate import RunInfo, Simulator, gravity_ramp, make_step, max_speed
from jaxpile.engine.state import Boundaries, Contacts, Particles, SimState, make_particles

__all__ = ["Boundaries", "Contacts", "Ensemble", "GROUND", "HardCollisions", "LEFT_WALL", "Particles", "RIGHT_WALL",
           "RunInfo", "SimState", "Simulator", "boundaries", "checkpoint", "collisions", "ensemble", "gravity_ramp",
           "make_boundaries", "make_particles", "make_step", "max_speed", "set_wall"]
