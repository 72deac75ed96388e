#!/bin/bash
# One lease of a GPU machine in one command: a smoke test that stops early (and cheaply) if the
# machine's packages cannot run the library, the prepared check (benchmarks/device_check.py), then
# the training rows (ROWS, default ant-field-k1-paper-small and half-cheetah-field-k1-paper-small) side by side for the
# time that is left, and, when PHASE2_S > 0, each row's phase 2 and `mjx-emp eval` in the last PHASE2_S
# seconds. Everything lands in $OUT: versions.txt (the settings, the GPU, the packages), smoke.log,
# check.jsonl (the check's rows), check.log, and per row <preset>.log, <preset>.metrics.jsonl, <preset>.skills.tar
# (its skills export: phase 2 and eval can go on from it on another machine), <preset>.phase2.jsonl
# and <preset>.eval.json. With SEEDS (e.g. "0 1 2 3") each row trains those seeds in one vmapped program
# (`--seeds`), and every per-row file above is per run, <preset>-s<seed>, but for the log and the metrics,
# which travel inside each run's skills export (a lease returns at most 8 files). Back home,
# `python benchmarks/gpu_summary.py $OUT` appends the lease's rows to results/gpu-leases.jsonl.
# LEASE names them (default gpu_lease_<GPU model>, such as gpu_lease_h200). See docs/gpu.md.
#
#   OUT=/tmp/out TOTAL_S=560 CHECK_S=300 bash benchmarks/device_lease.sh
#   OUT=/tmp/out TOTAL_S=540 CHECK_S=0 PHASE2_S=200 ROWS=ant-field-k1-paper-small \
#     TRAIN_FLAGS="--solver-iterations 4 --critic-layer-norm" bash benchmarks/device_lease.sh
#   DRY=1 OUT=/tmp/out TOTAL_S=240 CHECK_S=150 bash benchmarks/device_lease.sh   # tiny sizes, one row
#
# Wheels in .whl/ (mujoco, mujoco-mjx, tyro and what they need, for the machine's Python) are
# installed first; .whl/pins/ holds this project's pinned flax, optax and orbax-checkpoint, used only
# if the smoke test fails with the machine's own.
set -u
OUT=${OUT:-/tmp/device_out}
TOTAL_S=${TOTAL_S:-560}  # seconds this script may take, all steps together
CHECK_S=${CHECK_S:-300}  # of which the prepared check may take at most this many; 0 skips it
PHASE2_S=${PHASE2_S:-0}  # of which the rows' phase 2 and eval take the last this many; 0: none
ROWS=${ROWS:-ant-field-k1-paper-small half-cheetah-field-k1-paper-small}  # presets trained side by side
TRAIN_FLAGS=${TRAIN_FLAGS:-}  # config flags for every row, e.g. --solver-iterations 4
SEEDS=${SEEDS:-}  # seeds trained together in each row's one program; empty: the preset's own seed
DRY=${DRY:-0}
LEASE=${LEASE:-}  # the first part of the lease's row names; empty: gpu_lease_<GPU model>
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
printf '%s\n' "ROWS=$ROWS" "TRAIN_FLAGS=$TRAIN_FLAGS" "SEEDS=$SEEDS" "TOTAL_S=$TOTAL_S" "CHECK_S=$CHECK_S" \
  "PHASE2_S=$PHASE2_S" "DRY=$DRY" "LEASE=$LEASE" > "$OUT/versions.txt"  # the settings first, then the machine
