"""Batched ensembles: one compiled call advances B piles at once.

A `Simulator`'s pure step is mapped with `jax.vmap` over a leading batch axis
of the state and of the law parameters, so 16 seeds x 8 friction values of a
protocol are one compiled loop. What makes that work for DEM:

* Shapes. Every member has the same number of disks and one shared neighbour
  list capacity (slots per disk and per cell), the largest any member needs
  (`stack_states`); the extra slots stay empty and cost a little work.
* Decisions. jax-md's `lax.cond` rebuild becomes a select under `vmap`, so every
  member would rebuild at every step. The batched step (`make_step(...,
  axis_name="batch")`) ors the members' needs (`neighbors.any_member`, a
  `lax.pmax` over the named axis) and rebuilds the whole batch only on steps
  where some member needs it, carrying the contact history onto the new pairs
  in the same branch (`benchmarks/ensemble_throughput.py` measures it).
* Members one after another. Members acting out of phase (poured heaps, silos)
  make that or rebuild nearly every step, and a driver's `cond` (a flux pile's
  insertion) runs every step for every member. With `sequential=True` (a
  protocol's `Batch.sequential`), on one CPU device, the members run one after
  another inside the same compiled call (`lax.map` of each member's own loop),
  each rebuilding and running its driver's branch on its own steps; boxes and
  drops gain little and stay side by side. XLA compiles the two programs apart,
  so their states agree bit for bit or at round-off
  (docs/choices.md#members-side-by-side-or-one-after-another).
* Overflow. After each chunk the host checks every member; if any list
  overflowed, the whole batch gets a larger common capacity and the chunk is
  re-run from its start (no contact is ever dropped).
* Finished members. With `until`, a member whose predicate holds at the start
  of a chunk is frozen, so it ends exactly where `Simulator.run(until=...)`
  would have ended it alone; the run stops when every member has finished.
* Devices. With several `jax.devices()` (GPUs, or CPU devices from
  `XLA_FLAGS=--xla_force_host_platform_device_count=N`) the batch axis is
  sharded over them (`NamedSharding` on a one-axis mesh), the rebuild decision
  becoming one small all-reduce per step; the batch is padded with copies of
  its last member to a multiple of the device count (the padding dropped from
  the results). A batch stays on its process's `jax.local_devices()`: across
  processes and hosts a sweep runs whole batches on each (`jaxpile.distributed`),
  so no step waits for the network.
"""

from __future__ import annotations

from typing import Any, Callable, Protocol, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxpile.engine import blocks
from jaxpile.engine import neighbors as nb
from jaxpile.engine.batch import at_capacity, batch_size, member, stack, stack_states  # noqa: F401  (public here too)
from jaxpile.engine.compile import jit_one_off
from jaxpile.errors import InputError, SimulationError
from jaxpile.engine.loop import Advance, compiled_for, non_finite_disks, run_chunks
from jaxpile.engine.simulate import RunInfo, Simulator, make_step, max_speed
from jaxpile.engine.state import Boundaries, Particles, SimState


class Setup(Protocol):
    """What a member's set-up gives the ensemble (a `jaxpile.protocols.Setup`
    is one): the engine reads these and imports no protocol."""

    particles: Particles
    boundaries: Boundaries
    schedule: Callable | None
    driver: Callable | None
    protocol_state: Any
    box: tuple | None
    info: dict

Array = Any

AXIS = "batch"
"""The name of the batch axis (for `lax.pmax` and friends inside the step)."""


