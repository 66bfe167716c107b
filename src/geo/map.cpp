// The in-memory map: DEM heights, layer lookup (dependency-free: part of
// terralign::geo_core); reading a map from its manifest is map_io.cpp.
#include <terralign/geo/map.hpp>

#include <algorithm>
#include <cmath>

namespace terralign::geo {

double Dem::height_at(double x, double y) const {
  if (constant) return (std::isfinite(x) && std::isfinite(y)) ? constant_height : NAN;
  if (!extent.contains(x, y)) return NAN;
  double u, v;
  transform.world_to_pixel(x, y, u, v);
  const int w = heights.width(), h = heights.height();
  // Between the outermost post centres and the raster edge, hold the edge value.
  u = std::clamp(u, 0.0, static_cast<double>(w - 1));
  v = std::clamp(v, 0.0, static_cast<double>(h - 1));
  const int x0 = std::min(static_cast<int>(u), std::max(w - 2, 0));
  const int y0 = std::min(static_cast<int>(v), std::max(h - 2, 0));
  const int x1 = std::min(x0 + 1, w - 1), y1 = std::min(y0 + 1, h - 1);
  const double fx = u - x0, fy = v - y0;
  const double h00 = heights.at(x0, y0), h10 = heights.at(x1, y0);
  const double h01 = heights.at(x0, y1), h11 = heights.at(x1, y1);
  return (1 - fy) * ((1 - fx) * h00 + fx * h10) + fy * ((1 - fx) * h01 + fx * h11);
}

const Layer* Map::find_layer(const std::string& name) const {
  for (const auto& L : layers)
    if (L.name == name) return &L;
  return nullptr;
}

Extent Map::common_extent() const {
  Extent e{-INFINITY, -INFINITY, INFINITY, INFINITY};
  for (const auto& L : layers) e = e.intersect(L.extent);
  if (!dem.constant) e = e.intersect(dem.extent);
  return e;
}

std::string Map::layer_names() const {
  std::string s;
  for (const auto& L : layers) s += (s.empty() ? "" : ", ") + L.name;
  return s;
}

}  // namespace terralign::geo
