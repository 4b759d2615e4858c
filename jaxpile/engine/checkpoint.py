"""Checkpoints: the whole simulation state on disk, written atomically, and
restored so that a resumed run continues bit for bit.

A checkpoint is one `.npz` with every array of the `SimState` pytree (particles,
contact history, boundaries, the neighbour list with its reference positions,
the step count, the integrator's and the protocol's carried state: insertion
counters, PRNG keys, logs) under its pytree path, plus JSON metadata: the
jaxpile version, the law, its parameters, the precision, the neighbour-list
capacity and settings, and whatever the caller adds (the command that made the
run, say). It is written to a temporary file in the same folder, fsync'ed and
renamed over the old one, so a kill at any moment leaves the last complete
checkpoint readable.

To resume, build the same set-up again (same simulator, law, parameters and
protocol) and hand its fresh state to `restore` as the template: it re-creates
the neighbour list at the saved capacity (a run that re-allocated keeps its
larger list) and fills every array from the file, after checking that the
law, parameters, precision and shapes match.

Bit-identical continuation also needs the same chunk boundaries (a re-allocation
re-runs a chunk from its start, and the slot order it leaves changes the order
of the force sums): `Simulator.run(..., checkpoint=...)` saves only at chunk
boundaries, which a resumed run keeps.
"""

from __future__ import annotations

import json
import os
import zipfile
from typing import Any, NamedTuple

import warnings

import jax
import numpy as np

from jaxpile import config
from jaxpile.engine import batch
from jaxpile.engine import host_lists
from jaxpile.engine import transfer
from jaxpile.engine import neighbors as nb
from jaxpile.errors import InputError
from jaxpile.io import atomic_write
from jaxpile.engine.state import SimState

FORMAT = 3  # 2: contact history per half pair (Contacts.pairs); 3: Contacts.slot_demand. Bump when the layout changes
OLDEST_FORMAT = 2
"""The oldest format `restore` reads: a format-2 file lacks `Contacts.slot_demand`,
which it is given from its list (`_SINCE_3`)."""

_SINCE_3 = ".contacts.slot_demand"
"""Format 3's one new array, given to a format-2 file as its list's fullest
row. It only sizes a re-allocation after a chunk whose rebuild overflowed the
slots, and such a rebuild raises it past the slots itself: at a chunk boundary
any value up to the slots resumes the same run, bit for bit. The array itself
may then read lower than the uninterrupted run's (the most neighbours since
the list was allocated) until the run's next re-allocation restarts it."""


def _version() -> str:
    from jaxpile._version import __version__

    return __version__


def _leaves(state: SimState) -> tuple[list[str], list[Any], Any]:
    paths_and_leaves, treedef = jax.tree_util.tree_flatten_with_path(state)
    names = [jax.tree_util.keystr(path) for path, _ in paths_and_leaves]
    return names, [leaf for _, leaf in paths_and_leaves], treedef


def step_of(state: SimState) -> int:
    """The state's step count; for a batch (`jaxpile.engine.ensemble`) the furthest
    member's, which is the batch's own step count (members still running are all there)."""
    return int(np.max(np.asarray(state.step)))


def batch_of(state: SimState) -> int | None:
    """The batch size of an ensemble's state, None for one pile."""
    return int(np.shape(state.step)[0]) if np.ndim(state.step) else None


def _precision(state: SimState) -> str:
    return str(state.particles.position.dtype)


def _params_record(params) -> dict:
    return {k: (None if v is None else np.asarray(v).tolist()) for k, v in vars(params).items()}


def _law_name_and_reading(law) -> tuple[str, dict | None]:
    """`law` is a law's name or the `ContactLaw` itself; the latter also gives
    its reading (rotation and options), which a checkpoint records and checks."""
    if isinstance(law, str):
        return law, None
    return law.name, {"rotation": bool(law.rotation), **dict(law.options)}


