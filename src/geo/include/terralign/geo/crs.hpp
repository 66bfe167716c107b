// Coordinate reference systems of a map's projected frame, and conversion to and from
// geodetic latitude / longitude / height.
//
// Supported: UTM north and south on WGS 84 (EPSG 326zz, 327zz) and on NAD83 (EPSG 269zz,
// zones 1-23), UPS (EPSG 32661, 32761), any transverse Mercator with given parameters (all
// through GeographicLib), Swiss LV95 (EPSG 2056, the swisstopo rigorous oblique conformal
// cylindrical projection on the Bessel ellipsoid), and "local": a metric frame with no
// geodetic meaning, for which latitude / longitude are refused.
//
// Datums: NAD83 is treated as WGS 84 (they differ by about 1-2 m in North America, which is
// below the NAIP tiles' own registration error). LV95 converts WGS 84 <-> CH1903+ with
// swisstopo's three-parameter shift (674.374, 15.056, 405.346 m), good to about 1 m.
//
// Heights: every conversion passes the height through unchanged. z in the map frame is in
// the map's own vertical datum (for example EGM2008 orthometric heights in the
// Baviaanskloof DEM, or the ellipsoidal heights of a GNSS survey), and the "height" of a
// latitude / longitude / height triple is that same number: no geoid model is applied.
#pragma once

#include <string>

#include <terralign/geo/result.hpp>

namespace terralign::geo {

struct Geodetic {
  double lat_deg = 0;  // [-90, 90], positive north
  double lon_deg = 0;  // [-180, 180], positive east
  double height = 0;   // metres, in the map's vertical datum (see above)
};

// Parameters of a transverse Mercator projection (EPSG method 9807).
struct TransverseMercatorParams {
  double lat0_deg = 0;       // latitude of natural origin
  double lon0_deg = 0;       // central meridian
  double k0 = 1;             // scale factor on the central meridian, (0, 2)
  double false_easting = 0;  // metres
  double false_northing = 0; // metres
  double a = 6378137.0;      // ellipsoid semi-major axis, metres
  double inv_f = 298.257223563;  // inverse flattening
};

class Crs {
 public:
  enum class Kind { Local, TransverseMercator, PolarStereographic, SwissLv95 };

  Crs() = default;  // local
  static Crs local();
  // Known EPSG codes; anything else is an error naming the code and what is supported.
  static Result<Crs> from_epsg(int code);
  static Result<Crs> transverse_mercator(const TransverseMercatorParams& p);
  // Text forms: "EPSG:26914", "local", or a PROJ string "+proj=utm +zone=14 [+south]
  // [+datum=WGS84|NAD83]" or "+proj=tmerc +lat_0= +lon_0= +k= +x_0= +y_0= [+datum=|+ellps=]".
  static Result<Crs> parse(const std::string& text);

  Kind kind() const { return kind_; }
  bool is_local() const { return kind_ == Kind::Local; }
  int epsg() const { return epsg_; }  // 0 where the CRS has no EPSG code
  std::string name() const;
  // Same projection (same EPSG code, or the same parameters to 1e-9).
  bool same_as(const Crs& other) const;

  // Projected (x east, y north, z) -> geodetic. Error for a local CRS or a non-finite input.
  Result<Geodetic> to_geodetic(double x, double y, double z) const;
  // Geodetic -> projected. Error for a local CRS, |lat| > 90 or non-finite input.
  Status from_geodetic(const Geodetic& g, double& x, double& y, double& z) const;

 private:
  Kind kind_ = Kind::Local;
  int epsg_ = 0;
  TransverseMercatorParams tm_;
  bool ups_north_ = true;
};

}  // namespace terralign::geo
