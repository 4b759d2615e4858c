"""Up to how many fitted values forward mode beats the checkpointed reverse,
with XLA:CPU's multi-output fusion off and on: the measurement behind
`fit.forward_mode_max()` (`mode="auto"`).

Forward mode (`fit.value_and_gradient(..., "forward")`) runs one batched
tangent per fitted value beside the primal; the checkpointed reverse pays one
forward, one recomputation and one transposed pass whatever the count. So
forward mode wins up to some count, and where that count lies depends on what
a tangent costs against a transposed step, which the fusion changes. Each
configuration runs in a child process of its own (the flag is read once per
process), the two alternated for `--rounds` rounds; within a child every
program is timed side by side (`gradient_cost.side_by_side`: ratios to the
forward run of the same round, medians over its rounds), and each figure
below is the median of the children's.

The loss is gradient_cost.py's (the base's second moment of the normal wall
force after T steps of a 2D hooke pile with friction and spins), over the
first k of hooke's ten parameters (kn, kt, gamma_n, gamma_t, mu, then the
wall's five). Reverse mode's cost hardly depends on k, so it is timed at the
smallest and largest k only.

    python benchmarks/forward_mode_threshold.py [--sizes 10:1000,30:250] [--values 1,2,4,6,8,10]
        [--rounds 2] [--out results/cpu/forward_mode_threshold.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
PARAMS = dict(kn=1e4, kt=2857.14285714, gamma_n=50.0, gamma_t=25.0, mu=0.3,
              wall_kn=1e4, wall_kt=2857.14285714, wall_gamma_n=50.0, wall_gamma_t=25.0, wall_mu=0.5)


def child(sizes: list[tuple[int, int]], values: list[int], rounds: int) -> dict:
    """One configuration's ratios to the forward run (run in a child process)."""
    sys.path.insert(0, HERE)
    import jax

    import gradient_cost as gc
    import jaxpile
    from jaxpile import fit
    from jaxpile.laws import hooke

    out = {"multi_output_fusion": jaxpile.multi_output_fusion_on(), "sizes": []}
    for layers, steps in sizes:
        sim, _, state = gc.setup(layers, 0)
        params = hooke.make_params(**PARAMS)
        names = hooke.PARAM_NAMES

        def gradient(k, mode):
            chosen = {name: getattr(params, name) for name in names[:k]}
            loss = gc.loss_fn(sim, state, steps, mode == "reverse")
            return fit.value_and_gradient(lambda v: loss(params.set(**v)), chosen, mode), (chosen,)

        programs = {"forward": (jax.jit(gc.loss_fn(sim, state, steps, False)), (params,))}
        for k in (values[0], values[-1]):
            programs[f"reverse_{k}"] = gradient(k, "reverse")
        for k in values:
            programs[f"forward_mode_{k}"] = gradient(k, "forward")
        row = gc.side_by_side(programs, rounds=rounds)
        out["sizes"].append({"disks": state.particles.count, "steps": steps, "forward_s": row["forward_s"],
                             "ratio": {name: row[f"{name}_ratio"] for name in programs if name != "forward"}})
    return out


def crossover(ratios: dict, values: list[int]) -> int:
    """The largest k up to which forward mode is cheaper than the checkpointed
    reverse (the cheaper of its two timings, so the count errs low; 0: never)."""
    reverse = min(v for name, v in ratios.items() if name.startswith("reverse_"))
    best = 0
    for k in values:
        if ratios[f"forward_mode_{k}"] < reverse:
            best = k
        else:
            break
    return best


def main(argv=None) -> dict:
    import numpy as np

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10:1000,30:250", help="layers:steps, comma-separated")
    parser.add_argument("--values", default="1,2,4,6,8,10", help="how many values to fit (increasing)")
    parser.add_argument("--rounds", type=int, default=2, help="children per configuration, alternated")
    parser.add_argument("--inner-rounds", type=int, default=5, help="side-by-side rounds within a child")
    parser.add_argument("--out", default=None)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    try:
        sizes = [tuple(int(x) for x in s.split(":")) for s in args.sizes.split(",") if s]
        values = [int(v) for v in args.values.split(",") if v]
    except ValueError:
        parser.error("--sizes takes layers:steps pairs and --values whole numbers, comma-separated")
    if any(len(s) != 2 or min(s) < 1 for s in sizes) or not values or values != sorted(set(values)) \
            or not 1 <= values[0] <= values[-1] <= 10:
        parser.error("--sizes: layers:steps >= 1; --values: increasing, from 1 to 10 (hooke's parameters)")
    if args.rounds < 1 or args.inner_rounds < 1:
        parser.error("--rounds and --inner-rounds must be at least 1")
    if args.child:
        print(json.dumps(child(sizes, values, args.inner_rounds)))
        return {}

    sys.path.insert(0, HERE)
    from machine import describe

    runs = {"off": [], "on": []}
    for r in range(args.rounds):
        for name, flag in (("off", "0"), ("on", "1")):
            env = {**os.environ, "JAXPILE_MULTI_OUTPUT_FUSION": flag}
            command = [sys.executable, os.path.abspath(__file__), "--child", "--sizes", args.sizes,
                       "--values", args.values, "--inner-rounds", str(args.inner_rounds)]
            done = subprocess.run(command, capture_output=True, text=True, env=env)
            if done.returncode != 0:
                raise SystemExit(f"the fusion-{name} child failed:\n{done.stderr[-3000:]}")
            runs[name].append(json.loads(done.stdout.strip().splitlines()[-1]))
            print(f"round {r + 1}, multi-output fusion {name}: done", flush=True)

    result = {"machine": describe(), "command": "python benchmarks/forward_mode_threshold.py " + " ".join(
        argv if argv is not None else sys.argv[1:]), "configurations": {}}
    for name, children in runs.items():
        rows = []
        for s, (layers, steps) in enumerate(sizes):
            first = children[0]["sizes"][s]
            ratio = {p: float(np.median([c["sizes"][s]["ratio"][p] for c in children])) for p in first["ratio"]}
            rows.append({"disks": first["disks"], "steps": steps, "ratio": ratio,
                         "forward_s": float(np.median([c["sizes"][s]["forward_s"] for c in children])),
                         "forward_mode_up_to": crossover(ratio, values)})
        result["configurations"][name] = rows

    print(f"\n{result['machine']}; gradient time / forward time, medians of {args.rounds} children")
    for name, rows in result["configurations"].items():
        for row in rows:
            cells = "  ".join(f"{p.replace('forward_mode_', 'fwd').replace('reverse_', 'rev')} {v:.2f}"
                              for p, v in row["ratio"].items())
            print(f"  fusion {name:3s} {row['disks']:5d} disks x {row['steps']:5d} steps: {cells}"
                  f"  -> forward mode up to {row['forward_mode_up_to']}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)
    return result


if __name__ == "__main__":
    main()
