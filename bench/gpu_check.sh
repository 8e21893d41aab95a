#!/usr/bin/env bash
# The GPU check of issue 19, prepared to run unattended on a machine with a CUDA GPU (under 10 minutes: each step
# has its own time limit, 560 s in all, so one 600 s device call holds it):
#   1. the machine: nvidia-smi, torch and its CUDA build, bf16 support, what --precision auto picks;
#   2. the tests that need a GPU to mean all they say: host reads per step on CUDA (tests/test_transfers.py),
#      precision auto (tests/test_precision.py);
#   3. the update benchmark (bench/update_paths.py) on CUDA at E = 1, 10, 50 in fp32 and bf16, and the plain
#      per-member loop beside the ensemble at E = 10;
#   4. one paper-size cell on the GPU: APAC on changing_target, 50 seeds (E = 50, one process), the paper's networks
#      and minibatch 500, CELL_EPISODES training episodes (default 20, after the 10 babbling episodes), timed.
# Everything goes to $OUT (default ./gpu_check_out): a log per step and summary.txt.
#
#   OUT=/path/to/out bash bench/gpu_check.sh              # from the repository root
#   PYTHON=.venv/bin/python CELL_EPISODES=40 bash bench/gpu_check.sh
#
# It installs nothing: PYTHON (default: python on PATH) must have this package's dependencies with a CUDA torch
# (README: APAC_MJ_TORCH=cuda bash .ci/in-venv ...). A missing piece is written to summary.txt, not hidden.
set -u
cd "$(dirname "$0")/.."
OUT=${OUT:-$PWD/gpu_check_out}
PYTHON=${PYTHON:-python}
CELL_EPISODES=${CELL_EPISODES:-20}
mkdir -p "$OUT"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} MUJOCO_GL=${MUJOCO_GL:-egl}
summary="$OUT/summary.txt"
: > "$summary"
say() { echo "$*" | tee -a "$summary"; }
step() {  # step NAME TIMEOUT_S COMMAND...: run, log to $OUT/NAME.log, record status and wall time
  local name=$1 limit=$2; shift 2
  local t0=$SECONDS
  timeout "$limit" "$@" > "$OUT/$name.log" 2>&1
  local rc=$?
  say "$name: exit $rc after $((SECONDS - t0)) s ($OUT/$name.log)"
  return $rc
}

say "gpu_check $(date -u +%FT%TZ) commit $(git rev-parse --short HEAD 2>/dev/null || echo unknown)"
nvidia-smi > "$OUT/nvidia-smi.txt" 2>&1 || say "nvidia-smi failed (no GPU driver?)"
if ! "$PYTHON" - > "$OUT/machine.txt" 2>&1 <<'EOF'
import torch, mujoco, dm_control  # noqa: F401  (the dependencies)
from apac_mj.agent.precision import cpu_info, resolve
print("torch", torch.__version__, "cuda build", torch.version.cuda, "available", torch.cuda.is_available())
assert torch.cuda.is_available(), "torch sees no CUDA device"
print("GPU", torch.cuda.get_device_name(0), "bf16", torch.cuda.is_bf16_supported())
print("CPU", cpu_info().describe())
print("auto on cuda:", resolve("auto", "cuda"))
print("auto on cpu:", resolve("auto", "cpu"))
EOF
then
  say "the environment is not ready (see $OUT/machine.txt); nothing else was run"
  cat "$OUT/machine.txt" >> "$summary"
  exit 1
fi
cat "$OUT/machine.txt" >> "$summary"

step tests 90 "$PYTHON" -m pytest -q -p no:cacheprovider tests/test_transfers.py tests/test_precision.py
tail -3 "$OUT/tests.log" >> "$summary"

step bench_e1_e10 150 "$PYTHON" bench/update_paths.py --device cuda --cases fp32:1 fp32:10 bf16:1 bf16:10 \
  --rounds 5 --updates 5 --json "$OUT/bench_e1_e10.json"
sed -n '/^paper sizes/,$p' "$OUT/bench_e1_e10.log" >> "$summary"
step bench_e50 120 "$PYTHON" bench/update_paths.py --device cuda --cases fp32:1 fp32:50 bf16:50 --no-plain \
  --rounds 5 --updates 5 --json "$OUT/bench_e50.json"
sed -n '/^paper sizes/,$p' "$OUT/bench_e50.log" >> "$summary"

# one paper-size cell, E = 50 on the GPU (MuJoCo on the CPU): wall time per training episode of all 50 seeds
rm -rf "$OUT/cell"
step cell 200 "$PYTHON" -m apac_mj.cli train --task changing_target --agent apac --seeds 0-49 \
  --episodes "$CELL_EPISODES" --device cuda --precision fp32 --out "$OUT/cell" --no-progress
"$PYTHON" - "$OUT/cell" "$CELL_EPISODES" >> "$summary" 2>&1 <<'EOF'
import json, sys, pandas as pd
run, episodes = sys.argv[1], int(sys.argv[2])
m = pd.read_parquet(f"{run}/metrics.parquet")
cfg = json.load(open(f"{run}/config.json"))
print(f"cell: {m.seed.nunique()} seeds, {len(m)} episode rows ({episodes} training + {cfg['agent']['babbling_episodes']} "
      f"babbling per seed), {int(m.steps.sum())} seed-steps, device {cfg['device']}, precision {cfg['precision']}")
EOF
say "cell wall time above ('cell: exit 0 after N s'); per seed-step = N / the seed-steps line"
say "done"
