#!/usr/bin/env bash
# Runs the latency gate (`eyesim bench latency --baseline bench/latency-baseline.json`) N times on the build as it
# is and N times with every frame made 30 % slower (--inject-slowdown 0.3), one log line per run, then the counts.
#   scripts/latency_gate_runs.sh [--build DIR] [--runs N] [--baseline FILE] [--load K] [--only KIND] [-- ARGS]
#   --build DIR     build folder holding host/app/eyesim (default build/release)
#   --runs N        runs of each kind (default 20)
#   --baseline F    baseline to compare with (default bench/latency-baseline.json)
#   --load K        K background busy loops (`yes > /dev/null`) for the whole log, on top of whatever else runs
#   --only KIND     only the `unchanged` or only the `slowed` runs
#   -- ARGS         more options for every run (e.g. `-- --attempts 1`: one measurement per run, no confirmation)
# Exit status 0 when every unchanged run passed and every slowed run was flagged, 1 otherwise.
set -euo pipefail
cd "$(dirname "$0")/.."

build=build/release runs=20 baseline=bench/latency-baseline.json load=0 kinds="unchanged slowed"
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --only) kinds=$2; shift 2 ;;
    --) shift; extra=("$@"); break ;;
    --build) build=$2; shift 2 ;;
    --runs) runs=$2; shift 2 ;;
    --baseline) baseline=$2; shift 2 ;;
    --load) load=$2; shift 2 ;;
    *) echo "latency_gate_runs.sh: unknown option '$1'" >&2; exit 2 ;;
  esac
done
exe=$build/host/app/eyesim
[ -x "$exe" ] || { echo "latency_gate_runs.sh: $exe: not built" >&2; exit 2; }

hogs=()
stop_hogs() { for p in "${hogs[@]}"; do kill "$p" 2>/dev/null || true; done; }
trap stop_hogs EXIT
for _ in $(seq 1 "$load"); do
  yes > /dev/null &
  hogs+=($!)
done

echo "# $(date -u +%Y-%m-%dT%H:%MZ), $(nproc) cores, $(git rev-parse --short HEAD), baseline $baseline, $load extra busy loops, options: ${extra[*]:-(none)}"
passed=0 flagged=0
for kind in $kinds; do
  args=("${extra[@]}")
  [ "$kind" = slowed ] && args+=(--inject-slowdown 0.3)
  for i in $(seq 1 "$runs"); do
    rc=0
    out=$("$exe" bench latency --baseline "$baseline" "${args[@]}") || rc=$?
    line=$(grep '^gate:' <<<"$out" || echo "gate: no verdict (exit $rc)")
    printf '%-9s %2d  exit %d  load %-5s %s\n' "$kind" "$i" "$rc" "$(cut -d' ' -f1 /proc/loadavg)" "${line#gate: }"
    if [ "$kind" = unchanged ] && [ "$rc" = 0 ]; then passed=$((passed + 1)); fi
    if [ "$kind" = slowed ] && [ "$rc" = 3 ]; then flagged=$((flagged + 1)); fi
  done
done
summary=() ok=1
if [[ " $kinds " == *" unchanged "* ]]; then summary+=("unchanged: $passed of $runs passed"); [ "$passed" = "$runs" ] || ok=0; fi
if [[ " $kinds " == *" slowed "* ]]; then summary+=("slowed 30 %: $flagged of $runs flagged"); [ "$flagged" = "$runs" ] || ok=0; fi
(IFS=';'; echo "${summary[*]}" | sed 's/;/; /g')
[ "$ok" = 1 ]
