#include <cmath>

#include <doctest/doctest.h>

#include <terralign/geo/crs.hpp>

using terralign::geo::Crs;
using terralign::geo::Geodetic;

namespace {

struct Reference {
  const char* crs;
  double lat, lon;  // degrees
  double h;         // metres (matters for LV95: the datum shift moves the point by ~1e-4 h)
  double x, y;      // metres
};

// Computed independently with PROJ 9.1 (Debian proj-bin), whose transverse Mercator is the
// Poder/Engsager algorithm rather than GeographicLib's Krueger series, and whose LV95
// pipeline is the EPSG one (CH1903+ to WGS 84 (1) + Swiss Oblique Mercator 1995):
//   echo "LAT LON 0" | cs2cs -f %.4f EPSG:4326 CRS
const Reference kReferences[] = {
    {"EPSG:32633", 47.5, 13.2, 0, 364437.7419, 5262299.9449},
    {"EPSG:32633", 60.1, 9.5, 0, 194385.6765, 6675278.7256},  // 5.5 deg off the meridian
    {"EPSG:32733", -33.9, 18.4, 0, 814420.3310, 6243724.8401},
    {"EPSG:26914", 47.0203, -99.1651, 0, 487452.9335, 5207433.2048},  // the NAIP tile
    {"EPSG:32651", 24.68, 120.951, 0, 292674.7194, 2731063.7307},     // Tuniu
    {"EPSG:32661", 85.0, 30.0, 0, 2277728.6957, 1518959.7883},  // UPS north: PROJ prints N, E
    {"EPSG:32761", -87.0, -120.0, 0, 1711488.4125, 1833427.7573},  // UPS south: PROJ prints N, E
    // echo "LAT LON H" | cs2cs -f %.6f EPSG:4326 EPSG:2056
    {"EPSG:2056", 46.95108, 7.43864, 0, 2600000.577527, 1199999.692988},
    {"EPSG:2056", 47.3769, 8.5417, 400, 2683303.888535, 1247925.618304},
    {"EPSG:2056", 45.9, 6.2, 1000, 2503864.488187, 1083915.195669},
};

}  // namespace

TEST_CASE("projections agree with PROJ to 1 mm and round-trip to 1 mm") {
  for (const auto& r : kReferences) {
    CAPTURE(r.crs);
    CAPTURE(r.lat);
    auto crs = Crs::parse(r.crs);
    REQUIRE(crs.ok());
    double x = 0, y = 0, z = 0;
    REQUIRE(crs->from_geodetic(Geodetic{r.lat, r.lon, r.h}, x, y, z).ok());
    CHECK(std::abs(x - r.x) < 1e-3);
    CHECK(std::abs(y - r.y) < 1e-3);
    auto back = crs->to_geodetic(r.x, r.y, r.h);
    REQUIRE(back.ok());
    // 1 mm on the ground is about 9e-9 degrees of latitude.
    CHECK(std::abs(back->lat_deg - r.lat) < 9e-9);
    CHECK(std::abs((back->lon_deg - r.lon) * std::cos(r.lat * M_PI / 180)) < 9e-9);
    CHECK(back->height == r.h);  // heights pass through
  }
}

TEST_CASE("user-defined transverse Mercator (Lo25) agrees with PROJ") {
  // echo "-55094.504 -3727407.037 0" | cs2cs -f %.9f +proj=tmerc +lat_0=0 +lon_0=25 +k=1
  //   +x_0=0 +y_0=0 +datum=WGS84 +to EPSG:4326
  auto crs = Crs::parse("+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs=True");
  REQUIRE(crs.ok());
  auto g = crs->to_geodetic(-55094.504, -3727407.037, 0);
  REQUIRE(g.ok());
  CHECK(std::abs(g->lat_deg - -33.671718729) < 2e-9);
  CHECK(std::abs(g->lon_deg - 24.405920640) < 2e-9);
}

TEST_CASE("transverse Mercator with a non-zero latitude of origin") {
  // A TM whose origin is at 40 N has y = 0 at 40 N on the central meridian.
  terralign::geo::TransverseMercatorParams p;
  p.lat0_deg = 40;
  p.lon0_deg = 10;
  p.false_northing = 1000;
  auto crs = Crs::transverse_mercator(p);
  REQUIRE(crs.ok());
  double x, y, z;
  REQUIRE(crs->from_geodetic({40.0, 10.0, 0.0}, x, y, z).ok());
  CHECK(std::abs(x) < 1e-9);
  CHECK(std::abs(y - 1000) < 1e-9);
}

TEST_CASE("local maps refuse latitude and longitude with a clear message") {
  const Crs local = Crs::local();
  auto g = local.to_geodetic(1, 2, 3);
  REQUIRE(!g.ok());
  CHECK(g.error().message.find("no CRS") != std::string::npos);
  double x, y, z;
  CHECK(!local.from_geodetic({1, 2, 3}, x, y, z).ok());
}

TEST_CASE("bad CRS input: unknown EPSG code, geographic CRS, bad PROJ text, NaN, latitude > 90") {
  auto unknown = Crs::parse("EPSG:3857");
  REQUIRE(!unknown.ok());
  CHECK(unknown.error().message.find("unknown EPSG code 3857") != std::string::npos);
  auto geographic = Crs::parse("EPSG:4326");
  REQUIRE(!geographic.ok());
  CHECK(geographic.error().message.find("geographic") != std::string::npos);
  CHECK(!Crs::parse("EPSG:").ok());
  CHECK(!Crs::parse("EPSG:12a").ok());
  CHECK(!Crs::parse("+proj=lcc +lat_1=30").ok());
  CHECK(!Crs::parse("+proj=utm +zone=61").ok());
  CHECK(!Crs::parse("+proj=tmerc +k=0").ok());
  CHECK(!Crs::parse("WGS84").ok());
  auto utm = Crs::parse("EPSG:32633");
  REQUIRE(utm.ok());
  double x, y, z;
  auto nan = utm->from_geodetic({NAN, 13, 0}, x, y, z);
  REQUIRE(!nan.ok());
  CHECK(nan.error().message.find("non-finite") != std::string::npos);
  auto lat = utm->from_geodetic({91, 13, 0}, x, y, z);
  REQUIRE(!lat.ok());
  CHECK(lat.error().message.find("91") != std::string::npos);
  CHECK(!utm->to_geodetic(INFINITY, 0, 0).ok());
}

TEST_CASE("CRS identity: the same projection from an EPSG code and a PROJ string") {
  auto a = Crs::parse("EPSG:32614");
  auto b = Crs::parse("+proj=utm +zone=14 +datum=WGS84");
  auto c = Crs::parse("EPSG:26914");  // NAD83: another ellipsoid
  REQUIRE((a.ok() && b.ok() && c.ok()));
  CHECK(a->same_as(b.value()));
  CHECK(!a->same_as(c.value()));
  CHECK(!a->same_as(Crs::local()));
}
