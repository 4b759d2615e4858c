"""`jaxpile show DIR`: the figures of a `jaxpile pile`, `sweep` or `fit` run
drawn again from its files, without running anything.

A finished pile run is drawn from `state.npz` (the disks), `contacts.csv` (the
force network) and `base_forces.csv` + `summary.json` (the profile, with the
1992 theory where the run has it, and the protocol's own figures: energy,
angles, heap profile). A run still going, or stopped, is
drawn from its checkpoint (`checkpoint.in_folder`): the law and parameters
recorded there give the contact forces of the saved state (evaluated, not
advanced), and the kinetic energy samples saved with a box, tilt or flux run
give its energy curve. A sweep is drawn from `sweep.csv` + `sweep.json`, a fit
from `fit.json`.
"""

from __future__ import annotations

import json
import os
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np

from jaxpile.errors import InputError


def _network_from_csv(path):
    from jaxpile.measure.analysis import ContactNetwork
    from jaxpile.io import read_csv

    table = read_csv(path)
    disks = table["j"] >= 0  # wall rows have j = -1 - wall
    return ContactNetwork(i=table["i"][disks].astype(int), j=table["j"][disks].astype(int),
                          normal=table["normal"][disks], tangential=table["tangential"][disks])


def _finished(folder: str, out: str) -> list[str]:
    from jaxpile import io, plot

    summary = json.loads(open(os.path.join(folder, "summary.json")).read())
    state = io.load_arrays(os.path.join(folder, "state.npz"))
    active = state["particles.active"]
    contacts = os.path.join(folder, "contacts.csv")
    network = _network_from_csv(contacts) if os.path.exists(contacts) else None
    base = io.read_csv(os.path.join(folder, "base_forces.csv"))
    title = f"{summary.get('protocol', 'pile')} pile, {summary.get('law', '')} law (redrawn)"
    plot.pile_figure(state["particles.position"], state["particles.radius"], network, active=active,
                     title=title, path=os.path.join(out, "pile.png"))
    written = ["pile.png"]
    n_theory = h_theory = None
    from jaxpile.cli.presentation import presentation

    entry = presentation(summary.get("protocol", "lattice"))  # a summary without a protocol is a lattice run's
    if entry is not None and entry.profile_theory is not None and len(base["x"]):
        n_theory, h_theory, label = entry.profile_theory(summary, SimpleNamespace(**base)) or (None, None, "")
    plot.base_profile_figure(base["x"], base["normal"], base["horizontal"], theory_normal=n_theory,
                             theory_horizontal=h_theory, title=title, path=os.path.join(out, "profile.png"))
    written.append("profile.png")
    for figure in () if entry is None else entry.figures:  # the protocol's own (energy, angles, heap profile)
        written += figure(summary, title, out)
    return written


def state_from_checkpoint(path):
    """(state, law, params, metadata) of a checkpoint, enough to evaluate its
    contact forces (its neighbour list is the slots alone)."""
    from typing import NamedTuple

    from jaxpile.engine import checkpoint
    from jaxpile.laws import get_law_module
    from jaxpile.engine.state import Boundaries, Contacts, Particles, SimState

    meta = checkpoint.read_metadata(path)
    leaves = {k: jnp.asarray(v) for k, v in checkpoint.read_leaves(path).items()}

    def part(prefix, cls):
        fields = {k[len(prefix):]: v for k, v in leaves.items() if k.startswith(prefix) and "." not in k[len(prefix):]}
        return cls(**fields)

    class Slots(NamedTuple):  # what force evaluation reads of a neighbour list
        idx: jnp.ndarray

    state = SimState(particles=part(".particles.", Particles), contacts=part(".contacts.", Contacts),
                     boundaries=part(".boundaries.", Boundaries), neighbors=Slots(idx=leaves[".neighbors.idx"]),
                     step=leaves[".step"], neighbor_settings=None)
    law = get_law_module(meta["law"]).law(rotation=True)  # spins as saved (zero when rotation was off)
    params = law.params_type(**{k: None if v is None else jnp.asarray(v, state.particles.position.dtype)
                                for k, v in meta["params"].items()})
    return state, law, params, meta


