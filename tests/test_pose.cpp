#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <doctest/doctest.h>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/number_text.hpp>
#include <terralign/geo/numeric.hpp>
#include <terralign/geo/pose.hpp>

#include "support.hpp"

using namespace terralign;
using namespace terralign::geo;

namespace {

double angle_deg(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b) {
  return Eigen::AngleAxisd(a.conjugate() * b).angle() * 180.0 / M_PI;
}

// splitmix64: the same numbers on every machine.
struct SplitMix64 {
  std::uint64_t z;
  std::uint64_t operator()() {
    z += 0x9e3779b97f4a7c15ull;
    std::uint64_t x = z;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
    return x ^ (x >> 31);
  }
};

}  // namespace

TEST_CASE("pose text: parse, format, round trip") {
  auto p = parse_pose("487450.5 5207437.25 1370 0 1 0 0");
  REQUIRE(p.ok());
  CHECK(p->t_W_C.x() == 487450.5);
  CHECK(p->q_W_C.x() == 1.0);
  auto again = parse_pose(format_pose(p.value()));
  REQUIRE(again.ok());
  CHECK(again->t_W_C == p->t_W_C);
  CHECK(again->q_W_C.coeffs() == p->q_W_C.coeffs());
}

TEST_CASE("numbers in text: the shortest that reads back, whole numbers below 1e15 in full") {
  // "%g" alone wrote 60 as "6e+01" and 1370 as "1.37e+03" in messages and pose files.
  CHECK(format_pose(parse_pose("487450.5 5207437.25 1370 0 1 0 0").value()) == "487450.5 5207437.25 1370 0 1 0 0");
  CHECK(format_double(60) == "60");
  CHECK(format_double(-1000000) == "-1000000");
  CHECK(format_double(999999999999999) == "999999999999999");
  CHECK(format_double(1e15) == "1e+15");
  CHECK(format_double(1e300) == "1e+300");
  CHECK(format_double(0.0001) == "0.0001");
  CHECK(format_double(1e-5) == "1e-05");
  CHECK(format_double(5208159.9) == "5208159.9");
  CHECK(format_double(0.1 + 0.2) == "0.30000000000000004");
  CHECK(format_double(-0.0) == "-0");
  // Every text reads back as its double: 2000 doubles whose bits are drawn at random (NaN
  // aside), and the whole numbers 10^k, 3 x 10^k and -7 x 10^k up to 10^17.
  SplitMix64 rng{99};
  std::vector<double> values;
  for (int i = 0; i < 2000; ++i) {
    const std::uint64_t bits = rng();
    double v;
    std::memcpy(&v, &bits, sizeof v);
    if (!std::isnan(v)) values.push_back(v);
  }
  for (double p10 = 1; p10 <= 1e17; p10 *= 10) values.insert(values.end(), {p10, 3 * p10, -7 * p10});
  for (double v : values) {
    const std::string text = format_double(v);
    const auto back = parse_double(text);
    REQUIRE_MESSAGE(back.ok(), text);
    CHECK_MESSAGE(back.value() == v, text);
    if (v == std::trunc(v) && std::abs(v) < 1e15) CHECK_MESSAGE(text.find('e') == std::string::npos, text);
  }
}

TEST_CASE("bad pose text: zero-norm quaternion, NaN, wrong count, junk") {
  auto zero = parse_pose("1 2 3 0 0 0 0");
  REQUIRE(!zero.ok());
  CHECK(zero.error().message.find("quaternion norm is 0") != std::string::npos);
  auto nan = parse_pose("1 nan 3 1 0 0 0");
  REQUIRE(!nan.ok());
  CHECK(nan.error().message.find("not finite") != std::string::npos);
  auto six = parse_pose("1 2 3 1 0 0");
  REQUIRE(!six.ok());
  CHECK(six.error().message.find("has 6 numbers") != std::string::npos);
  CHECK(!parse_pose("1 2 3 1 0 0 0 9").ok());
  CHECK(!parse_pose("1 2 3 1 0 0 x").ok());
  CHECK(!parse_pose("1 2 3 2 0 0 0").ok());  // norm 2: probably swapped fields
}

