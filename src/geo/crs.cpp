#include <terralign/geo/crs.hpp>

#include <cmath>
#include <sstream>
#include <map>

#include <GeographicLib/Geocentric.hpp>
#include <GeographicLib/PolarStereographic.hpp>
#include <GeographicLib/TransverseMercator.hpp>

#include <terralign/geo/number_text.hpp>

namespace terralign::geo {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
constexpr double kWgs84A = 6378137.0, kWgs84InvF = 298.257223563;
constexpr double kGrs80InvF = 298.257222101;

const char* kSupported =
    "supported: EPSG:326zz and 327zz (WGS 84 / UTM), 269zz (NAD83 / UTM, zones 1-23), "
    "32661 and 32761 (UPS), 2056 (Swiss LV95), a +proj=tmerc or +proj=utm string, or local";

TransverseMercatorParams utm_params(int zone, bool north, double inv_f) {
  TransverseMercatorParams p;
  p.lat0_deg = 0;
  p.lon0_deg = 6.0 * zone - 183.0;
  p.k0 = 0.9996;
  p.false_easting = 500000.0;
  p.false_northing = north ? 0.0 : 10000000.0;
  p.a = kWgs84A;
  p.inv_f = inv_f;
  return p;
}

// ---- Swiss LV95 (swisstopo, "Formulas and constants for the calculation of the Swiss
// conformal cylindrical projection and for the transformation between coordinate
// systems", rigorous formulas on the Bessel 1841 ellipsoid). ----
struct Swiss {
  static constexpr double a = 6377397.155;
  static constexpr double inv_f = 299.1528128;
  static constexpr double E0 = 2600000.0, N0 = 1200000.0;
  static constexpr double dx = 674.374, dy = 15.056, dz = 405.346;  // CH1903+ -> WGS 84
  double e, e2, phi0, lam0, R, alpha, b0, K;
  Swiss() {
    const double f = 1.0 / inv_f;
    e2 = f * (2 - f);
    e = std::sqrt(e2);
    phi0 = (46.0 + 57.0 / 60 + 8.66 / 3600) * kDeg;
    lam0 = (7.0 + 26.0 / 60 + 22.50 / 3600) * kDeg;
    const double s0 = std::sin(phi0);
    R = a * std::sqrt(1 - e2) / (1 - e2 * s0 * s0);
    alpha = std::sqrt(1 + e2 / (1 - e2) * std::pow(std::cos(phi0), 4));
    b0 = std::asin(s0 / alpha);
    K = std::log(std::tan(kPi / 4 + b0 / 2)) - alpha * std::log(std::tan(kPi / 4 + phi0 / 2)) +
        alpha * e / 2 * std::log((1 + e * s0) / (1 - e * s0));
  }
  // Bessel geodetic (radians) -> LV95 E, N.
  void forward(double phi, double lam, double& E, double& N) const {
    const double sp = std::sin(phi);
    const double S = alpha * std::log(std::tan(kPi / 4 + phi / 2)) -
                     alpha * e / 2 * std::log((1 + e * sp) / (1 - e * sp)) + K;
    const double b = 2 * (std::atan(std::exp(S)) - kPi / 4);
    const double l = alpha * (lam - lam0);
    const double lbar = std::atan2(std::sin(l), std::sin(b0) * std::tan(b) + std::cos(b0) * std::cos(l));
    const double bbar = std::asin(std::cos(b0) * std::sin(b) - std::sin(b0) * std::cos(b) * std::cos(l));
    E = E0 + R * lbar;
    N = N0 + R / 2 * std::log((1 + std::sin(bbar)) / (1 - std::sin(bbar)));
  }
  void inverse(double E, double N, double& phi, double& lam) const {
    const double Y = E - E0, X = N - N0;
    const double lbar = Y / R;
    const double bbar = 2 * (std::atan(std::exp(X / R)) - kPi / 4);
    const double b = std::asin(std::cos(b0) * std::sin(bbar) + std::sin(b0) * std::cos(bbar) * std::cos(lbar));
    const double l = std::atan2(std::sin(lbar), std::cos(b0) * std::cos(lbar) - std::sin(b0) * std::tan(bbar));
    lam = lam0 + l / alpha;
    phi = b;
    for (int it = 0; it < 20; ++it) {  // converges to 1e-15 rad in about 6 steps
      const double S = (std::log(std::tan(kPi / 4 + b / 2)) - K) / alpha +
                       e * std::log(std::tan(kPi / 4 + std::asin(e * std::sin(phi)) / 2));
      const double next = 2 * std::atan(std::exp(S)) - kPi / 2;
      const bool done = std::abs(next - phi) < 1e-15;
      phi = next;
      if (done) break;
    }
  }
};

const Swiss& swiss() {
  static const Swiss s;
  return s;
}

Status check_geodetic(const Geodetic& g) {
  if (!std::isfinite(g.lat_deg) || !std::isfinite(g.lon_deg) || !std::isfinite(g.height))
    return Error{"latitude/longitude/height (" + format_double(g.lat_deg) + ", " +
                 format_double(g.lon_deg) + ", " + format_double(g.height) +
                 ") has a non-finite value"};
  if (std::abs(g.lat_deg) > 90)
    return Error{"latitude " + format_double(g.lat_deg) + " deg is outside [-90, 90]"};
  return Ok{};
}

}  // namespace

