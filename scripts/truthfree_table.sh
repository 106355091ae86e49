#!/usr/bin/env bash
# Regenerates the table "Do the truth-free figures track the truth?" of docs/validation.md: synthetic recordings
# over sensor noise levels, a rig.yaml perturbed by known amounts (passed with `validate --rig`) and the harder
# scenarios, each over several seeds; the truth errors (3D marker RMS, tip RMS) beside the truth-free figures
# (reprojection residual, the perturbed camera's own residual, ray residual, marker-pair distance error,
# eye-centre spread, dropouts); "no view" where a camera had no image matched in any frame. Prints the Markdown
# table (median over seeds, worst in brackets) on stdout.
#
#   scripts/truthfree_table.sh [--seeds "1 2 3 4 5"] [--seconds 4] [--eyesim PATH] [--work DIR] [--raw FILE]
set -euo pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
eyesim="$here/build/release/host/app/eyesim"
seeds="1 2 3 4 5"
seconds=4
work=""
raw=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --eyesim) eyesim="$2"; shift 2 ;;
    --work) work="$2"; shift 2 ;;
    --raw) raw="$2"; shift 2 ;;
    *) echo "truthfree_table.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -x "$eyesim" ] || { echo "truthfree_table.sh: $eyesim: not built" >&2; exit 1; }
if [ -z "$work" ]; then
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$work"
rows="$work/rows.tsv"
: >"$rows"

# One validate run → one row: case, seed, then the figures (JSON keys named in the python below).
measure() {  # case seed recording [validate options...]
  local name="$1" seed="$2" rec="$3"
  shift 3
  "$eyesim" validate --recording "$rec" --json "$@" >"$work/v.json"
  python3 - "$name" "$seed" "$work/v.json" >>"$rows" <<'EOF'
import json, sys
name, seed, path = sys.argv[1:4]
j = json.load(open(path))
t = j["truth_free"]
def f(v):
    return "nan" if v is None else repr(float(v))
cams = [c["reprojection_rms_px"] for c in t["per_camera"]]
print("\t".join([name, seed, f(j["marker3d_rms_um"]), f(j["tip_rms_um"]), f(j["eye_rot_rms_deg"]), f(t["reprojection_rms_px"]),
                 f(cams[0]), f(max(c for c in cams if c is not None)), f(t["ray_residual_rms_um"]),
                 f(t["pair_distance_rms_um"]), f(t["eye_centre"]["spread_rms_um"]), f(t["dropout_fraction"])]))
EOF
}

for seed in $seeds; do
  for noise in 0.5 1 2 4; do
    rec="$work/sweep_n${noise}_s${seed}"
    "$eyesim" synth --scenario sweep --seconds "$seconds" --seed "$seed" --noise "$noise" --out "$rec" >/dev/null
    measure "sweep, noise $noise" "$seed" "$rec"
  done
  base="$work/sweep_n1_s${seed}"
  for p in "rotate-deg 0.01" "rotate-deg 0.05" "rotate-deg 0.2" "move-um 20" "move-um 100" "focal-scale 1.001"; do
    set -- $p
    python3 "$here/scripts/perturb_rig.py" "$base/rig.yaml" "$work/rig.yaml" --camera 0 --"$1" "$2"
    case "$1" in
      rotate-deg) label="cam0 rotated $2°" ;;
      move-um) label="cam0 moved $2 µm" ;;
      focal-scale) label="cam0 focal +$(python3 -c "print(round(($2 - 1) * 100, 3))") %" ;;
    esac
    measure "sweep, $label (--rig)" "$seed" "$base" --rig "$work/rig.yaml"
  done
  for scenario in fast occlusion; do
    rec="$work/${scenario}_s${seed}"
    "$eyesim" synth --scenario "$scenario" --seconds "$seconds" --seed "$seed" --out "$rec" >/dev/null
    measure "$scenario" "$seed" "$rec"
  done
  rm -rf "$work"/sweep_n*_s"$seed" "$work"/fast_s"$seed" "$work"/occlusion_s"$seed"
done
[ -z "$raw" ] || cp "$rows" "$raw"

python3 - "$rows" "$seeds" "$seconds" <<'EOF'
import statistics, sys
rows, seeds, seconds = sys.argv[1], sys.argv[2].split(), sys.argv[3]
cases, data = [], {}
for line in open(rows):
    name, seed, *v = line.rstrip("\n").split("\t")
    if name not in data:
        cases.append(name)
        data[name] = []
    data[name].append([float(x) for x in v])
cols = [("truth 3D RMS µm", 0, "{:.1f}"), ("truth tip RMS µm", 1, "{:.1f}"), ("truth eye RMS °", 2, "{:.3f}"),
        ("reprojection RMS px", 3, "{:.3f}"), ("cam0 reprojection RMS px", 4, "{:.3f}"),
        ("worst camera reprojection RMS px", 5, "{:.3f}"), ("ray residual RMS µm", 6, "{:.1f}"),
        ("pair-distance error RMS µm", 7, "{:.1f}"), ("eye-centre spread RMS µm", 8, "{:.1f}"), ("dropouts %", 9, "{:.1f}")]
print(f"| recording ({seconds} s, seeds {' '.join(seeds)}) | " + " | ".join(c[0] for c in cols) + " |")
print("|---" * (len(cols) + 1) + "|")
for name in cases:
    cells = []
    for _, k, fmt in cols:
        v = [r[k] for r in data[name] if r[k] == r[k]]
        scale = 100.0 if k == 9 else 1.0
        # A camera none of whose images was matched has no residual: "no view".
        cells.append("no view" if not v else (fmt.format(statistics.median(v) * scale) + " (" + fmt.format(max(v) * scale) + ")"))
    print(f"| {name} | " + " | ".join(cells) + " |")
EOF