class Ensemble:
    """A `Simulator`'s step vmapped over a batch of piles (see the module notes).

    Example:
      >>> from jaxpile.protocols import box                              # doctest: +SKIP
      >>> sim = box.make_simulator("lee-herrmann")
      >>> ens = Ensemble(sim)
      >>> protocols = [box.protocol(72, width=1.6, height=1.6, seed=s) for s in range(4)]
      >>> params = [box.law_and_params("lee-herrmann", {"mu": mu})[2] for mu in (0.1, 0.1, 0.3, 0.3)]
      >>> state = ens.init(params, protocols)
      >>> state = ens.run(params, state, 100_000, until=lambda s: s.protocol_state.settled_at >= 0)

    Args:
      sim: the simulator whose law, dt, schedule, integrator, driver and
        chunking every member shares.
      devices: the devices to shard the batch over (default: all of this
        process's, `jax.local_devices()`; one device: no sharding).
      sequential: advance the members one after another inside each compiled
        chunk, each with its own rebuilds, instead of side by side (vmapped,
        the rebuild decided for the batch): faster where members rebuild out of
        phase, as poured heaps do (see the module notes). It applies on one CPU
        device; on a GPU, or sharded over devices, the members run side by side
        (`sequential` says which is used).
    """

    def __init__(self, sim: Simulator, *, devices: Sequence | None = None, sequential: bool = False):
        if not isinstance(sim, Simulator):
            raise InputError(f"Ensemble takes a Simulator; got {type(sim).__name__}.")
        self.sim = sim
        self.devices = list(jax.local_devices() if devices is None else devices)
        if not self.devices:
            raise InputError("devices is empty; pass None for all of jax.local_devices().")
        if not isinstance(sequential, bool):
            raise InputError(f"sequential must be True or False; got {sequential!r}.")
        # one CPU device, and the default backend too: an unsharded batch runs where jit puts it
        one_cpu = len(self.devices) == 1 and self.devices[0].platform == "cpu" and jax.default_backend() == "cpu"
        self.sequential = sequential and one_cpu
        # side by side: the rebuild decided for the batch (a real branch); one after another: each member's own
        self.step = make_step(sim.law, sim.dt, sim.schedule, sim.integrator, sim.hard_collisions, sim.driver,
                              axis_name=None if self.sequential else AXIS)
        self.mesh = Mesh(np.array(self.devices), (AXIS,)) if len(self.devices) > 1 else None
        if self.mesh is None:
            self._advance_jit = jax.jit(self._advance)
            self._start_jit = jit_one_off(jax.vmap(sim.start))  # run once per batch: see engine.compile
        else:  # every leaf split along the batch axis, in and out; the step count replicated
            split, whole = NamedSharding(self.mesh, PartitionSpec(AXIS)), NamedSharding(self.mesh, PartitionSpec())
            self._advance_jit = jax.jit(self._advance, in_shardings=(split, split, split, whole), out_shardings=split)
            self._start_jit = jit_one_off(jax.vmap(sim.start), in_shardings=(split, split), out_shardings=split)
        self._compiled: dict = {}
        # the simulator's `in_play` blocks, for every member at once (see `_block_for`)
        self._take_jit = jax.jit(lambda s, size, room: jax.vmap(lambda m: blocks.take(m, size, room))(s),
                                 static_argnums=(1, 2))
        self._put_jit = jax.jit(jax.vmap(blocks.put))
        self._block_pairs: dict[int, int] = {}  # pair entries each block size has needed
        self._loop = Advance(self._compiled_advance, self._reallocate, self._block_for,
                             lambda s, size, room: self.shard(self._take_jit(s, size, room)),
                             lambda s, new: self.shard(self._put_jit(s, new)),
                             lambda new, good: _check_batch_finite(new, last_good=good),
                             "the batch's neighbour list")

    # --------------------------------------------------------------- set-up
    def init(self, params, protocols: Sequence[Setup]) -> SimState:
        """Starts every member (each checked as `Simulator.init` checks one pile)
        and stacks them on a shared neighbour box and capacity.

        Args:
          params: one params pytree per member (a list), or one batched pytree
            with a leading axis of the members' count, or one unbatched pytree
            shared by all.
          protocols: one `Setup` per member; same disk count, driver and schedule.

        Returns:
          The batched `SimState` (leading axis: members), sharded over the
          devices when there are several.
        """
        protocols = list(protocols)
        if not protocols:
            raise InputError("an ensemble needs at least one member (protocols is empty).")
        params_list = self.member_params(params, len(protocols))
        if any((p.box is None) != (protocols[0].box is None) for p in protocols):
            raise InputError("either every member's protocol gives a neighbour box or none does.")
        # one setting for all: the longest reach and skin, a box that covers every member
        each = [self.sim.neighbor_settings(prm, p.particles, p.box) for p, prm in zip(protocols, params_list)]
        box, origin = tuple(float(b) for b in np.max([s.box for s in each], axis=0)), None
        if any(s.origin is not None for s in each):  # the grid from the lowest corner to the highest
            low = np.min([s.origin or (0.0,) * len(s.box) for s in each], axis=0)
            high = np.max([np.add(s.origin or 0.0, s.box) for s in each], axis=0)
            box, origin = tuple(float(b) for b in high - low), tuple(float(v) for v in low)
        settings = nb.NeighborSettings(box=box, cutoff=max(s.cutoff for s in each), skin=max(s.skin for s in each),
                                       capacity_multiplier=each[0].capacity_multiplier, origin=origin)
        states = []
        for i, (p, prm) in enumerate(zip(protocols, params_list)):
            for name in ("driver", "schedule"):
                if getattr(p, name) is not None and getattr(p, name) is not getattr(self.sim, name):
                    raise InputError(f"member {i}'s protocol {name} is not the simulator's; build the simulator "
                                     f"for this protocol (e.g. its make_simulator).")
            if p.info.get("dt") is not None and abs(p.info["dt"] - self.sim.dt) > 1e-12 * self.sim.dt:
                raise InputError(f"member {i} was set up for dt = {p.info['dt']:g} but the simulator uses "
                                 f"dt = {self.sim.dt:g}; pass the same dt to both.")
            states.append(self.sim.prepare(prm, p.particles, p.boundaries, protocol_state=p.protocol_state,
                                           neighbor_settings=settings))
        # the level a member's own start compiles at (see engine.compile), so that a
        # member starts exactly as the same pile run alone
        params, state = self.shard(stack(params_list)), self.shard(stack_states(states))
        return self._start_jit(states[0].particles.count, params, state)

    def member_params(self, params, count: int) -> list:
        """`params` as a list of `count` unbatched pytrees (see `init`)."""
        if isinstance(params, (list, tuple)):
            if len(params) != count:
                raise InputError(f"got {len(params)} params for {count} members; give one per member.")
            return list(params)
        leaves = jax.tree.leaves(params)
        if leaves and all(np.ndim(x) >= 1 for x in leaves):
            if batch_size(params) != count:
                raise InputError(f"the batched params have {batch_size(params)} members, the ensemble {count}.")
            return [member(params, i) for i in range(count)]
        return [params] * count

    def as_batch(self, params, count: int):
        """`params` (a list, a batched pytree, or one shared pytree) as a batched
        pytree matching a (possibly padded) batch of `count`, on the devices."""
        if isinstance(params, (list, tuple)):
            tree = stack(list(params))
        elif _is_batched(params):
            tree = params
        else:
            tree = stack([params] * count)
        n = batch_size(tree)
        if n != count and self.padded_size(n) != count:
            raise InputError(f"the params have {n} members, the state {count}.")
        return self.shard(tree)

    # -------------------------------------------------------------- sharding
    def padded_size(self, count: int) -> int:
        """The batch size after padding to a multiple of the device count."""
        d = len(self.devices)
        return -(-count // d) * d

    def shard(self, tree):
        """Pads a batched pytree to a multiple of the device count (copies of the
        last member) and places it sharded along the batch axis."""
        if self.mesh is None:
            return tree
        count = batch_size(tree)
        extra = self.padded_size(count) - count
        if extra:
            tree = jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)]), tree)
        sharding = NamedSharding(self.mesh, PartitionSpec(AXIS))
        return jax.device_put(tree, sharding)

    # ------------------------------------------------------------------ runs
    def _advance(self, params, state: SimState, frozen, n_steps) -> SimState:
        def one(prm, s, stop):
            new = lax.fori_loop(0, n_steps, lambda _, x: self.step(prm, x), s)
            return jax.tree.map(lambda a, b: jnp.where(stop, a, b), s, new)

        if self.sequential:
            return lax.map(lambda member: one(*member), (params, state, frozen))
        return jax.vmap(one, axis_name=AXIS)(params, state, frozen)

    def _compiled_advance(self, params, state, frozen, info: RunInfo):
        return compiled_for(self._compiled, self._advance_jit, (params, state, frozen), info)

    def _reallocate(self, state: SimState, overflowed: SimState) -> SimState:
        """Every member re-allocated from its chunk-start positions with room for
        what the chunk found in any member (as `Simulator._reallocate`), at the
        largest capacity any needs."""
        settings = state.neighbor_settings
        least_slots, least_window = nb.slots_needed(state, overflowed), nb.window_needed(state, overflowed)
        members = [member(state, i) for i in range(batch_size(state))]
        fresh = [nb.allocate(settings, m.particles.position, packed_radius=self.sim.packed_radius(m.particles),
                             min_slots=least_slots, min_window=least_window, fixed=m.particles.fixed)
                 for m in members]
        slots = max(f.max_occupancy for f in fresh)
        cells = None if fresh[0].cell_list_capacity is None else max(
            max(f.cell_list_capacity for f in fresh), state.neighbors.cell_list_capacity or 0)
        needed = nb.pairs_needed(state, overflowed)
        pairs = max(nb.pair_capacity_for(f.idx, needed, dimension=state.particles.dim, fixed=m.particles.fixed)
                    for f, m in zip(fresh, members))
        members = [at_capacity(m, slots, cells, pairs) for m in members]
        return self.shard(stack(members))

    def _block_for(self, state: SimState, n: int, known: dict) -> tuple[int, int] | None:
        """The block of leading disks that every member's next n steps can run
        on (`Simulator._block_for` with the largest `in_play` of the batch, and
        every member must `blocks.fits` it) and its pair entries, the most any
        member needs; or None (the chunk runs on every disk). A pour pays for
        the disks poured, as one pile does: the same arithmetic, so the same
        result bit for bit."""
        if self.sim.in_play is None:
            return None
        host = jax.device_get(state)
        count = host.particles.position.shape[1]
        each = [member(host, i) for i in range(batch_size(host))]
        size = blocks.block_size(max(int(self.sim.in_play(m, n)) for m in each), count)
        if size is None or not all(blocks.fits(m, size) for m in each):
            return None
        return size, max(blocks.pair_room(m, size, known.get(size, 0)) for m in each)

    def run(self, params, state: SimState, n_steps: int, *, until: Callable[[SimState], Array] | None = None,
            progress: bool | None = None, info: RunInfo | None = None, checkpoint: tuple | None = None,
            resumed: bool = False) -> SimState:
        """Advances every member up to `n_steps`, in chunks of the simulator's
        `chunk_steps`, with batch-wide overflow handling and NaN checks.

        Args:
          params: as in `init` (a list, a batched pytree, or one shared pytree).
          state: the batched state from `init` (or a previous `run`).
          until: optional traceable predicate `state -> bool` of one member
            (vmapped over the batch); a member whose predicate holds at a chunk
            boundary is frozen there, and the run ends when all are.
          progress: a progress bar over steps with the count of finished members
            (default: when stderr is a terminal).
          info: a `RunInfo` to accumulate timings into (`steps` counts batch steps).
          checkpoint: optional `(path, every[, extra])` as in `Simulator.run`:
            the whole batch is saved (`jaxpile.engine.checkpoint.save`) at chunk
            boundaries. To resume, `checkpoint.restore` it on a fresh
            `init` of the same members and run the steps left (the budget less
            `checkpoint.step_of(state)` for members started at step 0):
            members frozen at the save stay frozen, and the batch ends
            bit-identical to the uninterrupted run.
          resumed: `state` is a save of this same run: `until` is evaluated on
            it first (as it was when saved), so members finished there stay
            frozen; a fresh run checks `until` only at chunk boundaries.

        Returns:
          The batched state (padding members included when sharded; use
          `members(state)` or `member(state, i)` for the real ones).
        """
        if not isinstance(state, SimState):
            raise InputError("run() takes the batched SimState from Ensemble.init.")
        if int(n_steps) != n_steps or n_steps < 0:
            raise InputError(f"n_steps must be a whole number >= 0; got {n_steps!r}.")
        count = batch_size(state)
        params = self.as_batch(params, count)
        self.sim.check_params(member(params, 0), member(jax.device_get(state.particles), 0))
        _check_batch_finite(state, last_good=None)
        info = RunInfo() if info is None else info
        info.particles = count * state.particles.position.shape[1]
        finished = jax.jit(jax.vmap(until)) if until is not None else None
        last = [finished(state) if finished is not None and resumed else jnp.zeros(count, bool)]

        def status(s: SimState):
            if finished is not None:
                last[0] = finished(s)
            return self.shard(last[0]), bool(jnp.all(last[0]))

        state = run_chunks(self._loop, params, state, int(n_steps), chunk_steps=self.sim.chunk_steps, info=info,
                           status=status, start=(self.shard(last[0]), bool(jnp.all(last[0]))),
                           save=self.sim.checkpointer(params, checkpoint), progress=progress,
                           postfix=None if finished is None else
                           lambda frozen: {"finished": f"{int(jnp.sum(frozen))}/{count}"},
                           known_pairs=self._block_pairs)
        if finished is not None:
            info.at_rest = bool(jnp.all(last[0]))
        info.max_speed = float(_batch_max_speed(state))
        return state


