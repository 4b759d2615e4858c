#!/usr/bin/env bash
# Issue 17's estimator study at B = 128 on a GPU (one H100 or H200), the sizes 2 CPU cores
# cannot finish in a session: the box (102-disk boxes, W = H = 2, as the B = 8 and 32 rows)
# and the pour (40-disk heaps, as estimator_study_pour.json). Each row of a study is saved
# as it finishes (--resume skips it) and its batch every CHECKPOINT steps (--checkpoint-every),
# so a call cut off by its time limit loses at most that much.
#
#   bash benchmarks/gpu_estimator_study.sh OUT CASE SECONDS [CHECKPOINT]
#
# CASE: box or pour; PYTHON (default python3) runs it. Leaves OUT/study.tgz (the study's
# JSON, figure and the running row's batch checkpoint, *.ckpt, which git ignores) and
# OUT/log.txt. To continue in a later call: unpack study.tgz in the repository's root, name
# the .ckpt file in the call's `carry` (the JSON travels as an untracked file) and run the
# same command again.
#
# Sizes, from the GPU fits (H200): 3 x 32 paper boxes (409 disks) per iteration in 61-79 s,
# the same disks per batch as 3 x 128 boxes of 102; 3 x 64 heaps in 31-46 s. So the box's four
# rows (2 x central differences, 2 x smoothing with 2 pairs) need about 5 min, the pour's
# about 6 min plus its 32-heap target: one call each.
set -u
out=${1:?usage: gpu_estimator_study.sh OUT CASE SECONDS [CHECKPOINT]}
case=${2:?usage: gpu_estimator_study.sh OUT CASE SECONDS [CHECKPOINT]}
seconds=${3:?usage: gpu_estimator_study.sh OUT CASE SECONDS [CHECKPOINT]}
every=${4:-20000}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
log="$out/log.txt"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader >>"$log" 2>&1
"${PYTHON:-python3}" -c "import jax; print('jax', jax.__version__, jax.devices())" >>"$log" 2>&1
case "$case" in
    box) args=(--case box --n 102 --option width=2 --option height=2 --B 128 --repeats 2 --pairs 2
               --out benchmarks/results/estimator_study_b128.json --figure docs/estimator_study_b128.png) ;;
    pour) args=(--case pour --B 128 --repeats 2 --pairs 2 --estimators fd,smoothing,truncated:60
                --out benchmarks/results/estimator_study_pour_b128.json --figure docs/estimator_study_pour_b128.png) ;;
    *) echo "CASE must be box or pour" >&2; exit 2 ;;
esac
t0=$SECONDS
echo "== python benchmarks/estimator_study.py ${args[*]} --resume --checkpoint-every $every (limit $seconds s)" | tee -a "$log"
timeout "$seconds" "${PYTHON:-python3}" benchmarks/estimator_study.py "${args[@]}" --resume --checkpoint-every "$every" 2>&1 \
    | grep --line-buffered -v "Warning" | tee -a "$log"
echo "== exit ${PIPESTATUS[0]} after $((SECONDS - t0)) s" | tee -a "$log"
tar czf "$out/study.tgz" benchmarks/results/estimator_study_*b128.json* docs/estimator_study_*b128.png 2>/dev/null
