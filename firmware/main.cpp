// terralign on a microcontroller-class core: the learned tracker (and the classical one) at
// 188 x 120 on a Cortex-M7 without an OS, threads, exceptions or RTTI, every allocation
// served from one caller-provided buffer whose high-water mark is the stated working memory.
//
// The map (two NAIP years, 320 x 320 crops at 5 m, a constant DEM) and the weights (CMake's
// TERRALIGN_FW_WEIGHTS, s16) are linked into flash (blobs.S). For each test pose the "camera"
// image is a render of the 2016 or the 2017 layer at the true pose (there is no camera under
// QEMU); the localiser renders the 2016 layer at a prior a few metres and half a degree off (a
// tracking prior) and aligns (scenario.cpp). Printed per frame: the position and angle error
// before and after, converged, the answer's hash; then the memory. Exit status 0 only if no
// frame allocated, none failed with an error, and on the same-year frames both trackers at
// least halved the median position error (QEMU's instruction counts are not cycle times: no
// speed is claimed here).
#include <cstddef>
#include <cstdint>

#include "arena.hpp"
#include "scenario.hpp"
#include "semihosting.hpp"

extern "C" const std::uint8_t fw_weights[], fw_weights_end[];
extern "C" const std::uint8_t fw_naip_2016[], fw_naip_2017[];

namespace fw {
std::size_t stack_high_water();
}

namespace {

// The caller-provided buffer: every heap byte of the program comes from here (arena.cpp).
constexpr std::size_t kArenaBytes = TERRALIGN_FW_ARENA_BYTES;
alignas(16) __attribute__((section(".arena"))) unsigned char g_arena[kArenaBytes];

}  // namespace

// Called by the reset handler before the static constructors (the C++ library's allocate).
extern "C" void firmware_init() { fw::arena_init(g_arena, kArenaBytes); }

extern "C" int firmware_main() {
  fw::Blobs blobs;
  blobs.weights = fw_weights;
  blobs.weights_bytes = static_cast<std::size_t>(fw_weights_end - fw_weights);
  blobs.weights_name = TERRALIGN_FW_WEIGHTS_NAME;
  blobs.naip_2016 = fw_naip_2016;
  blobs.naip_2017 = fw_naip_2017;
  fw::Platform platform;
  platform.write = fw::write;
  platform.memory = fw::arena_stats;
  platform.stack_high_water = fw::stack_high_water;
  return fw::run_scenario(blobs, platform);
}
