// The caller's floating-point environment (terralign/geo/float_environment.hpp): the onboard
// path computes in the default one whatever its caller set, and gives the caller's back. Before
// session 82 rounding upward moved every answer of the firmware's test, and a trap on
// FE_INVALID killed the process in its first render.
#include <cmath>
#include <cstring>
#include <memory>
#include <string>

#include <doctest/doctest.h>

#include <terralign/geo/float_environment.hpp>
#include <terralign/nn/weights.hpp>
#include <terralign/raster/renderer.hpp>

#include "localizer.hpp"
#include "nadir_scene.hpp"

using namespace terralign;

namespace {

// An optimiser may not fold these: the sum's last bit shows the rounding mode.
volatile double g_one = 1.0, g_tiny = 0x1p-60;

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

}  // namespace

TEST_CASE("float environment: a scope installs the default one and gives the caller's back") {
  REQUIRE(float_environment_is_default());
  CHECK(g_one + g_tiny == 1.0);  // to nearest
  {
    const HostileFloatEnvironment hostile;
    MESSAGE("hostile: " << std::string(HostileFloatEnvironment::description()));
    CHECK_FALSE(float_environment_is_default());
#if !(defined(__ARM_ARCH_PROFILE) && __ARM_ARCH_PROFILE == 'M')
    CHECK(g_one + g_tiny > 1.0);  // upward
#endif
    {
      const FloatEnvironmentScope scope;
      CHECK(float_environment_is_default());
      CHECK(g_one + g_tiny == 1.0);
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
