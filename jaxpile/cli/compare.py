"""`jaxpile compare DIR [DIR ...]`: the summaries of finished `jaxpile pile`
runs, one row each, side by side."""

from __future__ import annotations

import os

from jaxpile import config
from jaxpile.cli.pile_outputs import headline
from jaxpile.errors import InputError
from jaxpile.cli.presentation import PRESENTATIONS, presentation


def compare_table(dirs) -> str:
    """The table `jaxpile compare` prints: each run's protocol, law, disks, mu,
    steps, rate and its protocol's result; a folder that holds no finished
    run's summary.json is refused."""
    from jaxpile import io

    rows = []
    for d in dirs:
        path = os.path.join(d, "summary.json")
        if not os.path.isfile(path):
            raise InputError(f"{path} not found: give folders written by 'jaxpile pile --out DIR'.")
        s = io.read_json(path, "a run's summary.json")
        if not isinstance(s, dict):
            raise InputError(f"{path} is not a run's summary (a JSON object).")
        rows.append((d, s))
    head = (f"{'run':32s} {'protocol':>8s} {'law':>12s} {'disks':>6s} {'mu':>5s} {'steps':>8s} {'p-steps/s':>10s}  "
            "result")
    lines = [head, "-" * len(head)]
    for d, s in rows:
        protocol = s.get("protocol", "lattice")  # a summary without a protocol is a lattice run's
        steps = s.get("steps", (s.get("run") or {}).get("steps", 0))
        rate = s.get("particle_steps_per_second") or 0.0
        mu = s.get("params", {}).get("mu")
        try:  # a summary.json from elsewhere, or cut down, lacks what its protocol's row reads
            registered = presentation(protocol) if protocol in PRESENTATIONS else None
            if registered is None:
                raise KeyError(f"protocol {protocol!r}")
            result = (registered.compare(s) if registered.compare is not None
                      else headline(protocol, s).strip().splitlines()[0])
            lines.append(f"{d:32s} {protocol:>8s} {s['law']:>12s} {s['n_particles']:6d} "
                         f"{('%5.2f' % mu) if mu is not None else '    -'} {steps:8d} {rate:10.3g}  {result}")
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(f"{os.path.join(d, 'summary.json')} is not a finished {protocol} run's summary "
                             f"({type(err).__name__}: {err}); give folders written by 'jaxpile pile --out DIR'."
                             ) from None
    recorded = [(d, s["settings"]) for d, s in rows if isinstance(s.get("settings"), dict)]
    for d, settings in recorded[1:]:
        differ = config.differences(recorded[0][1], settings)
        if differ:
            lines.append(f"note: {d} ran under other JAX/XLA settings than {recorded[0][0]} ({'; '.join(differ)}): "
                         "the same seed differs at round-off, grown by the dynamics (jaxpile.config).")
    lines.append(
        "dev N, dev H (lattice): largest deviation of the ground forces from Liffman et al. 1992 eqs. 42 and 44.\n"
        "The analytic forces assume frictionless disks at rest; with disk-disk friction the base forces\n"
        "depend on how the pile was loaded (tangential springs lock in shear), so mu > 0 departs from them."
    )
    return "\n".join(lines)
