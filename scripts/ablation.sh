#!/usr/bin/env bash
# The output-parameterisation ablation of BENCHMARKS.md ("Learning from scratch"): every variant
# trains the teacher from configs/small.toml (its built-in synthetic people) for the same number
# of steps, then `prism evaluate` scores the NVS output, the 3DGS render I_gs and copy-the-source
# on the same held-out views. Prints one markdown table row per variant.
#
#   scripts/ablation.sh [STEPS] [VIEWS] [OUT]      defaults: 150 steps, 20 views, runs/ablation
#
# Needs a release build (cargo build --release) and python3 for reading the JSON.
set -euo pipefail
cd "$(dirname "$0")/.."
STEPS="${1:-150}"
VIEWS="${2:-20}"
OUT="${3:-runs/ablation}"
PRISM=target/release/prism
mkdir -p "$OUT"

# name | sed edits of configs/small.toml (empty: the shipped recipe)
PAPER='s/^gs_colour = .*/gs_colour = "regressed"/; s/^gs_depth = .*/gs_depth = "head"/; s/^gs_scale = .*/gs_scale = 1.0/; s/^gs_keying = .*/gs_keying = false/; s/^gs_rim_depth = .*/gs_rim_depth = 0.0/; s/^nvs_output = .*/nvs_output = "direct"/; s/^head_upsample = .*/head_upsample = 0/; s/^gs_opacity = .*/gs_opacity = 0.0/; s/^smplx = .*/smplx = 1.0/'
VARIANTS=(
  "paper: plain NVS head, 3DGS head as in the paper|$PAPER"
  "paper + residual NVS over the paper's I_gs|$PAPER; s/^nvs_output = .*/nvs_output = \"residual\"/; s/^smplx = .*/smplx = 0.05/"
  "recipe (shipped small.toml)|"
  "recipe, NVS decoder direct (I_gs still trained)|s/^nvs_output = .*/nvs_output = \"direct\"/"
  "recipe without keying (opacity from 1/2)|s/^gs_keying = .*/gs_keying = false/"
  "recipe without L_opacity|s/^gs_opacity = .*/gs_opacity = 0.0/"
  "recipe with gs_scale = 1 (paper's size)|s/^gs_scale = .*/gs_scale = 1.0/"
  "recipe with gs_depth = head (no point-branch depth)|s/^gs_depth = .*/gs_depth = \"head\"/"
  "recipe with gs_colour = flow|s/^gs_colour = .*/gs_colour = \"flow\"/"
  "recipe with l_smplx = 1 (paper)|s/^smplx = .*/smplx = 1.0/"
)

echo "| variant | NVS PSNR | SSIM | LPIPS | I_gs PSNR | I_gs LPIPS | s / step |"
echo "|---|---|---|---|---|---|---|"
i=0
for entry in "${VARIANTS[@]}"; do
  name="${entry%%|*}"
  edits="${entry#*|}"
  dir="$OUT/v$i"
  i=$((i + 1))
  sed -e "${edits:-}" configs/small.toml > "$OUT/v$((i - 1)).toml"
  if [ ! -f "$dir/evaluation/evaluation.json" ]; then
    rm -rf "$dir"
    "$PRISM" train-teacher --config "$OUT/v$((i - 1)).toml" --out "$dir" --steps "$STEPS" --quiet > "$dir.log" 2>&1
    "$PRISM" evaluate --checkpoint "$dir" --views "$VIEWS" --quiet >> "$dir.log" 2>&1
  fi
  python3 - "$dir" "$name" <<'EOF'
import json, sys
d, name = sys.argv[1], sys.argv[2]
e = json.load(open(f"{d}/evaluation/evaluation.json"))
steps = [json.loads(l) for l in open(f"{d}/metrics.jsonl")]
secs = sorted(s["seconds"] for s in steps if "seconds" in s)
gs = e.get("gs")
gs_cols = f"{gs['psnr']:.2f} | {gs['lpips']:.4f}" if gs else "- | -"
print(f"| {name} | {e['psnr']:.2f} | {e['ssim']:.4f} | {e['lpips']:.4f} | {gs_cols} | {secs[len(secs) // 2]:.2f} |")
if name.startswith("recipe (shipped"):
    c = e["copy_source"]
    print(f"| copy the source view (baseline) | {c['psnr']:.2f} | {c['ssim']:.4f} | {c['lpips']:.4f} | | | |")
EOF
done
