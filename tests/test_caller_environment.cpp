// What a program that embeds terralign may have set for its whole process, and terralign must
// not depend on (session 82):
// - the floating-point environment (terralign/geo/float_environment.hpp): the onboard path
//   computes in the default one whatever its caller set, and gives the caller's back. Before,
//   rounding upward moved every answer of the firmware's test, and a trap on FE_INVALID killed
//   the process in its first render;
// - the locale (terralign/geo/number_text.hpp): numbers are read and written in the "C"
//   locale's terms. Before, under a locale with a decimal comma the shipped weight file's
//   agreement threshold read as 1 instead of 1.25 and the learned tracker refused to set up.
#include <clocale>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <locale>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <doctest/doctest.h>

#include <terralign/geo/crs.hpp>
#include <terralign/geo/float_environment.hpp>
#include <terralign/geo/image_io.hpp>
#include <terralign/geo/number_text.hpp>
#include <terralign/iclk/deep_aligner.hpp>
#include <terralign/nn/weights.hpp>
#include <terralign/raster/renderer.hpp>

#include "localizer.hpp"
#include "nadir_scene.hpp"
#include "support.hpp"

using namespace terralign;

namespace {

// An optimiser may not fold these: the sum's last bit shows the rounding mode.
volatile double g_one = 1.0, g_tiny = 0x1p-60;
volatile float g_min_normal = 0x1p-126f;  // half of it is a subnormal float

// The classical tracker on the 2016 image (it does not converge across years), the learned one
// on 2017's.
cli::LocalizeOutput localize(const test::Scene& s, const nn::WeightFile* weights) {
  auto loc = cli::Localizer::create(s.map, s.cam, "2016", iclk::TrackerOptions{}, 2, weights);
  REQUIRE(loc.ok());
  auto out = loc.value()->localize((weights ? s.live_2017 : s.live).view(), s.prior);
  REQUIRE(out.ok());
  return out.value();
}

void check_same_bits(const cli::LocalizeOutput& a, const cli::LocalizeOutput& b) {
  CHECK(std::memcmp(a.T_W_C.t_W_C.data(), b.T_W_C.t_W_C.data(), sizeof(double) * 3) == 0);
  CHECK(std::memcmp(a.T_W_C.q_W_C.coeffs().data(), b.T_W_C.q_W_C.coeffs().data(), sizeof(double) * 4) == 0);
  CHECK(std::memcmp(a.covariance.data(), b.covariance.data(), sizeof(double) * 36) == 0);
  CHECK(a.converged == b.converged);
  CHECK(a.iterations == b.iterations);
  CHECK(std::string(a.reason) == b.reason);
}

// German numbers: a decimal comma, and a point between groups of three digits.
struct CommaNumbers : std::numpunct<char> {
  char do_decimal_point() const override { return ','; }
  char do_thousands_sep() const override { return '.'; }
  std::string do_grouping() const override { return "\3"; }
};

// While it lives, the process's C++ locale writes and reads numbers as CommaNumbers does, and
// its C locale is de_DE.UTF-8's where this machine has it (scripts/install-deps.sh makes it);
// the caller's are given back at the end.
class CommaLocale {
 public:
  CommaLocale() : cpp_(std::locale::global(std::locale(std::locale::classic(), new CommaNumbers))) {
    const char* was = std::setlocale(LC_ALL, nullptr);
    c_was_ = was ? was : "C";
    for (const char* name : {"de_DE.UTF-8", "de_DE.utf8"})
      if (!c_set_) c_set_ = std::setlocale(LC_ALL, name) != nullptr;
  }
  ~CommaLocale() {
    std::setlocale(LC_ALL, c_was_.c_str());
    std::locale::global(cpp_);
  }
  bool c_set() const { return c_set_; }

 private:
  std::locale cpp_;
  std::string c_was_;
  bool c_set_ = false;
};

}  // namespace

