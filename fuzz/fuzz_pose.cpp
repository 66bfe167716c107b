// Pose text ("x y z qw qx qy qz"), CRS text, and the numbers in text that both and the
// command-line tools read (terralign/geo/number_text.hpp).
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>

#include <terralign/geo/crs.hpp>
#include <terralign/geo/number_text.hpp>
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
  for (const char separator : {' ', ':', ','}) (void)terralign::geo::parse_numbers(text, separator);
  (void)terralign::geo::parse_integer(text);
  // A number read and written reads back as the same bits (NaN's payload aside).
  const auto v = terralign::geo::parse_double(text);
  if (v.ok() && v.value() == v.value()) {
    const auto back = terralign::geo::parse_double(terralign::geo::format_double(v.value()));
    if (!back.ok() || std::memcmp(&back.value(), &v.value(), sizeof(double)) != 0) std::abort();
  }
  return 0;
}