TEST_CASE("yaw/pitch/roll and omega/phi/kappa conventions") {
  const Eigen::Vector3d c(100, 200, 900);
  // Level aircraft heading north with a nadir camera: optical axis down, image top north.
  const Pose north = pose_from_ypr(c, 0, 0, 0);
  CHECK((north.R() * Eigen::Vector3d::UnitZ() - Eigen::Vector3d(0, 0, -1)).norm() < 1e-12);
  CHECK((north.R() * -Eigen::Vector3d::UnitY() - Eigen::Vector3d(0, 1, 0)).norm() < 1e-12);
  // Heading east: image top east, image right south.
  const Pose east = pose_from_ypr(c, 90, 0, 0);
  CHECK((east.R() * -Eigen::Vector3d::UnitY() - Eigen::Vector3d(1, 0, 0)).norm() < 1e-12);
  CHECK((east.R() * Eigen::Vector3d::UnitX() - Eigen::Vector3d(0, -1, 0)).norm() < 1e-12);
  // Nose up 10 degrees turns the belly, and a nadir camera's axis, forward (north).
  const Pose up = pose_from_ypr(c, 0, 10, 0);
  CHECK((up.R() * Eigen::Vector3d::UnitZ()).y() == doctest::Approx(std::sin(10 * M_PI / 180)));
  // Right wing down 10 degrees turns the belly to the left (west when heading north).
  const Pose right_down = pose_from_ypr(c, 0, 0, 10);
  CHECK((right_down.R() * Eigen::Vector3d::UnitZ()).x() == doctest::Approx(-std::sin(10 * M_PI / 180)));
  // A camera tilted 30 degrees forward looks 30 degrees ahead of nadir.
  const Pose tilted = pose_from_ypr(c, 0, 0, 0, tilted_mount(30));
  const Eigen::Vector3d axis = tilted.R() * Eigen::Vector3d::UnitZ();
  CHECK(axis.y() == doctest::Approx(0.5));
  CHECK(axis.z() == doctest::Approx(-std::sqrt(3.0) / 2));
  // omega = phi = kappa = 0: the PATB camera looks down its -z with y north: the same view.
  const Pose opk = pose_from_opk(c, 0, 0, 0);
  CHECK(angle_deg(opk.q_W_C, north.q_W_C) < 1e-9);
  CHECK(opk.t_W_C == c);
}

TEST_CASE("Tuniu: OPK in UTM 51N and the OpenSfM reconstruction are the same poses (shared data)") {
  TERRALIGN_REQUIRE_SHARED(opk_path, "odm_tuniu_river_2019/camera/odm_xyz_opk.csv");
  TERRALIGN_REQUIRE_SHARED(rec_path, "odm_tuniu_river_2019/camera/reconstruction.json");
  auto crs = Crs::from_epsg(32651);
  REQUIRE(crs.ok());
  auto read = read_opensfm_shots(rec_path, crs.value());
  REQUIRE(read.ok());
  // Its reference_lla projects to whole metres (292632, 2731169): OpenDroneMap's grid-aligned
  // offset frame, not a true topocentric one (PROVENANCE.md calls it topocentric).
  CHECK(read->frame == OpenSfmFrame::ProjectedOffset);
  const auto* shots = &read->poses;
  auto topo = read_opensfm_shots(rec_path, crs.value(), OpenSfmFrame::Topocentric);
  REQUIRE(topo.ok());
  std::ifstream in(opk_path);
  std::string line;
  std::getline(in, line);  // header
  int compared = 0;
  while (std::getline(in, line)) {
    std::istringstream s(line);
    std::string name;
    double x, y, z, omega, phi, kappa;
    s >> name >> x >> y >> z >> omega >> phi >> kappa;
    name = name.substr(1, name.size() - 2);  // quoted
    CAPTURE(name);
    REQUIRE(shots->count(name) == 1);
    const Pose a = pose_from_opk({x, y, z}, omega, phi, kappa);
    const Pose& b = shots->at(name);
    // The CSV rounds to 1 mm and 0.001 degree; the two are exports of one bundle adjustment.
    CHECK((a.t_W_C - b.t_W_C).norm() < 0.05);
    CHECK(angle_deg(a.q_W_C, b.q_W_C) < 0.05);
    // Read as topocentric, the same numbers would be turned by the meridian convergence
    // (-0.856 deg at 120.95 E in zone 51) and moved about 2 m: the frame matters.
    CHECK(angle_deg(a.q_W_C, topo->poses.at(name).q_W_C) == doctest::Approx(0.856).epsilon(0.01));
    ++compared;
  }
  CHECK(compared == 3);
}

