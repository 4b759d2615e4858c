#!/usr/bin/env bash
# Issue 17's recoveries at GPU sizes (one H100 or H200): the paper's box piles (W = H = 4,
# 409 disks, Lee-Herrmann) with 32 a side, and 40-disk Baxter heaps with 64 a side (four
# times the CPU run's). Each case is a `benchmarks/studies/fitting/fit_recovery.py` run; its fit resumes
# from its checkpoint in .gpu_runs/CASE when run again, and stops at its time limit.
#
#   bash benchmarks/studies/fitting/gpu_recovery.sh OUT [BOX_SECONDS] [POUR_SECONDS]
#
# leaves OUT/recovery.tgz (every case's JSON, checkpoint and figure) and OUT/log.txt.
# A second device call did not find .gpu_runs/ (measured; the folder was ignored through
# .git/info/exclude and empty here): to resume, unpack the returned recovery.tgz in the repository's root here and
# name .gpu_runs in the call's `carry` (measured: a warm rerun without it redid both
# targets and lost four minutes of device time). To resume from the committed results in a
# later session: copy benchmarks/results/fit_recovery/gpu_h200/NAME_{checkpoint,target}.json
# to .gpu_runs/NAME/CASE_{checkpoint,target}.json (NAME box-paper or pour-64, CASE box or pour)
# and carry .gpu_runs (done on 2026-11-26: `bash benchmarks/studies/fitting/gpu_recovery.sh OUT 270 110`).
set -u
out=${1:?usage: gpu_recovery.sh OUT [BOX_SECONDS] [POUR_SECONDS]}
box_s=${2:-300}
pour_s=${3:-200}
mkdir -p "$out" .gpu_runs
export PYTHONUNBUFFERED=1
log="$out/log.txt"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader >>"$log" 2>&1
python3 -c "import jax; print('jax', jax.__version__, jax.devices())" >>"$log" 2>&1

run_case() {  # NAME SECONDS ARGS...
    local name=$1 seconds=$2
    shift 2
    local t0=$SECONDS
    echo "== $name: python benchmarks/studies/fitting/fit_recovery.py $* (limit ${seconds} s)" | tee -a "$log"
    timeout "$seconds" python3 benchmarks/studies/fitting/fit_recovery.py "$@" --out ".gpu_runs/$name" \
        --figure ".gpu_runs/$name/fit_recovery_$name.png" 2>&1 | tee -a "$log"
    echo "== $name: exit ${PIPESTATUS[0]} after $((SECONDS - t0)) s" | tee -a "$log"
    tar czf "$out/recovery.tgz" .gpu_runs
}

run_case box-paper "$box_s" box --ensemble 32 --option width=4 --option height=4
run_case pour-64 "$pour_s" pour --ensemble 64