TEST_CASE("locale: a caller's decimal comma changes no number terralign reads or writes") {
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  const auto threshold = iclk::DeepAligner::max_disagreement(weights.value());
  REQUIRE(threshold.ok());
  const std::string pfm = test::temp_dir() + "/locale.pfm";
  ImageF depth(1024, 2, 1);
  for (std::size_t i = 0; i < depth.pixels().size(); ++i) depth.pixels()[i] = 0.5f * static_cast<float>(i);

  const CommaLocale comma;
  std::ostringstream grouped;
  grouped << 1024 << ' ' << 1.5;
  REQUIRE(grouped.str() == "1.024 1,5");  // the C++ locale is in effect
  if (comma.c_set()) {
    char buf[16];
    std::snprintf(buf, sizeof buf, "%.2f", 1.25);
    REQUIRE(std::string(buf) == "1,25");  // and so is the C one
  } else {
    MESSAGE("no de_DE.UTF-8 locale here (scripts/install-deps.sh makes one): the C locale is not tried");
  }

  // The learned tracker's thresholds, read from the weight file's text.
  const auto under_comma = iclk::DeepAligner::max_disagreement(weights.value());
  REQUIRE(under_comma.ok());
  CHECK(under_comma.value() == threshold.value());
  iclk::TrackerOptions options;
  const auto aligner = iclk::DeepAligner::create(weights.value(), 376, 240, options, 1);
  CHECK_MESSAGE(aligner.ok(), (aligner.ok() ? std::string() : aligner.error().message));
  // geo's numbers in text: poses, manifests, world files, messages.
  CHECK(geo::parse_double("1.25").value() == 1.25);
  CHECK(geo::parse_double(" +2.5e3").value() == 2500);
  CHECK_FALSE(geo::parse_double("1,25").ok());
  // The command-line tools' options and text files: whole tokens only (session 83: "700:900m"
  // and "classic:20x" were read as 700:900 and classic:20, and "--seed -1" as 2^64 - 1).
  CHECK(geo::parse_numbers("700.5:900", ':').value() == std::vector<double>{700.5, 900});
  CHECK(geo::parse_numbers(" 0.5\t12.25  -3 ", ' ').value() == std::vector<double>{0.5, 12.25, -3});
  CHECK(geo::parse_numbers("", ' ').value().empty());
  CHECK_FALSE(geo::parse_numbers("700:900m", ':').ok());
  CHECK_FALSE(geo::parse_numbers("700:", ':').ok());
  CHECK_FALSE(geo::parse_numbers("1,,2", ',').ok());
  CHECK(geo::parse_integer("-12").value() == -12);
  CHECK(geo::parse_integer("+1000").value() == 1000);
  CHECK_FALSE(geo::parse_integer("20x").ok());
  CHECK_FALSE(geo::parse_integer("1.5").ok());
  CHECK_FALSE(geo::parse_integer("99999999999999999999").ok());
  CHECK(geo::format_double(1234.5) == "1234.5");
  CHECK(geo::format_double(0.1) == "0.1");
  auto pose = geo::parse_pose("487450.5 5207437.25 1370 0 1 0 0");
  REQUIRE(pose.ok());
  CHECK(pose->t_W_C.x() == 487450.5);
  CHECK(geo::format_pose(pose.value()) == "487450.5 5207437.25 1370 0 1 0 0");
  CHECK(geo::Crs::from_epsg(26914).value().name() ==
        "EPSG:26914 (transverse Mercator lat_0=0 lon_0=-99 k=0.9996 x_0=500000 y_0=0 GRS80)");
  // The renderer's messages (before session 89 std::to_string's "559,750000" here).
  auto map = geo::load_map(test::source_path("data/naip_west/map.json"));
  auto cam = geo::load_camera(test::source_path("data/cameras/uav_752x480.json"));
  REQUIRE(map.ok());
  REQUIRE(cam.ok());
  auto renderer = raster::Renderer::create(map.value(), cam.value());
  REQUIRE(renderer.ok());
  auto frame = renderer.value()->make_output({"2016"});
  REQUIRE(frame.ok());
  auto below = geo::parse_pose("487450.5 5207436.5 559.75 0 1 0 0");  // the sample's ground is at 570 m
  REQUIRE(below.ok());
  const Status drawn = renderer.value()->render(below.value(), frame.value());
  REQUIRE_FALSE(drawn.ok());
  CHECK(drawn.error().message == "render: camera at z 559.75 m is below the terrain (570 m) at (487450.5, 5207436.5)");
  // A PFM depth image: its header's numbers, written and read back.
  REQUIRE(geo::save_pfm(pfm, depth.view()).ok());
  std::ifstream f(pfm, std::ios::binary);
  std::string head(15, '\0');
  f.read(head.data(), 15);
  CHECK(head == "Pf\n1024 2\n-1.0\n");
  auto back = geo::read_pfm(pfm);
  REQUIRE(back.ok());
  CHECK(back->pixels() == depth.pixels());
}

