#include <cmath>
#include <cstring>
#include <vector>

#include <doctest/doctest.h>

#include <terralign/geo/file.hpp>
#include <terralign/geo/geotiff.hpp>

#include "support.hpp"

using namespace terralign;
using namespace terralign::geo;
using terralign::test::source_path;

namespace {

std::string fixture(const char* name) { return source_path(std::string("tests/data/tiff/") + name); }

// Sets the value of a SHORT/LONG tag of the first IFD of a little-endian classic TIFF.
void patch_tag(std::vector<std::uint8_t>& b, std::uint16_t tag, std::uint32_t value) {
  auto u16 = [&](std::size_t at) { return static_cast<std::uint16_t>(b[at] | b[at + 1] << 8); };
  const std::size_t ifd = b[4] | b[5] << 8 | b[6] << 16 | static_cast<std::size_t>(b[7]) << 24;
  const int n = u16(ifd);
  for (int i = 0; i < n; ++i) {
    const std::size_t e = ifd + 2 + 12 * static_cast<std::size_t>(i);
    if (u16(e) != tag) continue;
    if (u16(e + 2) == 3) {  // SHORT
      b[e + 8] = static_cast<std::uint8_t>(value);
      b[e + 9] = static_cast<std::uint8_t>(value >> 8);
    } else {
      for (int k = 0; k < 4; ++k) b[e + 8 + static_cast<std::size_t>(k)] = static_cast<std::uint8_t>(value >> (8 * k));
    }
  }
}

}  // namespace

// Pixel values printed by `gdallocationinfo -valonly FILE 5 7` and `... 39 29`, origins by
// gdalinfo (GDAL 3.6.2) for the fixtures tests/data/tiff/make.sh writes.
TEST_CASE("GeoTIFF layouts and codecs read the same pixels and geotransform as GDAL") {
  const char* lossless[] = {"rgb_strips_none.tif", "rgb_strips_lzw.tif", "rgb_tiles_deflate.tif",
                            "rgb_separate_packbits.tif", "rgb_pixel_is_point.tif", "rgba.tif"};
  for (const char* name : lossless) {
    CAPTURE(name);
    auto r = read_geotiff(fixture(name));
    REQUIRE(r.ok());
    CHECK(r->width == 40);
    CHECK(r->height == 30);
    CHECK(r->sample == SampleType::U8);
    REQUIRE(r->transform.has_value());
    CHECK(r->transform->gdal()[0] == doctest::Approx(487400.6).epsilon(1e-12));
    CHECK(r->transform->gdal()[3] == doctest::Approx(5207246.2).epsilon(1e-12));
    CHECK(r->transform->gdal()[1] == 5.0);
    CHECK(r->transform->gdal()[5] == -5.0);
    CHECK(r->crs.epsg == 26914);
    CHECK(r->u8.at(5, 7, 0) == 56);
    CHECK(r->u8.at(5, 7, 1) == 79);
    CHECK(r->u8.at(5, 7, 2) == 58);
    CHECK(r->u8.at(39, 29, 0) == 84);
    CHECK(r->u8.at(39, 29, 1) == 95);
    CHECK(r->u8.at(39, 29, 2) == 72);
  }
  CHECK(read_geotiff(fixture("rgb_pixel_is_point.tif"))->pixel_is_point);
  CHECK(read_geotiff(fixture("rgba.tif"))->has_alpha);
  CHECK(!read_geotiff(fixture("rgb_strips_none.tif"))->has_alpha);
}

TEST_CASE("JPEG-in-TIFF (YCbCr) decodes to RGB within 2 levels of GDAL") {
  // GDAL printed 58 82 60 and 86 94 83. Both go through libjpeg; the bound allows for a
  // different chroma upsampling path.
  auto r = read_geotiff(fixture("rgb_tiles_jpeg.tif"));
  REQUIRE(r.ok());
  const int want[2][3] = {{58, 82, 60}, {86, 94, 83}};
  for (int c = 0; c < 3; ++c) {
    CHECK(std::abs(r->u8.at(5, 7, c) - want[0][c]) <= 2);
    CHECK(std::abs(r->u8.at(39, 29, c) - want[1][c]) <= 2);
  }
}