def metadata(state: SimState, law, params, **extra) -> dict:
    """What a checkpoint records besides the arrays (`law`: the `ContactLaw`, or its name)."""
    law_name, reading = _law_name_and_reading(law)
    return {
        "format": FORMAT,
        "jaxpile_version": _version(),
        "law": law_name,
        "law_reading": reading,
        "params": _params_record(params),
        "precision": _precision(state),
        "n_particles": int(state.particles.count),
        "step": step_of(state),
        "batch": batch_of(state),
        "neighbor_capacity": int(state.neighbors.max_occupancy),
        "cell_capacity": None if state.neighbors.cell_list_capacity is None else int(state.neighbors.cell_list_capacity),
        "neighbor_settings": list(state.neighbor_settings),
        "settings": config.settings(),  # float64 and XLA's: a resume under others ends elsewhere (round-off, grown)
        "extra": extra,
    }


def _json_value(value):
    """numpy scalars and arrays in the recorded facts (a sweep's rows, say) as plain JSON."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable: record plain numbers, strings and lists.")


def save(path, state: SimState, law, params, **extra) -> None:
    """Writes `state` (every array of it) and its metadata to `path`, atomically.

    Args:
      path: the `.npz` file (replaced atomically if it exists).
      state: the state, at a chunk boundary of its run.
      law: the `ContactLaw` (its name and reading are checked on restore), or
        only its name.
      params: the law's parameters, recorded and checked on restore.
      **extra: JSON-able facts to keep with it (e.g. the command line).
    """
    names, leaves, _ = _leaves(state)
    arrays = {f"leaf:{name}": np.asarray(jax.device_get(leaf)) for name, leaf in zip(names, leaves)}
    arrays["metadata"] = np.asarray(json.dumps(metadata(state, law, params, **extra), default=_json_value))
    atomic_write(path, lambda f: np.savez(f, **arrays))


class Checkpoint(NamedTuple):
    """Where a run saves itself, how often, and the facts recorded with each save.

    `Simulator.run(checkpoint=...)`, `Ensemble.run`, a protocol's run and a
    sweep take one (or the plain tuple `(path, every[, facts])` it is).

    Attributes:
      path: the `.npz` file; it may hold `{step}` (one file per save).
      every: the save interval in steps (at the first chunk boundary at or past
        each multiple, and at the run's end).
      facts: JSON-able facts written with each save, as they stand then (a
        log that grows is saved up to date).
    """

    path: str
    every: int
    facts: dict = {}

    @classmethod
    def of(cls, value) -> "Checkpoint | None":
        """`value` (None, a `Checkpoint` or `(path, every[, facts])`) as a `Checkpoint`, or None."""
        if value is None or isinstance(value, cls):
            return value
        if not isinstance(value, tuple) or len(value) not in (2, 3):
            raise InputError(f"checkpoint must be (path, every) or (path, every, extra); got {value!r}.")
        return cls(*value)

    def with_facts(self, path=None, **facts) -> "Checkpoint":
        """This checkpoint with more facts (and, given `path`, another file):
        how a run of several stages or phases records where a save belongs."""
        return Checkpoint(self.path if path is None else path, self.every, {**self.facts, **facts})


def with_facts(spec, path=None, **facts) -> Checkpoint | None:
    """`Checkpoint.of(spec).with_facts(path, **facts)`; None stays None."""
    spec = Checkpoint.of(spec)
    return None if spec is None else spec.with_facts(path, **facts)


def sibling(path, stage: str) -> str:
    """`DIR/checkpoint.npz` -> `DIR/checkpoint.<stage>.npz`: the file of one
    stage of a run of several (the box pile a tilt starts from)."""
    stem, suffix = os.path.splitext(str(path))
    return f"{stem}.{stage}{suffix or '.npz'}"


def stage_files(path) -> list[str]:
    """The files of the other stages of the run saved at `path`
    (`checkpoint.<stage>.npz`, `sibling`), the last good one's included."""
    import glob

    stem, suffix = os.path.splitext(str(path))
    return sorted(glob.glob(glob.escape(stem) + ".*" + (suffix or ".npz")))


def in_folder(folder) -> str | None:
    """The checkpoint to resume or draw the `jaxpile pile` or `sweep` run in
    `folder` from: `checkpoint.npz`, or else the file of an earlier stage (a
    tilt run stopped while still building its box pile: `checkpoint.box.npz`);
    None when there is neither."""
    path = os.path.join(folder, "checkpoint.npz")
    if os.path.exists(path):
        return path
    stages = [f for f in stage_files(path) if f != sibling(path, "last-good")]
    return stages[0] if stages else None


def _unreadable(path, e: Exception) -> InputError:
    """One line, in jaxpile's words, for a file `np.load` cannot give us."""
    if isinstance(e, FileNotFoundError):
        why = "there is no such file"
    elif isinstance(e, IsADirectoryError):
        why = "it is a folder"
    elif isinstance(e, (zipfile.BadZipFile, EOFError)) or "zip" in str(e).lower():
        why = "it is not a complete .npz file (truncated, or another kind of file)"
    elif "pickle" in str(e).lower() or "object arrays" in str(e).lower():
        why = "it holds Python objects, which a jaxpile checkpoint never does (it may not be safe to load)"
    elif isinstance(e, KeyError):
        why = "it is an .npz without jaxpile's metadata (written by another program)"
    elif isinstance(e, PermissionError):
        why = "it cannot be read (permissions)"
    else:
        why = f"it cannot be read as one ({type(e).__name__})"
    return InputError(f"{path} is not a readable jaxpile checkpoint: {why}.")


def read_metadata(path) -> dict:
    """The metadata of a checkpoint, without its arrays."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["metadata"]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise _unreadable(path, e) from e
    if not isinstance(meta, dict) or not isinstance(meta.get("format"), int):
        raise InputError(f"{path} is not a readable jaxpile checkpoint: its metadata is not jaxpile's.")
    return meta


def read_leaves(path) -> dict:
    """The saved arrays of a checkpoint by pytree path (`.particles.position`, ...),
    a format-2 file's given the one array format 3 added (`_SINCE_3`)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            leaves = {k[len("leaf:"):]: data[k] for k in data.files if k.startswith("leaf:")}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
        raise _unreadable(path, e) from e
    if ".contacts.pairs" in leaves and ".neighbors.idx" in leaves and _SINCE_3 not in leaves:
        leaves[_SINCE_3] = host_lists.slot_count(leaves[".neighbors.idx"])
    return leaves


def _at_saved_capacity(template: SimState, slots: int, cells: int | None, pairs: int) -> SimState:
    """The template with its neighbour list (each member's, for a batch) at
    the saved capacity; its arrays are then all replaced from the file."""
    if batch_of(template) is not None:
        members = [batch.member(template, i) for i in range(batch_of(template))]
        return batch.stack([batch.at_capacity(m, slots, cells, pairs) for m in members])
    neighbors = nb.rebuild_at_capacity(template.neighbors, template.particles.position, slots, cells,
                                       template.neighbor_settings, template.particles.fixed)
    c = template.contacts
    pairs = transfer.to_device(host_lists.half_pairs(neighbors.idx, pairs))
    contacts = c.set(pairs=pairs, history=transfer.zeros(pairs.shape[:1] + c.history.shape[1:], c.history.dtype))
    return template.set(neighbors=neighbors, contacts=contacts)


def restore(path, template: SimState, law, params) -> SimState:
    """The state saved in `path`, rebuilt on `template`'s structure.

    Args:
      path: a file written by `save`.
      template: a fresh state of the same set-up (`Simulator.init` with the same
        particles, boundaries and protocol state; `Ensemble.init` for a batch):
        it gives the pytree structure and the static fields; its arrays are
        all replaced.
      law, params: the law (`ContactLaw`, or its name) and parameters the run
        continues with; they must be those the checkpoint was written with, and
        a `ContactLaw` must be in the same reading (rotation, options) when the
        checkpoint recorded one.

    Raises:
      InputError: unreadable file, another jaxpile checkpoint format, another
        law, other parameters, another precision or another set-up (particle
        count, array names or shapes).
    """
    meta = read_metadata(path)
    law_name, reading = _law_name_and_reading(law)
    if meta["format"] > FORMAT:
        raise InputError(f"{path} was written by jaxpile {meta.get('jaxpile_version', '?')} in checkpoint format "
                         f"{meta['format']}, newer than this jaxpile's {FORMAT}: update jaxpile to resume it.")
    if meta["format"] < OLDEST_FORMAT:
        raise InputError(f"{path} has the older checkpoint format {meta['format']} (jaxpile "
                         f"{meta.get('jaxpile_version', '?')}); this jaxpile reads formats {OLDEST_FORMAT} to "
                         f"{FORMAT}: run it again.")
    missing = sorted({"law", "params", "precision", "n_particles", "neighbor_settings", "neighbor_capacity"} - set(meta))
    if missing:
        raise InputError(f"{path} is not a readable jaxpile checkpoint: its metadata lacks {', '.join(missing)}.")
    if meta["law"] != law_name:
        raise InputError(f"{path} was written with the {meta['law']} law; resuming with {law_name} is not "
                         "the same run. Resume with the law it was written with.")
    saved_reading = meta.get("law_reading")
    if reading is not None and saved_reading is not None and saved_reading != reading:
        differ = ", ".join(f"{k} {saved_reading.get(k)!r} there, {reading.get(k)!r} here"
                           for k in sorted(set(saved_reading) | set(reading)) if saved_reading.get(k) != reading.get(k))
        raise InputError(f"{path} was written with the {law_name} law in another reading ({differ}); "
                         "resuming in another reading is not the same run.")
    if meta["precision"] != _precision(template):
        raise InputError(f"{path} holds a {meta['precision']} run; the set-up to resume is "
                         f"{_precision(template)}. Resume with --precision {meta['precision']}.")
    record = _params_record(params)
    # a parameter absent on one side reads as unset (None): one a law gained later, left unset, matches
    changed = sorted(k for k in set(meta["params"]) | set(record) if meta["params"].get(k) != record.get(k))
    if changed:
        raise InputError(f"{path} was written with other law parameters ({', '.join(changed)} differ); "
                         "resuming with other parameters is not the same run.")
    differ = config.differences(meta.get("settings"), batch=meta.get("batch") is not None)
    if differ:
        warnings.warn(f"{path} was written under other JAX/XLA settings ({'; '.join(differ)}): the resumed run "
                      "goes on, and ends where an uninterrupted run under these settings would, not that one "
                      "(jaxpile.configure sets the commands' settings).", stacklevel=2)
    if meta["n_particles"] != template.particles.count:
        raise InputError(f"{path} holds {meta['n_particles']} disks; the set-up to resume has "
                         f"{template.particles.count}. Build the same set-up it was written from.")

    # every setting but the capacity multiplier, which only sizes new lists (the run resumes at its
    # saved capacities): a save resumes whatever multiplier the resuming simulator asks for
    compared = [i for i, name in enumerate(nb.NeighborSettings._fields) if name != "capacity_multiplier"]
    saved, wanted = meta["neighbor_settings"], json.loads(json.dumps(list(template.neighbor_settings)))
    saved = list(saved) + [None] * (len(wanted) - len(saved))  # a save from before the grid had an origin
    if [saved[i] for i in compared] != [wanted[i] for i in compared]:
        raise InputError(f"{path} was written with neighbour settings {meta['neighbor_settings']}; the set-up "
                         f"to resume has {list(template.neighbor_settings)}. Build the same set-up (box, skin).")

    if meta.get("batch") != batch_of(template):
        raise InputError(f"{path} holds {'a batch of ' + str(meta.get('batch')) if meta.get('batch') else 'one pile'}; "
                         f"the set-up to resume has {'a batch of ' + str(batch_of(template)) if batch_of(template) else 'one pile'}. "
                         "Build the same set-up it was written from.")
    # the saved run may have re-allocated its list: give the template that capacity
    saved = read_leaves(path)
    saved_pairs = saved.get(".contacts.pairs")
    if saved_pairs is None or saved_pairs.ndim < 2:
        raise InputError(f"{path} holds no contact pair list: it was not written by this jaxpile.")
    template = _at_saved_capacity(template, meta["neighbor_capacity"], meta["cell_capacity"], saved_pairs.shape[-2])
    names, leaves, treedef = _leaves(template)
    if set(saved) != set(names):
        raise InputError(f"{path} holds another kind of state (arrays {sorted(set(saved) ^ set(names))[:4]} do "
                         "not match): build the same set-up, protocol and integrator it was written from.")
    restored = []
    for name, leaf in zip(names, leaves):
        value = saved[name]
        if value.shape != np.shape(leaf) or value.dtype != np.asarray(leaf).dtype:
            raise InputError(f"{path}: {name} is {value.dtype}{list(value.shape)}, the set-up has "
                             f"{np.asarray(leaf).dtype}{list(np.shape(leaf))}. Build the same set-up.")
        restored.append(transfer.to_device(value))
    return jax.tree_util.tree_unflatten(treedef, restored)
