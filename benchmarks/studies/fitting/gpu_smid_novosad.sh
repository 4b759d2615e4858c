#!/usr/bin/env bash
# Smid and Novosad's pile fitted with rolling resistance on one GPU (H100 or H200): first a recovery
# of a known mu_roll from a synthetic target of 300-disk poured heaps, then the fit of mu_roll to the
# declared dip (0.25) and angle of repose (32.6 deg). The sliding friction is held
# at the paper's mu = 0.5: at mu_roll = 0.3, mu = 0.3 and 0.5 give the same angle and dip seed for
# seed (-0.5 +- 1.3 deg, +0.06 +- 0.07; docs/rolling_resistance.md), so these statistics do not
# constrain mu. Each fit is a `jaxpile fit --estimator central` that saves its history after every
# Gauss-Newton iteration and its running batch every 20,000 steps, and is stopped at its time limit; a
# later call resumes it where it stopped. What it wrote
# comes back in OUT/smid_novosad.tgz, with OUT/log.txt: unpack it into .gpu_runs/ here and carry
# .gpu_runs on the next call (a finished fit is skipped, a made target reused).
#
#   bash benchmarks/studies/fitting/gpu_smid_novosad.sh OUT [RECOVERY_SECONDS] [FIT_SECONDS] [SIZE] [SPREAD]
#
# SPREAD: the pour's source, release x within +-SPREAD sigma (the paper's 3). Released within +-0.5 sigma,
# the 300-disk heaps at mu_roll = 0.15 dip 21 +- 10 % below their flanks (docs/rolling_resistance.md); the
# paper's source gives no significant dip at the reported angle. A SPREAD other than 3 writes its fits to
# .gpu_runs/recovery_spreadSPREAD and .gpu_runs/smid-novosad_spreadSPREAD.
#
# The device has JAX but not jax-md: copy the .venv's jax_md package into .gpu_site/ (git ignores it
# and .gpu_runs/) and carry it. SIZE=small runs both at a size a CPU finishes in minutes (one iteration).
set -u
out=${1:?usage: gpu_smid_novosad.sh OUT [RECOVERY_SECONDS] [FIT_SECONDS] [SIZE] [SPREAD]}
recovery_s=${2:-280}
fit_s=${3:-280}
size=${4:-paper}
spread=${5:-3}
. "$(dirname "$0")/../gpu_device.sh"  # OUT, .gpu_runs, py, log
# the 1997 law (n = 36, r0 = 1.2, mu = 0.5) with the rolling spring of the committed heaps
# (docs/rolling_resistance.md): k_roll = 1000, gamma_roll = 30; mu_roll fitted from 0.25
common=(--protocol pour --law baxter --params mu_roll --rotation on --rolling sds --set k_roll=1000
        --set gamma_roll=30 --set mu=0.5 --set mu_roll=0.25
        --estimator central --difference-step 0.2 --steps 6 --checkpoint-every 20000 --no-progress)
if [ "$size" = small ]; then
    # 40 disks: the smallest heap with an angle on every side; its base is too short for dip_below_flanks
    common+=(--n 40 --ensemble 2 --steps 1 --statistics central_dip,repose_mean)
else
    # the dip read in fixed narrow windows, which a 300-disk heap's 15 bins resolve (heap.dip_below_flanks)
    common+=(--n 300 --ensemble 16 --statistics dip_below_flanks,repose_mean)
fi
suffix=
if [ "$(printf '%g' "$spread")" != 3 ]; then
    common+=(--option "spread=$spread")
    suffix=_spread$spread
fi

run_fit() {  # NAME SECONDS TARGET_ARGS...
    local name=$1 seconds=$2
    shift 2
    local dir=".gpu_runs/$name" t0=$SECONDS target=("$@")
    if [ -f "$dir/fit.json" ]; then
        echo "== $name: finished in an earlier call ($dir/fit.json)" | tee -a "$log"
        return
    fi
    if [ -f "$dir/fit_checkpoint.json" ] || [ -f "$dir/target_batch.npz" ]; then  # left by an earlier call: continue
        target+=(--resume)
    elif [ -f "$dir/target.json" ] && [ "${target[0]}" = --truth ]; then  # a target made before its first iteration
        target=(--target "$dir/target.json")
    fi
    local args=("${common[@]}" "${target[@]}" --out "$dir")
    echo "== $name: jaxpile fit ${args[*]} (limit ${seconds} s)" | tee -a "$log"
    timeout "$seconds" $py -c "import sys; from jaxpile.cli import main; sys.exit(main())" fit "${args[@]}" \
        2>&1 | tee -a "$log"
    echo "== $name: exit ${PIPESTATUS[0]} after $((SECONDS - t0)) s" | tee -a "$log"
    tar czf "$out/smid_novosad.tgz" ".gpu_runs/recovery$suffix" ".gpu_runs/smid-novosad$suffix" 2>/dev/null
}

# a value that is not a round number, near where the committed heaps put the minimum, from seeds the
# fit never sees (the target's: 1000 on)
run_fit "recovery$suffix" "$recovery_s" --truth mu_roll=0.17 --target-seeds 1000
run_fit "smid-novosad$suffix" "$fit_s" --target smid-novosad
