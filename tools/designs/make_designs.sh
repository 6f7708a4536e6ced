#!/usr/bin/env bash
# Builds the shipped display designs (issue 14): for each target, the DOE
# stage (models/nedrt_train/design.py, resumed if its checkpoint exists),
# the DOE files and the design file in designs/, and the card with the
# validation table measured by nedrt eval on data/images/val.
#
#   bash tools/designs/make_designs.sh                 # the paper-model designs
#   bash tools/designs/make_designs.sh allsharp        # one
#   bash tools/designs/make_designs.sh realeye         # for the real eye (§4a)
#   RUNS=/scratch/runs STEPS=500 bash tools/designs/make_designs.sh
#
# Needs .venv with the trainer installed (scripts/test.sh makes it) and a
# release build of nedrt.
set -euo pipefail
cd "$(dirname "$0")/../.."
RUNS="${RUNS:-models/runs}"
STEPS="${STEPS:-500}"
TARGETS=("$@")
[ ${#TARGETS[@]} -eq 0 ] && TARGETS=(allsharp multifocal)
NEDRT="${NEDRT:-target/release/nedrt}"
[ -x "$NEDRT" ] || cargo build --release
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"

for t in "${TARGETS[@]}"; do
    run="$RUNS/design-$t"
    resume=()
    [ -f "$run/checkpoint.pt" ] && resume=(--resume)
    # A design name is its target, but for the real eye's (docs/model.md
    # §4a): the multifocal target through 3–5 mm pupils with the eye's LCA,
    # evaluated through a 4 mm pupil with the eye's LCA.
    case "$t" in
        realeye) target=multifocal; stage=(--pupils-mm 3,4,5 --eye-lca on); eye=(--pupil-mm 4 --eye-lca on) ;;
        *) target="$t"; stage=(); eye=() ;;
    esac
    .venv/bin/nedrt-train design --target "$target" "${stage[@]}" --steps "$STEPS" \
        --out "$run" --name "$t" "${resume[@]}"
    mkdir -p "designs/$t"
    cp "$run/doe-$t-design.safetensors" "designs/$t/doe-design.safetensors"
    cp "$run/doe-$t-fabrication.safetensors" "designs/$t/doe-fabrication.safetensors"
    k=$(.venv/bin/python -c "import json,sys; print(json.load(open(sys.argv[1]))['wiener_k_linear'])" "$run/design.json")
    cat > "designs/$t.toml.tmp" <<EOF
# nedrt display design "$t", made by tools/designs/make_designs.sh:
# the DOE stage of docs/training.md (nedrt_train.design --target $target ${stage[*]}).
name = "$t"
target = "$target"
# The fabrication file (3 µm radial profile); the 6 µm design file is beside it.
doe = "$t/doe-fabrication.safetensors"
# Wiener constant K optimised with the DOE, the display clamped to [0, 1].
wiener_k = $k
card = "$t/card.json"
EOF
    mv "designs/$t.toml.tmp" "designs/$t.toml"
    "$NEDRT" --design "$t" "${eye[@]}" eval --images data/images/val --out-dir "designs/$t/eval" \
        --methods conventional,ai,doe+wiener --focus-cues
    .venv/bin/python tools/designs/make_card.py "$t" "$run" "designs/$t"
done