def _is_batched(params) -> bool:
    leaves = jax.tree.leaves(params)
    return bool(leaves) and all(np.ndim(x) >= 1 for x in leaves)


def members(state: SimState, count: int | None = None) -> list[SimState]:
    """The first `count` members (default: all) of a batched state, each a plain `SimState`."""
    count = batch_size(state) if count is None else int(count)
    return [member(state, i) for i in range(count)]


_batch_max_speed = jax.jit(lambda state: jnp.max(jax.vmap(max_speed)(state)))


def _check_batch_finite(state: SimState, *, last_good) -> None:
    p = state.particles
    bad = non_finite_disks(p)
    if not np.asarray(bad).any():
        return
    bad = np.asarray(bad)
    m = int(np.argmax(bad.any(axis=1)))
    i = int(np.argmax(bad[m]))
    step = int(np.asarray(state.step)[m])
    where = f"member {m}, particle {i} (position {np.asarray(p.position[m, i])}, velocity {np.asarray(p.velocity[m, i])})"
    if last_good is None:
        raise InputError(f"non-finite position or velocity in the input: {where}.")
    raise SimulationError(f"non-finite position or velocity by step {step}: first offending {where}. "
                          "The last good batch is in this error's `last_good_state`.",
                          last_good_state=last_good, step=step)


__all__ = ["AXIS", "Ensemble", "at_capacity", "batch_size", "member", "members", "stack", "stack_states"]