Crs Crs::local() { return Crs{}; }

Result<Crs> Crs::transverse_mercator(const TransverseMercatorParams& p) {
  const double vals[] = {p.lat0_deg, p.lon0_deg, p.k0, p.false_easting, p.false_northing, p.a, p.inv_f};
  for (double v : vals)
    if (!std::isfinite(v)) return Error{"transverse Mercator parameter is not finite"};
  if (!(p.k0 > 0 && p.k0 < 2)) return Error{"transverse Mercator scale factor k0 = " + format_double(p.k0) + " is outside (0, 2)"};
  if (!(p.a > 6e6 && p.a < 7e6)) return Error{"ellipsoid semi-major axis " + format_double(p.a) + " m is outside (6e6, 7e6)"};
  if (!(p.inv_f > 1)) return Error{"ellipsoid inverse flattening " + format_double(p.inv_f) + " must be > 1"};
  if (std::abs(p.lat0_deg) > 90) return Error{"latitude of origin " + format_double(p.lat0_deg) + " is outside [-90, 90]"};
  Crs c;
  c.kind_ = Kind::TransverseMercator;
  c.tm_ = p;
  return c;
}

Result<Crs> Crs::from_epsg(int code) {
  Crs c;
  c.epsg_ = code;
  if (code >= 32601 && code <= 32660) {
    c.kind_ = Kind::TransverseMercator;
    c.tm_ = utm_params(code - 32600, true, kWgs84InvF);
  } else if (code >= 32701 && code <= 32760) {
    c.kind_ = Kind::TransverseMercator;
    c.tm_ = utm_params(code - 32700, false, kWgs84InvF);
  } else if (code >= 26901 && code <= 26923) {
    c.kind_ = Kind::TransverseMercator;
    c.tm_ = utm_params(code - 26900, true, kGrs80InvF);
  } else if (code == 32661 || code == 32761) {
    c.kind_ = Kind::PolarStereographic;
    c.ups_north_ = code == 32661;
  } else if (code == 2056) {
    c.kind_ = Kind::SwissLv95;
  } else if (code == 4326 || code == 4269 || code == 4258) {
    return Error{"EPSG:" + std::to_string(code) +
                 " is a geographic (degree) CRS; a map needs a projected metric CRS (" +
                 kSupported + ")"};
  } else {
    return Error{"unknown EPSG code " + std::to_string(code) + " (" + kSupported + ")"};
  }
  return c;
}

