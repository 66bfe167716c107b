#!/usr/bin/env bash
# The onboard core (geo_core, raster, nn, iclk) as static libraries for a Cortex-M7 (or
# MCU_CPU=cortex-m55) with arm-none-eabi-g++: Thumb-2, hard float, newlib, -fno-exceptions
# -fno-rtti, no threads, warnings as errors; then the code size of each library. For the
# Cortex-M7 it also links the firmware image (firmware/) and runs it on QEMU's mps2-an500
# with semihosting: the learned and the classical tracker at 188 x 120 in one caller-provided
# working-memory buffer, which it must fit, with no allocation per frame, and each frame's
# answer must be the host twin's to the bit (firmware/host.cpp, built in the host build).
# Build folder: build/mcu-<cpu> (or $MCU_BUILD).
set -euo pipefail
cd "$(dirname "$0")/.."
cpu=${MCU_CPU:-cortex-m7}
build=${MCU_BUILD:-build/mcu-$cpu}
if ! bash scripts/install-deps.sh gcc-arm-none-eabi libstdc++-arm-none-eabi-newlib libnewlib-arm-none-eabi \
     qemu-system-arm; then
  echo "mcu: the arm-none-eabi toolchain could not be installed; skipped"
  exit 0
fi
cmake -S . -B "$build" -DCMAKE_TOOLCHAIN_FILE=cmake/toolchains/arm-none-eabi.cmake \
  -DTERRALIGN_MCU_CPU="$cpu" -DCMAKE_BUILD_TYPE=MinSizeRel -DTERRALIGN_WERROR=ON >/dev/null
cmake --build "$build" -j "$(nproc)"
echo
echo "code size for $cpu (arm-none-eabi-size, bytes; every template instance the libraries hold):"
printf '| library | text | data | bss |\n|---|---|---|---|\n'
for lib in geo/libterralign_geo_core raster/libterralign_raster nn/libterralign_nn iclk/libterralign_iclk; do
  arm-none-eabi-size -t "$build/src/$lib.a" | awk -v n="$(basename $lib)" 'END { printf "| %s | %d | %d | %d |\n", n, $1, $2, $3 }'
done
if [ -f "$build/firmware/terralign_firmware.elf" ]; then
  echo
  arm-none-eabi-size "$build/firmware/terralign_firmware.elf"
  echo "running the firmware on qemu-system-arm -M mps2-an500 (Cortex-M7):"
  # QEMU writes the semihosting console to its stderr.
  status=0
  timeout 1200 qemu-system-arm -M mps2-an500 -nographic -semihosting-config enable=on,target=native \
    -kernel "$build/firmware/terralign_firmware.elf" 2>&1 | tee "$build/firmware.log" || status=$?
  [ "$status" -eq 0 ] || exit "$status"
  # Every frame's answer must be the host twin's (firmware/host.cpp) to the bit.
  bash scripts/same-answers-as-host.sh "the Cortex-M7 firmware" "$build/firmware.log"
fi