TEST_CASE("Baviaanskloof: a frame's pose projects its ortho tile's centre near the image centre (shared data)") {
  TERRALIGN_REQUIRE_SHARED(dem, "ngi_baviaanskloof_2015/dem/dem.tif");
  TERRALIGN_REQUIRE_SHARED(ortho, "ngi_baviaanskloof_2015/ortho/ngi_rgb_byte_1.tif");
  // Manifest built on the fly so the AGPL files are read in place, never copied.
  const std::string manifest = R"({"dem": {"file": ")" + dem + R"("}, "layers": [{"name": "2015", "file": ")" + ortho + R"("}]})";
  auto map = parse_map(manifest, "baviaanskloof.json", "");
  REQUIRE(map.ok());
  CHECK(map->crs.kind() == Crs::Kind::TransverseMercator);
  // ngi_int_param.yaml: f = 120 mm on a 92.16 x 165.888 mm sensor of 640 x 1152 px
  // (0.144 mm pixels), principal point at the centre, no distortion.
  CameraModel cam;
  cam.width = 640;
  cam.height = 1152;
  cam.fx = cam.fy = 120.0 / 0.144;
  cam.cx = 319.5;
  cam.cy = 575.5;
  // ngi_xyz_opk.csv, frame 0182 (its ortho is ngi_rgb_byte_1).
  const Pose T_W_C = pose_from_opk({-55094.504, -3727407.037, 5258.308}, -0.349, 0.298, -179.087);
  const Layer& L = map->layers[0];
  const double xc = 0.5 * (L.extent.min_x + L.extent.max_x), yc = 0.5 * (L.extent.min_y + L.extent.max_y);
  const double zc = map->dem.height_at(xc, yc);
  REQUIRE(std::isfinite(zc));
  Eigen::Vector2d px = Eigen::Vector2d::Zero();
  REQUIRE(cam.project<double>(T_W_C.inverse() * Eigen::Vector3d(xc, yc, zc), px));
  MESSAGE("ortho centre projects to (" << px.x() << ", " << px.y() << "), image centre (319.5, 575.5)");
  // PROVENANCE.md: each ortho's footprint centre lies 50-130 m from its frame's camera
  // centre, up to 23 px at the frame's 5.6 m pixels; the frame is near nadir (tilt < 0.5 deg,
  // another 8 px at most), so 25 px bounds the honest answer while a wrong sign or axis
  // (hundreds of pixels) fails.
  CHECK(std::abs(px.x() - 319.5) < 25);
  CHECK(std::abs(px.y() - 575.5) < 25);
  // kappa = -179 deg: the image's top faces south, so the ortho's north edge, 3.5 km north of
  // its centre (630 px), lands below the image centre by about that much. A kappa off by
  // 180 degrees puts it above.
  const double zn = map->dem.height_at(xc, L.extent.max_y - 10);
  REQUIRE(std::isfinite(zn));
  REQUIRE(cam.project<double>(T_W_C.inverse() * Eigen::Vector3d(xc, L.extent.max_y - 10, zn), px));
  MESSAGE("ortho north edge projects to (" << px.x() << ", " << px.y() << ")");
  CHECK(px.y() > 575.5 + 500);
  CHECK(std::abs(px.x() - 319.5) < 60);
}

namespace {

// Distance in units of the last place of b (b's spacing above |b|).
double ulps(double a, double b) {
  if (a == b) return 0;
  return std::abs(a - b) / (std::nextafter(std::abs(b), INFINITY) - std::abs(b));
}

}  // namespace

