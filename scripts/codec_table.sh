#!/usr/bin/env bash
# Regenerates the codec table of docs/validation.md: a `sweep` recording written as raw UYVY fields and as each
# video format `eyesim synth --format` writes (interlaced PAL as cameras record it), then per recording
# `eyesim fpga --json` (centroid error, also over clear and over partly hidden markers, and signed bias against the
# rendered centroids, wall time),
# `eyesim validate --json` (3D marker, tip and eye errors) and bench_recording (what opening costs, reading speed).
# Each figure is the worst over the seeds (largest error, largest |bias|, slowest; fewest blobs refined). Prints
# the Markdown table on stdout. --refine: `fpga` and `validate` with --refine (each blob's centroid from the refinement stage's
# shaded-sphere fit on Y, Cb, Cr instead of the pipeline's chroma-only centroid).
#
#   scripts/codec_table.sh [--seeds "1 2"] [--seconds 10] [--formats "uyvy ffv1 ffv1-420 ffv1-411 dv dv411 mpeg2 mpeg2-422 h264"]
#                          [--refine] [--build DIR] [--eyesim PATH] [--work DIR]
set -euo pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
build="$here/build/release"
seeds="1 2"
seconds=10
formats="uyvy ffv1 ffv1-420 ffv1-411 dv dv411 mpeg2 mpeg2-422 h264"
work=""
refine=()
eyesim=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --formats) formats="$2"; shift 2 ;;
    --build) build="$2"; shift 2 ;;
    --eyesim) eyesim="$2"; shift 2 ;;
    --refine) refine=(--refine); shift ;;
    --work) work="$2"; shift 2 ;;
    *) echo "codec_table.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -n "$eyesim" ] || eyesim="$build/host/app/eyesim"
bench="$build/bench/rig/bench_recording"
for p in "$eyesim" "$bench"; do [ -x "$p" ] || { echo "codec_table.sh: $p: not built" >&2; exit 1; }; done
if [ -z "$work" ]; then
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$work"

now() { date +%s.%N; }
for seed in $seeds; do
  for f in $formats; do
    d="$work/sweep_${seed}_$f"
    if [ ! -f "$d.synth.json" ]; then
      if ! "$eyesim" synth --scenario sweep --seconds "$seconds" --seed "$seed" --format "$f" --out "$d" --json \
        >"$d.synth.json" 2>"$d.synth.err"; then
        echo "codec_table.sh: synth --format $f: $(tail -1 "$d.synth.err")" >&2
        rm -f "$d.synth.json"
        continue
      fi
    fi
    t0=$(now)
    "$eyesim" fpga --recording "$d" "${refine[@]}" --json >"$d.fpga.json" 2>"$d.fpga.err"
    t1=$(now)
    echo "$t0 $t1" >"$d.fpga.wall"
    "$eyesim" validate --recording "$d" "${refine[@]}" --json >"$d.validate.json" 2>"$d.validate.err" || true
    "$bench" "$d" >"$d.bench.json"
    du -sb "$d"/cam0.* | cut -f1 >"$d.bytes"
    echo "codec_table.sh: seed $seed $f done" >&2
  done
done

python3 - "$work" "$seeds" "$formats" "$seconds" "${#refine[@]}" <<'EOF'
import json, math, os, sys
work, seeds, formats, seconds = sys.argv[1], sys.argv[2].split(), sys.argv[3].split(), float(sys.argv[4])
refined = sys.argv[5] != "0"
names = {"uyvy": "raw UYVY fields", "ffv1": "FFV1 4:2:2 .mkv (lossless)",
         "ffv1-420": "FFV1 of 4:2:0 planes (lossless; subsampling alone)",
         "ffv1-411": "FFV1 of 4:1:1 planes (lossless; subsampling alone)", "dv": "DV 4:2:0 .avi (25 Mbit/s)",
         "dv411": "DVCPRO25 4:1:1 .avi (25 Mbit/s)", "mpeg2": "MPEG-2 4:2:0 .mpg (q 2, ≤ 15 Mbit/s)",
         "mpeg2-422": "MPEG-2 4:2:2 intra .mpg (D-10 / IMX: q 1, ≤ 50 Mbit/s)",
         "h264": "H.264 4:2:0 .mp4 (CRF 8)"}
