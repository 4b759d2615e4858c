"""A batch of piles as one pytree: member states stacked on a leading axis.

The tree helpers that both the batched runner (`jaxpile.engine.ensemble`) and the
checkpoints (`jaxpile.engine.checkpoint`, which restores a batch) need, in a module
of their own so that neither imports the other (no import cycle
checkpoint -> ensemble -> simulate -> checkpoint). `jaxpile.engine.ensemble`
re-exports every name here.
"""

from __future__ import annotations

from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxpile.engine import host_lists
from jaxpile.engine import transfer
from jaxpile.engine import neighbors as nb
from jaxpile.errors import InputError, SimulationError
from jaxpile.engine.state import SimState


def _concrete(x) -> bool:
    """A concrete array with its own dtype: a numpy array, or a jax array that
    is neither traced nor weakly typed (a Python scalar's weak type must
    survive, or a float32 pile's params would turn it float64)."""
    if isinstance(x, np.ndarray):
        return True
    return isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer) and not x.weak_type


def _one_device(x) -> bool:
    return isinstance(x, np.ndarray) or len(x.sharding.device_set) == 1


def stack(trees: Sequence[Any]) -> Any:
    """Stacks pytrees of the same structure along a new leading axis.

    Concrete leaves are stacked by numpy on the host: `jnp.stack` run op by
    op would compile a program for every leaf shape and member count (see
    docs/choices.md#eager-compiles)."""
    if not trees:
        raise InputError("an ensemble needs at least one member.")

    def one(*xs):
        if all(_concrete(x) for x in xs):
            return transfer.to_device(np.stack([np.asarray(x) for x in xs]))
        return jnp.stack([jnp.asarray(x) for x in xs])

    return jax.tree.map(one, *trees)


_member_jit = jax.jit(lambda tree, i: jax.tree.map(lambda x: x[i], tree))


def member(tree: Any, i: int) -> Any:
    """Member i of a batched pytree (its leaves indexed on the leading axis).

    A batch of jax arrays on one device is cut by one compiled program per
    batch shape, the index an argument: indexed op by op, every leaf would
    compile a slice for every member (docs/choices.md#eager-compiles)."""
    leaves = jax.tree.leaves(tree)
    if leaves and all(isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer) and _one_device(x)
                      for x in leaves):
        return _member_jit(tree, jnp.int32(i))
    return jax.tree.map(lambda x: x[i], tree)


def batch_size(tree: Any) -> int:
    """The leading (batch) axis length of a batched pytree."""
    leaves = jax.tree.leaves(tree)
    if not leaves:
        raise InputError("the batched pytree has no arrays.")
    return int(np.shape(leaves[0])[0])


def _capacity(state: SimState) -> tuple[int, int | None, int]:
    return state.neighbors.max_occupancy, state.neighbors.cell_list_capacity, int(state.contacts.pairs.shape[-2])


def at_capacity(state: SimState, max_occupancy: int, cell_capacity: int | None, pairs: int | None = None) -> SimState:
    """The state with its neighbour list rebuilt at the given capacity (and
    `pairs` half-pair entries; default: as many as now) and its contact history
    carried onto the new pairs."""
    pairs = int(state.contacts.pairs.shape[-2]) if pairs is None else int(pairs)
    if _capacity(state) == (max_occupancy, cell_capacity, pairs):
        return state
    neighbors = nb.rebuild_at_capacity(state.neighbors, state.particles.position, max_occupancy, cell_capacity,
                                       state.neighbor_settings, state.particles.fixed)
    return state.set(neighbors=neighbors,
                     contacts=host_lists.contacts_for(state.contacts, state.neighbors.idx, neighbors.idx, pairs))


def stack_states(states: Sequence[SimState]) -> SimState:
    """One batched state from member states of the same size and settings:
    every neighbour list is brought to the largest capacity of any member."""
    states = list(states)
    if not states:
        raise InputError("an ensemble needs at least one member.")
    first = states[0]
    for i, s in enumerate(states[1:], 1):
        if s.particles.count != first.particles.count:
            raise InputError(f"every member must hold the same number of disks; member 0 has "
                             f"{first.particles.count}, member {i} has {s.particles.count}.")
        if s.neighbor_settings != first.neighbor_settings:
            raise InputError(f"member {i}'s neighbour settings {s.neighbor_settings} differ from member 0's "
                             f"{first.neighbor_settings}; build every member with the same box (Ensemble.init "
                             "does this).")
    slots = max(s.neighbors.max_occupancy for s in states)
    cells = [s.neighbors.cell_list_capacity for s in states]
    cells = None if any(c is None for c in cells) else max(cells)
    pairs = max(int(s.contacts.pairs.shape[-2]) for s in states)
    states = [at_capacity(s, slots, cells, pairs) for s in states]
    overflowed = [i for i, s in enumerate(states) if bool(nb.overflowed(s))]
    if overflowed:  # cannot happen at the largest allocated capacity; never pass it on silently
        raise SimulationError(f"the shared neighbour capacity overflowed for member(s) {overflowed}.", states[0])
    return stack(states)


# ----------------------------------------------------------------- ensemble
