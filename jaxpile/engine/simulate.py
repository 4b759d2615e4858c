"""Pure steps and the chunked runner.

`make_step(law, dt)` gives a pure `step(params, state) -> state`: law parameters
are an explicit pytree argument (never closed over), so `jax.grad` and optax see
them and changing them never recompiles. `Simulator` adds what needs the host:
allocating the neighbour list, checking inputs, running in chunks of a
`lax.fori_loop` with a progress bar, re-allocating and re-running a chunk when the
neighbour list overflowed (no contact is ever dropped), NaN detection, and
"run until at rest".
"""

from __future__ import annotations

import contextlib
import contextvars
import math
from dataclasses import dataclass, field
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxpile.engine import blocks, host_lists
from jaxpile.engine.checkpoint import Checkpoint
from jaxpile.engine import transfer
from jaxpile.engine.compile import jit_one_off
from jaxpile.engine import neighbors as nb
from jaxpile.engine.collisions import HardCollisions, hard_collision_velocities
from jaxpile.errors import InputError
from jaxpile.engine.integrators import Integrator, get_integrator
from jaxpile.engine.loop import Advance, Checkpointer, check_finite, compiled_for, run_chunks
from jaxpile.engine.interactions import ContactForces, evaluate, external_force, in_slots
from jaxpile.laws.base import ContactLaw
from jaxpile.engine.state import Boundaries, Contacts, Particles, SimState

Array = Any


def make_step(law: ContactLaw, dt: float, schedule: Callable | None = None,
              integrator: str | Integrator = "velocity_verlet",
              hard_collisions: HardCollisions | None = None,
              driver: Callable | None = None,
              axis_name: str | None = None) -> Callable[[Any, SimState], SimState]:
    """A pure, jittable `step(params, state) -> state`.

    Args:
      law: the contact law.
      dt: the time step.
      schedule: optional `state -> Boundaries`, the boundaries in force during
        the step (e.g. `gravity_ramp`); it reads the stored boundaries and the
        step count and leaves the stored boundaries as they are.
      integrator: a name in `jaxpile.engine.integrators.INTEGRATORS` (`velocity_verlet`,
        `leapfrog`, `gear`, `implicit_midpoint`) or an `Integrator`. The state
        must have been prepared by `Simulator.init` with the same integrator.
      hard_collisions: optional `collisions.HardCollisions`: pairs that meet fast
        collide impulsively (Liffman et al. 1992, eqs. 1-21) before the step,
        and hand over to the soft law by eq. 22 (see
        `collisions.hard_collision_velocities`). Off by default.
      driver: optional `state -> state` applied at the start of every step,
        inside the compiled loop, whose changes persist: what a protocol does
        while it runs (activate the next parked disk, remove a wall, tilt
        gravity), with its own carried data in `state.protocol_state`. It must
        keep every array's shape and dtype.
      axis_name: the name of the `vmap` axis the step will be mapped over (see
        `jaxpile.engine.ensemble`): the neighbour-list rebuild (with the history carried
        onto the new pairs) is then decided once for the whole batch, so it stays a real branch
        instead of running for every member at every step. None for one pile.
    """
    integ = get_integrator(integrator)

    def step(params, state: SimState) -> SimState:
        if driver is not None:
            state = driver(state)
        boundaries = state.boundaries if schedule is None else schedule(state.set(step=state.step + integ.force_step))

        def forces_at(p: Particles, step_positions=None):
            neighbors, contacts = nb.update_with_contacts(state.neighbors, state.contacts, p.position,
                                                          state.neighbor_settings, axis_name, p.fixed)
            cf = evaluate(law, params, p, contacts, boundaries, dt, step_positions)
            contacts = contacts.set(history=cf.pair.history, wall_history=cf.wall.history)
            force = cf.force + external_force(p, boundaries)
            return force, cf.torque, (neighbors, contacts)

        particles = state.particles
        if hard_collisions is not None:
            velocity, spin, _ = hard_collision_velocities(particles, state.neighbors.idx, boundaries, dt,
                                                          hard_collisions, law.rotation)
            particles = particles.set(velocity=velocity, angular_velocity=spin)
        particles, extra, (neighbors, contacts) = integ.advance(
            particles, state.integrator_state, dt, law.rotation, forces_at)
        return state.set(particles=particles, contacts=contacts, neighbors=neighbors, step=state.step + 1,
                         integrator_state=extra)

    return step


