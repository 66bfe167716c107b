// Affine geotransform between raster pixels and the map's projected frame.
//
// Stored in GDAL's order: X = c[0] + col * c[1] + row * c[2], Y = c[3] + col * c[4] +
// row * c[5], where (col, row) are CORNER coordinates: (0, 0) is the outer corner of the
// first pixel (GDAL's PixelIsArea convention). terralign puts pixel centres at integer
// coordinates, so the centre of pixel (i, j) is at corner coordinates (i + 0.5, j + 0.5);
// pixel_to_world() and world_to_pixel() take and return centre-based coordinates.
#pragma once

#include <array>
#include <string>

#include <terralign/geo/result.hpp>

namespace terralign::geo {

struct Extent {
  double min_x = 0, min_y = 0, max_x = 0, max_y = 0;
  bool empty() const { return !(max_x > min_x && max_y > min_y); }
  double width() const { return max_x - min_x; }
  double height() const { return max_y - min_y; }
  bool contains(double x, double y) const {
    return x >= min_x && x <= max_x && y >= min_y && y <= max_y;
  }
  Extent intersect(const Extent& o) const;
};

class GeoTransform {
 public:
  GeoTransform() = default;
  // Checks the coefficients: finite, with a non-degenerate 2x2 part.
  static Result<GeoTransform> from_gdal(const std::array<double, 6>& c);
  // A north-up grid: upper-left outer corner (x0, y0) and square pixels of `pixel` metres.
  static GeoTransform north_up(double x0, double y0, double pixel_x, double pixel_y);

  const std::array<double, 6>& gdal() const { return c_; }

  // (u, v): pixel-centre coordinates (integer = centre of a pixel). Returns world X, Y.
  void pixel_to_world(double u, double v, double& x, double& y) const;
  // The inverse; exact up to rounding for any non-degenerate transform.
  void world_to_pixel(double x, double y, double& u, double& v) const;

  // Ground size of one pixel step along columns and rows, in metres.
  double pixel_size_x() const;
  double pixel_size_y() const;
  bool north_up() const { return c_[2] == 0.0 && c_[4] == 0.0 && c_[5] < 0.0; }

  // The bounding box of a width x height raster's outer corners.
  Extent extent(int width, int height) const;

 private:
  std::array<double, 6> c_{0, 1, 0, 0, 0, -1};
  std::array<double, 6> inv_{0, 1, 0, 0, 0, -1};
};

// Reads an ESRI world file (.pgw, .jgw, .tfw, .wld): six numbers A D B E C F, where C, F
// are the world coordinates of the CENTRE of the upper-left pixel.
Result<GeoTransform> read_world_file(const std::string& path);
Result<GeoTransform> parse_world_file(const std::string& text, const std::string& name);

// The world file that would sit beside an image (foo.png -> foo.pgw, foo.pngw, foo.wld),
// or "" when none of them exists.
std::string find_world_file(const std::string& image_path);

}  // namespace terralign::geo
