#!/usr/bin/env bash
# Smid and Novosad's pile fitted with rolling resistance on one GPU (H100 or H200): first a recovery
# of known (mu, mu_roll) from a synthetic target of 300-disk poured heaps, then the fit of the same
# two parameters to the declared dip (0.25) and angle of repose (32.6 deg) (issue 50, part 4). Each is
# a `jaxpile fit --estimator central` that saves its history after every Gauss-Newton iteration and is
# stopped at its time limit; a later call resumes it (`--resume`). What it wrote comes back in
# OUT/smid_novosad.tgz, with OUT/log.txt.
#
#   bash benchmarks/studies/fitting/gpu_smid_novosad.sh OUT [RECOVERY_SECONDS] [FIT_SECONDS] [SIZE]
#
# The device has JAX but not jax-md: copy the .venv's jax_md package into .gpu_site/ (ignored by
# .git/info/exclude) and carry it. SIZE=small runs both at a size a CPU finishes in minutes (one iteration).
set -u
out=${1:?usage: gpu_smid_novosad.sh OUT [RECOVERY_SECONDS] [FIT_SECONDS] [SIZE]}
recovery_s=${2:-280}
fit_s=${3:-280}
size=${4:-paper}
mkdir -p "$out" .gpu_runs
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD/.gpu_site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
py=${PYTHON:-python3}
log="$out/log.txt"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader >>"$log" 2>&1
$py -c "import jax; print('jax', jax.__version__, jax.devices())" >>"$log" 2>&1
# the 1997 law (n = 36, r0 = 1.2) with the rolling spring of the committed heaps (docs/rolling_resistance.md):
# k_roll = 1000, gamma_roll = 30; mu and mu_roll are fitted, from mu = 0.5 (the paper's), mu_roll = 0.2
common=(--protocol pour --law baxter --params mu,mu_roll --rotation on --rolling sds --set k_roll=1000
        --set gamma_roll=30 --set mu=0.5 --set mu_roll=0.2 --statistics central_dip,repose_mean
        --estimator central --difference-step 0.2 --steps 6 --no-progress)
if [ "$size" = small ]; then
    common+=(--n 40 --ensemble 2 --steps 1)  # 40 disks: the smallest heap with an angle on every side
else
    common+=(--n 300 --ensemble 16)
fi

run_fit() {  # NAME SECONDS ARGS...
    local name=$1 seconds=$2
    shift 2
    local t0=$SECONDS args=("$@" --out ".gpu_runs/$name")
    # a history left by an earlier call (carried back as .gpu_runs/NAME): continue it
    [ -f ".gpu_runs/$name/fit_checkpoint.json" ] && args+=(--resume)
    echo "== $name: jaxpile fit ${args[*]} (limit ${seconds} s)" | tee -a "$log"
    timeout "$seconds" $py -c "import sys; from jaxpile.cli import main; sys.exit(main())" fit "${args[@]}" \
        2>&1 | tee -a "$log"
    echo "== $name: exit ${PIPESTATUS[0]} after $((SECONDS - t0)) s" | tee -a "$log"
    tar czf "$out/smid_novosad.tgz" .gpu_runs
}

# values that are not round numbers, from seeds the fit never sees (the target's: 1000 on)
run_fit recovery "$recovery_s" "${common[@]}" --truth mu=0.37 --truth mu_roll=0.27 --target-seeds 1000
run_fit smid-novosad "$fit_s" "${common[@]}" --target smid-novosad
