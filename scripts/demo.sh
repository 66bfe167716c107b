#!/usr/bin/env bash
# The main job on the sample data shipped in the repo: builds terralign (installing what it
# needs on a fresh Debian 12 machine), then describes the sample maps.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake -S . -B build/release -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build/release -j "$(nproc)" --target terralign_cli
tl=build/release/tools/terralign/terralign
out=${1:-out/demo}
mkdir -p "$out"
set -x
$tl info --map data/naip_west/map.json
$tl info --map data/christchurch/000121.json