Result<Crs> Crs::parse(const std::string& text) {
  if (text == "local" || text.empty()) return local();
  if (text.rfind("EPSG:", 0) == 0 || text.rfind("epsg:", 0) == 0) {
    const std::string num = text.substr(5);
    if (num.empty() || num.size() > 6 || num.find_first_not_of("0123456789") != std::string::npos)
      return Error{"CRS '" + text + "': expected EPSG:<number>"};
    return from_epsg(std::stoi(num));
  }
  if (text.rfind("+proj=", 0) != 0)
    return Error{"CRS '" + text + "' is not understood (" + kSupported + ")"};
  std::map<std::string, std::string> kv;
  std::istringstream in(text);
  std::string tok;
  while (in >> tok) {
    if (tok[0] != '+') return Error{"CRS '" + text + "': token '" + tok + "' does not start with '+'"};
    const auto eq = tok.find('=');
    kv[tok.substr(1, eq == std::string::npos ? std::string::npos : eq - 1)] =
        eq == std::string::npos ? "" : tok.substr(eq + 1);
  }
  double inv_f = kWgs84InvF;
  for (const char* key : {"datum", "ellps"}) {
    auto it = kv.find(key);
    if (it == kv.end()) continue;
    if (it->second == "WGS84") inv_f = kWgs84InvF;
    else if (it->second == "NAD83" || it->second == "GRS80") inv_f = kGrs80InvF;
    else return Error{"CRS '" + text + "': " + key + "=" + it->second + " is not supported (WGS84, NAD83, GRS80)"};
  }
  auto number = [&](const char* key, double def) -> Result<double> {
    auto it = kv.find(key);
    if (it == kv.end()) return def;
    auto r = parse_double(it->second);
    if (!r.ok()) return with_context(std::string("CRS '") + text + "': +" + key, r.error());
    return r;
  };
  const std::string proj = kv["proj"];
  if (proj == "utm") {
    TERRALIGN_TRY_ASSIGN(const double zone, number("zone", NAN));
    if (!(zone >= 1 && zone <= 60) || zone != std::floor(zone))
      return Error{"CRS '" + text + "': UTM zone " + format_double(zone) + " is not an integer in [1, 60]"};
    return transverse_mercator(utm_params(static_cast<int>(zone), kv.count("south") == 0, inv_f));
  }
  if (proj == "tmerc") {
    TransverseMercatorParams p;
    p.inv_f = inv_f;
    TERRALIGN_TRY_ASSIGN(p.lat0_deg, number("lat_0", 0));
    TERRALIGN_TRY_ASSIGN(p.lon0_deg, number("lon_0", 0));
    TERRALIGN_TRY_ASSIGN(p.k0, number("k", 1));
    if (kv.count("k_0")) { TERRALIGN_TRY_ASSIGN(p.k0, number("k_0", 1)); }
    TERRALIGN_TRY_ASSIGN(p.false_easting, number("x_0", 0));
    TERRALIGN_TRY_ASSIGN(p.false_northing, number("y_0", 0));
    return transverse_mercator(p);
  }
  return Error{"CRS '" + text + "': projection '" + proj + "' is not supported (" + kSupported + ")"};
}

std::string Crs::name() const {
  switch (kind_) {
    case Kind::Local: return "local metric frame (no geodetic reference)";
    case Kind::SwissLv95: return "EPSG:2056 (CH1903+ / LV95)";
    case Kind::PolarStereographic: return ups_north_ ? "EPSG:32661 (UPS north)" : "EPSG:32761 (UPS south)";
    case Kind::TransverseMercator: {
      std::ostringstream s;
      if (epsg_) s << "EPSG:" << std::to_string(epsg_) << " (";  // no locale's digit grouping
      s << "transverse Mercator lat_0=" << format_double(tm_.lat0_deg)
        << " lon_0=" << format_double(tm_.lon0_deg) << " k=" << format_double(tm_.k0)
        << " x_0=" << format_double(tm_.false_easting) << " y_0=" << format_double(tm_.false_northing)
        << (tm_.inv_f == kGrs80InvF ? " GRS80" : " WGS84");
      if (epsg_) s << ")";
      return s.str();
    }
  }
  return "?";
}

bool Crs::same_as(const Crs& o) const {
  if (kind_ != o.kind_) return false;
  switch (kind_) {
    case Kind::Local: return true;
    case Kind::SwissLv95: return true;
    case Kind::PolarStereographic: return ups_north_ == o.ups_north_;
    case Kind::TransverseMercator: {
      auto close = [](double a, double b) { return std::abs(a - b) <= 1e-9 * std::max(1.0, std::abs(a)); };
      return close(tm_.lat0_deg, o.tm_.lat0_deg) && close(tm_.lon0_deg, o.tm_.lon0_deg) &&
             close(tm_.k0, o.tm_.k0) && close(tm_.false_easting, o.tm_.false_easting) &&
             close(tm_.false_northing, o.tm_.false_northing) && close(tm_.a, o.tm_.a) &&
             close(tm_.inv_f, o.tm_.inv_f);
    }
  }
  return false;
}

