// The firmware's test: the learned and the classical tracker at 188 x 120 on a two-year
// map, four poses a year (scenario.cpp). The Cortex-M7 image (main.cpp) runs it from flash
// in one working-memory buffer; its host twin (host.cpp) runs it on the build machine from
// the same files, so that scripts/build-mcu.sh can ask the board for the host's answers to
// the bit (each frame's line ends with its answer's hash).
#pragma once

#include <cstddef>
#include <cstdint>

#include "arena.hpp"

namespace fw {

// The inputs the firmware links into flash (blobs.S.in); the host twin reads them.
struct Blobs {
  const std::uint8_t* weights = nullptr;
  std::size_t weights_bytes = 0;
  const char* weights_name = "";
  const std::uint8_t* naip_2016 = nullptr;  // 320 x 320 RGB (firmware/data/README.md)
  const std::uint8_t* naip_2017 = nullptr;
};

// What the platform gives the test: its console, and its memory's accounting (the
// firmware's buffer; on the host an allocation count with no buffer, capacity 0, and no
// stack measure).
struct Platform {
  void (*write)(const char* text) = nullptr;
  const ArenaStats& (*memory)() = nullptr;
  std::size_t (*stack_high_water)() = nullptr;  // null: not measured
};

// Runs the test and prints it; the exit status: 0 only if no frame allocated, none failed
// with an error, and on the same-year frames both trackers at least halved the median
// position error; 2 when set-up failed.
int run_scenario(const Blobs& blobs, const Platform& platform);

}  // namespace fw
