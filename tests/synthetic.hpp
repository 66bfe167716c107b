// Synthetic maps built in memory for renderer and solver tests.
#pragma once

#include <cmath>
#include <functional>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/map.hpp>

namespace terralign::test {

// A layer of w x h texels of `texel` metres, upper-left outer corner at (x0, y0), colour
// from fn(column, row) -> RGB in 0..255.
inline geo::Layer make_layer(const std::string& name, int w, int h, double x0, double y0, double texel,
                             const std::function<void(int, int, std::uint8_t*)>& fn) {
  geo::Layer L;
  L.name = name;
  L.path = "(synthetic " + name + ")";
  L.transform = geo::GeoTransform::north_up(x0, y0, texel, texel);
  L.extent = L.transform.extent(w, h);
  L.rgba.resize(w, h, 4);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      std::uint8_t* p = &L.rgba.at(x, y, 0);
      fn(x, y, p);
      p[3] = 255;
    }
  L.valid_pixels = static_cast<std::int64_t>(w) * h;
  return L;
}

inline geo::Map flat_map(double height, geo::Layer layer) {
  geo::Map m;
  m.path = "(synthetic)";
  m.dem.constant = true;
  m.dem.constant_height = height;
  m.dem.min_height = m.dem.max_height = height;
  m.dem.extent = geo::Extent{-INFINITY, -INFINITY, INFINITY, INFINITY};
  m.layers.push_back(std::move(layer));
  return m;
}

// A DEM of w x h posts of `spacing` metres, outer corner (x0, y0), heights fn(x, y) in map
// coordinates of the post centres.
inline geo::Map dem_map(int w, int h, double x0, double y0, double spacing,
                        const std::function<double(double, double)>& height, geo::Layer layer) {
  geo::Map m;
  m.path = "(synthetic dem)";
  m.dem.constant = false;
  m.dem.transform = geo::GeoTransform::north_up(x0, y0, spacing, spacing);
  m.dem.extent = m.dem.transform.extent(w, h);
  m.dem.heights.resize(w, h, 1);
  double lo = INFINITY, hi = -INFINITY;
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i) {
      double x, y;
      m.dem.transform.pixel_to_world(i, j, x, y);
      const double z = height(x, y);
      m.dem.heights.at(i, j) = static_cast<float>(z);
      lo = std::min(lo, z);
      hi = std::max(hi, z);
    }
  m.dem.min_height = lo;
  m.dem.max_height = hi;
  m.layers.push_back(std::move(layer));
  return m;
}

// The paper's evaluation camera: 752 x 480, f = 651.2 px, centred, no distortion.
inline geo::CameraModel paper_camera() {
  geo::CameraModel c;
  c.width = 752;
  c.height = 480;
  c.fx = c.fy = 651.2;
  c.cx = 375.5;
  c.cy = 239.5;
  return c;
}

}  // namespace terralign::test