TEST_CASE("sin_cos, atan2_portable, log_portable: within 2 ulp of the C library's, its signs and specials") {
  // Tolerance: glibc's results are within about half an ulp of the truth; our Taylor series
  // and Cody-Waite reduction add at most one rounding per step of a few, measured at most 2 ulp
  // over 4 million arguments when they were written (session 80). Tried against it there: 1/5!
  // written 1/121 (sin and cos 1.9e11 ulp off), the middle part of pi / 2 dropped (1.1e12),
  // atan(1/2) 1e-16 high (atan2 3 ulp) and the log's series cut to five terms (3.2e5 ulp).
  SplitMix64 next{0x9e3779b97f4a7c15ull};
  auto uniform = [&](double lo, double hi) { return lo + (hi - lo) * static_cast<double>(next() >> 11) * 0x1.0p-53; };
  double worst_sin = 0, worst_cos = 0, worst_atan2 = 0, worst_log = 0;
  for (int i = 0; i < 200000; ++i) {
    const double scale[] = {4.0, 1e-3, 1e5, 1e-12};
    const double x = uniform(-1, 1) * scale[i % 4];
    double s, c;
    sin_cos(x, s, c);
    worst_sin = std::max(worst_sin, ulps(s, std::sin(x)));
    worst_cos = std::max(worst_cos, ulps(c, std::cos(x)));
    const double y = uniform(-3, 3) * (i % 3 == 0 ? 1e-6 : 1.0), w = uniform(-3, 3);
    worst_atan2 = std::max(worst_atan2, ulps(atan2_portable(y, w), std::atan2(y, w)));
    const double v = i % 2 ? uniform(0, 1) : std::ldexp(uniform(0.5, 1), static_cast<int>(next() % 2000) - 1000);
    worst_log = std::max(worst_log, ulps(log_portable(v), std::log(v)));
  }
  CHECK(worst_sin <= 2);
  CHECK(worst_cos <= 2);
  CHECK(worst_atan2 <= 2);
  CHECK(worst_log <= 2);
  MESSAGE("worst ulp: sin " << worst_sin << ", cos " << worst_cos << ", atan2 " << worst_atan2 << ", log " << worst_log);

  double s, c;
  sin_cos(-0.0, s, c);
  CHECK((s == 0 && std::signbit(s) && c == 1));
  sin_cos(INFINITY, s, c);
  CHECK((std::isnan(s) && std::isnan(c)));
  sin_cos(NAN, s, c);
  CHECK((std::isnan(s) && std::isnan(c)));
  sin_cos(1e300, s, c);  // reduced modulo the double nearest 2 pi: finite, on the unit circle
  CHECK(std::abs(s * s + c * c - 1) < 1e-15);
  for (const double y : {0.0, -0.0, 1.0, -1.0, HUGE_VAL, -HUGE_VAL})
    for (const double x : {0.0, -0.0, 1.0, -1.0, HUGE_VAL, -HUGE_VAL}) {
      CAPTURE(y);
      CAPTURE(x);
      const double a = atan2_portable(y, x), b = std::atan2(y, x);
      CHECK((a == b && std::signbit(a) == std::signbit(b)));
    }
  CHECK(std::isnan(atan2_portable(NAN, 1.0)));
  CHECK(std::isnan(atan2_portable(1.0, NAN)));
  CHECK(log_portable(1.0) == 0.0);
  CHECK(log_portable(0.0) == -INFINITY);
  CHECK(std::isnan(log_portable(-1.0)));
  CHECK(log_portable(INFINITY) == INFINITY);
  CHECK(ulps(log_portable(4.9e-324), std::log(4.9e-324)) <= 2);  // the least subnormal
}

