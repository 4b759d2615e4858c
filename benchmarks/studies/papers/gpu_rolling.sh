#!/usr/bin/env bash
# Rolling resistance on one GPU (H100 or H200): the 1993 box's angle of repose against
# mu_roll (hooke, spins on, LAMMPS's `rolling sds`), and the dropped pile's central dip over a
# (mu, mu_roll) grid at 300 disks, 16 piles a point (issue 50, parts 3 and 4). Each is a
# `jaxpile sweep`, checkpointed as it runs and stopped at its time limit: what it measured, or
# its checkpoint to resume from, comes back in OUT/rolling.tgz, with OUT/log.txt.
#
#   bash benchmarks/studies/papers/gpu_rolling.sh OUT [BOX_SECONDS] [DROP_SECONDS] [SIZE]
#
# The device has JAX but not jax-md: copy the .venv's jax_md package into .gpu_site/ (ignored by
# .git/info/exclude) and carry it. SIZE=small runs both at a size a CPU finishes in a minute.
set -u
out=${1:?usage: gpu_rolling.sh OUT [BOX_SECONDS] [DROP_SECONDS] [SIZE]}
box_s=${2:-120}
drop_s=${3:-360}
size=${4:-paper}
. "$(dirname "$0")/../gpu_device.sh"  # OUT, .gpu_runs, py, log
# k_roll = 1000 mg/sigma (a rolling period of ~0.3 sqrt(sigma/g) for a pair of unit disks), gamma_roll = 30
# (a third of critical for it): the slider's cap mu_roll R_eff |F_n| is what is varied.
roll=(--rotation on --rolling sds --set k_roll=1000 --set gamma_roll=30)
if [ "$size" = small ]; then
    box=(--n 40 --option width=2 --option height=2 --seeds 2 --vary mu_roll=0,0.2)
    drop=(--n 12 --seeds 2 --vary mu=0.5 --vary mu_roll=0.1,0.3 --option relax_steps=20000)
else
    box=(--seeds 16 --vary mu_roll=0,0.05,0.1,0.2,0.4)  # the paper's W = H = 4 box: 409 disks
    drop=(--n 300 --seeds 16 --vary mu=0.3,0.6 --vary mu_roll=0.05,0.1,0.3 --option relax_steps=200000)
fi

run_case() {  # NAME SECONDS ARGS...
    local name=$1 seconds=$2
    shift 2
    local t0=$SECONDS args=("$@" --checkpoint-every 20000 --no-progress --out ".gpu_runs/$name")
    # a checkpoint left by an earlier call (carried back as .gpu_runs/NAME): resume it with its own settings
    [ -f ".gpu_runs/$name/checkpoint.npz" ] && args=(--resume ".gpu_runs/$name" --no-progress)
    echo "== $name: jaxpile sweep ${args[*]} (limit ${seconds} s)" | tee -a "$log"
    timeout "$seconds" $py -c "import sys; from jaxpile.cli import main; sys.exit(main())" sweep "${args[@]}" \
        2>&1 | tee -a "$log"
    echo "== $name: exit ${PIPESTATUS[0]} after $((SECONDS - t0)) s" | tee -a "$log"
    tar czf "$out/rolling.tgz" .gpu_runs
}

run_case box-roll "$box_s" --protocol box --law hooke "${roll[@]}" --set mu=0.2 "${box[@]}"
run_case drop-roll "$drop_s" --protocol drop --law hooke "${roll[@]}" "${drop[@]}"
