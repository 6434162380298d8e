#!/usr/bin/env bash
# The main job on the embedded default (no Prefect server, no network): set up .venv, make a small synthetic
# session, process it through the Prefect flow and write the result bundle.
#   bash scripts/demo.sh [OUT_DIR]        (default out/demo)
# VYSICS_PRESET=default for the full settings (default here: fast); DEMO_PRESET=small|full for a bigger session.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/_venv.sh"
OUT="${1:-out/demo}"
mkdir -p "$OUT"
vysics synth --object baking_box --interaction push --seed 0 --preset "${DEMO_PRESET:-tiny}" \
  --out "$OUT/session" --archive "$OUT/session.zip"
vysics run "$OUT/session.zip" --out "$OUT/bundle" --preset "${VYSICS_PRESET:-fast}" --data-dir "$OUT/data"
echo
echo "bundle written to $OUT/bundle:"
(cd "$OUT/bundle" && find . -type f | sort | sed 's|^\./|  |')