_OBSERVERS: contextvars.ContextVar[tuple] = contextvars.ContextVar("jaxpile_observers", default=())


@contextlib.contextmanager
def observing(observer: Callable[[SimState, float], None]):
    """Inside the block, every `Simulator.run` calls `observer(state, dt)` with
    its first state and the state at each chunk boundary: how a trajectory is
    recorded (`export.trajectory`) through a protocol's own runs without
    threading an argument through each. Host-side; batched runs are not observed."""
    token = _OBSERVERS.set(_OBSERVERS.get() + (observer,))
    try:
        yield observer
    finally:
        _OBSERVERS.reset(token)


def _observe(state: SimState, dt: float) -> None:
    for observer in _OBSERVERS.get():
        observer(state, dt)


def gravity_ramp(steps: int) -> Callable[[SimState], Boundaries]:
    """A schedule that switches gravity on smoothly over `steps` steps,
    g(t) = g s(t / T) with s the C1 smoothstep 3u^2 - 2u^3.

    Loading a pile quasi-statically matters: a pile that starts just touching
    and feels full gravity at once bounces, its contacts unload completely at
    the top of the first bounce, and frictional contacts that carry shear then
    slip (the 45-layer lattice pile collapses that way)."""
    if int(steps) != steps or steps < 1:
        raise InputError(f"the gravity ramp needs a positive whole number of steps; got {steps!r}.")

    def schedule(state: SimState) -> Boundaries:
        u = jnp.clip(state.step.astype(state.boundaries.gravity.dtype) / steps, 0.0, 1.0)
        return state.boundaries.set(gravity=state.boundaries.gravity * u * u * (3.0 - 2.0 * u))

    return schedule


@dataclass
class RunInfo:
    """What a run did (host-side numbers, for summaries and benchmarks)."""

    steps: int = 0
    wall_seconds: float = 0.0
    compile_seconds: float = 0.0
    reallocations: int = 0
    at_rest: bool = False
    max_speed: float = float("nan")
    speed_history: list = field(default_factory=list)

    particles: int = 0
    """Disks advanced each step (every member's, for a batch): the rate's numerator."""

    phases: dict = field(default_factory=dict)
    """A protocol's run: the step each of its phases ended at (`protocols.stages`)."""

    @property
    def particle_steps_per_second(self) -> float:
        return self.particles * self.steps / self.wall_seconds if self.wall_seconds > 0 else float("nan")


@jax.jit  # one program per shape: the runners ask for it on the host after every chunk
def max_speed(state: SimState) -> Array:
    """Largest translational or rim speed |v| + |omega| r over movable active disks."""
    p = state.particles
    spheres = p.angular_velocity.ndim == p.position.ndim  # a spin vector per sphere (any batch axes before)
    spin = jnp.linalg.norm(p.angular_velocity, axis=-1) if spheres else jnp.abs(p.angular_velocity)
    speed = jnp.linalg.norm(p.velocity, axis=-1) + spin * p.radius
    return jnp.max(jnp.where(p.movable, speed, 0.0), initial=0.0)


def check_walls_used(law_name: str, params, boundaries: Boundaries) -> None:
    """Refuses a wall parameter (`wall_*`) set for a set-up without walls: it would act on nothing."""
    if boundaries.wall_normal.shape[0]:
        return
    named = [name for name, value in vars(params).items() if name.startswith("wall_") and value is not None]
    if named:
        raise InputError(f"{law_name} parameter(s) {', '.join(named)} set, but this set-up has no walls (its base, "
                         "if any, is fixed disks, which take the disk parameters): they would act on nothing; "
                         "leave them unset.")


