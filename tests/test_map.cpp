#include <cmath>

#include <doctest/doctest.h>

#include <terralign/geo/map.hpp>

#include "support.hpp"

using namespace terralign;
using namespace terralign::geo;
using terralign::test::source_path;

namespace {

const std::string kTiff = source_path("tests/data/tiff");

Result<Map> manifest(const std::string& json) { return parse_map(json, "m.json", kTiff); }

std::string error_of(const Result<Map>& r) { return r.ok() ? std::string("(loaded)") : r.error().message; }

}  // namespace

TEST_CASE("the sample NAIP map: five years on their own grids, one CRS") {
  auto m = load_map(source_path("data/naip_west/map.json"));
  REQUIRE(m.ok());
  CHECK(m->crs.epsg() == 26914);
  REQUIRE(m->layers.size() == 5);
  const Layer* l2016 = m->find_layer("2016");
  const Layer* l2017 = m->find_layer("2017");
  REQUIRE((l2016 && l2017));
  // The years are offset by up to a few metres (PROVENANCE.md): 2016 starts at x 485900.6,
  // 2017 at 485902.
  CHECK(l2016->transform.gdal()[0] == 485900.6);
  CHECK(l2017->transform.gdal()[0] == 485902.0);
  // NoData 0 is masked: the last pixel of 2016 is (0, 0, 0).
  CHECK(l2016->rgba.at(619, 723, 3) == 0);
  CHECK(l2016->rgba.at(311, 517, 3) == 255);
  CHECK(l2016->rgba.at(311, 517, 0) == 79);
  const Extent common = m->common_extent();
  CHECK(common.min_x == 485902.0);
  CHECK(common.max_x == 488999.0);
  CHECK(m->dem.height_at(487000, 5207000) == 570.0);
}

TEST_CASE("the Christchurch maps: PNG layers placed by their world files in a local frame") {
  auto m = load_map(source_path("data/christchurch/000121.json"));
  REQUIRE(m.ok());
  CHECK(m->crs.is_local());
  REQUIRE(m->layers.size() == 2);
  CHECK(m->layers[0].transform.pixel_size_x() == doctest::Approx(0.2));
  CHECK(m->layers[0].extent.max_y == doctest::Approx(204.8));
  CHECK(!m->crs.to_geodetic(10, 10, 0).ok());
  // What the two surveys disagree on, split between them (the manifest's description).
  CHECK(m->layers[0].registration_sigma_m == 0.7);
  CHECK(m->layers[1].registration_sigma_m == 0.7);
}

TEST_CASE("DEM heights are bilinear between posts, NaN on no-data and outside") {
  auto m = manifest(R"({"dem": {"file": "dem_int16.tif"}, "layers": [{"name": "a", "file": "rgb_strips_lzw.tif"}]})");
  REQUIRE(m.ok());
  const Dem& d = m->dem;
  double x00, y00, x10, y10;
  d.transform.pixel_to_world(5, 7, x00, y00);
  d.transform.pixel_to_world(6, 7, x10, y10);
  const double h0 = d.heights.at(5, 7), h1 = d.heights.at(6, 7);
  CHECK(d.height_at(x00, y00) == doctest::Approx(h0));
  CHECK(d.height_at(0.25 * x00 + 0.75 * x10, y00) == doctest::Approx(0.25 * h0 + 0.75 * h1));
  CHECK(std::isnan(d.height_at(d.extent.min_x - 1, y00)));
  CHECK(d.min_height <= d.max_height);
}

TEST_CASE("layers given as PNG with a transform array in the manifest") {
  auto m = manifest(R"({"dem": {"constant": 10}, "layers": [{"name": "p", "file": "no_georef.png",
                        "transform": [1000, 2, 0, 2000, 0, -2]}]})");
  REQUIRE(m.ok());
  CHECK(m->layers[0].extent.min_x == 1000);
  CHECK(m->layers[0].extent.min_y == 2000 - 60);
  CHECK(m->crs.is_local());
}

TEST_CASE("a layer's registration sigma and the DEM's vertical sigma: read where stated, 0 where not") {
  auto m = manifest(R"({"dem": {"constant": 10, "vertical_sigma_m": 2.5},
                        "layers": [{"name": "a", "file": "rgba.tif", "registration_sigma_m": 0.7},
                                   {"name": "b", "file": "rgba.tif"}]})");
  REQUIRE(m.ok());
  CHECK(m->dem.vertical_sigma_m == 2.5);
  CHECK(m->find_layer("a")->registration_sigma_m == 0.7);
  CHECK(m->find_layer("b")->registration_sigma_m == 0);
  auto plain = manifest(R"({"dem": {"file": "dem_int16.tif"}, "layers": [{"name": "a", "file": "rgba.tif"}]})");
  REQUIRE(plain.ok());
  CHECK(plain->dem.vertical_sigma_m == 0);
}