def load(p):
    try:
        with open(p) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None
def num(x):
    return x if isinstance(x, (int, float)) else None
def worst(vals, key=lambda v: v):
    vals = [v for v in vals if v is not None]
    return max(vals, key=key) if vals else None
def fmt(v, spec):
    return "n/a" if v is None else format(v, spec)
print("| recording | centroid RMS px | clear / partly hidden px | clear markers' bias x, y top / bottom px | bias x / y px | y bias top / bottom px | 3D µm | tip µm | eye ° "
      "| `fpga` wall s | open ms (frames decoded) | read fields/s | Mbit/s per camera | lost fields |"
      + (" blobs refined % |" if refined else ""))
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if refined else ""))
for f in formats:
    rows = []
    for s in seeds:
        d = os.path.join(work, f"sweep_{s}_{f}")
        fp, va, be = load(d + ".fpga.json"), load(d + ".validate.json"), load(d + ".bench.json")
        if fp is None or be is None:
            continue
        t0, t1 = map(float, open(d + ".fpga.wall").read().split())
        bias = fp.get("centroid_bias_px") or {}
        vis = fp.get("centroid_by_visibility") or {}
        rows.append({
            "rms": num(fp.get("centroid_rms_px")),
            "clear": num((vis.get("clear") or {}).get("rms_px")),
            "hidden": num((vis.get("partly_hidden") or {}).get("rms_px")),
            "cbx": num(((vis.get("clear") or {}).get("bias_px") or {}).get("x")),
            "cbt": num(((vis.get("clear") or {}).get("bias_px") or {}).get("y_top")),
            "cbb": num(((vis.get("clear") or {}).get("bias_px") or {}).get("y_bottom")), "bx": num(bias.get("x")), "by": num(bias.get("y")),
            "byt": num(bias.get("y_top")), "byb": num(bias.get("y_bottom")),
            "m3d": num(va.get("marker3d_rms_um")) if va else None, "tip": num(va.get("tip_rms_um")) if va else None,
            "eye": num(va.get("eye_rot_rms_deg")) if va else None, "wall": t1 - t0,
            "open": be["open_ms"], "dec": be["decoded_frames_at_open"], "fps": be["fields_per_s"],
            "mbit": int(open(d + ".bytes").read()) * 8 / 1e6 / seconds, "lost": fp.get("lost_fields", 0),
            "refined": 100.0 * fp["refined"] / fp["blobs"] if refined and fp.get("blobs") else None})
    if not rows:
        print(f"| {names.get(f, f)} | not written (see stderr) |" + " |" * (13 if refined else 12))
        continue
    w = lambda k, absval=False: worst([r[k] for r in rows], key=(abs if absval else (lambda v: v)))
    print(f"| {names.get(f, f)} | {fmt(w('rms'), '.4f')} | {fmt(w('clear'), '.4f')} / {fmt(w('hidden'), '.4f')} "
          f"| {fmt(w('cbx', True), '+.4f')}, {fmt(w('cbt', True), '+.4f')} / {fmt(w('cbb', True), '+.4f')} "
          f"| {fmt(w('bx', True), '+.4f')} / {fmt(w('by', True), '+.4f')} "
          f"| {fmt(w('byt', True), '+.4f')} / {fmt(w('byb', True), '+.4f')} | {fmt(w('m3d'), '.1f')} "
          f"| {fmt(w('tip'), '.1f')} | {fmt(w('eye'), '.4f')} | {w('wall'):.1f} | {w('open'):.0f} ({w('dec')}) "
          f"| {min(r['fps'] for r in rows):.0f} | {w('mbit'):.1f} | {w('lost')} |"
          + (f" {fmt(min((r['refined'] for r in rows if r['refined'] is not None), default=None), '.0f')} |"
             if refined else ""))
print()
print(f"`sweep`, {seconds:g} s, seeds {', '.join(seeds)}; each figure the worst over the seeds"
      + ("; centroids from the refinement stage (`--refine`)." if refined else "."))
EOF
