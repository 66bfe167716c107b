// A localizer over several layers of one map (cli::Localizer::create with a list): the image is
// aligned to the first layer, and to the next only where the alignment before did not
// converge. Here the layer that cannot be aligned to is a featureless one ("blank": the
// 2016 layer painted one grey), which no tracker converges on.
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

#include <terralign/geo/map.hpp>
#include <terralign/nn/weights.hpp>
#include <terralign/raster/renderer.hpp>

#include "alloc_counter.hpp"
#include "localizer.hpp"
#include "nadir_scene.hpp"
#include "support.hpp"

using namespace terralign;

namespace {

using test::Scene;

// The shared scene (nadir_scene.hpp) with two featureless layers more, "blank" and "blank2".
Scene scene() {
  Scene s = test::scene();
  for (const char* name : {"blank", "blank2"}) {
    geo::Layer blank = *s.map.find_layer("2016");
    blank.name = name;
    for (std::size_t k = 0; k < blank.rgba.size(); k += 4)
      for (std::size_t c = 0; c < 3; ++c) blank.rgba.data()[k + c] = 128;
    s.map.layers.push_back(std::move(blank));
  }
  return s;
}

// attempts: where given, the localizer's attempts() of the layers tried.
cli::LocalizeOutput localize(const Scene& s, const std::vector<std::string>& layers, const nn::WeightFile* weights,
                             std::vector<cli::LayerAttempt>* attempts = nullptr) {
  auto loc = cli::Localizer::create(s.map, s.cam, layers, iclk::TrackerOptions{}, 2, weights);
  REQUIRE(loc.ok());
  CHECK(loc.value()->layer_count() == layers.size());
  auto out = loc.value()->localize(s.live.view(), s.prior);
  REQUIRE(out.ok());
  if (attempts) attempts->assign(loc.value()->attempts(), loc.value()->attempts() + out->layers_tried);
  return out.value();
}

// Whether it converged, which layer answered and how many were tried.
void check_answer(const cli::LocalizeOutput& out, bool converged, int layer, int tried) {
  CHECK(out.converged == converged);
  CHECK(out.layer == layer);
  CHECK(out.layers_tried == tried);
}

}  // namespace

TEST_CASE("layers: the next layer is tried only where the one before did not converge, and answers as it would alone") {
  Scene s = scene();
  // The answering layer's own registration sigma counts, not the first's: the blank layer
  // states 5 m, which would widen the covariance by 25 m^2 an axis.
  s.map.find_layer("blank")->registration_sigma_m = 5.0;
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  const nn::WeightFile* learned = &weights.value();
  for (const nn::WeightFile* w : {static_cast<const nn::WeightFile*>(nullptr), learned}) {
    CAPTURE(w != nullptr);
    const cli::LocalizeOutput alone = localize(s, {"2016"}, w);
    REQUIRE(alone.converged);
    check_answer(alone, true, 0, 1);
    CHECK((alone.T_W_C.t_W_C - s.truth.t_W_C).norm() < 1.0);  // same year: centimetres (README)

    const cli::LocalizeOutput blank = localize(s, {"blank"}, w);
    check_answer(blank, false, 0, 1);

    // The first layer converges: the second is never tried.
    const cli::LocalizeOutput first = localize(s, {"2016", "blank"}, w);
    check_answer(first, true, 0, 1);
    CHECK(first.T_W_C.t_W_C == alone.T_W_C.t_W_C);
    CHECK(first.iterations == alone.iterations);

    // The first fails: the second answers, bit for bit as it does alone (its own options and
    // sigma), and its iterations count both layers'.
    std::vector<cli::LayerAttempt> attempts;
    const cli::LocalizeOutput second = localize(s, {"blank", "2016"}, w, &attempts);
    check_answer(second, true, 1, 2);
    CHECK(second.T_W_C.t_W_C == alone.T_W_C.t_W_C);
    CHECK(second.T_W_C.q_W_C.coeffs() == alone.T_W_C.q_W_C.coeffs());
    CHECK(second.covariance == alone.covariance);
    CHECK(second.disagreement_px == alone.disagreement_px);
    CHECK(second.iterations == alone.iterations + blank.iterations);
    // Each layer's attempt says what it said alone: the blank layer's failure and why, then
    // the answer.
    REQUIRE(attempts.size() == 2);
    CHECK_FALSE(attempts[0].converged);
    CHECK(std::string(attempts[0].reason) == blank.reason);
    CHECK(attempts[0].iterations == blank.iterations);
    CHECK(attempts[0].residual_final == blank.residual_final);
    CHECK(attempts[1].converged);
    CHECK(std::string(attempts[1].reason) == alone.reason);
    CHECK(attempts[1].iterations == alone.iterations);
    CHECK(attempts[1].disagreement_px == alone.disagreement_px);

    // None converges: the last layer's failure, at the prior, with every layer's cost.
    const cli::LocalizeOutput none = localize(s, {"blank", "blank2"}, w);
    check_answer(none, false, 1, 2);
    CHECK(none.T_W_C.t_W_C == s.prior.t_W_C);
    CHECK(none.reason == blank.reason);
    CHECK(none.iterations == 2 * blank.iterations);  // blank2 is blank's twin
  }
}