TEST_CASE("fma_float_by_double gives std::fma's bits: random triples, sums beside a rounding midpoint, subnormals, specials") {
  // std::fma is correctly rounded wherever it comes from (an instruction, or the C library's
  // fmaf), so any bit apart is a bug: no tolerance. A NaN result needs only be a NaN.
  SplitMix64 next{0x2545f4914f6cdd1dull};
  auto from_bits = [](std::uint32_t b) {
    float f;
    std::memcpy(&f, &b, sizeof f);
    return f;
  };
  auto bits_of = [](float f) {
    std::uint32_t b;
    std::memcpy(&b, &f, sizeof b);
    return b;
  };
  int checked = 0, apart = 0, naive_apart = 0;
  auto check = [&](float a, float b, float c) {
    const float want = std::fma(a, b, c), got = fma_float_by_double(a, b, c);
    ++checked;
    const bool same = std::isnan(want) ? std::isnan(got) : bits_of(got) == bits_of(want);
    if (!same && ++apart <= 5) MESSAGE("fma(" << a << ", " << b << ", " << c << "): " << got << ", std::fma " << want);
    // The same sum rounded twice (to double, then to float), for the cases' teeth.
    const float naive = static_cast<float>(static_cast<double>(a) * static_cast<double>(b) + static_cast<double>(c));
    if (!std::isnan(want) && bits_of(naive) != bits_of(want)) ++naive_apart;
  };
  // Any bit patterns (NaN, infinities, subnormals among them), and sums that cancel: c the
  // negated product rounded to float, moved by up to 3 ulp.
  for (int i = 0; i < 400000; ++i) {
    const std::uint64_t r = next();
    const float a = from_bits(static_cast<std::uint32_t>(r)), b = from_bits(static_cast<std::uint32_t>(r >> 32));
    check(a, b, from_bits(static_cast<std::uint32_t>(next())));
    const float near = -static_cast<float>(static_cast<double>(a) * static_cast<double>(b));
    check(a, b, from_bits(bits_of(near) + static_cast<std::uint32_t>(next() % 7) - 3u));
  }
  // Sums just below a midpoint between two floats: c with a random exponent, u its ulp, and
  // a b = +-(u / 2)(1 - 2^-2k), 2^-2k under a double's precision for k >= 15 (so rounding to
  // double lands on the midpoint and ties to even picks wrong for odd c, half the time).
  // c + u and the negative product give sums just above one.
  int midpoint_cases = 0;
  for (int i = 0; i < 20000; ++i) {
    const std::uint32_t exponent = 1 + static_cast<std::uint32_t>(next() % 200);  // c normal, 2^-126..2^74
    const float c = from_bits(exponent << 23 | static_cast<std::uint32_t>(next() & 0x7fffffu));
    const float u = std::nextafter(c, INFINITY) - c;
    const int k = 1 + static_cast<int>(next() % 23);
    const float a = u / 2 * (1 + std::ldexp(1.0f, -k)), b = 1 - std::ldexp(1.0f, -k);
    check(a, b, c);
    check(-a, b, c + u);
    check(-a, b, -c);
    midpoint_cases += 3;
  }
  // The same beside subnormal results: u = 2^-149, a b = 2^-150 (1 - 2^-2k).
  for (int i = 0; i < 20000; ++i) {
    const float c = from_bits(static_cast<std::uint32_t>(next() % 0x800000u));
    const int k = 1 + static_cast<int>(next() % 23);
    const float a = std::ldexp(1.0f + std::ldexp(1.0f, -k), -75), b = std::ldexp(1.0f - std::ldexp(1.0f, -k), -75);
    check(a, b, c);
    check(-a, b, -c);
  }
  // Signed zeros, infinities, NaN, overflow and the largest and least values.
  const float special[] = {0.0f, -0.0f, 1.0f, -1.0f, INFINITY, -INFINITY, NAN, 3.4028235e38f, -3.4028235e38f,
                           1.17549435e-38f, 1.4e-45f, -1.4e-45f, 0.5f, 2.0f};
  for (float a : special)
    for (float b : special)
      for (float c : special) check(a, b, c);
  MESSAGE(checked << " triples, " << midpoint_cases << " beside a midpoint; rounded twice, " << naive_apart << " would differ");
  CHECK(apart == 0);
  // The cases reach what they test: rounding twice is wrong on thousands of them.
  CHECK(naive_apart > 1000);
  // fma_float is std::fma or this: the same bits either way.
  CHECK(bits_of(fma_float(0.1f, 0.2f, 0.3f)) == bits_of(std::fma(0.1f, 0.2f, 0.3f)));
}

TEST_CASE("rotations from axes and angles and back: Eigen's AngleAxis to a few ulp, with terralign's sine") {
  // Each helper computes what Eigen::AngleAxis does, in its order, with sin_cos and
  // atan2_portable for the C library's: within 1e-15 (a few ulp of entries near 1) of Eigen's.
  const Eigen::Vector3d axes[] = {Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(), Eigen::Vector3d::UnitZ(),
                                  Eigen::Vector3d(1, -2, 0.5).normalized()};
  for (const Eigen::Vector3d& axis : axes)
    for (const double angle : {0.0, 1e-9, 0.3, -1.2, 3.0, 3.14159}) {
      CAPTURE(angle);
      const Eigen::AngleAxisd aa(angle, axis);
      CHECK((rotation_matrix(axis, angle) - aa.toRotationMatrix()).cwiseAbs().maxCoeff() < 1e-15);
      const Eigen::Quaterniond q = rotation_quaternion(axis, angle), qe(aa);
      CHECK((q.coeffs() - qe.coeffs()).cwiseAbs().maxCoeff() < 1e-15);
      const Eigen::AngleAxisd back(qe);
      CHECK(std::abs(rotation_angle(qe) - back.angle()) < 1e-15);
      CHECK((rotation_vector(qe) - back.angle() * back.axis()).cwiseAbs().maxCoeff() < 1e-15);
      double a;
      Eigen::Vector3d u;
      angle_axis(qe, a, u);
      CHECK((u - back.axis()).cwiseAbs().maxCoeff() < 1e-15);
    }
  // The identity: angle 0 about x, as Eigen's; a quaternion with w < 0 turns the same way.
  double a;
  Eigen::Vector3d u;
  angle_axis(Eigen::Quaterniond::Identity(), a, u);
  CHECK((a == 0 && u == Eigen::Vector3d::UnitX()));
  const Eigen::Quaterniond q = rotation_quaternion(Eigen::Vector3d::UnitZ(), 0.5);
  const Eigen::Quaterniond minus(-q.w(), -q.x(), -q.y(), -q.z());
  CHECK((rotation_vector(minus) - rotation_vector(q)).norm() < 1e-15);
}
