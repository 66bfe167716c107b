// Pose text ("x y z qw qx qy qz") and CRS text.
#include <cstdint>
#include <string>

#include <terralign/geo/crs.hpp>
#include <terralign/geo/pose.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  auto p = terralign::geo::parse_pose(text);
  if (p.ok()) (void)terralign::geo::format_pose(p.value());
  auto crs = terralign::geo::Crs::parse(text);
  if (crs.ok()) {
    double x, y, z;
    (void)crs->from_geodetic({47.0, -99.0, 500.0}, x, y, z);
    (void)crs->to_geodetic(500000.0, 5200000.0, 500.0);
  }
  return 0;
}
