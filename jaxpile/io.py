"""Saving states and results: npz for states, CSV for tables, JSON for summaries."""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from typing import Any, Protocol

import numpy as np

class SimState(Protocol):
    """What `state_arrays` reads of a state (a `jaxpile.engine.state.SimState`
    is one): io sits below the engine and imports none of it."""

    particles: Any
    contacts: Any
    boundaries: Any
    step: Any
    integrator_state: Any


def state_arrays(state: SimState) -> dict:
    """A flat dict of numpy arrays describing the state (no neighbour list),
    with the integrator's carried state (Gear's higher derivatives) when it has one."""
    p, c, b = state.particles, state.contacts, state.boundaries
    return {
        **{f"particles.{k}": np.asarray(v) for k, v in vars(p).items()},
        **{f"contacts.{k}": np.asarray(v) for k, v in vars(c).items()},
        **{f"boundaries.{k}": np.asarray(v) for k, v in vars(b).items()},
        "step": np.asarray(state.step),
        **({} if state.integrator_state is None else
           {f"integrator_state.{k}": np.asarray(v) for k, v in vars(state.integrator_state).items()}),
    }


def save_state(path, state: SimState, **metadata) -> None:
    """Writes the state's arrays (plus `metadata` as JSON) to an npz, atomically."""
    arrays = state_arrays(state)
    arrays["metadata"] = np.asarray(json.dumps(metadata, default=str))
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays))


def load_arrays(path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def write_csv(path, columns: dict) -> None:
    """Columns of numbers as CSV with a header row, each number to the last bit
    (17 significant digits read back exactly)."""
    names = list(columns)
    table = np.column_stack([np.asarray(columns[n], float) for n in names]) if names else np.zeros((0, 0))
    atomic_write(path, lambda f: np.savetxt(f, table, delimiter=",", header=",".join(names), comments="", fmt="%.17g"),
                  text=True)


def read_csv(path) -> dict:
    with open(path) as f:
        names = f.readline().strip().split(",")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # a table with no rows is valid: empty columns
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        return {n: np.zeros(0) for n in names}
    return {n: data[:, k] for k, n in enumerate(names)}


def read_json(path, what: str = "a file jaxpile wrote"):
    """The JSON held in `path`, or `InputError` in one line when the file is
    missing, unreadable or not JSON (cut short by a crash, or another file)."""
    from jaxpile.errors import InputError

    try:
        with open(path) as fh:
            return json.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file (expected {what}).") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"{path} is not readable as {what} ({type(err).__name__}: {err}).") from None


def write_json(path, obj) -> None:
    atomic_write(path, lambda f: f.write(json.dumps(obj, indent=2, default=float) + "\n"), text=True)


def atomic_write(path, write, text: bool = False) -> None:
    """Write to a temporary file in the same folder, fsync, then rename."""
    if os.path.isdir(path):
        from jaxpile.errors import InputError

        raise InputError(f"{path} is a folder: give a file name to write to.")
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=os.path.splitext(path)[1])
    try:
        with os.fdopen(fd, "w" if text else "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def plain(value):
    """Measurements as JSON: arrays to lists, named tuples to dicts."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if hasattr(value, "_asdict"):
        return {k: plain(v) for k, v in value._asdict().items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "shape") and hasattr(value, "tolist"):
        return np.asarray(value).tolist()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)