TEST_CASE("float environment: a scope installs the default one and gives the caller's back") {
  REQUIRE(float_environment_is_default());
  CHECK(g_one + g_tiny == 1.0);  // to nearest
  CHECK(g_min_normal * 0.5f > 0.0f);  // subnormals kept
  {
    const HostileFloatEnvironment hostile;
    const std::string what = HostileFloatEnvironment::description();
    MESSAGE("hostile: " << what);
    CHECK_FALSE(float_environment_is_default());
#if !(defined(__ARM_ARCH_PROFILE) && __ARM_ARCH_PROFILE == 'M')
    CHECK(g_one + g_tiny > 1.0);  // upward
#endif
    if (what.find("flush to zero") != std::string::npos) CHECK(g_min_normal * 0.5f == 0.0f);
    {
      const FloatEnvironmentScope scope;
      CHECK(float_environment_is_default());
      CHECK(g_one + g_tiny == 1.0);
      CHECK(g_min_normal * 0.5f > 0.0f);
      {
        const FloatEnvironmentScope nested;
        CHECK(float_environment_is_default());
      }
      CHECK(float_environment_is_default());
    }
    CHECK_FALSE(float_environment_is_default());  // given back
    CHECK(g_one + g_tiny > 1.0);
  }
  CHECK(float_environment_is_default());
}

TEST_CASE("float environment: the learned and the classical localizer give the default environment's answer under a hostile one") {
  const test::Scene s = test::scene();
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  const nn::WeightFile* const trackers[] = {nullptr, &weights.value()};
  for (const nn::WeightFile* w : trackers) {
    const std::string tracker = w ? "learned" : "classical";
    CAPTURE(tracker);
    const cli::LocalizeOutput plain = localize(s, w);
    CHECK(plain.converged);
    cli::LocalizeOutput upset;
    bool given_back = false;
    {
      // Set-up and frame both under it; on x86-64 a trap on FE_INVALID or FE_DIVBYZERO ends
      // the test binary here if any onboard computation runs outside a scope.
      const HostileFloatEnvironment hostile;
      upset = localize(s, w);
      given_back = !float_environment_is_default();
    }
    CHECK(given_back);
    check_same_bits(plain, upset);
  }
}

TEST_CASE("float environment: the renderer alone draws the default environment's bytes under a hostile one") {
  const test::Scene s = test::scene();
  auto render = [&](bool hostile) {
    std::unique_ptr<HostileFloatEnvironment> upset;
    if (hostile) upset = std::make_unique<HostileFloatEnvironment>();
    auto r = raster::Renderer::create(s.map, s.cam);
    REQUIRE(r.ok());
    auto out = r.value()->make_output({"2016"});
    REQUIRE(out.ok());
    // Without the renderer's own scope, x86-64's trap on FE_INVALID ends the test binary here.
    REQUIRE(r.value()->render(s.prior, out.value()).ok());
    CHECK(float_environment_is_default() == !hostile);
    return std::move(out.value());
  };
  const raster::RenderOutput plain = render(false), upset = render(true);
  const auto& a = plain.depth.pixels();
  const auto& b = upset.depth.pixels();
  REQUIRE(a.size() == b.size());
  CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0);
  CHECK(plain.rgb[0].pixels() == upset.rgb[0].pixels());
}