Result<Geodetic> Crs::to_geodetic(double x, double y, double z) const {
  if (kind_ == Kind::Local)
    return Error{"the map has no CRS (a local metric frame): latitude/longitude are not defined"};
  if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z))
    return Error{"map coordinates (" + format_double(x) + ", " + format_double(y) + ", " +
                 format_double(z) + ") have a non-finite value"};
  Geodetic g;
  g.height = z;
  switch (kind_) {
    case Kind::TransverseMercator: {
      const GeographicLib::TransverseMercator tm(tm_.a, 1.0 / tm_.inv_f, tm_.k0);
      double x0 = 0, y0 = 0;
      tm.Forward(tm_.lon0_deg, tm_.lat0_deg, tm_.lon0_deg, x0, y0);
      tm.Reverse(tm_.lon0_deg, x - tm_.false_easting, y - tm_.false_northing + y0, g.lat_deg, g.lon_deg);
      break;
    }
    case Kind::PolarStereographic: {
      const auto& ups = GeographicLib::PolarStereographic::UPS();
      ups.Reverse(ups_north_, x - 2e6, y - 2e6, g.lat_deg, g.lon_deg);
      break;
    }
    case Kind::SwissLv95: {
      double phi = 0, lam = 0;
      swiss().inverse(x, y, phi, lam);
      const GeographicLib::Geocentric bessel(Swiss::a, 1.0 / Swiss::inv_f);
      const GeographicLib::Geocentric& wgs = GeographicLib::Geocentric::WGS84();
      // z is a WGS 84 height (see from_geodetic), but the shift needs the Bessel height of
      // the point: iterate on it (the two differ by tens of metres and vary slowly, so
      // three steps reach 1e-6 m).
      double h_bessel = z;
      for (int it = 0; it < 4; ++it) {
        double X, Y, Z, h_wgs;
        bessel.Forward(phi / kDeg, lam / kDeg, h_bessel, X, Y, Z);
        wgs.Reverse(X + Swiss::dx, Y + Swiss::dy, Z + Swiss::dz, g.lat_deg, g.lon_deg, h_wgs);
        h_bessel += z - h_wgs;
      }
      g.height = z;  // heights pass through (see the header)
      break;
    }
    case Kind::Local: break;
  }
  if (!std::isfinite(g.lat_deg) || !std::isfinite(g.lon_deg))
    return Error{"map coordinates (" + format_double(x) + ", " + format_double(y) +
                 ") are outside the domain of " + name()};
  return g;
}

Status Crs::from_geodetic(const Geodetic& g, double& x, double& y, double& z) const {
  if (kind_ == Kind::Local)
    return Error{"the map has no CRS (a local metric frame): latitude/longitude cannot be converted"};
  TERRALIGN_TRY(check_geodetic(g));
  z = g.height;
  switch (kind_) {
    case Kind::TransverseMercator: {
      const GeographicLib::TransverseMercator tm(tm_.a, 1.0 / tm_.inv_f, tm_.k0);
      double x0 = 0, y0 = 0;
      tm.Forward(tm_.lon0_deg, tm_.lat0_deg, tm_.lon0_deg, x0, y0);
      tm.Forward(tm_.lon0_deg, g.lat_deg, g.lon_deg, x, y);
      x += tm_.false_easting;
      y += tm_.false_northing - y0;
      break;
    }
    case Kind::PolarStereographic: {
      if ((g.lat_deg < 0) == ups_north_ && g.lat_deg != 0)
        return Error{"latitude " + format_double(g.lat_deg) + " is in the wrong hemisphere for " + name()};
      const auto& ups = GeographicLib::PolarStereographic::UPS();
      ups.Forward(ups_north_, g.lat_deg, g.lon_deg, x, y);
      x += 2e6;
      y += 2e6;
      break;
    }
    case Kind::SwissLv95: {
      const GeographicLib::Geocentric bessel(Swiss::a, 1.0 / Swiss::inv_f);
      const GeographicLib::Geocentric& wgs = GeographicLib::Geocentric::WGS84();
      double X, Y, Z, lat, lon, h;
      wgs.Forward(g.lat_deg, g.lon_deg, g.height, X, Y, Z);
      bessel.Reverse(X - Swiss::dx, Y - Swiss::dy, Z - Swiss::dz, lat, lon, h);
      swiss().forward(lat * kDeg, lon * kDeg, x, y);
      break;
    }
    case Kind::Local: break;
  }
  if (!std::isfinite(x) || !std::isfinite(y))
    return Error{"latitude/longitude (" + format_double(g.lat_deg) + ", " + format_double(g.lon_deg) +
                 ") is outside the domain of " + name()};
  return Ok{};
}

}  // namespace terralign::geo
