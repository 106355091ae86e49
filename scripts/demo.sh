#!/usr/bin/env bash
# Installs what is missing, builds the programs (release preset) and runs `eyesim demo` on the built-in
# default scene, writing into build/demo. Extra arguments go to `eyesim demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cmake --preset release >/dev/null
targets=(eyesim)
[ -f firmware/CMakeLists.txt ] && targets+=(eyesim-device)
cmake --build --preset release -j "$(nproc)" --target "${targets[@]}"
# The recording and report go to build/demo (ignored by git) unless --out is given.
out=(--out build/demo)
for a in "$@"; do case "$a" in --out|--out=*) out=() ;; esac; done
exec build/release/host/app/eyesim demo "${out[@]}" "$@"
