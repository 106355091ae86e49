#!/usr/bin/env bash
# Installs what is missing, builds (release preset) and runs the tests: every `unit` test, then the bounded
# `fuzz` runs (protocol stream parser, capture reader, device commands; clang + libFuzzer).
#   --stress   also run the `stress` label (long numerical stress runs)
#   --asan     build and run the unit tests under AddressSanitizer + UBSan instead of release
#   --no-fuzz  skip the fuzz run
set -euo pipefail
cd "$(dirname "$0")/.."

preset=release stress=0 fuzz=1
for arg in "$@"; do
  case "$arg" in
    --stress) stress=1 ;;
    --asan) preset=asan ;;
    --no-fuzz) fuzz=0 ;;
    *) echo "test.sh: unknown option '$arg' (use --stress, --asan, --no-fuzz)" >&2; exit 2 ;;
  esac
done
jobs=$(nproc)

bash scripts/setup.sh
cmake --preset "$preset" >/dev/null
cmake --build --preset "$preset" -j "$jobs"

if [ "$fuzz" = 1 ]; then
  cmake --preset fuzz >/dev/null
  cmake --build --preset fuzz -j "$jobs" --target eyesim_fuzz_all
  ctest --test-dir build/fuzz -L fuzz --output-on-failure
fi
if [ "$stress" = 1 ]; then
  ctest --test-dir "build/$preset" -L stress --output-on-failure -j "$jobs"
fi
# Last, so its closing "N tests passed, N failed" line is the run's verdict.
ctest --test-dir "build/$preset" -L unit --output-on-failure -j "$jobs" --timeout 900
