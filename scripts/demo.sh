#!/usr/bin/env bash
# Installs what is missing, builds the programs (release preset) and runs `eyesim demo` on the built-in
# default scene. Extra arguments go to `eyesim demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cmake --preset release >/dev/null
targets=(eyesim)
[ -f firmware/CMakeLists.txt ] && targets+=(eyesim-device)
cmake --build --preset release -j "$(nproc)" --target "${targets[@]}"
exec build/release/host/app/eyesim demo "$@"
