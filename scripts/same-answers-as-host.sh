#!/usr/bin/env bash
# Usage: scripts/same-answers-as-host.sh WHAT LOG
# The firmware's test (firmware/scenario.cpp) prints a line per frame ending in the hash of
# its answer (pose, covariance, flag, iterations, reason). LOG holds that output from another
# machine (WHAT names it: the Cortex-M7 under QEMU, the aarch64 build); this runs the test's
# host twin (terralign_firmware_host) in the host build ($TERRALIGN_HOST_BUILD, by default
# build/release; configured and built here if it is not) and exits 1, showing the lines that
# differ, unless every frame's line is the same to the bit.
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -eq 2 ] || { echo "usage: $0 WHAT LOG" >&2; exit 2; }
what=$1
log=$2
host_build=${TERRALIGN_HOST_BUILD:-build/release}
if [ ! -f "$host_build/CMakeCache.txt" ]; then
  bash scripts/install-deps.sh
  cmake -S . -B "$host_build" -DCMAKE_BUILD_TYPE=Release >/dev/null
fi
cmake --build "$host_build" -j "$(nproc)" --target terralign_firmware_host >/dev/null
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$host_build/firmware/terralign_firmware_host" >"$work/host.log"
tr -d '\r' <"$log" | grep ' answer ' >"$work/other" || true
grep ' answer ' "$work/host.log" >"$work/host" || true
frames=$(wc -l <"$work/other")
if [ "$frames" -eq 0 ] || ! cmp -s "$work/other" "$work/host"; then
  echo "$what: its answers are not the host's ($(uname -m), $host_build/firmware/terralign_firmware_host); $what < > host:"
  diff "$work/other" "$work/host" || true
  exit 1
fi
echo "$what: its $frames answers are the host's to the bit ($(uname -m), $host_build/firmware/terralign_firmware_host)"
