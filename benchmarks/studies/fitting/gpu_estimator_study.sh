#!/usr/bin/env bash
# Issue 17's estimator study at B = 128 on a GPU (one H100 or H200), the sizes 2 CPU cores
# cannot finish in a session: the box (102-disk boxes, W = H = 2, as the B = 8 and 32 rows)
# and the pour (40-disk heaps, as estimator_study_pour.json). Each row of a study is saved
# as it finishes (--resume skips it) and its batch every CHECKPOINT steps (--checkpoint-every),
# so a call cut off by its time limit loses at most that much.
#
#   bash benchmarks/studies/fitting/gpu_estimator_study.sh OUT CASE SECONDS [CHECKPOINT]
#
# CASE: box or pour; PYTHON (default python3) runs it. Leaves OUT/study.tgz (the study's
# JSON, figure and the running row's batch checkpoint, *.ckpt, which git ignores) and
# OUT/log.txt. To continue in a later call: unpack study.tgz in the repository's root, name
# the .ckpt file in the call's `carry` (the JSON travels as an untracked file) and run the
# same command again.
#
# Measured on one H100 (2026-11-26), the two cases side by side on the one GPU
# (XLA_PYTHON_CLIENT_MEM_FRACTION=0.4 each, `... box 540 & ... pour 540; wait`): the box's four
# rows (2 x central differences, 2 x smoothing with 2 pairs) in 327 s; the pour's target and
# its rows at 74-146 s (central differences), 81-105 s (smoothing) and 160 s (truncated:60,
# its host run and compile included; a row has no mid-row save). The committed pour JSON
# lacks one row (truncated:60, repeat 1): `... pour 400` on a GPU runs it alone.
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
echo "== python benchmarks/studies/fitting/estimator_study.py ${args[*]} --resume --checkpoint-every $every (limit $seconds s)" | tee -a "$log"
timeout "$seconds" "${PYTHON:-python3}" benchmarks/studies/fitting/estimator_study.py "${args[@]}" --resume --checkpoint-every "$every" 2>&1 \
    | grep --line-buffered -v "Warning" | tee -a "$log"
echo "== exit ${PIPESTATUS[0]} after $((SECONDS - t0)) s" | tee -a "$log"
tar czf "$out/study.tgz" benchmarks/results/estimator_study_*b128.json* docs/estimator_study_*b128.png 2>/dev/null
