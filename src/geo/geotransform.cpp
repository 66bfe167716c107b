#include <terralign/geo/geotransform.hpp>
#include <terralign/geo/number_text.hpp>
#include <terralign/geo/numeric.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <vector>

namespace terralign::geo {

Extent Extent::intersect(const Extent& o) const {
  return Extent{std::max(min_x, o.min_x), std::max(min_y, o.min_y), std::min(max_x, o.max_x),
                std::min(max_y, o.max_y)};
}

Result<GeoTransform> GeoTransform::from_gdal(const std::array<double, 6>& c) {
  for (int i = 0; i < 6; ++i) {
    if (!std::isfinite(c[static_cast<std::size_t>(i)]))
      return Error{"geotransform coefficient " + std::to_string(i) + " is " +
                   format_double(c[static_cast<std::size_t>(i)]) + ", not a finite number"};
  }
  const double det = c[1] * c[5] - c[2] * c[4];
  const double scale = std::max({std::abs(c[1]), std::abs(c[2]), std::abs(c[4]), std::abs(c[5])});
  if (!(scale > 0) || std::abs(det) < 1e-12 * scale * scale)
    return Error{"geotransform [" + format_double(c[0]) + ", " + format_double(c[1]) + ", " +
                 format_double(c[2]) + ", " + format_double(c[3]) + ", " + format_double(c[4]) +
                 ", " + format_double(c[5]) + "] is degenerate (pixel axes are parallel or zero)"};
  GeoTransform g;
  g.c_ = c;
  // Inverse: (col, row) = A^-1 (X - c0, Y - c3).
  g.inv_[1] = c[5] / det;
  g.inv_[2] = -c[2] / det;
  g.inv_[4] = -c[4] / det;
  g.inv_[5] = c[1] / det;
  g.inv_[0] = c[0];
  g.inv_[3] = c[3];
  return g;
}

GeoTransform GeoTransform::north_up(double x0, double y0, double pixel_x, double pixel_y) {
  auto r = from_gdal({x0, pixel_x, 0.0, y0, 0.0, -pixel_y});
  TERRALIGN_ASSERT(r.ok(), "GeoTransform::north_up: pixel sizes must be non-zero and finite");
  return r.value();
}

void GeoTransform::pixel_to_world(double u, double v, double& x, double& y) const {
  const double col = u + 0.5, row = v + 0.5;
  x = c_[0] + col * c_[1] + row * c_[2];
  y = c_[3] + col * c_[4] + row * c_[5];
}

void GeoTransform::world_to_pixel(double x, double y, double& u, double& v) const {
  const double dx = x - inv_[0], dy = y - inv_[3];
  u = inv_[1] * dx + inv_[2] * dy - 0.5;
  v = inv_[4] * dx + inv_[5] * dy - 0.5;
}

double GeoTransform::pixel_size_x() const { return hypot_exact(c_[1], c_[4]); }
double GeoTransform::pixel_size_y() const { return hypot_exact(c_[2], c_[5]); }

Extent GeoTransform::extent(int width, int height) const {
  Extent e{INFINITY, INFINITY, -INFINITY, -INFINITY};
  for (int corner = 0; corner < 4; ++corner) {
    const double col = (corner & 1) ? width : 0, row = (corner & 2) ? height : 0;
    const double x = c_[0] + col * c_[1] + row * c_[2];
    const double y = c_[3] + col * c_[4] + row * c_[5];
    e.min_x = std::min(e.min_x, x);
    e.max_x = std::max(e.max_x, x);
    e.min_y = std::min(e.min_y, y);
    e.max_y = std::max(e.max_y, y);
  }
  return e;
}

Result<GeoTransform> parse_world_file(const std::string& text, const std::string& name) {
  std::istringstream in(text);
  std::array<double, 6> v{};
  std::string token;
  for (int i = 0; i < 6; ++i) {
    if (!(in >> token))
      return Error{name + ": world file has " + std::to_string(i) +
                   " numbers, needs 6 (A D B E C F)"};
    auto num = parse_double(token);
    if (!num.ok()) return with_context(name + ": world file line " + std::to_string(i + 1), num.error());
    v[static_cast<std::size_t>(i)] = num.value();
  }
  if (in >> token) return Error{name + ": world file has more than 6 numbers ('" + token + "')"};
  const double A = v[0], D = v[1], B = v[2], E = v[3], C = v[4], F = v[5];
  // C, F address the centre of the upper-left pixel; GDAL's origin is its outer corner.
  auto gt = GeoTransform::from_gdal({C - 0.5 * A - 0.5 * B, A, B, F - 0.5 * D - 0.5 * E, D, E});
  if (!gt.ok()) return with_context(name, gt.error());
  return gt;
}

Result<GeoTransform> read_world_file(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return Error{path + ": cannot open world file"};
  std::ostringstream ss;
  ss << f.rdbuf();
  if (ss.str().size() > 4096) return Error{path + ": world file is over 4096 bytes; not a world file"};
  return parse_world_file(ss.str(), path);
}

std::string find_world_file(const std::string& image_path) {
  const auto dot = image_path.find_last_of('.');
  const auto slash = image_path.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) {
    std::ifstream f(image_path + ".wld");
    return f ? image_path + ".wld" : std::string();
  }
  const std::string stem = image_path.substr(0, dot);
  const std::string ext = image_path.substr(dot + 1);
  std::vector<std::string> candidates;
  if (ext.size() >= 2) candidates.push_back(stem + "." + ext.front() + ext.back() + "w");
  candidates.push_back(stem + "." + ext + "w");
  candidates.push_back(stem + ".wld");
  for (const auto& c : candidates) {
    std::ifstream f(c);
    if (f) return c;
  }
  return {};
}

}  // namespace terralign::geo
