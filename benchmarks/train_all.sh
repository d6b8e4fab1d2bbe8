#!/usr/bin/env bash
# Train every trainable model on GRID speaker 1 and score them all on the test split:
# the commands behind docs/results-grid.md.
#
#     bash benchmarks/train_all.sh [train|evaluate|all] [CORPUS] [MODELS_DIR]
#
# Run from the repository root. CORPUS defaults to ../shared/data/grid_s1 (beside the
# repository), MODELS_DIR to /tmp/models; `vispeech` is the virtualenv's (.venv/bin/vispeech,
# or $VISPEECH). Each model trains on the train split and stops early on the validation split,
# on ONE thread (OpenMP/MKL/OpenBLAS threads 1, which also sets torch's intra-op pool to 1).
# A model's log, ending with its wall seconds, goes to MODELS_DIR/<model>.log. The alignment
# is cached (~/.cache/vispeech), so only the very first run aligns the corpus (about 90 s).
# `evaluate` scores the four data-free models (authored parameters), the trained folders and
# the shipped default model `grid-tdnn`, with post-processing (what users get) and without
# (raw model output), and prints the summary table of docs/results-grid.md.
set -euo pipefail

STEP=${1:-all}
CORPUS=$(realpath "${2:-../shared/data/grid_s1}")
MODELS=$(realpath -m "${3:-/tmp/models}")
VISPEECH=$(realpath "${VISPEECH:-.venv/bin/vispeech}")
PYTHON=$(dirname "$VISPEECH")/python
TAYLOR_EPOCHS=${TAYLOR_EPOCHS:-9}  # cap: one epoch on the full train split takes about 120 s
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
mkdir -p "$MODELS"

train() {  # train FOLDER [vispeech train options...]
    local name=$1 start
    shift
    start=$(date +%s.%N)
    "$VISPEECH" train --corpus "$CORPUS" --quiet "$@" -o "$MODELS/$name" 2>&1 | tee "$MODELS/$name.log"
    echo "wall seconds: $(echo "$(date +%s.%N) - $start" | bc)" | tee -a "$MODELS/$name.log"
}

evaluate() {  # evaluate NAME [--postprocessing none]: tables -> MODELS_DIR/evaluate-NAME.{md,txt}
    local name=$1
    shift
    # Run beside the models folder so that the tables label a trained model "models/<folder>".
    (cd "$(dirname "$MODELS")" && m=$(basename "$MODELS") &&
     "$VISPEECH" evaluate --corpus "$CORPUS" --split test --quiet "$@" \
        -m baseline -m beskow-rules -m cohen-massaro -m ohman \
        -m "$m/cohen-massaro" -m "$m/ohman" \
        -m "$m/sliding-window-thesis" -m "$m/sliding-window-thesis-features" -m "$m/sliding-window-taylor" \
        -m "$m/tdnn-beskow" -m "$m/tdnn-lowlatency" -m grid-tdnn \
        --markdown "$MODELS/evaluate-$name.md") | tee "$MODELS/evaluate-$name.txt"
}

if [[ $STEP == train || $STEP == all ]]; then
    train cohen-massaro -m cohen-massaro
    train ohman -m ohman
    train sliding-window-thesis -m sliding-window-thesis
    train sliding-window-thesis-features -m sliding-window-thesis --input features
    train tdnn-beskow -m tdnn-beskow
    train tdnn-lowlatency -m tdnn-lowlatency
    train sliding-window-taylor -m sliding-window-taylor --epochs "$TAYLOR_EPOCHS"
fi

if [[ $STEP == evaluate || $STEP == all ]]; then
    evaluate postprocess
    evaluate raw --postprocessing none
    # Summary: per model and setting, from the two Markdown tables. Lip channels: the 19
    # mouth* channels every model predicts (mouthClose, Funnel, Pucker, Smile, Dimple,
    # Stretch, RollLower/Upper, ShrugLower/Upper, Press, LowerDown, UpperUp; both sides).
    "$PYTHON" - "$MODELS/evaluate-postprocess.md" "$MODELS/evaluate-raw.md" <<'EOF' | tee "$MODELS/summary.md"
import math
import sys

from vispeech.targets.tables import TARGET_CHANNELS

LIPS = [c for c in TARGET_CHANNELS if c.startswith("mouth")]


def tables(path):
    """Rows of the metrics and closure tables of an `evaluate --markdown` file."""
    metrics, closures = {}, {}
    for line in open(path, encoding="utf-8"):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.startswith("| ") or cells[0] == "model":
            continue
        if len(cells) == 7 and "/" in cells[1] and cells[1].split("/")[0].isdigit():
            closures[cells[0]] = cells
        elif len(cells) == 7:
            metrics[cells[0], cells[1]] = cells
    return metrics, closures


for path, setting in zip(sys.argv[1:], ("on (default)", "off (raw model output)")):
    metrics, closures = tables(path)
    print(f"\nPost-processing {setting}:\n")
    print("| model | jawOpen r | jawOpen RMSE | jawOpen RMSE % | mouthClose r "
          f"| mean r, {len(LIPS)} lip channels | /p b m/ closed | closed frames % (tracked) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for model in dict.fromkeys(m for m, _ in metrics):
        jaw, close = metrics[model, "jawOpen"], metrics[model, "mouthClose"]
        lips = [float(metrics[model, c][4]) for c in LIPS if metrics[model, c][4] != "n/a"]
        lip_r = f"{sum(lips) / len(lips):.3f}" + (f" ({len(lips)} with r)" if len(lips) < len(LIPS) else "")
        c = closures[model]
        print(f"| {model} | {jaw[4]} | {math.sqrt(float(jaw[2])):.3f} | {jaw[3]} | {close[4]} "
              f"| {lip_r} | {c[1]} ({c[2]} %) | {c[3]} ({c[4]}) |")
EOF
fi
