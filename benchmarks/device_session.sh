#!/bin/bash
# One lease of a GPU machine in one command: a smoke test that stops early (and cheaply) if the
# machine's packages cannot run the library, the prepared check (benchmarks/device_check.py), then
# ant-field-small-k1 and half-cheetah-small-k1 trained side by side for the time that is left.
# Everything lands in $OUT: versions.txt, smoke.log, device_check_gpu.json, check.log, and
# <preset>.metrics.jsonl / <preset>.log per training row. See docs/gpu.md.
#
#   OUT=/tmp/out TOTAL_S=560 CHECK_S=300 bash benchmarks/device_session.sh
#   DRY=1 OUT=/tmp/out TOTAL_S=240 CHECK_S=150 bash benchmarks/device_session.sh   # tiny sizes, one row
#
# Wheels in .whl/ (mujoco, mujoco-mjx, tyro and what they need, for the machine's Python) are
# installed first; .whl/pins/ holds this project's pinned flax, optax and orbax-checkpoint, used only
# if the smoke test fails with the machine's own.
set -u
OUT=${OUT:-/tmp/device_out}
TOTAL_S=${TOTAL_S:-560}  # seconds this script may take, all steps together
CHECK_S=${CHECK_S:-300}  # of which the prepared check may take at most this many
DRY=${DRY:-0}
RUNS=${RUNS:-/tmp/runs}  # the training rows' run directories (their checkpoints stay on the machine)
PY=${PYTHON:-python3}
mkdir -p "$OUT"
began=$(date +%s)
left() { echo $((TOTAL_S - ($(date +%s) - began))); }

export PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=${JAX_COMPILATION_CACHE_DIR:-/tmp/jax-cache}  # the check's programs, reused
WHEELS=${WHEELS:-.whl}  # WHEELS=none where the packages are installed already
if [ -d "$WHEELS" ] && ls "$WHEELS"/*.whl >/dev/null 2>&1; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site "$WHEELS"/*.whl \
    || exit 3
  export PYTHONPATH=/tmp/site:${PYTHONPATH:-}
fi
export PYTHONPATH=$PWD:${PYTHONPATH:-}

smoke() {
  $PY - <<'PY'
import importlib.metadata as md, jax
for name in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax", "orbax-checkpoint", "tyro", "numpy"):
    try:
        print(name, md.version(name))
    except md.PackageNotFoundError:
        print(name, "missing")
print("devices", jax.devices())
from mjx_emp.envs.env import make_env
env = make_env("ant_field")
state = env.reset(jax.random.key(0))
state = jax.jit(env.step)(state, jax.numpy.zeros(env.action_size))
jax.block_until_ready(state)
from mjx_emp.algos.registry import all_presets, make_agent
import dataclasses
cfg = dataclasses.replace(all_presets()["point-mass-k1"][1], num_envs=4, batch_size=8, gc_grad_steps=1,
                          gs_grad_steps=1, replay_capacity=256, gs_replay_capacity=32, start_capacity=32)
agent = make_agent(cfg)
print("smoke epoch", agent.metrics(*agent.train_epoch(agent.init()), 1.0)["env_steps"])
PY
}
nvidia-smi > "$OUT/versions.txt" 2>&1
if ! smoke >> "$OUT/versions.txt" 2> "$OUT/smoke.log"; then
  echo "smoke test failed with the machine's packages; trying the pinned flax/optax/orbax" | tee -a "$OUT/smoke.log"
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    "$WHEELS"/pins/*.whl
  smoke >> "$OUT/versions.txt" 2>> "$OUT/smoke.log" || { tail -30 "$OUT/smoke.log"; exit 4; }
fi
cat "$OUT/versions.txt"

check_args=(--out "$OUT/device_check_gpu.json" --budget-s $((CHECK_S - 120)) --steps memory train rollout seeds)
[ "$DRY" = 1 ] && check_args+=(--dry-run)
timeout --signal=KILL "$CHECK_S" $PY benchmarks/device_check.py "${check_args[@]}" 2>&1 \
  | tee "$OUT/check.log" | grep -v '^W'

rows=(ant-field-small-k1 half-cheetah-small-k1)
train_args=()
[ "$DRY" = 1 ] && rows=(point-mass-k1) && train_args=(--epochs 2)  # one row: the suite pays for each compile
budget=$(( $(left) - 15 ))
echo "training ${rows[*]} side by side for $budget s"
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.4  # two processes share the one GPU
for preset in "${rows[@]}"; do
  timeout --signal=TERM --kill-after=10 "$budget" \
    $PY -m mjx_emp.cli train "$preset" --run-dir "$RUNS/$preset" "${train_args[@]}" > "$OUT/$preset.log" 2>&1 &
done
wait
for preset in "${rows[@]}"; do
  cp "$RUNS/$preset/metrics.jsonl" "$OUT/$preset.metrics.jsonl" 2>/dev/null
  tail -3 "$OUT/$preset.log"
done
echo "session done in $(( $(date +%s) - began )) s"