def _checkpointed(path: str, out: str) -> list[str]:
    from jaxpile import plot
    from jaxpile.measure import analysis
    from jaxpile.engine.simulate import Simulator

    from jaxpile.engine import checkpoint

    meta = checkpoint.read_metadata(path)
    if meta.get("batch"):
        rows = len(meta["extra"].get("rows", []))
        raise InputError(f"{path} holds a running sweep's batch ({meta['batch']} piles at step {meta['step']}; "
                         f"{rows} members measured so far): `jaxpile show` draws a sweep once it has written "
                         "sweep.json.")
    state, law, params, meta = state_from_checkpoint(path)
    sim = Simulator(law, 1.0)  # dt is not used: forces are evaluated, not advanced
    network = analysis.contact_network(sim, params, state)
    base = analysis.base_forces(sim, params, state)
    stage = meta["extra"].get("stage") or meta["extra"].get("phase")
    title = f"{meta['law']} law, checkpoint at step {meta['step']}" + (f" ({stage})" if stage else "")
    plot.pile_figure(state.particles.position, state.particles.radius, network, active=state.particles.active,
                     title=title, path=os.path.join(out, "pile.png"))
    plot.base_profile_figure(base.x, base.normal, base.horizontal, title=title, path=os.path.join(out, "profile.png"))
    written = ["pile.png", "profile.png"]
    samples = meta["extra"].get("samples")
    if samples and samples.get("time"):  # the kinetic energy sampled so far: the run's own energy figure
        from jaxpile.cli.presentation import energy_figure

        written += energy_figure({"kinetic_energy": samples}, title, out)
    return written


def _sweep(folder: str, out: str) -> list[str]:
    from jaxpile import sweeps

    result = sweeps.read(folder)
    sweeps.figure(result, result.info.get("summary_by"), path=os.path.join(out, "sweep.png"))
    return ["sweep.png"]


def _fit(folder: str, out: str) -> list[str]:
    from jaxpile import fit

    record = json.loads(open(os.path.join(folder, "fit.json")).read())
    if "interval" in record and "names" in record:  # an ensemble fit (jaxpile.fit.ensemble_fit)
        from jaxpile.fit import ensemble_fit

        ensemble_fit.figure(ensemble_fit.EnsembleFitResult.from_json(record), path=os.path.join(out, "fit.png"))
        return ["fit.png"]
    saved = record.get("target_profile")
    if saved is not None:
        horizontal = None if saved["horizontal"] is None else np.asarray(saved["horizontal"])
        target = SimpleNamespace(x_over_b=np.asarray(saved["x_over_b"]), normal=np.asarray(saved["normal"]),
                                 horizontal=horizontal)
    elif record.get("target") == "smid-novosad":
        target = fit.smid_novosad_profile()
    elif os.path.exists(str(record.get("target"))):
        target = fit.load_profile_csv(record["target"])
    else:
        raise InputError(f"{folder}/fit.json does not hold its target profile and its target "
                         f"{record.get('target')!r} cannot be found: re-run the fit to redraw it.")

    def profile(p):
        return fit.Profile(np.asarray(p["x_over_b"]), np.asarray(p["normal"]),
                           None if p.get("horizontal") is None else np.asarray(p["horizontal"]))

    result = SimpleNamespace(history=record["history"], best_step=record["best_step"], loss=record["loss"])
    fit.fit_figure(result, target, profile(record["profile_before"]), profile(record["profile_after"]),
                   path=os.path.join(out, "fit.png"))
    return ["fit.png"]


def show(folder: str, out: str | None = None, *, checkpoint: bool = False) -> list[str]:
    """Draws the figures of the run in `folder` into `out` (default:
    `folder/shown`, so the run's own figures stay as the run wrote them):
    `pile.png` and `profile.png` of a pile run (and `energy.png` of a sampled
    run's checkpoint), `sweep.png` of a sweep, `fit.png` of a fit. A finished
    pile run is drawn from its results, unless `checkpoint` asks for its last
    checkpoint; a run with only a checkpoint is drawn from that. Returns the
    file names written."""
    from jaxpile.engine import checkpoint as ckpt

    out = os.path.join(folder, "shown") if out is None else out
    if not os.path.isdir(folder):
        raise InputError(f"{folder} is not a folder; give one written by `jaxpile pile`, `sweep` or `fit` --out.")
    has = {name: os.path.exists(os.path.join(folder, name)) for name in ("sweep.json", "fit.json")}
    finished = all(os.path.exists(os.path.join(folder, f)) for f in ("summary.json", "state.npz", "base_forces.csv"))
    saved = ckpt.in_folder(folder)
    if not (finished or saved or any(has.values())):
        raise InputError(f"{folder} holds neither a finished `jaxpile pile` run (summary.json, state.npz, "
                         "base_forces.csv), a checkpoint.npz, a sweep (sweep.json) nor a fit (fit.json).")
    if checkpoint and saved is None:
        raise InputError(f"{folder} has no checkpoint.npz (runs write one with --checkpoint-every STEPS).")
    os.makedirs(out, exist_ok=True)
    if has["sweep.json"] and not checkpoint:
        return _sweep(folder, out)
    if has["fit.json"] and not checkpoint:
        return _fit(folder, out)
    return _checkpointed(saved, out) if (checkpoint or not finished) else _finished(folder, out)