TEST_CASE("layers: a fallback allocates nothing, and gives the same bytes on 1 and 2 threads") {
  const Scene s = scene();
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  cli::LocalizeOutput answers[2];
  for (int threads : {1, 2}) {
    const std::vector<std::string> layers{"blank", "2016"};
    auto loc = cli::Localizer::create(s.map, s.cam, layers, iclk::TrackerOptions{}, threads, &weights.value());
    REQUIRE(loc.ok());
    REQUIRE(loc.value()->localize(s.live.view(), s.prior).ok());  // the first call may size lazily
    test::AllocationCounter count;
    auto out = loc.value()->localize(s.live.view(), s.prior);
    const long allocations = count.allocations();
    REQUIRE(out.ok());
    CHECK(allocations == 0);
    answers[threads - 1] = out.value();
  }
  check_answer(answers[0], true, 1, 2);
  CHECK(std::memcmp(answers[0].T_W_C.t_W_C.data(), answers[1].T_W_C.t_W_C.data(), sizeof(double) * 3) == 0);
  CHECK(std::memcmp(answers[0].T_W_C.q_W_C.coeffs().data(), answers[1].T_W_C.q_W_C.coeffs().data(), sizeof(double) * 4) == 0);
}

TEST_CASE("layers: no layer, a name the map lacks and a name given twice are refused, naming it") {
  const Scene s = scene();
  auto refused = [&](const std::vector<std::string>& layers) {
    auto loc = cli::Localizer::create(s.map, s.cam, layers, iclk::TrackerOptions{}, 1);
    REQUIRE_FALSE(loc.ok());
    return loc.error().message;
  };
  CHECK(refused({}).find("no reference layer") != std::string::npos);
  CHECK(refused({"2016", "1999"}).find("'1999'") != std::string::npos);
  CHECK(refused({"2016", ""}).find("''") != std::string::npos);
  CHECK(refused({"2016", "2012", "2016"}).find("'2016' is given twice") != std::string::npos);
}

#if defined(TERRALIGN_CLI)  // built with the command-line program
TEST_CASE("layers: align and eval take a list, report the answering layer, and refuse a name the map lacks") {
  const std::string tl = TERRALIGN_CLI;
  const std::string map = test::source_path("data/naip_west/map.json");
  const std::string cam = test::source_path("data/cameras/uav_752x480.json");
  const std::string out = test::temp_dir() + "/eval_layers.json";
  const std::string base = tl + " eval --map " + map + " --camera " + cam +
                           " --query-layer 2016 --count 3 --seed 3 --altitude 700:900 --methods init,classic:20";
  REQUIRE(std::system((base + " --ref-layer 2016,2012 --json " + out + " >/dev/null 2>&1").c_str()) == 0);
  const auto j = nlohmann::json::parse(test::read_text(out));
  CHECK(j["ref_layer"] == "2016,2012");
  int by_first = 0;
  for (const auto& sj : j["methods"]["classic:20"]["samples"]) {
    CHECK((sj["layer"] == "2016" || sj["layer"] == "2012"));
    by_first += sj["converged"].get<bool>() && sj["layer"] == "2016";
  }
  // Same year, the classical tracker converges on the first layer (README: 97-98 % within 5 px).
  CHECK(by_first >= 2);
  CHECK(j["methods"]["classic:20"]["answered_by"]["2016"].get<int>() == by_first);
  CHECK(std::system((base + " --ref-layer 2016,1999 >/dev/null 2>&1").c_str()) != 0);
  CHECK(std::system((base + " --ref-layer 2016, >/dev/null 2>&1").c_str()) != 0);
}
#endif  // TERRALIGN_CLI