TEST_CASE("elevation rasters: int16 and float32 with GDAL_NODATA") {
  auto i16 = read_geotiff(fixture("dem_int16.tif"));
  REQUIRE(i16.ok());
  CHECK(i16->sample == SampleType::I16);
  CHECK(i16->f32.at(5, 7) == 10.0f);
  CHECK(i16->f32.at(39, 29) == 65.0f);
  REQUIRE(i16->nodata.has_value());
  CHECK(*i16->nodata == -32768.0);
  auto f32 = read_geotiff(fixture("dem_float32.tif"));
  REQUIRE(f32.ok());
  CHECK(f32->sample == SampleType::F32);
  CHECK(f32->f32.at(5, 7) == 456.5f);
  CHECK(f32->f32.at(39, 29) == 484.5f);
  REQUIRE(f32->nodata.has_value());
  CHECK(std::isnan(*f32->nodata));
}

TEST_CASE("the committed NAIP tile reads as gdalinfo and gdallocationinfo report") {
  // gdalinfo data/naip_west/naip_2016.tif: Size is 620, 724; Origin = (485900.6, 5209246.2);
  // Pixel Size = (5, -5); NoData 0. gdallocationinfo -valonly at (0,0): 116 128 97;
  // (100,200): 72 101 79; (311,517): 79 114 75; (600,5): 85 106 82; (619,723): 0 0 0.
  auto r = read_geotiff(source_path("data/naip_west/naip_2016.tif"));
  REQUIRE(r.ok());
  CHECK(r->width == 620);
  CHECK(r->height == 724);
  CHECK(r->bands == 3);
  CHECK(r->transform->gdal()[0] == 485900.6);
  CHECK(r->transform->gdal()[3] == 5209246.2);
  CHECK(r->nodata.value_or(-1) == 0.0);
  const int px[5][5] = {{0, 0, 116, 128, 97}, {100, 200, 72, 101, 79}, {311, 517, 79, 114, 75},
                        {600, 5, 85, 106, 82}, {619, 723, 0, 0, 0}};
  for (const auto& p : px)
    for (int c = 0; c < 3; ++c) CHECK(r->u8.at(p[0], p[1], c) == p[2 + c]);
}

TEST_CASE("the original 4-band NAIP strip file reads as GDAL reports (shared data)") {
  TERRALIGN_REQUIRE_SHARED(path, "naip_nd_2009_2020/naip/m_4709963_se_14_1_20160816.tif");
  // gdallocationinfo -valonly at (100,200): 72 101 79 182 (the 4th band is near-infrared).
  auto r = read_geotiff(path);
  REQUIRE(r.ok());
  CHECK(r->bands == 4);
  CHECK(r->has_alpha);  // the file labels its NIR band as unassociated alpha; see test_map
  CHECK(r->u8.at(100, 200, 3) == 182);
  CHECK(r->u8.at(311, 517, 3) == 190);
}

TEST_CASE("ModelTransformation: a rotated geotransform (Baviaanskloof frame, shared data)") {
  TERRALIGN_REQUIRE_SHARED(path, "ngi_baviaanskloof_2015/frames/3324c_2015_1004_05_0182_RGB.tif");
  // gdalinfo: GeoTransform = -53284.28524772511, -5.639122614945984, -0.01588913558893879,
  //                          -3730647.082199863, -0.01588913558907734, 5.639122614946245
  auto r = read_geotiff(path);
  REQUIRE(r.ok());
  CHECK(r->width == 640);
  CHECK(r->height == 1152);
  const auto& c = r->transform->gdal();
  CHECK(c[0] == doctest::Approx(-53284.28524772511).epsilon(1e-14));
  CHECK(c[1] == doctest::Approx(-5.639122614945984).epsilon(1e-14));
  CHECK(c[2] == doctest::Approx(-0.01588913558893879).epsilon(1e-12));
  CHECK(c[3] == doctest::Approx(-3730647.082199863).epsilon(1e-14));
  CHECK(c[5] == doctest::Approx(5.639122614946245).epsilon(1e-14));
  REQUIRE(r->crs.tm.has_value());
  CHECK(r->crs.tm->lon0_deg == 25.0);
  CHECK(r->crs.tm->k0 == 1.0);
}

