#!/usr/bin/env bash
# Regenerates the wand-calibration table of docs/calibration.md ("Measured against truth"): per seed, a rig that
# differs from the default one (every camera turned, moved and its focal length scaled by seeded amounts with
# scripts/perturb_rig.py) records a `wand` recording; `eyesim calibrate` solves it with intrinsics from a file
# that holds the true K and distortion on other poses with zero clock offsets (so no pose or clock can leak),
# --truth-rig scoring the result; then a `sweep` recording of the same rig is validated with the true rig.yaml
# and with the calibrated one (`validate --rig`). Prints one Markdown row per seed, then the median and worst.
# `calibrate` runs with its defaults (wand centroids from the refinement stage); --calibrate-options "--no-refine"
# gives the FPGA model's centroids alone.
# --board: the intrinsics calibrated too, from a `checkerboard` recording of the same rig (--board-seconds, 34 s:
# 16 holds per camera), instead of the file.
#
#   scripts/calibration_table.sh [--seeds "201 202 203 204 205"] [--seconds 40] [--sweep-seconds 10] [--board]
#                                [--board-seconds 34] [--eyesim PATH] [--work DIR] [--calibrate-options "..."]
set -euo pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
eyesim="$here/build/release/host/app/eyesim"
seeds="201 202 203 204 205"
seconds=40
sweep_seconds=10
work=""
cal_opts=""
board=0
board_seconds=34
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --sweep-seconds) sweep_seconds="$2"; shift 2 ;;
    --eyesim) eyesim="$2"; shift 2 ;;
    --work) work="$2"; shift 2 ;;
    --calibrate-options) cal_opts="$2"; shift 2 ;;
    --board) board=1; shift ;;
    --board-seconds) board_seconds="$2"; shift 2 ;;
    *) echo "calibration_table.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -x "$eyesim" ] || { echo "calibration_table.sh: $eyesim: not built" >&2; exit 1; }
if [ -z "$work" ]; then
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$work"
rows="$work/rows.tsv"
: >"$rows"

for seed in $seeds; do
  d="$work/$seed"
  rm -rf "$d"
  mkdir -p "$d"
  # The default rig, written by synth, then every camera perturbed by seeded amounts.
  "$eyesim" synth --scenario static --seconds 0.02 --out "$d/default" >/dev/null
  cp "$d/default/rig.yaml" "$d/true.yaml"
  for cam in 0 1 2; do
    read -r rot move focal < <(python3 -c "
import random; r = random.Random($seed * 10 + $cam)
print(r.uniform(-1, 1), r.uniform(-3000, 3000), 1 + r.uniform(-0.01, 0.01))")
    python3 "$here/scripts/perturb_rig.py" "$d/true.yaml" "$d/true.yaml" --camera "$cam" --rotate-deg "$rot" \
      --move-um "$move" --focal-scale "$focal"
  done
  # Intrinsics file: the true K and distortion; poses turned 3° and moved 5 mm, clocks 0.
  cp "$d/true.yaml" "$d/intrinsics.yaml"
  for cam in 0 1 2; do
    python3 "$here/scripts/perturb_rig.py" "$d/intrinsics.yaml" "$d/intrinsics.yaml" --camera "$cam" --rotate-deg 3 \
      --move-um 5000
  done
  sed -i 's/field_time_offset_us: .*/field_time_offset_us: 0./' "$d/intrinsics.yaml"

  "$eyesim" synth --scenario wand --seconds "$seconds" --seed "$seed" --rig "$d/true.yaml" --out "$d/wand" >/dev/null
  intrinsics=(--intrinsics "$d/intrinsics.yaml")
  if [ "$board" = 1 ]; then
    "$eyesim" synth --scenario checkerboard --seconds "$board_seconds" --seed "$seed" --rig "$d/true.yaml" --out "$d/board" >/dev/null
    intrinsics=(--board "$d/board")
  fi
  # shellcheck disable=SC2086
  "$eyesim" calibrate --wand "$d/wand" "${intrinsics[@]}" --out "$d/calibrated.yaml" \
    --truth-rig "$d/true.yaml" --json $cal_opts >"$d/calibrate.json"
  rm -rf "$d/wand" "$d/board"
  "$eyesim" synth --scenario sweep --seconds "$sweep_seconds" --seed "$seed" --rig "$d/true.yaml" --out "$d/sweep" >/dev/null
  "$eyesim" validate --recording "$d/sweep" --json >"$d/validate_true.json"
  "$eyesim" validate --recording "$d/sweep" --rig "$d/calibrated.yaml" --json >"$d/validate_calibrated.json"
  rm -rf "$d/sweep" "$d/default"
  python3 - "$d" "$seed" >>"$rows" <<'EOF'
import json, sys
d, seed = sys.argv[1], sys.argv[2]
c = json.load(open(d + "/calibrate.json"))
vt = json.load(open(d + "/validate_true.json"))
vc = json.load(open(d + "/validate_calibrated.json"))
cams = c["cameras"]
row = [
    seed,
    c["samples"],
    max(k["truth"]["centre_error_um"] for k in cams),
    max(k["truth"]["rotation_error_deg"] for k in cams),
    max(max(abs(k["truth"]["fx_error_pct"]), abs(k["truth"]["fy_error_pct"])) for k in cams),
    max(abs(k["truth"]["time_offset_error_us"]) for k in cams),
    max(k["image_error_px_rms"] for k in cams),
    max(k["image_error_frame_px_rms"] for k in cams),
    max(k["truth"]["projection_error_px_rms"] for k in cams),
    c["wand_length_error_mm"]["rms"] * 1e3,
    c["solve_s"],
    vt["marker3d_rms_um"],
    vc["marker3d_rms_um"],
    100.0 * (vc["marker3d_rms_um"] / vt["marker3d_rms_um"] - 1.0),
    vt["tip_rms_um"],
    vc["tip_rms_um"],
]
print("\t".join(str(x) for x in row))
EOF
done

python3 - "$rows" <<'EOF'
import sys, statistics
rows = [l.rstrip("\n").split("\t") for l in open(sys.argv[1]) if l.strip()]
head = ["seed", "samples", "centre µm", "rotation °", "focal %", "clock µs", "image px (field)", "image px (frame)",
        "projection px", "wand length µm", "solve s", "3D µm true rig", "3D µm calibrated", "3D change %",
        "tip µm true", "tip µm calibrated"]
fmt = ["{}", "{}", "{:.1f}", "{:.4f}", "{:.3f}", "{:.1f}", "{:.4f}", "{:.4f}", "{:.4f}", "{:.2f}", "{:.2f}", "{:.1f}",
       "{:.1f}", "{:+.1f}", "{:.1f}", "{:.1f}"]
print("| " + " | ".join(head) + " |")
print("|" + "---|" * len(head))
for r in rows:
    print("| " + " | ".join(f.format(int(v) if i < 2 else float(v)) for i, (f, v) in enumerate(zip(fmt, r))) + " |")
cols = list(zip(*rows))
med = ["median", ""] + [fmt[i].format(statistics.median(float(v) for v in cols[i])) for i in range(2, len(head))]
# Worst: the largest value (the largest change, for the 3D change; the least samples).
worst = ["worst", str(min(int(v) for v in cols[1]))] + [fmt[i].format(max(float(v) for v in cols[i])) for i in range(2, len(head))]
print("| " + " | ".join(med) + " |")
print("| " + " | ".join(worst) + " |")
EOF
