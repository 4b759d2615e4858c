"""How often each interval of an ensemble fit holds the truth (issue 17):
Gauss-Newton's (its last step's finite-difference Jacobian) and the line's
through all the fit's ensembles (`jaxpile.fit.regression`), over many fits of
the two toys of tests/test_ensemble_fit.py (a pile's statistics as functions
of log mu: no protocol runs, seconds in all):

- "common random numbers": noise fixed per seed, the same at every mu (a
  smooth protocol: the box, the lattice);
- "chaotic": noise drawn afresh for each (mu, seed) (a discharge, a pour).

    python tools/regression_coverage.py [--fits 40] [--out benchmarks/results/regression_coverage.json]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fits", type=int, default=40)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "regression_coverage.json"))
    args = parser.parse_args(argv)
    import jaxpile

    jaxpile.configure()  # float64 and the commands' XLA settings

    from test_ensemble_fit import ChaoticToyRunner, ToyRunner, _target

    from jaxpile.fit import ensemble_fit as ef

    truth, stats = 0.3137, ef.Statistics(columns=("angle", "feature"))
    out = {"truth": truth, "fits": args.fits, "seeds_a_side": 32, "start": 0.2, "step": 0.2, "iterations": 6,
           "command": "python tools/regression_coverage.py " + " ".join(argv or sys.argv[1:])}
    for label, make in (("chaotic", lambda: ChaoticToyRunner(noise=1.0)),
                        ("common random numbers", lambda: ToyRunner())):
        inside = {"gauss_newton": 0, "line": 0}
        errors = {"gauss_newton": [], "line": []}
        for k in range(args.fits):  # independent targets and fits: disjoint seeds
            runner = make()
            target = _target(runner, truth, seeds=range(1000 * (k + 1), 1000 * (k + 1) + 32))
            fit = ef.fit(runner, ["mu"], {"mu": 0.2}, target, seeds=range(100 * k, 100 * k + 32), statistics=stats,
                         progress=False, gradient=ef.Gradient(step=0.2), stopping=ef.Stopping(steps=6))
            line = fit.record["regression"]
            for name, value, (lo, hi) in (("gauss_newton", fit.values["mu"], fit.interval["mu"]),
                                          ("line", line["values"]["mu"], line["interval"]["mu"])):
                inside[name] += int(lo < truth < hi)
                errors[name].append(abs(float(np.log(value / truth))))
        out[label] = {name: {"inside": inside[name], "mean_abs_log_error": float(np.mean(errors[name]))}
                      for name in inside}
        print(f"{label}: the truth inside Gauss-Newton's interval in {inside['gauss_newton']}/{args.fits} fits, "
              f"the line's in {inside['line']}/{args.fits}; mean |log error| "
              f"{np.mean(errors['gauss_newton']):.4f} and {np.mean(errors['line']):.4f}")
    pathlib.Path(args.out).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
