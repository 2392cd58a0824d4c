#!/usr/bin/env bash
# The GPU checks of one lent-device session (about 9 minutes on one H200), each stage
# under its own timeout, logs under $OUT (default ./device_out):
#   1. the packages this image lacks, from wheels in .whl/ (mujoco, mujoco-mjx, brax and
#      their small dependencies; benchmarks/RESULTS.md "GPU" says which), and imports;
#   2. brax SAC against our SAC+HER and D2C (`benchmarks.run --only throughput --no-sb3`:
#      the image has no SB3);
#   3. the command users are told to run, `python train.py --env ant` (the paper preset on
#      an accelerator), stopped by SIGTERM after ANT_S seconds: the env steps/s of the
#      paper preset and a clean stop;
#   4. vmapped seeds of the paper preset on medium_maze.
# Usage (from the repo root): bash benchmarks/device.sh
set -u
OUT=${OUT:-device_out}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl >"$OUT/install.log" 2>&1 || { tail -20 "$OUT/install.log"; exit 3; }
  export PYTHONPATH=/tmp/site:$PWD
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
python3 -c "import jax, mujoco, brax, envs; print(jax.__version__, jax.devices(), mujoco.__version__, brax.__version__, envs.make('ant').horizon)" || exit 4
echo "== throughput $(date +%T)"
timeout "${THROUGHPUT_S:-270}" python3 -m benchmarks.run --only throughput --no-sb3 2>&1 | tee "$OUT/throughput.log"
echo "== ant, default preset $(date +%T)"
timeout -s TERM "${ANT_S:-150}" python3 train.py --env ant --total-steps 3000000 --out /tmp/ant_paper 2>&1 \
  | tr '\r' '\n' | tail -40 >"$OUT/ant.log"
tail -8 "$OUT/ant.log"
cp /tmp/ant_paper/metrics.jsonl* /tmp/ant_paper/config.json "$OUT/" 2>/dev/null
echo "== seeds $(date +%T)"
timeout "${SEEDS_S:-200}" python3 -m benchmarks.trainer --parts seeds --env medium_maze --preset paper \
  --seeds 1 8 32 2>&1 | tee "$OUT/seeds.log"
echo "== end $(date +%T)"
