// Camera JSON: parse, and exercise project / unproject on what parses.
#include <cstdint>
#include <string>

#include <terralign/geo/camera.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  auto cam = terralign::geo::parse_camera(std::string(reinterpret_cast<const char*>(data), size), "fuzz.json");
  if (!cam.ok()) return 0;
  Eigen::Vector3d ray;
  Eigen::Vector2d px;
  if (cam->unproject(Eigen::Vector2d(0.0, 0.0), ray)) (void)cam->project<double>(ray, px);
  return 0;
}
