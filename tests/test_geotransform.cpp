#include <cmath>

#include <doctest/doctest.h>

#include <terralign/geo/geotransform.hpp>

using terralign::geo::GeoTransform;

TEST_CASE("geotransform: pixel centres at integers, exact inverse, rotated grids") {
  auto gt = GeoTransform::from_gdal({1000, 2, 0.5, 5000, 0.25, -2});
  REQUIRE(gt.ok());
  double x, y, u, v;
  gt->pixel_to_world(0, 0, x, y);  // centre of the first pixel = corner + half a step
  CHECK(x == doctest::Approx(1000 + 1 + 0.25));
  CHECK(y == doctest::Approx(5000 + 0.125 - 1));
  for (double pu : {-3.5, 0.0, 17.25, 1000.0})
    for (double pv : {-1.0, 0.5, 333.0}) {
      gt->pixel_to_world(pu, pv, x, y);
      gt->world_to_pixel(x, y, u, v);
      CHECK(std::abs(u - pu) < 1e-9);
      CHECK(std::abs(v - pv) < 1e-9);
    }
  const auto e = GeoTransform::north_up(10, 20, 1, 1).extent(4, 3);
  CHECK(e.min_x == 10);
  CHECK(e.max_x == 14);
  CHECK(e.min_y == 17);
  CHECK(e.max_y == 20);
}

TEST_CASE("world file: C, F address the upper-left pixel's centre") {
  auto gt = terralign::geo::parse_world_file("0.2\n0\n0\n-0.2\n0.1\n204.7\n", "a.pgw");
  REQUIRE(gt.ok());
  CHECK(gt->gdal()[0] == doctest::Approx(0.0));
  CHECK(gt->gdal()[3] == doctest::Approx(204.8));
  CHECK(gt->gdal()[1] == 0.2);
  CHECK(gt->gdal()[5] == -0.2);
}

TEST_CASE("bad world files and degenerate transforms are refused with the value") {
  auto few = terralign::geo::parse_world_file("1 0 0 -1 5", "x.wld");
  REQUIRE(!few.ok());
  CHECK(few.error().message.find("has 5 numbers") != std::string::npos);
  auto text = terralign::geo::parse_world_file("1 0 0 -1 5 abc", "x.wld");
  REQUIRE(!text.ok());
  CHECK(text.error().message.find("'abc' is not a number") != std::string::npos);
  CHECK(!terralign::geo::parse_world_file("1 0 0 -1 5 6 7", "x.wld").ok());
  auto zero = terralign::geo::parse_world_file("0 0 0 -1 5 6", "x.wld");
  REQUIRE(!zero.ok());
  CHECK(zero.error().message.find("degenerate") != std::string::npos);
  CHECK(!GeoTransform::from_gdal({0, NAN, 0, 0, 0, -1}).ok());
  CHECK(!terralign::geo::read_world_file("/nonexistent/x.pgw").ok());
}
