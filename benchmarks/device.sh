#!/usr/bin/env bash
# The GPU checks of one lent-device session, each stage under its own timeout, logs under
# $OUT (default ./device_out). STAGES picks them (default: "throughput ant seeds", about
# 9 minutes on one H200 with its start; one command may run 10):
#   install     always: the packages the image lacks, from wheels in .whl/ (mujoco,
#               mujoco-mjx, brax and their small dependencies; RESULTS.md "GPU" lists
#               them), and the imports;
#   throughput  brax SAC against our SAC+HER and D2C (`benchmarks.run --only throughput
#               --no-sb3`: the image has no SB3);
#   ant         the command users are told to run, `python train.py --env ant` (the paper
#               preset on an accelerator, one env per iteration), stopped by SIGTERM after
#               ANT_S seconds: the env steps/s of the paper preset, a clean stop, and its
#               critic's Q;
#   ant_clip    the same with the TD target clipped to the return's range;
#   ant_envs4, ant_envs20  the same with 4 (20) envs per iteration instead of the paper
#               preset's 1 on Ant: new data every 1,200 (6,000) updates instead of 300.
#               20 was the preset until 2026-12-04 and its critic diverged (RESULTS.md,
#               "updates per data refresh"); their env steps/s against the preset's;
#   ant_quick   `--preset quick` (2x256, utd 0.25): its env steps/s on the GPU, which says
#               whether a 3M-env-step run fits in one command;
#   ant_quick_big  quick with Table 2's 3x512 networks and batch 512;
#   ant_walk50_big  the CPU's best Ant configuration so far (stop 62's 50-walk-step run,
#               benchmarks/runs/..._walk50_seed0_config.json) with Table 2's 3x512
#               networks and batch 512: whether the paper's network size moves the
#               frontier faster than 2x256 (on 2 CPU cores about one cell per 300k env
#               steps to 1.5M, a quarter of that after; RESULTS.md, stops 63-64). Give it
#               ANT_S=480 or more;
#   seeds       vmapped seeds of the paper preset on medium_maze.
# Usage (from the repo root): STAGES="ant ant_envs4 ant_quick" bash benchmarks/device.sh
# The wheels (for the image's Python 3.12; `.whl/` is ignored by git and travels as a
# carried path), fetched on a machine with pip:
#   for p in mujoco==4.0.1 mujoco-core==4.0.1 mujoco-studio==4.0.1 mujoco-mjx==3.17.0 \
#       brax==0.14.2 ml_collections==1.1.0 trimesh==5.2.0 tensorboardX==2.6.5 jaxopt glfw \
#       pyopengl; do
#     pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#       --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
#       --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any \
#       -d .whl "$p"
#   done
set -u
OUT=${OUT:-device_out}
STAGES=${STAGES:-throughput ant seeds}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl >"$OUT/install.log" 2>&1 || { tail -20 "$OUT/install.log"; exit 3; }
  export PYTHONPATH=/tmp/site:$PWD
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
python3 -c "import jax, mujoco, brax, envs; print(jax.__version__, jax.devices(), mujoco.__version__, brax.__version__, envs.make('ant').horizon)" || exit 4

ant() {  # ant NAME [train.py flags]: the default-preset Ant run, stopped after ANT_S s
  local name=$1
  shift
  echo "== $name $(date +%T)"
  timeout -s TERM "${ANT_S:-150}" python3 train.py --env ant --total-steps 3000000 \
    --out "/tmp/$name" "$@" 2>&1 | tr '\r' '\n' | tail -40 >"$OUT/$name.log"
  tail -4 "$OUT/$name.log"
  cp "/tmp/$name/metrics.jsonl" "$OUT/${name}_metrics.jsonl" 2>/dev/null
}

for stage in $STAGES; do
  case $stage in
    throughput)
      echo "== throughput $(date +%T)"
      timeout "${THROUGHPUT_S:-270}" python3 -m benchmarks.run --only throughput --no-sb3 2>&1 \
        | tee "$OUT/throughput.log" ;;
    ant) ant ant ;;
    ant_clip) ant ant_clip --sac.clip-target true ;;
    ant_envs4) ant ant_envs4 --num-envs 4 --curriculum.rematch-every 6000 ;;
    ant_envs20) ant ant_envs20 --num-envs 20 --curriculum.rematch-every 2000 ;;
    ant_quick) ant ant_quick --preset quick ;;
    ant_quick_big)
      ant ant_quick_big --preset quick --sac.hidden-sizes 512,512,512 --sac.batch-size 512 ;;
    ant_walk50_big)
      ant ant_walk50_big --config \
        benchmarks/runs/ant_quick_issue15_rk4_utd1_lr3e-4_clf3x256_clip_minfuture1_poolphase_walk50_seed0_config.json \
        --sac.hidden-sizes 512,512,512 --sac.batch-size 512 ;;
    seeds)
      echo "== seeds $(date +%T)"
      timeout "${SEEDS_S:-200}" python3 -m benchmarks.trainer --parts seeds --env medium_maze \
        --preset paper --seeds 1 8 32 2>&1 | tee "$OUT/seeds.log" ;;
    *) echo "unknown stage: $stage (throughput ant ant_clip ant_envs4 ant_envs20 ant_quick ant_quick_big ant_walk50_big seeds)" >&2
      exit 2 ;;
  esac
done
echo "== end $(date +%T)"
