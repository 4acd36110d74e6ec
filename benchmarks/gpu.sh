#!/usr/bin/env bash
# The GPU checks in one command (goal: under 8 minutes on one GPU): the MJX env at 1024, 8192
# and 32768 scenes, the AL trainer on MJX at 1024 agents, and a paper-profile sweep (Fig 8A's
# grid, 5 seeds, the paper's 150 + 300 episodes) on MJX. Needs a JAX with GPU support in the
# active environment (e.g. pip install -e . "jax[cuda12]"). Results: results/benchmarks/gpu/
# (or $OUT/gpu when OUT is set), with each step's log.
set -u
cd "$(dirname "$0")/.."
dest="${OUT:-results/benchmarks}/gpu"
mkdir -p "$dest"
python -c "import jax; print(jax.devices())" | tee "$dest/devices.txt"
if ! python -c "import jax, sys; sys.exit(jax.default_backend() != 'gpu')"; then
    echo "no GPU visible to JAX: nothing measured" >&2
    exit 2
fi
step() {  # step NAME SECONDS COMMAND...: run with a time limit, log, keep going on failure
    local name=$1 limit=$2
    shift 2
    echo "== $name (limit ${limit} s)"
    local t0=$SECONDS
    timeout "$limit" "$@" >"$dest/$name.log" 2>&1
    echo "$name: rc $? in $((SECONDS - t0)) s" | tee -a "$dest/summary.txt"
    tail -n 12 "$dest/$name.log"
}
step env_mjx 150 python benchmarks/env_throughput.py --backends mjx --batches 1024 8192 32768 \
    --out "$dest/env_throughput.json"
step al_mjx 150 python benchmarks/al_throughput.py --batches 8 --episodes 5 --ref-agents 1 \
    --loops auto_reset --mjx-batch 1024 --mjx-episodes 3 --out "$dest/al_throughput.json"
step sweep_mjx 150 python -m grounding_jax.sweep sweeps/fig8a_critic_lr.toml \
    --set 'backend="mjx"' --out "$dest/sweeps" --overwrite --no-progress
