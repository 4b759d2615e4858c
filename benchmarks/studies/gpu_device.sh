# Sourced by the scripts that run a study on a lent GPU (`OUT` set first): the output folder and
# .gpu_runs/, Python unbuffered with the carried jax_md (.gpu_site/) on its path, `py` and `log`, and
# the device and JAX version written to OUT/log.txt.
mkdir -p "$out" .gpu_runs
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD/.gpu_site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
py=${PYTHON:-python3}
log="$out/log.txt"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader >>"$log" 2>&1
$py -c "import jax; print('jax', jax.__version__, jax.devices())" >>"$log" 2>&1
