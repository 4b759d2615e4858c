"""Every protocol with every contact law, through the command line, at a small size.

Prints one row per (protocol, law): whether it ran, ended at rest, how many
disks, its headline measurement and the wall time. The unit tests cover each
protocol with the laws its paper uses; this script is the check that the
others run too (too slow for the suite: 28 runs, a compile each).

    python benchmarks/protocol_law_matrix.py [--out DIR] [--protocols box,tilt] [--laws hooke,baxter]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import tempfile
import time

from jaxpile.cli import main

SMALL = {
    "lattice": ["--layers", "6"],
    "sloped": ["--slope", "45", "--n", "21"],
    "drop": ["--n", "8"],
    "box": ["--n", "40", "--option", "width=1.6", "--option", "height=1.2"],
    "tilt": ["--n", "40", "--option", "rate_degrees=0.05"],
    "flux": ["--n", "5", "--option", "width=1.2"],
    "pour": ["--n", "16", "--option", "release_height=8", "--speed-tol", "1e-3"],
}
LAWS = ["hooke", "liffman", "lee-herrmann", "baxter"]
HEADLINE = {
    "lattice": "max_rel_dev_normal", "sloped": "central_slope_rel_dev", "drop": "weight_balance",
    "box": "repose_cumulative_parabola", "tilt": "theta_t", "flux": "steady_mean", "pour": "force_balance",
}


def at_rest(summary: dict):
    for key in ("at_rest",):
        if key in summary:
            return summary[key]
    return (summary.get("run") or {}).get("at_rest")


def main_matrix(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="keep each run's files here (default: a temporary folder)")
    parser.add_argument("--protocols", default=",".join(SMALL))
    parser.add_argument("--laws", default=",".join(LAWS))
    args = parser.parse_args(argv)
    root = args.out or tempfile.mkdtemp(prefix="jaxpile_matrix_")
    print(f"{'protocol':9s} {'law':13s} {'rc':>3s} {'at rest':>8s} {'disks':>6s} {'headline':>28s} {'seconds':>8s}")
    failures = 0
    for protocol in args.protocols.split(","):
        for law in args.laws.split(","):
            out = os.path.join(root, f"{protocol}_{law}")
            t0 = time.perf_counter()
            captured = io.StringIO()
            with contextlib.redirect_stdout(captured), contextlib.redirect_stderr(captured):
                try:
                    rc = main(["pile", "--protocol", protocol, "--law", law, *SMALL[protocol], "--no-progress",
                               "--out", out])
                except Exception as error:  # report and go on: this is a survey
                    rc, captured = 99, io.StringIO(f"{type(error).__name__}: {error}")
            seconds = time.perf_counter() - t0
            summary = {}
            if rc == 0:
                with open(os.path.join(out, "summary.json")) as f:
                    summary = json.load(f)
            key = HEADLINE[protocol]
            value = summary.get(key)
            headline = f"{key} = {value:.4g}" if isinstance(value, float) else (f"{key} = {value}" if value is not None else "")
            failures += rc != 0
            print(f"{protocol:9s} {law:13s} {rc:3d} {str(at_rest(summary)):>8s} {summary.get('n_particles', 0):6d} "
                  f"{headline:>28s} {seconds:8.1f}", flush=True)
            if rc != 0:
                print("    " + captured.getvalue().strip().splitlines()[-1][:300], flush=True)
    print(f"files under {root}; {failures} failed")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main_matrix())
