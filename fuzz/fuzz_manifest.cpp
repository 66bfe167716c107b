// Map manifests. Relative paths resolve in tests/data/tiff, so the fuzzer can reach the real
// raster loaders through names found in its corpus.
#include <cstdint>
#include <string>

#include <terralign/geo/map.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  terralign::geo::MapLoadOptions opt;
  opt.limits.max_side = 4096;
  opt.limits.max_bytes = 64 << 20;
  auto m = terralign::geo::parse_map(std::string(reinterpret_cast<const char*>(data), size), "fuzz.json",
                                     TERRALIGN_SOURCE_DIR "/tests/data/tiff", opt);
  if (m.ok()) (void)m->dem.height_at(487450.0, 5207200.0);
  return 0;
}