TEST_CASE("bad manifests: each refused with the file and the value") {
  SUBCASE("missing manifest") {
    auto r = load_map("/nonexistent/map.json");
    CHECK(error_of(r).find("/nonexistent/map.json") != std::string::npos);
  }
  SUBCASE("JSON syntax error with line and column") {
    auto r = manifest("{\n  \"dem\": {\"constant\": 1},\n  \"layers\": [,]\n}");
    CHECK(error_of(r).find("m.json:3:14") != std::string::npos);
  }
  SUBCASE("unknown key") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layer": []})");
    CHECK(error_of(r).find("unknown key 'layer'") != std::string::npos);
  }
  SUBCASE("unknown key in a layer") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif", "year": 1}]})");
    CHECK(error_of(r).find("layers[0]: unknown key 'year'") != std::string::npos);
  }
  SUBCASE("a layer file that does not exist") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "2030", "file": "naip_2030.tif"}]})");
    CHECK(error_of(r).find("naip_2030.tif") != std::string::npos);
  }
  SUBCASE("no layers") {
    CHECK(error_of(manifest(R"({"dem": {"constant": 1}, "layers": []})")).find("non-empty") != std::string::npos);
    CHECK(error_of(manifest(R"({"dem": {"constant": 1}})")).find("missing 'layers'") != std::string::npos);
  }
  SUBCASE("no DEM") {
    CHECK(error_of(manifest(R"({"layers": [{"name": "a", "file": "rgba.tif"}]})")).find("missing 'dem'") != std::string::npos);
  }
  SUBCASE("layer name used twice") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif"}, {"name": "a", "file": "rgba.tif"}]})");
    CHECK(error_of(r).find("'a' is used twice") != std::string::npos);
  }
  SUBCASE("no geotransform and no world file") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "no_georef.png"}]})");
    CHECK(error_of(r).find("no geotransform") != std::string::npos);
  }
  SUBCASE("layers in different CRSs") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif"}, {"name": "b", "file": "rgb_utm33.tif"}]})");
    CHECK(error_of(r).find("different CRSs") != std::string::npos);
    CHECK(error_of(r).find("EPSG:32633") != std::string::npos);
  }
  SUBCASE("manifest CRS disagrees with the rasters") {
    auto r = manifest(R"({"crs": "EPSG:32614", "dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif"}]})");
    CHECK(error_of(r).find("EPSG:26914") != std::string::npos);
  }
  SUBCASE("unknown EPSG code in the manifest") {
    auto r = manifest(R"({"crs": "EPSG:999999", "dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif"}]})");
    CHECK(error_of(r).find("unknown EPSG code 999999") != std::string::npos);
  }
  SUBCASE("a DEM that is all no-data") {
    auto r = manifest(R"({"dem": {"file": "dem_all_nodata.tif"}, "layers": [{"name": "a", "file": "rgba.tif"}]})");
    CHECK(error_of(r).find("all no-data") != std::string::npos);
  }
  SUBCASE("a layer with an unsupported band count") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "two_bands.tif"}]})");
    CHECK(error_of(r).find("2 bands") != std::string::npos);
  }
  SUBCASE("a float layer (an elevation raster given as an orthoimage)") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "dem_float32.tif"}]})");
    CHECK(error_of(r).find("float32 samples") != std::string::npos);
  }
  SUBCASE("a raster in a geographic CRS") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "geographic.tif"}]})");
    CHECK(error_of(r).find("geographic") != std::string::npos);
  }
  SUBCASE("both a file and a constant for the DEM") {
    auto r = manifest(R"({"dem": {"constant": 1, "file": "dem_int16.tif"}, "layers": [{"name": "a", "file": "rgba.tif"}]})");
    CHECK(error_of(r).find("not both") != std::string::npos);
  }
  SUBCASE("a transform with the wrong length") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "no_georef.png", "transform": [1, 2, 3]}]})");
    CHECK(error_of(r).find("array of 6 numbers") != std::string::npos);
  }
  SUBCASE("a layer bigger than the stated limit") {
    MapLoadOptions opt;
    opt.limits.max_side = 20;
    auto r = parse_map(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif"}]})", "m.json", kTiff, opt);
    CHECK(error_of(r).find("exceeds the limit of 20") != std::string::npos);
  }
  SUBCASE("a registration sigma that is negative, too large or not a number") {
    auto neg = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif", "registration_sigma_m": -1}]})");
    CHECK(error_of(neg).find("layers[0]: 'registration_sigma_m' -1 m must lie in [0, 1000]") != std::string::npos);
    auto big = manifest(R"({"dem": {"constant": 1, "vertical_sigma_m": 1200.5}, "layers": [{"name": "a", "file": "rgba.tif"}]})");
    CHECK(error_of(big).find("dem: 'vertical_sigma_m' 1200.5 m must lie in [0, 1000]") != std::string::npos);
    auto text = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif", "registration_sigma_m": "1 m"}]})");
    CHECK(error_of(text).find("'registration_sigma_m' must be a number, found \"1 m\"") != std::string::npos);
  }
  SUBCASE("layers that do not overlap") {
    auto r = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "no_georef.png", "transform": [0, 1, 0, 0, 0, -1]},
                                                            {"name": "b", "file": "no_georef.png", "transform": [500, 1, 0, 0, 0, -1]}]})");
    CHECK(error_of(r).find("no area in common") != std::string::npos);
  }
}

TEST_CASE("a 4th band labelled alpha counts as alpha only if it is a 0/255 mask (NAIP's NIR is not)") {
  auto rgba = manifest(R"({"dem": {"constant": 1}, "layers": [{"name": "a", "file": "rgba.tif"}]})");
  REQUIRE(rgba.ok());
  CHECK(rgba->layers[0].rgba.at(5, 7, 0) == 56);
  CHECK(rgba->layers[0].rgba.at(5, 7, 3) == 255);
  const std::string naip = terralign::test::shared_data("naip_nd_2009_2020/naip/m_4709963_se_14_1_20160816.tif");
  if (naip.empty()) return;
  auto m = parse_map(R"({"dem": {"constant": 1}, "layers": [{"name": "2016", "file": ")" + naip + R"("}]})", "n.json", "");
  REQUIRE(m.ok());
  // NIR 182 at (100, 200) would be "partly transparent"; as RGB + NIR the pixel is valid, and
  // only the NoData corner (0, 0, 0) is masked.
  CHECK(m->layers[0].rgba.at(100, 200, 3) == 255);
  CHECK(m->layers[0].rgba.at(619, 723, 3) == 0);
}
