#!/usr/bin/env bash
# Train mer-base (or the paper configuration) on one accelerator in about 9 minutes; results in $OUT.
#
#   OUT=/path/to/out tools/train_device.sh [--config base|paper] [--minutes M] [--eval-input DIR] [--ref-group K]
#       [--init DIR] [--batch-size B] [--lr LR] [--warmup N] [--lr-decay-steps N] [--lr-min-ratio R] [--ffn F]
#   OUT=/tmp/x tools/train_device.sh --dry-run [--init mer_models/bundled/mer-base]   # CPU, 2 training steps (tests/tools/test_train_device.py)
#
# --init continues from a checkpoint's weights (fresh optimiser), e.g. the bundled mer-base, instead of
# training from scratch; the rate options override the preset's (a continuation wants a lower --lr and a
# decay over about the steps the minutes buy: docs/model.md, Results: mer-base).
#
# Steps (each on synthetic motion generated in code: the weights carry no LAFAN1 licence):
#   1. shards: `mer shards build --synthetic` for the 8 built-in robots (sources and targets), 1 augmentation;
#   2. teacher: `mer shards solve`, one process per shard file (the device machine's CPU cores);
#   3. train: tools/learning_curve.py, bf16 autocast (a CPU dry run: only where native), for --minutes of wall time, evaluated after every
#      chunk on --eval-input (a LAFAN1-layout folder carried to the device) when given;
#   4. evaluate: `mer evaluate` (model and optimiser on the same windows) when --eval-input is given.
# $OUT receives: config.json, model.safetensors, train_log.jsonl, run.learning_curve.jsonl, teacher.json,
# evaluation.json/.txt, and log.txt (everything printed).
set -euo pipefail
cd "$(dirname "$0")/.."
: "${OUT:?set OUT to the output folder}"
CONFIG=base MINUTES=5 EVAL_INPUT="" DRY=0 DEVICE=cuda CLIPS=8 STEPS_CHUNK=400 BATCH=() GROUP=() TRAIN=()
while [ $# -gt 0 ]; do
  case "$1" in
    --config) CONFIG=$2; shift 2 ;;
    --minutes) MINUTES=$2; shift 2 ;;
    --eval-input) EVAL_INPUT=$2; shift 2 ;;
    --dry-run) DRY=1; shift ;;
    --ref-group) GROUP=(--ref-group "$2"); shift 2 ;;  # samples per window in a batch (TrainConfig.ref_group)
    --init) TRAIN+=(--init "$2"); shift 2 ;;
    --batch-size) BATCH=(--batch-size "$2"); shift 2 ;;
    --lr|--warmup|--lr-decay-steps|--lr-min-ratio|--ffn) TRAIN+=("$1" "$2"); shift 2 ;;  # --ffn: a wider feed-forward (with --init: widened)
    *) echo "unknown option $1 (see the header of $0)" >&2; exit 2 ;;
  esac
done
ROBOTS="g1 h1 h1_2 atlas oli tron1 talos valkyrie"
SECONDS_PER_CLIP=20
if [ "$DRY" = 1 ]; then DEVICE=cpu CLIPS=1 SECONDS_PER_CLIP=4 MINUTES=0 STEPS_CHUNK=2 ROBOTS="g1 h1" BATCH=(--batch-size 4); fi
PY=${PYTHON:-python3}
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
mkdir -p "$OUT"
WORK=${WORK:-$(mktemp -d)}
exec > >(tee -a "$OUT/log.txt") 2>&1
echo "train_device: config $CONFIG, $MINUTES min, device $DEVICE, work $WORK"
$PY -c "import torch, h5py, safetensors, mcap, yourdfpy; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
if [ "$DEVICE" = cuda ]; then $PY -c "import torch; assert torch.cuda.is_available(), 'no CUDA device'; print(torch.cuda.get_device_name())"; fi
NCPU=$($PY -c "import os; print(os.cpu_count() or 1)")
BF16=(--bf16)  # native on accelerators; on a CPU (the dry run) only with AMX/AVX512-BF16, else emulated and slow
if [ "$DEVICE" = cpu ] && ! $PY -c "import sys; from mer_models.training.train import native_bf16; sys.exit(0 if native_bf16('cpu') else 1)"; then BF16=(); fi
t0=$(date +%s)
$PY -m mer_models shards build --synthetic "$CLIPS" --synthetic-seconds "$SECONDS_PER_CLIP" --robots $ROBOTS --targets $ROBOTS \
  --augment 1 --workers "$NCPU" --quiet --out "$WORK/shards"
N=$(ls "$WORK"/shards/*.h5 | wc -l)
pids=()
for i in $(seq 0 $((N - 1))); do
  OMP_NUM_THREADS=$(( NCPU / N > 0 ? NCPU / N : 1 )) $PY -m mer_models shards solve "$WORK/shards" --shard-index "$i" --num-shards "$N" \
    --quiet --json > "$WORK/teacher-$i.json" & pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; done
$PY -c "import json,sys; print(json.dumps([r for f in sys.argv[1:] for r in json.load(open(f))], indent=1))" "$WORK"/teacher-*.json > "$OUT/teacher.json"
echo "train_device: shards + teacher in $(( $(date +%s) - t0 )) s"
t1=$(date +%s)
EVAL=()
if [ -n "$EVAL_INPUT" ]; then EVAL=(--eval-input "$EVAL_INPUT" --eval-targets g1 h1 atlas --eval-windows 16); fi
$PY tools/learning_curve.py --config "$CONFIG" --shards "$WORK/shards" --out "$WORK/run" --device "$DEVICE" "${BF16[@]}" \
  --clock wall --max-minutes "$MINUTES" --chunk-steps "$STEPS_CHUNK" "${BATCH[@]}" "${GROUP[@]}" "${TRAIN[@]}" "${EVAL[@]}"
echo "train_device: training in $(( $(date +%s) - t1 )) s"
cp "$WORK/run/config.json" "$WORK/run/model.safetensors" "$WORK/run/train_log.jsonl" "$WORK/run.learning_curve.jsonl" "$OUT/"
if [ -n "$EVAL_INPUT" ]; then
  for src in g1 h1; do
    $PY -m mer_models evaluate --model "$WORK/run" --input "$EVAL_INPUT" --source $src --targets $ROBOTS --split all \
      --max-windows 32 --methods model refine optimize --device "$DEVICE" --save "$OUT/evaluation-$src.json" | tee "$OUT/evaluation-$src.txt"
  done
fi
echo "train_device: done in $(( $(date +%s) - t0 )) s"