nvidia-smi >> "$OUT/versions.txt" 2>&1
if ! smoke >> "$OUT/versions.txt" 2> "$OUT/smoke.log"; then
  echo "smoke test failed with the machine's packages; trying the pinned flax/optax/orbax" | tee -a "$OUT/smoke.log"
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    "$WHEELS"/pins/*.whl
  smoke >> "$OUT/versions.txt" 2>> "$OUT/smoke.log" || { tail -30 "$OUT/smoke.log"; exit 4; }
fi
cat "$OUT/versions.txt"

if [ "$CHECK_S" -gt 0 ]; then
  check_args=(--results "$OUT/check.jsonl" --budget-s $((CHECK_S - 120)) --steps memory train rollout seeds)
  [ "$DRY" = 1 ] && check_args+=(--dry-run)
  [ -n "$LEASE" ] && check_args+=(--lease "$LEASE")
  timeout --signal=KILL "$CHECK_S" $PY benchmarks/device_check.py "${check_args[@]}" 2>&1 \
    | tee "$OUT/check.log" | grep -v '^W'
fi

read -r -a rows <<< "$ROWS"
read -r -a train_args <<< "$TRAIN_FLAGS"
phase2_args=()
eval_args=()
if [ "$DRY" = 1 ]; then  # one row: the suite pays for each compile
  rows=(point-mass-k1) && train_args+=(--epochs 2)
  phase2_args=(--epochs 1 --num-envs 4 --iterations 1 --grad-steps 1 --eval-rounds 1)
  eval_args=(--episodes 8)
fi
seed_args=()
[ -n "$SEEDS" ] && read -r -a seeds <<< "$SEEDS" && seed_args=(--seeds "${seeds[@]}")
runs_of() {  # the run directories (under $RUNS) a row trains: the row's own, or one per seed
  if [ -n "$SEEDS" ]; then for seed in "${seeds[@]}"; do echo "$1-s$seed"; done; else echo "$1"; fi
}
EXPORT_S=${EXPORT_S:-60}  # the runs' skills exports (`mjx-emp export`, side by side on the CPU), small enough for $OUT
budget=$(( $(left) - 15 - PHASE2_S - EXPORT_S ))
echo "training ${rows[*]} side by side for $budget s"
[ "${#rows[@]}" -gt 1 ] && export XLA_PYTHON_CLIENT_MEM_FRACTION=$(printf 0.%02d $(( 80 / ${#rows[@]} )))  # one GPU, shared
for preset in "${rows[@]}"; do
  timeout --signal=TERM --kill-after=10 "$budget" $PY -m mjx_emp.cli train "$preset" --run-dir "$RUNS/$preset" \
    "${seed_args[@]}" "${train_args[@]}" > "$OUT/$preset.log" 2>&1 &
done
wait
runs=()
for preset in "${rows[@]}"; do for run in $(runs_of "$preset"); do runs+=("$run"); done; done
for run in "${runs[@]}"; do  # the skills without their replays: phase 2 and eval can run on them elsewhere
  (JAX_PLATFORMS=cpu timeout --signal=KILL "$EXPORT_S" $PY -m mjx_emp.cli export "$RUNS/$run" --out "$RUNS/$run.skills" \
    > "$RUNS/$run.export.log" 2>&1 && tar cf "$OUT/$run.skills.tar" -C "$RUNS" "$run.skills") &  # orbax nests too deep for $OUT
done
wait
for preset in "${rows[@]}"; do for run in $(runs_of "$preset"); do cat "$RUNS/$run.export.log" >> "$OUT/$preset.log"; done; done
if [ "$PHASE2_S" -gt 0 ]; then  # phase 2 on each run's newest checkpoint, then its figures
  [ "${#runs[@]}" -gt 1 ] && export XLA_PYTHON_CLIENT_MEM_FRACTION=$(printf 0.%02d $(( 80 / ${#runs[@]} )))
  for preset in "${rows[@]}"; do
    for run in $(runs_of "$preset"); do
      (
        timeout --signal=TERM --kill-after=30 $(( PHASE2_S / 2 )) \
          $PY -m mjx_emp.cli phase2 "$RUNS/$run" "${phase2_args[@]}" > "$RUNS/$run.phase2.log" 2>&1
        timeout --signal=KILL $(( $(left) > 20 ? $(left) - 10 : 10 )) $PY -m mjx_emp.cli eval "$RUNS/$run" "${eval_args[@]}" \
          --out "$OUT/$run.eval.json" >> "$RUNS/$run.phase2.log" 2>&1
      ) &
    done
  done
  wait
  for preset in "${rows[@]}"; do for run in $(runs_of "$preset"); do cat "$RUNS/$run.phase2.log" >> "$OUT/$preset.log"; done; done
fi
for run in "${runs[@]}"; do
  [ -n "$SEEDS" ] || cp "$RUNS/$run/metrics.jsonl" "$OUT/$run.metrics.jsonl" 2>/dev/null  # else in its export
  cp "$RUNS/$run/phase2/metrics.jsonl" "$OUT/$run.phase2.jsonl" 2>/dev/null
done
for preset in "${rows[@]}"; do tail -3 "$OUT/$preset.log"; done
echo "lease done in $(( $(date +%s) - began )) s"
