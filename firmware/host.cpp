// The firmware's test on the build machine (terralign_firmware_host): scenario.cpp on the
// same weights and map crops, read from files, with the host's libraries. Its frame lines
// must be the Cortex-M7's and every other build's, answer hashes included
// (scripts/same-answers-as-host.sh compares them).
//   terralign_firmware_host [WEIGHTS NAIP_2016 NAIP_2017]   (defaults: the firmware's files)
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "alloc_counter.hpp"  // the suite's: operator new replaced, counting
#include "scenario.hpp"

namespace {

// Allocations only (the suite's counter, alive through the run): the host has no buffer
// (capacity 0).
const terralign::test::AllocationCounter* g_counter = nullptr;
fw::ArenaStats g_counted;

bool read_file(const char* path, std::size_t expect, std::vector<std::uint8_t>& out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) {
    std::fprintf(stderr, "terralign_firmware_host: cannot open %s\n", path);
    return false;
  }
  out.assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  if (expect && out.size() != expect) {
    std::fprintf(stderr, "terralign_firmware_host: %s has %zu bytes, a 320 x 320 RGB crop %zu\n", path, out.size(),
                 expect);
    return false;
  }
  return true;
}

void write_stdout(const char* text) { std::fputs(text, stdout); }
const fw::ArenaStats& counted() {
  g_counted.allocations = g_counter->allocations();
  return g_counted;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 1 && argc != 4) {
    std::fprintf(stderr, "usage: %s [WEIGHTS NAIP_2016_RGB NAIP_2017_RGB]\n", argv[0]);
    return 2;
  }
  const char* weights_path = argc == 4 ? argv[1] : TERRALIGN_FW_WEIGHTS_PATH;
  const char* naip_2016_path = argc == 4 ? argv[2] : TERRALIGN_FW_NAIP_2016;
  const char* naip_2017_path = argc == 4 ? argv[3] : TERRALIGN_FW_NAIP_2017;
  constexpr std::size_t kCropBytes = 320 * 320 * 3;
  std::vector<std::uint8_t> weights, naip_2016, naip_2017;
  if (!read_file(weights_path, 0, weights) || !read_file(naip_2016_path, kCropBytes, naip_2016) ||
      !read_file(naip_2017_path, kCropBytes, naip_2017))
    return 2;
  const std::string name = std::string(weights_path).substr(std::string(weights_path).find_last_of('/') + 1);
  fw::Blobs blobs;
  blobs.weights = weights.data();
  blobs.weights_bytes = weights.size();
  blobs.weights_name = name.c_str();
  blobs.naip_2016 = naip_2016.data();
  blobs.naip_2017 = naip_2017.data();
  const terralign::test::AllocationCounter counter;
  g_counter = &counter;
  fw::Platform platform;
  platform.write = write_stdout;
  platform.memory = counted;
  return fw::run_scenario(blobs, platform);
}