def _is_concrete(tree) -> bool:
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(tree))


class Simulator:
    """A law, a time step and the host-side machinery around the pure step.

    Example:
      >>> import jaxpile
      >>> from jaxpile.laws import hooke
      >>> law = hooke.law(rotation=False)
      >>> params = hooke.make_params(kn=1e4, gamma_n=50.0, mu=0.0, wall_mu=1.0)
      >>> particles, boundaries = jaxpile.protocols.lattice.equilateral_pile(3)
      >>> sim = jaxpile.Simulator(law, dt=5e-4)
      >>> state = sim.init(params, particles, boundaries)
      >>> state = sim.run(params, state, 100, progress=False)

    Args:
      law: a `ContactLaw`.
      dt: the time step.
      schedule: optional `state -> Boundaries` in force at each step
        (`make_step`), e.g. `gravity_ramp(steps)`.
      integrator: `velocity_verlet` (default), `leapfrog` (Baxter et al. 1997),
        `gear` (fifth-order predictor-corrector, Lee & Herrmann 1993),
        `implicit_midpoint` (Liffman et al. 1992, eq. 24), or an `Integrator`.
      driver: optional `state -> state` run at the start of every compiled step
        (`make_step`): protocols insert disks, remove walls, tilt gravity.
      hard_collisions: optional `collisions.HardCollisions(restitution, mu)`:
        fast approaches collide impulsively (Liffman et al. 1992, eqs. 1-22).
      skin: neighbour-list skin (default: 20% of the largest diameter).
      capacity_multiplier: head-room of the neighbour slots at allocation.
      packed_lists: size the neighbour list from the start for the disks
        close-packed (`neighbors.packed_capacity`), so disks that fall, flow or
        are pressed into a pile keep their list; False sizes it for the start
        (smallest, re-allocated as they pack: a compile and a chunk re-run each).
      chunk_steps: steps per compiled chunk between host checks.
      max_initial_overlap: largest allowed start overlap as a fraction of the
        contact distance r_i + r_j (deeper means the start positions are wrong).
      in_play: optional host-side `(state, steps) -> m`: no disk past the first
        m is in play during the next `steps` steps. A pour gives it, and each
        chunk runs on the smallest leading block of disks that holds them
        (`jaxpile.engine.blocks`): the same result bit for bit, cheaper.
    """

    def __init__(
        self,
        law: ContactLaw,
        dt: float,
        *,
        schedule: Callable | None = None,
        integrator: str | Integrator = "velocity_verlet",
        hard_collisions: HardCollisions | None = None,
        driver: Callable | None = None,
        skin: float | None = None,
        capacity_multiplier: float = 1.5,
        packed_lists: bool = True,
        chunk_steps: int = 1000,
        max_initial_overlap: float = 0.05,
        in_play: Callable[[SimState, int], int] | None = None,
    ):
        if not (dt > 0 and math.isfinite(dt)):
            raise InputError(f"dt must be positive and finite; got {dt}.")
        if chunk_steps < 1:
            raise InputError(f"chunk_steps must be >= 1; got {chunk_steps}.")
        if skin is not None and not (skin >= 0 and math.isfinite(skin)):
            raise InputError(f"skin must be >= 0 (a negative skin would drop contacts); got {skin}.")
        if not capacity_multiplier >= 1:
            raise InputError(f"capacity_multiplier must be >= 1; got {capacity_multiplier}.")
        if not max_initial_overlap > 0:
            raise InputError(f"max_initial_overlap must be > 0; got {max_initial_overlap}.")
        self.law = law
        self.dt = float(dt)
        self.skin = skin
        self.capacity_multiplier = capacity_multiplier
        self.packed_lists = bool(packed_lists)
        self.chunk_steps = int(chunk_steps)
        self.max_initial_overlap = max_initial_overlap
        self.schedule = schedule
        self.integrator = get_integrator(integrator)
        if hard_collisions is not None:
            hard_collisions.check()
        self.hard_collisions = hard_collisions
        self.driver = driver
        self.in_play = in_play
        self._block_pairs: dict[int, int] = {}  # pair entries each block size has needed
        self.step = make_step(law, self.dt, schedule, self.integrator, hard_collisions, driver)
        self._advance_jit = jax.jit(self._advance)
        # one program for a rollout called eagerly (and for its derivatives under an eager jax.grad); inlined
        # in a program that calls it
        self._rollout_jit = jax.jit(self._rollout, static_argnums=(2, 3, 4))
        self._refresh_jit = jax.jit(self.refresh_forces)
        self._start_jit = jit_one_off(self.start)  # run once per pile: see engine.compile
        self._compiled: dict = {}
        self._loop = Advance(self._compiled_advance, self._reallocate, self._block_for, blocks.take_jit,
                             blocks.put_jit, lambda new, good: check_finite(new.particles, step=int(new.step),
                                                                              last_good=good))

    # ------------------------------------------------------------------ set-up
    def check_params(self, params, particles: Particles) -> None:
        """Law-level checks and the time-step stability limit."""
        if not _is_concrete(params):
            return
        self.law.validate(params)
        for name, value in vars(params).items():
            if value is not None and np.ndim(value) != 0:
                raise InputError(f"{self.law.name} parameter {name} has shape {np.shape(value)}: one pile takes one "
                                 "value per parameter (batched parameters go to `jaxpile.Ensemble`).")
        movable = np.asarray(particles.active) & ~np.asarray(particles.fixed)  # on the host: no compile
        if not movable.any():
            movable = np.ones_like(movable)
        limit = self.law.stable_time_step(params, float(np.asarray(particles.mass)[movable].min()),
                                          float(np.asarray(particles.radius)[movable].min()))
        limit *= self.integrator.stability_factor
        if self.dt > limit:
            raise InputError(
                f"dt = {self.dt:g} is above the stability limit of the {self.law.name} law with the "
                f"{self.integrator.name} integrator (about {limit:.3g} for the stiffest contact and "
                f"lightest disk); use dt <= {limit:.3g}, or about {limit / 5:.3g} for accurate collisions."
            )

    def check_dimension(self, particles: Particles, boundaries: Boundaries) -> None:
        """Refuses disks and walls or gravity of different dimensions, and, for
        spheres, a law of disks only or hard collisions (the 1992 paper's, 2D)."""
        d = particles.dim
        walls, gravity = boundaries.wall_normal.shape[-1], boundaries.gravity.shape[-1]
        if walls != d or gravity != d:
            raise InputError(f"the particles are {d}D but the walls are {walls}D and gravity {gravity}D: make the "
                             f"boundaries with make_boundaries(dim={d}).")
        self.law.history_for(d)  # a law of disks only refuses spheres
        if d == 3 and self.hard_collisions is not None:
            raise InputError("hard collisions (Liffman et al. 1992) are for disks only; spheres take a soft law.")

    def packed_radius(self, particles: Particles) -> float | None:
        """The radius lists are sized for a packed pile of (`neighbors.allocate`):
        the smallest disk's, or None with `packed_lists=False`."""
        if not self.packed_lists or particles.count == 0:
            return None
        return float(np.min(np.asarray(particles.radius)))

    def neighbor_settings(self, params, particles: Particles, box=None) -> nb.NeighborSettings:
        """The neighbour-list settings `init` uses: the law's reach for the
        largest disk as cutoff, the skin, and the cell-list box (see `init`)."""
        radius = np.asarray(particles.radius)
        r_max = float(radius.max())
        cutoff = float(self.law.interaction_range(params, r_max, r_max))
        skin = 0.2 * 2 * r_max if self.skin is None else float(self.skin)
        origin = None
        if box is None:  # from 0, or from the lowest position where one is negative (a heap about x = 0)
            pos = np.asarray(particles.position)
            low = np.minimum(pos.min(axis=0), 0.0)
            extent = pos.max(axis=0) - low
            box = tuple(float(e) + 2 * (cutoff + skin) for e in extent)
            origin = tuple(float(v) for v in low) if np.any(low < 0) else None
        return nb.NeighborSettings(tuple(float(b) for b in box), cutoff, skin, float(self.capacity_multiplier),
                                   origin)

    def init(self, params, particles: Particles, boundaries: Boundaries, *, box=None,
             protocol_state=None, neighbor_settings: nb.NeighborSettings | None = None) -> SimState:
        """Allocates the neighbour list, zeroes the contact history, checks the
        inputs and evaluates the forces at t = 0.

        Args:
          box: `(width, height)` the neighbour cell list covers; default: the
            bounding box of the disks (and the origin), with a margin of one
            neighbour cutoff on each side.
          protocol_state: the driver's carried data (any pytree), stored in
            `state.protocol_state`.
          neighbor_settings: all the neighbour-list settings at once (overrides
            `box`; an ensemble gives its members one common setting).
        """
        state = self.prepare(params, particles, boundaries, box=box, protocol_state=protocol_state,
                             neighbor_settings=neighbor_settings)
        return self._start_jit(state.particles.count, params, state)

    def prepare(self, params, particles: Particles, boundaries: Boundaries, *, box=None, protocol_state=None,
                neighbor_settings: nb.NeighborSettings | None = None) -> SimState:
        """`init` up to the forces: the checks, the neighbour list and zero
        history, on the host. `start(params, state)` finishes it (it is pure, so
        an ensemble maps it over its members in one call)."""
        self.check_dimension(particles, boundaries)
        self.check_params(params, particles)
        check_walls_used(self.law.name, params, boundaries)
        check_finite(particles, step=0)
        settings = self.neighbor_settings(params, particles, box) if neighbor_settings is None else neighbor_settings
        neighbors = nb.allocate(settings, particles.position, packed_radius=self.packed_radius(particles),
                                fixed=particles.fixed)
        n = neighbors.idx.shape[0]
        h = self.law.history_for(particles.dim)
        w = boundaries.wall_normal.shape[0]
        dtype = particles.position.dtype
        capacity = nb.pair_capacity_for(neighbors.idx, dimension=particles.dim, fixed=particles.fixed)
        pairs = transfer.to_device(host_lists.half_pairs(neighbors.idx, capacity))
        contacts = Contacts(  # put on the device without compiling (see engine.transfer)
            pairs=pairs,
            demand=transfer.to_device(host_lists.pair_count(neighbors.idx), jnp.int32),
            slot_demand=transfer.to_device(host_lists.slot_count(neighbors.idx), jnp.int32),
            history=transfer.zeros((pairs.shape[0], h), dtype),
            wall_history=transfer.zeros((n, w, h), dtype),
        )
        state = SimState(particles, contacts, boundaries, neighbors, transfer.zeros((), jnp.int32), settings,
                         protocol_state=protocol_state)
        self._check_overlaps(state)
        return state

    def start(self, params, state: SimState) -> SimState:
        """The forces at t = 0 and the integrator's own preparation (half kick
        back, Gear derivatives) of a `prepare`d state. Pure."""
        state = self.refresh_forces(params, state)
        boundaries = self.boundaries_at(state)

        def force_fn(position, velocity, angular_velocity):
            p = state.particles.set(position=position, velocity=velocity, angular_velocity=angular_velocity)
            cf = evaluate(self.law, params, p, state.contacts, boundaries, 0.0)
            return cf.force + external_force(p, boundaries), cf.torque

        particles, extra = self.integrator.start(state.particles, self.dt, self.law.rotation, force_fn)
        return state.set(particles=particles, integrator_state=extra)

    def boundaries_at(self, state: SimState) -> Boundaries:
        """The boundaries in force at the state's step (the schedule applied)."""
        return state.boundaries if self.schedule is None else self.schedule(state)

    def refresh_forces(self, params, state: SimState) -> SimState:
        """The state with `force`/`torque` re-evaluated from its positions and
        velocities with these `params` (history not advanced). Pure."""
        boundaries = self.boundaries_at(state)
        p = state.particles
        cf = evaluate(self.law, params, p, state.contacts, boundaries, 0.0)
        return state.set(particles=p.set(force=cf.force + external_force(p, boundaries), torque=cf.torque))

    def contact_forces(self, params, state: SimState) -> ContactForces:
        """Every contact's force at the state as stored, without advancing
        history; `pair` laid out as the neighbour slots `[n, k]` (each disk's
        view of its contacts, `interactions.in_slots`), for the measurements."""
        return _evaluate_jit(state.particles.count, self.law, params, state)

    def _check_overlaps(self, state: SimState) -> None:
        p = state.particles
        idx = np.asarray(state.neighbors.idx)
        n = idx.shape[0]
        pos, rad = np.asarray(p.position), np.asarray(p.radius)
        active = np.asarray(p.active)
        i_idx = np.repeat(np.arange(n)[:, None], idx.shape[1], axis=1)
        ok = (idx < n) & (idx > i_idx)
        i, j = i_idx[ok], idx[ok]
        fixed = np.asarray(p.fixed)
        both = active[i] & active[j] & ~(fixed[i] & fixed[j])  # fixed pairs never interact
        i, j = i[both], j[both]
        if len(i):
            contact = rad[i] + rad[j]
            overlap = (contact - np.linalg.norm(pos[i] - pos[j], axis=-1)) / contact
            worst = int(np.argmax(overlap))
            if overlap[worst] > self.max_initial_overlap:
                raise InputError(
                    f"particles {i[worst]} and {j[worst]} start overlapped by {overlap[worst]:.1%} of their "
                    f"contact distance (allowed: {self.max_initial_overlap:.0%}); move them apart "
                    "or raise max_initial_overlap."
                )
        d = np.asarray(state.boundaries.wall_normal) @ pos.T - np.asarray(state.boundaries.wall_offset)[:, None]
        walls = np.asarray(state.boundaries.wall_active)[:, None] & active[None, :] & ~np.asarray(p.fixed)[None, :]
        depth = np.where(walls, (rad[None, :] - d) / rad[None, :], -np.inf)
        if depth.size and depth.max() > 2 * self.max_initial_overlap:
            wall, i = np.unravel_index(int(np.argmax(depth)), depth.shape)
            raise InputError(
                f"particle {i} starts {depth[wall, i]:.1%} of its radius inside wall {wall}; "
                "move it out of the wall."
            )

    # --------------------------------------------------------- pure rollouts
    def rollout(self, params, state: SimState, n_steps: int, *, checkpoint: bool | int = False,
                refresh: bool = True) -> SimState:
        """`n_steps` steps as one `lax.scan`: pure and differentiable.

        The starting force is first re-evaluated with `params` (`refresh=True`),
        so that the whole rollout, and its gradient, depends on `params` alone.
        No overflow handling happens inside; check `neighbors.overflowed(state)`
        on the result (or call `run` first to size the neighbour list).

        Args:
          checkpoint: memory of the reverse pass. False stores every step's
            intermediates (memory grows like n_steps). True splits the rollout
            into blocks of about sqrt(n_steps) steps under `jax.checkpoint`: the
            reverse pass keeps only the state at each block's start and
            recomputes one block at a time, so memory grows like sqrt(n_steps)
            for about one extra forward pass. An int sets the block length.
        """
        n_steps = int(n_steps)
        if checkpoint is not True and checkpoint is not False and int(checkpoint) < 1:
            raise InputError(f"checkpoint must be True, False or a block length >= 1; got {checkpoint!r}.")
        checkpoint = checkpoint if isinstance(checkpoint, bool) else int(checkpoint)
        return self._rollout_jit(params, state, n_steps, checkpoint, bool(refresh))

    def _rollout(self, params, state: SimState, n_steps: int, checkpoint: bool | int, refresh: bool) -> SimState:
        if refresh:
            state = self.refresh_forces(params, state)
        if not checkpoint:
            return _scan_steps(self.step, params, state, n_steps)
        block = max(1, round(math.sqrt(n_steps))) if checkpoint is True else checkpoint
        blocks, rest = divmod(n_steps, block)
        run_block = jax.checkpoint(lambda p, s: _scan_steps(self.step, p, s, block), prevent_cse=False)
        state, _ = lax.scan(lambda s, _: (run_block(params, s), None), state, None, length=blocks)
        return _scan_steps(self.step, params, state, rest)

    def _advance(self, params, state: SimState, frozen, n_steps) -> SimState:
        """`n_steps` steps (`frozen`: None, one pile has no members to hold still)."""
        return lax.fori_loop(0, n_steps, lambda _, s: self.step(params, s), state)

    def _compiled_advance(self, params, state: SimState, frozen, info: RunInfo):
        return compiled_for(self._compiled, self._advance_jit, (params, state, frozen), info)

    # ------------------------------------------------------------ host runs
    def _reallocate(self, state: SimState, overflowed) -> SimState:
        """Lists with room for what the chunk that ended in `overflowed` found
        (`nb.slots_needed`, `nb.window_needed`, `nb.pairs_needed`), history
        carried over; a list never shrinks."""
        neighbors = nb.allocate(state.neighbor_settings, state.particles.position,
                                packed_radius=self.packed_radius(state.particles),
                                min_slots=nb.slots_needed(state, overflowed),
                                min_window=nb.window_needed(state, overflowed), fixed=state.particles.fixed)
        pairs = nb.pair_capacity_for(neighbors.idx, at_least=nb.pairs_needed(state, overflowed),
                                     dimension=state.particles.dim, fixed=state.particles.fixed)
        contacts = host_lists.contacts_for(state.contacts, state.neighbors.idx, neighbors.idx, pairs)
        return state.set(neighbors=neighbors, contacts=contacts)

    def _block_for(self, state: SimState, n: int, known: dict) -> tuple[int, int] | None:
        """The block of leading disks the next n steps can run on and its pair
        entries (`known`: those each block size has needed), or None (all disks)."""
        if self.in_play is None:
            return None
        size = blocks.block_size(int(self.in_play(state, n)), state.particles.count)
        if size is None or not blocks.fits(state, size):
            return None
        return size, blocks.pair_room(state, size, known.get(size, 0))

    def run(
        self,
        params,
        state: SimState,
        n_steps: int,
        *,
        progress: bool | None = None,
        info: RunInfo | None = None,
        until: Callable[[SimState], bool] | None = None,
        checkpoint: tuple | None = None,
        resumed: bool = False,
    ) -> SimState:
        """Advances `n_steps` in chunks, with overflow handling and NaN checks.

        Args:
          progress: show a progress bar (default: when stderr is a terminal).
          info: a `RunInfo` to accumulate timings into.
          until: optional host predicate checked after each chunk; the run stops
            early when it returns True.
          checkpoint: optional `Checkpoint(path, every, facts)` (or the tuple
            `(path, every[, facts])`): the
            state is saved with `jaxpile.engine.checkpoint.save` at the first chunk
            boundary at or past each multiple of `every` of the step count, and
            at the end of the run. `path` may hold `{step}` (one file per checkpoint); otherwise
            each save replaces the last, atomically. `extra`: a dict of JSON-able
            facts recorded with it. To resume, `checkpoint.restore` the file on
            a fresh state of the same set-up and run the remaining steps: the
            result is bit-identical to the uninterrupted run. If NaN/inf
            appears, the last finite state is saved as `<path>.last-good.npz`
            (named in the `SimulationError`). The facts in `extra` are
            written as they stand at each save (a log that grows is saved up
            to date).
          resumed: `state` is a checkpoint this same run (this `until`) saved:
            `until` was evaluated on it then, so it is evaluated first now, and
            if it holds no step is taken (the uninterrupted run stopped there).
        """
        if not isinstance(state, SimState):
            raise InputError("run() takes a SimState; build one with Simulator.init(params, particles, boundaries).")
        try:  # a count: not NaN, inf, a fraction or text (a 0-d array of one is fine)
            whole = (not isinstance(n_steps, bool) and math.isfinite(float(n_steps)) and int(n_steps) == n_steps
                     and n_steps >= 0)
        except (TypeError, ValueError):
            whole = False
        if not whole:
            raise InputError(f"n_steps must be a whole number >= 0; got {n_steps!r}.")
        self.check_params(params, state.particles)
        check_finite(state.particles, step=int(state.step))
        info = RunInfo() if info is None else info
        info.particles = state.particles.count
        save = self.checkpointer(params, checkpoint)
        stop = resumed and until is not None and until(state)
        return run_chunks(self._loop, params, state, n_steps, chunk_steps=self.chunk_steps, info=info,
                          status=lambda s: (None, until is not None and until(s)), start=(None, stop),
                          save=save, progress=progress,
                          observe=lambda s: _observe(s, self.dt), known_pairs=self._block_pairs)

    def checkpointer(self, params, checkpoint) -> "Checkpointer | None":
        """The saver for `run(checkpoint=...)` (a `Checkpoint`, or its tuple
        `(path, every[, facts])`), or None."""
        checkpoint = Checkpoint.of(checkpoint)
        if checkpoint is None:
            return None
        every = checkpoint.every
        if int(every) != every or every < 1:
            raise InputError(f"the checkpoint interval must be a whole number of steps >= 1; got {every!r}.")
        return Checkpointer(str(checkpoint.path), int(every), dict(checkpoint.facts), self.law, params)

    def run_until_rest(
        self,
        params,
        state: SimState,
        *,
        speed_tolerance: float = 1e-4,
        max_steps: int = 1_000_000,
        progress: bool | None = None,
        checkpoint: tuple | None = None,
        resumed: bool = False,
    ) -> tuple[SimState, RunInfo]:
        """Runs until every movable disk is slower than `speed_tolerance`
        (checked after each chunk) or `max_steps` have been taken
        (`checkpoint` and `resumed` as in `run`)."""
        if not speed_tolerance > 0:
            raise InputError(f"speed_tolerance must be > 0; got {speed_tolerance}.")
        info = RunInfo()

        def at_rest(s: SimState) -> bool:
            speed = float(max_speed(s))
            info.speed_history.append((int(s.step), speed))
            return speed < speed_tolerance

        state = self.run(params, state, max_steps, progress=progress, info=info, until=at_rest, checkpoint=checkpoint,
                         resumed=resumed)
        info.max_speed = float(max_speed(state))
        info.at_rest = info.max_speed < speed_tolerance
        return state, info


def _scan_steps(step, params, state: SimState, n: int) -> SimState:
    if n == 0:
        return state
    state, _ = lax.scan(lambda s, _: (step(params, s), None), state, None, length=n)
    return state


def _evaluate(law: ContactLaw, params, state: SimState) -> ContactForces:
    cf = evaluate(law, params, state.particles, state.contacts, state.boundaries, 0.0)
    return cf._replace(pair=in_slots(cf.pair, state.contacts.pairs, state.neighbors.idx))


_evaluate_jit = jit_one_off(_evaluate, static_argnums=0)  # a measurement's one call: see engine.compile
