"""The lattice's pathwise fit: the pile `jaxpile fit --estimator pathwise`
differentiates, the paper's deterministic equilateral pile (Liffman et al.
1992, Figs. 7-9) loaded by a gravity ramp and settled, the whole loading
differentiated (docs/gradients.md)."""

from __future__ import annotations

from jaxpile.errors import InputError
from jaxpile.measure.heap import ProfileSetting
from jaxpile.protocols import lattice


def fit_ramp(layers: int) -> int:
    """The gravity-ramp steps of the pile a pathwise fit differentiates (it
    settles for as many again); refuses a pile too small for a profile."""
    if layers < 2:
        raise InputError(f"--layers must be >= 2 for a profile; got {layers}.")
    return max(600, 100 * layers)


def pathwise_problem(law, start: dict, *, size: int = 6, seed: int = 0, options: dict | None = None,
                     bins: int | None = None, window: int | None = None, progress=None):
    """What `jaxpile fit --estimator pathwise` differentiates: the `size`-layer
    pile loaded by a gravity ramp and settled, the whole quasi-static loading
    (2 x ramp steps), its base profile read in `bins` columns (default: one per
    bottom disk). The pile is the paper's, deterministic, and differentiated
    whole: `seed`, `options`, `window` and `progress` are not used.
    Returns `(sim, params, state, steps, setting, window, description)`."""
    from jaxpile.engine.simulate import Simulator, gravity_ramp

    _, contact_law, params = lattice.law_and_params(law, start)
    ramp = fit_ramp(size)
    particles, boundaries = lattice.equilateral_pile(size)
    sim = Simulator(contact_law, lattice.PAPER_SETTING["dt"], schedule=gravity_ramp(ramp))
    state = sim.init(params, particles, boundaries)
    setting = ProfileSetting("ground", 0.5, size + 0.5, bins or size, 0.3)
    return sim, params, state, 2 * ramp, setting, None, (
        f"{size}-layer lattice pile, gravity ramped over {ramp} steps and settled for {ramp}: "
        "the whole loading differentiated")


def pathwise_dry_run(law, start: dict, *, size: int = 6, seed: int = 0, options: dict | None = None,
                     window: int | None = None):
    """`(what, particles, params, steps of the build, steps differentiated)` of
    `pathwise_problem`, set up and checked, not run (`seed`, `options` and
    `window` are not used, as there)."""
    from jaxpile.engine.simulate import Simulator

    per_step = 2 * fit_ramp(size)
    _, contact_law, params = lattice.law_and_params(law, start)
    particles, _ = lattice.equilateral_pile(size)
    Simulator(contact_law, lattice.PAPER_SETTING["dt"]).check_params(params, particles)
    return f"a {size}-layer lattice pile", particles, params, {}, per_step


__all__ = ["fit_ramp", "pathwise_dry_run", "pathwise_problem"]
