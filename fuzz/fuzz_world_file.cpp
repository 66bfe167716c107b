// World files (.pgw / .jgw / .wld).
#include <cstdint>
#include <string>

#include <terralign/geo/geotransform.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  auto gt = terralign::geo::parse_world_file(std::string(reinterpret_cast<const char*>(data), size), "fuzz.wld");
  if (gt.ok()) {
    double x, y, u, v;
    gt->pixel_to_world(1.5, 2.5, x, y);
    gt->world_to_pixel(x, y, u, v);
  }
  return 0;
}