TEST_CASE("bad GeoTIFF input: each refused with the file and the value") {
  SUBCASE("missing file") {
    auto r = read_geotiff("/nonexistent/dem.tif");
    REQUIRE(!r.ok());
    CHECK(r.error().message.find("/nonexistent/dem.tif") != std::string::npos);
  }
  SUBCASE("not a TIFF") {
    auto r = read_geotiff(fixture("no_georef.png"));
    REQUIRE(!r.ok());
    CHECK(r.error().message.find("not a TIFF") != std::string::npos);
  }
  SUBCASE("truncated TIFF, at every length from the header on") {
    auto bytes = read_file(fixture("rgb_tiles_deflate.tif"));
    REQUIRE(bytes.ok());
    int refused = 0, tried = 0;
    for (std::size_t len = 0; len < bytes->size(); len += 97, ++tried) {
      auto r = read_geotiff_memory(bytes->data(), len, "cut.tif");
      refused += !r.ok();
    }
    CHECK(refused == tried);  // the pixel data runs to the end: every cut loses some
  }
  SUBCASE("0 x N raster") {
    auto bytes = read_file(fixture("rgb_strips_none.tif"));
    REQUIRE(bytes.ok());
    patch_tag(*bytes, 256, 0);  // ImageWidth
    auto r = read_geotiff_memory(bytes->data(), bytes->size(), "zero.tif");
    REQUIRE(!r.ok());
    CHECK(r.error().message.find("zero.tif") != std::string::npos);
  }
  SUBCASE("raster larger than the stated limit") {
    RasterLimits small;
    small.max_side = 32;
    auto r = read_geotiff(fixture("rgb_strips_none.tif"), small);
    REQUIRE(!r.ok());
    CHECK(r.error().message.find("40 x 30 raster exceeds the limit of 32") != std::string::npos);
    RasterLimits tiny_bytes;
    tiny_bytes.max_bytes = 1000;
    auto b = read_geotiff(fixture("rgb_strips_none.tif"), tiny_bytes);
    REQUIRE(!b.ok());
    CHECK(b.error().message.find("needs 3600 bytes") != std::string::npos);
  }
  SUBCASE("tiles far larger than the raster (a header fuzz_geotiff found)") {
    // One tile buffer must fit the raster's limit: a 40 x 30 raster in 65520 x 65520 tiles
    // would otherwise allocate 12.9 GB for one of them (the default limit is 2 GiB).
    auto bytes = read_file(fixture("rgb_tiles_deflate.tif"));
    REQUIRE(bytes.ok());
    patch_tag(*bytes, 322, 65520);  // TileWidth
    patch_tag(*bytes, 323, 65520);  // TileLength
    auto r = read_geotiff_memory(bytes->data(), bytes->size(), "huge_tiles.tif");
    REQUIRE(!r.ok());
    CHECK(r.error().message.find("huge_tiles.tif") != std::string::npos);
    // In a 32-bit process libtiff refuses the header itself: the tile's size overflows its
    // tmsize_t (found on armhf, session 84).
    const char* why = sizeof(void*) >= 8 ? "tiles of 65520 x 65520 need 12878611200 bytes each, over the limit"
                                         : "Integer overflow";
    CHECK(r.error().message.find(why) != std::string::npos);
  }
  SUBCASE("unsupported sample format") {
    auto r = read_geotiff(fixture("dem_float64.tif"));
    REQUIRE(!r.ok());
    CHECK(r.error().message.find("64-bit float") != std::string::npos);
  }
  SUBCASE("geographic CRS") {
    auto r = read_geotiff(fixture("geographic.tif"));
    REQUIRE(r.ok());
    auto crs = r->crs.resolve();
    REQUIRE(!crs.ok());
    CHECK(crs.error().message.find("geographic") != std::string::npos);
  }
}
