"""Gradients of the base-force profile through whole rollouts, for every law,
against central finite differences (float64).

A 3-layer pile thrown sideways with spin, so that frictional contacts slide
and stick while it lands (making the result depend on the friction and
tangential stiffness), with a thin neighbour skin so the list is rebuilt inside
the rollout. The measured quantity is the smooth base profile (`fit.base_load`
+ `fit.smooth_base_profile`, normal and horizontal, 7 bins) projected on fixed
random weights: its gradient is the profile's Jacobian applied to those weights.
One law runs with `checkpoint=True` (blocks of sqrt(T) steps recomputed in the
reverse pass), which must give the same numbers. Memory: the compiled gradient
with checkpointing grows sub-linearly with the number of steps."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile  # noqa: F401  (float64)
from jaxpile import fit
from jaxpile.engine.compile import one_off_options
from jaxpile.laws import baxter, hooke, lee_herrmann, liffman
from jaxpile.protocols import lattice
from jaxpile.engine.simulate import Simulator

STEPS = 120

# law, params, the parameters to differentiate (the mu, k_t / K_s, n), checkpoint
CASES = {
    "hooke": (hooke.law(rotation=True), dict(kn=1e4, gamma_n=50.0, mu=0.3), ("mu", "kt", "kn"), True),
    "lee-herrmann": (lee_herrmann.law(), dict(kn=1e5, gamma_n=100.0, mu=0.3), ("mu", "ks", "kn"), False),
    "baxter": (baxter.law(), dict(n=36.0, r0=1.2, mu=0.5), ("n", "mu"), False),
    "liffman": (liffman.law(), dict(ks=1e4), ("ks", "mu_roll", "k_slip"), False),
}
MODULES = {"hooke": hooke, "lee-herrmann": lee_herrmann, "baxter": baxter, "liffman": liffman}


def thrown_pile():
    particles, boundaries = lattice.equilateral_pile(3)
    rng = np.random.default_rng(4)
    return particles.set(velocity=jnp.asarray(rng.normal(0, 0.3, (6, 2))),
                         angular_velocity=jnp.asarray(rng.normal(0, 2.0, 6))), boundaries


def profile_projection(sim, state, steps, checkpoint):
    weights = jnp.asarray(np.random.default_rng(0).normal(size=(2, 7)))

    def loss(params):
        final = sim.rollout(params, state, steps, checkpoint=checkpoint)
        load = fit.base_load(sim, params, final)
        prof = fit.smooth_base_profile(load, x_left=0.5, x_right=3.5, bins=7, bandwidth=0.5)
        raw = jnp.stack([prof.normal * prof.peak, prof.horizontal * prof.peak])  # unnormalised, in mg
        return jnp.sum(weights * raw)

    return loss


@pytest.mark.parametrize("law_name", list(CASES))
def test_grad_of_base_profile_matches_central_differences(law_name):
    law, values, names, checkpoint = CASES[law_name]
    params = MODULES[law_name].make_params(**values)
    particles, boundaries = thrown_pile()
    sim = Simulator(law, dt=2e-4, skin=0.01)
    state = sim.init(params, particles, boundaries)
    final = sim.rollout(params, state, STEPS)
    assert not np.array_equal(np.asarray(final.neighbors.reference_position),
                              np.asarray(state.neighbors.reference_position))  # rebuilt inside
    # one compiled program for the gradient and the shifted losses (the loss is its value
    # output): a second, forward-only program cost as much to compile again
    # the checkpointed program (hooke's) compiles at level 0, as the engine's own one-off programs of a
    # small pile do: 4 times faster to compile, and the comparison is of derivatives, not of XLA's optimiser
    value_and_grad = jax.jit(jax.value_and_grad(profile_projection(sim, state, STEPS, checkpoint)),
                             compiler_options=one_off_options(6) if checkpoint else None)
    _, grad = value_and_grad(params)

    def loss(shifted):
        return float(value_and_grad(shifted)[0])

    for name in names:
        x = float(getattr(params, name))
        h = 1e-6 * x
        # the shifted value keeps the parameter's own dtype (not a weakly typed Python float), so
        # every shift runs the one compiled program instead of compiling it again per parameter
        dtype = getattr(params, name).dtype
        fd = (loss(params.set(**{name: jnp.asarray(x + h, dtype)}))
              - loss(params.set(**{name: jnp.asarray(x - h, dtype)}))) / (2 * h)
        g = float(getattr(grad, name))
        assert abs(g) * x > 1e-6, f"{law_name}: d/d{name} vanishes: the case does not exercise it"
        assert g == pytest.approx(fd, rel=1e-4, abs=1e-9 / x), f"{law_name}: d/d{name}"


def test_checkpointed_gradient_memory_grows_sublinearly_with_steps():
    """XLA's own temporary-buffer figure for the compiled gradient: 16 times the
    steps must cost far less than 16 times the memory (sqrt(T) blocks: about 4)."""
    params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.3)
    particles, boundaries = thrown_pile()
    sim = Simulator(hooke.law(rotation=True), dt=2e-4)
    state = sim.init(params, particles, boundaries)

    def temp_bytes(steps):
        g = jax.jit(jax.grad(lambda p: jnp.sum(sim.rollout(p, state, steps, checkpoint=True).particles.position)))
        # compiled as the engine compiles a small pile's one-off programs (LLVM level 0 on a CPU):
        # the figure is XLA's buffer assignment, before LLVM, the same bytes at every level
        # (130000 and 406416 at 0 and at the default), in ~2/3 of the compile time
        options = one_off_options(particles.count)
        return g.lower(params).compile(options).memory_analysis().temp_size_in_bytes

    small, large = temp_bytes(64), temp_bytes(1024)
    assert large < 6 * small, (small, large)


def test_gradient_stays_finite_for_a_disk_behind_a_wall_that_is_off():
    """A disk far behind a removed wall, with a steep law (baxter n = 60): its
    masked-out wall force once overflowed to inf, and inf * 0 made the gradient NaN."""
    from jaxpile.engine.boundaries import make_boundaries, set_wall, LEFT_WALL
    from jaxpile.engine.interactions import evaluate
    from jaxpile.engine.state import Contacts, make_particles

    particles = make_particles(np.array([[-3.0, 0.5], [5.0, 0.5]]), 0.5)
    boundaries = set_wall(make_boundaries(left=0.0, right=10.0), LEFT_WALL, active=False)
    law = baxter.law()
    pairs = jnp.full((1, 2), 2)  # no pair
    contacts = Contacts(pairs=pairs, history=jnp.zeros((1, 1)), wall_history=jnp.zeros((2, 3, 1)),
                        demand=jnp.int32(0), slot_demand=jnp.int32(0))

    def total(n):
        cf = evaluate(law, baxter.make_params(n=n), particles, contacts, boundaries, 1e-3)
        return jnp.sum(cf.force**2)

    assert np.isfinite(float(jax.grad(total)(60.0)))
