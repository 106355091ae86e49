#!/usr/bin/env bash
# Regenerates the table "Over seeds" of docs/validation.md: `eyesim synth` + `eyesim validate --json` over seeds ×
# durations × scenarios (default: seeds 21–30, on which no parameter was tuned; 2 s and 10 s; sweep, fast,
# occlusion, surgery), two runs at a time, and prints one Markdown table with a row per scenario and duration: the
# median and the worst over the seeds of the 3D RMS over all matched markers (flagged partly occluded ones
# included), the 3D RMS of the reliable markers alone (the flagged ones left out), tip RMS (all measured poses, and
# those whose truth has the tip inside the eye), eye rotation RMS and
# exposure mid → pose p50 / p99, with the seeds behind each row. A seed whose figure is null (never measured) is
# named in the row's last column and left out of that figure; a failed run is an error.
#
#   scripts/seed_table.sh [--seeds "21 22 ... 30"] [--seconds "2 10"] [--scenarios "sweep fast occlusion surgery"]
#                         [--jobs 2] [--eyesim PATH] [--work DIR] [--raw FILE] [-- validate options...]
#
# --raw FILE keeps one line per run (scenario, seconds, seed, figures; TSV) to rebuild or extend the table; --work
# DIR keeps the validate JSON of each run (recordings are removed as soon as they are scored). A line per finished
# run goes to stderr.
set -euo pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
eyesim="$here/build/release/host/app/eyesim"
seeds="21 22 23 24 25 26 27 28 29 30"
durations="2 10"
scenarios="sweep fast occlusion surgery"
jobs=2
work=""
raw=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds="$2"; shift 2 ;;
    --seconds) durations="$2"; shift 2 ;;
    --scenarios) scenarios="$2"; shift 2 ;;
    --jobs) jobs="$2"; shift 2 ;;
    --eyesim) eyesim="$2"; shift 2 ;;
    --work) work="$2"; shift 2 ;;
    --raw) raw="$2"; shift 2 ;;
    --) shift; break ;;
    *) echo "seed_table.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -x "$eyesim" ] || { echo "seed_table.sh: $eyesim: not built" >&2; exit 1; }
command -v python3 >/dev/null || { echo "seed_table.sh: python3 not found" >&2; exit 1; }
[ "$jobs" -ge 1 ] 2>/dev/null || { echo "seed_table.sh: --jobs must be a positive integer" >&2; exit 2; }
if [ -z "$work" ]; then
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$work"
validate_opts=("$@")

# One run: synth, validate, keep the JSON, drop the recording. Output: the JSON file; stderr in NAME.err.
one() {  # scenario seconds seed [validate options...]
  local sc="$1" sec="$2" seed="$3"
  shift 3
  local name="${sc}_${sec}s_seed${seed}"
  local rec="$work/$name.rec"
  rm -rf "$rec"
  if ! "$eyesim" synth --scenario "$sc" --seconds "$sec" --seed "$seed" --out "$rec" >/dev/null 2>"$work/$name.err" ||
     ! "$eyesim" validate --recording "$rec" --json "$@" >"$work/$name.json" 2>>"$work/$name.err"; then
    rm -rf "$rec"
    echo "seed_table.sh: $name failed: $(tail -n 1 "$work/$name.err")" >&2
    return 1
  fi
  rm -rf "$rec"
  echo "seed_table.sh: $name done" >&2
}

# The longest runs first, so that the two job slots finish together.
list="$work/runs.txt"
: >"$list"
for sec in $(printf '%s\n' $durations | sort -rn); do
  for sc in $scenarios; do
    for seed in $seeds; do echo "$sc $sec $seed" >>"$list"; done
  done
done
status=0
running=0
while read -r sc sec seed; do
  if [ "$running" -ge "$jobs" ]; then
    wait -n || status=1
    running=$((running - 1))
  fi
  one "$sc" "$sec" "$seed" "${validate_opts[@]}" </dev/null &
  running=$((running + 1))
done <"$list"
while [ "$running" -gt 0 ]; do
  wait -n || status=1
  running=$((running - 1))
done
[ "$status" -eq 0 ] || { echo "seed_table.sh: some runs failed (above)" >&2; exit 1; }

python3 - "$work" "$raw" "$scenarios" "$durations" "$seeds" <<'EOF'
import json, os, statistics, sys
work, raw, scenarios, durations, seeds = sys.argv[1], sys.argv[2], sys.argv[3].split(), sys.argv[4].split(), sys.argv[5].split()
# (column title, how to read it from the JSON, format)
def ms(j, q):
    # Older builds named the span fpga_chain.latency_exposure_to_poses_us.
    e = j.get("exposure_to_pose_us") or j.get("fpga_chain", {}).get("latency_exposure_to_poses_us") or {}
    return None if e.get(q) is None else e[q] / 1e3
cols = [("3D all matched µm", lambda j: j.get("marker3d_all_rms_um"), "{:.1f}"),
        ("3D reliable only µm", lambda j: j.get("marker3d_rms_um"), "{:.1f}"),
        ("tip µm", lambda j: j.get("tip_rms_um"), "{:.1f}"),
        ("tip in the eye µm", lambda j: j.get("tip_in_eye_rms_um"), "{:.1f}"),
        ("eye °", lambda j: j.get("eye_rot_rms_deg"), "{:.4f}"),
        ("exposure→pose p50 ms", lambda j: ms(j, "p50"), "{:.1f}"),
        ("exposure→pose p99 ms", lambda j: ms(j, "p99"), "{:.1f}")]
out_raw = open(raw, "w") if raw else None
if out_raw:
    print("\t".join(["scenario", "seconds", "seed"] + [c[0] for c in cols]), file=out_raw)
print("| scenario | s | " + " | ".join(c[0] + " median (worst)" for c in cols) + " | seeds |")
print("|---" * (len(cols) + 3) + "|")
for sc in scenarios:
    for sec in durations:
        vals = [[] for _ in cols]
        nulls = {}
        for seed in seeds:
            j = json.load(open(os.path.join(work, f"{sc}_{sec}s_seed{seed}.json")))
            row = []
            for k, (title, get, _) in enumerate(cols):
                v = get(j)
                row.append("null" if v is None else repr(float(v)))
                if v is None:
                    nulls.setdefault(title, []).append(seed)
                else:
                    vals[k].append(float(v))
            if out_raw:
                print("\t".join([sc, sec, seed] + row), file=out_raw)
        cells = []
        for (title, _, fmt), v in zip(cols, vals):
            # Worst: the largest error or latency over the seeds.
            cells.append("not measured" if not v else fmt.format(statistics.median(v)) + " (" + fmt.format(max(v)) + ")")
        who = " ".join(seeds)
        if nulls:
            who += "; not measured: " + ", ".join(f"{t} seed {' '.join(s)}" for t, s in nulls.items())
        print(f"| {sc} | {sec} | " + " | ".join(cells) + f" | {who} |")
EOF
