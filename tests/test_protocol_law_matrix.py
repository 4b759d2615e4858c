"""Every protocol with every contact law, through the command line, at a small size.

The unit tests cover each protocol with the laws its paper uses; this is the
check that the others run too (too slow for the default suite: 28 runs, a
compile each), marked `soak`: `make soak` (or `pytest -m soak`) runs it. Each
(protocol, law) is one test: its `jaxpile pile` must exit 0. So is each
protocol's sweep of a small batch under the commands' XLA settings.

Run by hand, it prints one row per (protocol, law): whether it ran, ended at
rest, how many disks, its headline measurement and the wall time.

    python tests/test_protocol_law_matrix.py [--out DIR] [--protocols box,tilt] [--laws hooke,baxter]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import tempfile
import time

import pytest

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


def run_one(protocol: str, law: str, out: str) -> tuple[int, dict, str, float]:
    """`jaxpile pile` of one (protocol, law) into `out`: its exit status, its
    summary (empty unless it ran), what it printed and its wall time."""
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
    return rc, summary, captured.getvalue(), seconds


@pytest.mark.soak
@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("protocol", list(SMALL))
def test_protocol_runs_with_law(protocol, law, tmp_path):
    rc, _, printed, _ = run_one(protocol, law, str(tmp_path / f"{protocol}_{law}"))
    assert rc == 0, (printed.strip().splitlines() or [""])[-1][:300]


SWEEPS = {
    "lattice": ["--n", "4", "--vary", "kn=1e5,2e5"],
    "sloped": ["--n", "21", "--option", "alpha_degrees=45", "--option", "max_steps=40000", "--vary", "kn=1e5"],
    "drop": ["--n", "6", "--vary", "mu_roll=0.1"],
    "box": ["--n", "30", "--option", "width=1.2", "--option", "height=1.0", "--mu", "0.3"],
    "tilt": ["--n", "30", "--option", "rate_degrees=0.05", "--mu", "0.3"],
    "flux": ["--n", "4", "--option", "width=1.0", "--option", "max_time=0.2", "--mu", "0.3"],
    "pour": ["--n", "12", "--option", "release_height=8", "--option", "substrate_disks=15", "--speed-tol", "1e-3",
             "--mu", "0.3"],
    "hopper": ["--n", "60", "--mu", "0.3"],
}


@pytest.mark.soak
@pytest.mark.parametrize("devices", [1, 2])
@pytest.mark.parametrize("protocol", list(SWEEPS))
def test_protocol_sweeps_a_batch_under_the_commands_settings(protocol, devices, tmp_path):
    """`jaxpile sweep` over four seeds in a user's environment: the batched
    step compiled with XLA:CPU's multi-output fusion, as every command runs
    (the suite itself runs without it), members whose set-ups drew different
    piles stacked into one batch; on one CPU device (a protocol's members one
    after another where it asks for it) and sharded over two (side by side)."""
    from test_imports import clean_env, python

    command = "import sys; from jaxpile.cli import main; sys.exit(main(sys.argv[1:]))"
    python(command, clean_env(JAXPILE_HOST_DEVICES=str(devices)), "sweep", "--protocol", protocol, *SWEEPS[protocol],
           "--seeds", "4", "--no-progress", "--out", str(tmp_path))


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
            rc, summary, printed, seconds = run_one(protocol, law, os.path.join(root, f"{protocol}_{law}"))
            key = HEADLINE[protocol]
            value = summary.get(key)
            headline = f"{key} = {value:.4g}" if isinstance(value, float) else (f"{key} = {value}" if value is not None else "")
            failures += rc != 0
            print(f"{protocol:9s} {law:13s} {rc:3d} {str(at_rest(summary)):>8s} {summary.get('n_particles', 0):6d} "
                  f"{headline:>28s} {seconds:8.1f}", flush=True)
            if rc != 0:
                print("    " + printed.strip().splitlines()[-1][:300], flush=True)
    print(f"files under {root}; {failures} failed")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main_matrix())
