// The learned tracker in C++ (src/iclk/deep_aligner.cpp) against the PyTorch model that
// trained its weights (training/deep_iclk.py), on committed validation pairs.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <utility>

#include <doctest/doctest.h>

#include <terralign/nn/weights.hpp>

#include "alloc_counter.hpp"
#include <terralign/iclk/deep_aligner.hpp>
#include "same_answer.hpp"
#include "support.hpp"

using namespace terralign;

namespace {

nn::WeightFile load(const char* rel) {
  auto w = nn::read_weights(test::source_path(rel));
  REQUIRE_MESSAGE(w.ok(), (w.ok() ? "" : w.error().message));
  return std::move(w.value());
}

// The weights `terralign` runs by default (CMake's TERRALIGN_SHIPPED_WEIGHTS).
nn::WeightFile shipped_weights() {
  auto w = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE_MESSAGE(w.ok(), (w.ok() ? "" : w.error().message));
  return std::move(w.value());
}

struct Pair {
  ImageF ref, depth, live;
  iclk::Pinhole<float> K{};
  double altitude = 0;
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
};

// PyTorch's final pose for pair k of a vectors file (R_k, t_k), into p.
void read_pose(const nn::WeightFile& v, int k, Pair& p) {
  const float* R = v.find("R_" + std::to_string(k))->data.data();
  const float* t = v.find("t_" + std::to_string(k))->data.data();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) p.R(r, c) = R[r * 3 + c];
    p.t[r] = t[r];
  }
}

Pair pair_of(const nn::WeightFile& v, int k) {
  const std::string s = std::to_string(k);
  Pair p;
  auto image = [&](const std::string& name, int channels, ImageF& out) {
    const nn::TensorData* t = v.find(name);
    REQUIRE(t);
    REQUIRE(t->shape.size() == (channels == 1 ? 2u : 3u));
    out.resize(t->shape[1], t->shape[0], channels);
    std::memcpy(out.data(), t->data.data(), t->data.size() * sizeof(float));
  };
  image("ref_" + s, 3, p.ref);
  image("depth_" + s, 1, p.depth);
  image("live_" + s, 3, p.live);
  const float* K = v.find("K_" + s)->data.data();
  p.K = {K[0], K[1], K[2], K[3]};
  p.altitude = v.find("altitude_" + s)->data[0];
  read_pose(v, k, p);
  return p;
}

iclk::TrackerOptions options() {
  iclk::TrackerOptions o;
  o.iterations = 20;
  return o;
}

// PyTorch's model has no coarse search (DeepAligner::kCoarseSearchPx) and runs every step
// (no DeepAligner::kMinStepPx): parity is between the same mathematics, so the C++ side
// starts from the identity too and stops on nothing but step_tol. With the motion stop pair 1
// of s16w64 ends 4e-4 rad and 0.26 m (at 647 m) from PyTorch's answer: steps of under 0.01 px
// left along a direction the image hardly constrains.
iclk::TrackerOptions parity_options() {
  iclk::TrackerOptions o = options();
  o.coarse_search_px = -1;
  o.min_step_px = -1;
  return o;
}

// Aligns p with `weights` from the identity under parity_options() with a tilt prior (radians)
// and an altitude prior (metres): neither acts, no up vector or height being set, so the
// answer is the same and only the agreement threshold they select differs.
iclk::TrackResult<iclk::DeepAligner::Warp> align_with_priors(const nn::WeightFile& weights, const Pair& p,
                                                             double tilt_prior_rad, double altitude_prior_m) {
  iclk::TrackerOptions o = parity_options();
  o.tilt_prior_rad = tilt_prior_rad;
  o.altitude_prior_m = altitude_prior_m;
  auto D = iclk::DeepAligner::create(weights, p.ref.width(), p.ref.height(), o, 1);
  REQUIRE(D.ok());
  return D.value()->align(p.ref.view(), p.depth.view(), p.live.view(), p.K, iclk::SE3<float>::identity());
}

// Aligns p with `weights` from the identity, as PyTorch's model starts, and checks the answer
// against PyTorch's pose in p: converged, within the bound of 1e-4 rad and 1e-3 of the
// altitude. Both sides are float32 with double 6x6 solves; they differ in summation order
// (chunked sums here, BLAS there), so agreement is to float rounding amplified by 80
// iterations, not to the bit. Returns the C++ answer.
iclk::SE3<double> check_parity(const nn::WeightFile& weights, const Pair& p, int channels, const std::string& what) {
  auto D = iclk::DeepAligner::create(weights, p.ref.width(), p.ref.height(), parity_options(), 2);
  REQUIRE_MESSAGE(D.ok(), (D.ok() ? "" : D.error().message));
  CAPTURE(what);
  CHECK(D.value()->channels() == channels);
  const auto& r = D.value()->align(p.ref.view(), p.depth.view(), p.live.view(), p.K, iclk::SE3<float>::identity());
  const std::string why = r.reason;
  CAPTURE(why);
  CHECK(r.converged);
  const iclk::SE3<double> T = r.params.cast<double>();
  const double angle = Eigen::AngleAxisd(T.R * p.R.transpose()).angle();
  const double dt = (T.t - p.t).norm();
  MESSAGE(what << ": rotation differs by " << angle << " rad, translation by " << dt << " m (altitude " << p.altitude
               << " m)");
  CHECK(angle <= 1e-4);
  CHECK(dt <= 1e-3 * p.altitude);
  return T;
}

// The answer of one learned alignment, as one number: FNV-1a (the weight files' checksum) over
// the bytes of the pose, the covariance, the final residual, the agreement test's
// disagreement, the iterations and the flag.
std::uint64_t answer_hash(const iclk::TrackResult<iclk::DeepAligner::Warp>& r) {
  std::uint64_t h = nn::fnv1a64(r.params.R.data(), sizeof(float) * 9);
  h = nn::fnv1a64(r.params.t.data(), sizeof(float) * 3, h);
  h = nn::fnv1a64(r.covariance.data(), sizeof(double) * 36, h);
  h = nn::fnv1a64(&r.residual_final, sizeof r.residual_final, h);
  h = nn::fnv1a64(&r.disagreement_px, sizeof r.disagreement_px, h);
  h = nn::fnv1a64(&r.iterations, sizeof r.iterations, h);
  const unsigned char converged = r.converged ? 1 : 0;
  return nn::fnv1a64(&converged, 1, h);
}

}  // namespace

TEST_CASE("learned tracker: one answer, to the bit, on every machine (x86-64 and aarch64, every SIMD build, GCC and clang)") {
  // Every kernel gives its scalar twin's bits (the encoder's and M-estimator's convolutions,
  // the solver's), nothing fuses a multiply and an add but what the code says, Eigen's own
  // vector code is off, and nothing on the path calls a libm function whose last bit is the C
  // library's (std::hypot: hypot_exact; the sigmoid's exp: plain multiplies and adds): so the x86-64 suites (GCC
  // release, clang under ASan + UBSan, on AVX2 or AVX-512 hosts) and the aarch64 one (NEON,
  // under qemu) must all give this alignment's answer to the bit. The pair: the first committed
  // parity pair, the shipped s16w64, the product's settings. A change that moves this number
  // moves every machine's answers alike (other weights, a sum in another order): say so in its
  // commit and put the new number here (the failure prints it). A machine on which it fails
  // alone gives answers of its own: that is the bug.
  const nn::WeightFile vectors = load("tests/data/nn/deep_parity.tlw");
  const Pair p = pair_of(vectors, 0);
  auto D = iclk::DeepAligner::create(load("weights/deep_iclk_s16w64.tlw"), p.ref.width(), p.ref.height(), options(), 1);
  REQUIRE(D.ok());
  const auto& r = D.value()->align(p.ref.view(), p.depth.view(), p.live.view(), p.K, iclk::SE3<float>::identity());
  CHECK(r.converged);
  const std::uint64_t h = answer_hash(r);
  constexpr std::uint64_t kAnswer = 0x298b0530015b05d5ull;
  char hex[32];
  std::snprintf(hex, sizeof hex, "0x%016llxull", static_cast<unsigned long long>(h));
  CHECK_MESSAGE(h == kAnswer, "this machine's answer hashes to " << std::string(hex) << ", t = " << r.params.t.transpose()
                                << ", " << r.iterations << " iterations");
}

TEST_CASE("learned tracker: the C++ pipeline ends where PyTorch ends on the committed validation pairs") {
  // The shipped files: the default (s16w64 since session 38; its poses from make_deep_parity.py
  // --skip-near-bound, which leaves out a pair where PyTorch steps past the C++ solver's
  // divergence bound) and s16, the firmware's. Two feature channels a level since session 28;
  // one and four: the next case. And s8w48m8 (session 66, the smaller network), on pairs of its
  // own: on the committed ones two of its three runs step near the divergence bound
  // (make_deep_parity.py --skip-near-bound kept one), so it has its own three pairs and poses.
  struct Parity {
    const char *weights, *vectors, *poses;
  };
  for (const auto& [file, vectors_file, poses_file] :
       {Parity{"weights/deep_iclk_s16w64.tlw", "tests/data/nn/deep_parity.tlw", "tests/data/nn/deep_parity_s16w64.tlw"},
        Parity{"weights/deep_iclk_s16.tlw", "tests/data/nn/deep_parity.tlw", "tests/data/nn/deep_parity.tlw"},
        Parity{"weights/deep_iclk_s8w48m8.tlw", "tests/data/nn/deep_parity_s8w48m8.tlw",
               "tests/data/nn/deep_parity_s8w48m8.tlw"}}) {
    const nn::WeightFile vectors = load(vectors_file);
    int pairs = 0;
    while (vectors.find("ref_" + std::to_string(pairs))) ++pairs;
    REQUIRE(pairs == 3);
    const nn::WeightFile weights = load(file);
    const nn::WeightFile poses = load(poses_file);
    int checked = 0;
    for (int k = 0; k < pairs; ++k) {
      if (!poses.find("R_" + std::to_string(k))) continue;
      Pair p = pair_of(vectors, k);
      read_pose(poses, k, p);
      check_parity(weights, p, 2, std::string(file) + ", pair " + std::to_string(k));
      ++checked;
    }
    CHECK(checked >= 2);
  }
}

namespace {

// The weights with each level's features grouped into `channels` (export_deep.py's
// 'mean fL IN G' for train_deep.py --channels G; no G is one group): the same tensors, another
// network.
nn::WeightFile grouped(nn::WeightFile w, int channels) {
  std::string& a = w.architecture;
  int levels = 0;
  for (std::size_t at = a.find("\nmean f"); at != std::string::npos; at = a.find("\nmean f", at + 1), ++levels) {
    const std::size_t end = a.find('\n', at + 1);
    const std::size_t input = a.find(' ', at + 6);  // the space after "mean fL"
    const std::size_t group = std::min(a.find(' ', input + 1), end);
    a.replace(group, end - group, " " + std::to_string(channels));
  }
  REQUIRE(levels == 5);
  return w;
}

}  // namespace

TEST_CASE("learned tracker: with one and with four feature channels a level the C++ pipeline ends where PyTorch ends") {
  // training/make_deep_parity.py weights/deep_iclk_s16.tlw tests/data/nn/deep_parity.tlw
  // tests/data/nn/deep_parity_cK.tlw --channels K: the same pairs, PyTorch's poses with the
  // shipped tensors' outputs averaged in K groups in place of the shipped two (each channel
  // normalised on its own, the residual and Jacobians per channel, one weight a pixel from the
  // channels' RMS residual and means). With the shipped file above, every solver the learned
  // tracker instantiates (1, 2 and 4 channels) has PyTorch's answer to meet.
  const nn::WeightFile pairs = load("tests/data/nn/deep_parity.tlw");
  for (const int channels : {1, 4}) {
    const nn::WeightFile weights = grouped(load("weights/deep_iclk_s16.tlw"), channels);
    const nn::WeightFile poses = load(channels == 1 ? "tests/data/nn/deep_parity_c1.tlw" : "tests/data/nn/deep_parity_c4.tlw");
    int n = 0;
    for (; poses.find("R_" + std::to_string(n)); ++n) {
      Pair p = pair_of(pairs, n);
      const Eigen::Vector3d shipped_t = p.t;
      read_pose(poses, n, p);
      const iclk::SE3<double> T =
          check_parity(weights, p, channels, "pair " + std::to_string(n) + ", " + std::to_string(channels) + " channels");
      // Not the shipped answer: the grouping changed the features, not only their layout
      // (PyTorch's answers differ from the shipped ones by 0.6-4.5 m here, and the C++ follows
      // each within 3 mm).
      CHECK((T.t - shipped_t).norm() > 0.1);
    }
    CHECK(n == 3);
  }
}

TEST_CASE("learned tracker: refuses feature channels it has no solver for, naming them") {
  const nn::WeightFile shipped = shipped_weights();
  auto two = iclk::DeepAligner::create(grouped(shipped, 2), 192, 128, options(), 1);
  REQUIRE_MESSAGE(two.ok(), (two.ok() ? "" : two.error().message));
  CHECK(two.value()->channels() == 2);
  auto eight = iclk::DeepAligner::create(grouped(shipped, 8), 192, 128, options(), 1);
  REQUIRE_FALSE(eight.ok());
  MESSAGE(eight.error().message);
  CHECK(eight.error().message.find("have 8 channels a level; the learned tracker runs 1, 2 or 4") != std::string::npos);
  auto three = iclk::DeepAligner::create(grouped(shipped, 3), 192, 128, options(), 1);  // 16 outputs at level 0
  REQUIRE_FALSE(three.ok());
  CHECK(three.error().message.find("3 groups do not divide 16 channels") != std::string::npos);
}

TEST_CASE("learned tracker: same bytes on 1 and 2 threads, and no heap allocation per pair") {
  const nn::WeightFile weights = shipped_weights();
  const nn::WeightFile vectors = load("tests/data/nn/deep_parity.tlw");
  const Pair p = pair_of(vectors, 0);
  auto one = iclk::DeepAligner::create(weights, p.ref.width(), p.ref.height(), options(), 1);
  auto two = iclk::DeepAligner::create(weights, p.ref.width(), p.ref.height(), options(), 2);
  REQUIRE(one.ok());
  REQUIRE(two.ok());
  const auto a = one.value()->align(p.ref.view(), p.depth.view(), p.live.view(), p.K, iclk::SE3<float>::identity());
  long allocations = 0;
  iclk::TrackResult<iclk::DeepAligner::Warp> b;
  {
    test::AllocationCounter count;
    b = two.value()->align(p.ref.view(), p.depth.view(), p.live.view(), p.K, iclk::SE3<float>::identity());
    allocations = count.allocations();
  }
  CHECK(allocations == 0);
  test::check_same_answer(a, b);
}

TEST_CASE("learned tracker: align_to aligns the last live image to another reference as align() would, allocating nothing") {
  // What a map of several layers does (cli::Localizer): the live image is encoded once, for the
  // first layer's reference; the next layer's reference is aligned to those features. Pair 1's
  // reference stands for the first layer, a refine() against it in between (it runs fewer
  // levels and must leave the live features of the others alone), then pair 0's reference.
  const nn::WeightFile weights = shipped_weights();
  const nn::WeightFile vectors = load("tests/data/nn/deep_parity.tlw");
  const Pair p = pair_of(vectors, 0), other = pair_of(vectors, 1);
  REQUIRE(other.ref.width() == p.ref.width());
  REQUIRE(other.ref.height() == p.ref.height());
  auto fresh = iclk::DeepAligner::create(weights, p.ref.width(), p.ref.height(), options(), 2);
  auto kept = iclk::DeepAligner::create(weights, p.ref.width(), p.ref.height(), options(), 2);
  REQUIRE(fresh.ok());
  REQUIRE(kept.ok());
  const auto a = fresh.value()->align(p.ref.view(), p.depth.view(), p.live.view(), p.K, iclk::SE3<float>::identity());
  REQUIRE(a.converged);  // a pair PyTorch aligns: a comparison of answers, not of two failures
  kept.value()->align(other.ref.view(), other.depth.view(), p.live.view(), other.K, iclk::SE3<float>::identity());
  kept.value()->refine(other.ref.view(), other.depth.view(), other.K, 2);
  long allocations = 0;
  iclk::TrackResult<iclk::DeepAligner::Warp> b;
  {
    test::AllocationCounter count;
    b = kept.value()->align_to(p.ref.view(), p.depth.view(), p.K, iclk::SE3<float>::identity());
    allocations = count.allocations();
  }
  CHECK(allocations == 0);
  CHECK(b.converged);
  test::check_same_answer(a, b);
}

TEST_CASE("learned tracker: refuses a size too small for its levels and another network's weights") {
  const nn::WeightFile weights = shipped_weights();
  auto small = iclk::DeepAligner::create(weights, 188, 100, options(), 1);
  REQUIRE_FALSE(small.ok());
  CHECK(small.error().message.find("188 x 100") != std::string::npos);
  // Lv et al.'s converted checkpoint has an encoder of 8 input channels: not this pipeline's.
  const nn::WeightFile lv = load("weights/lv19_tum_abc.tlw");
  auto other = iclk::DeepAligner::create(lv, 192, 128, options(), 1);
  REQUIRE_FALSE(other.ok());
  MESSAGE(other.error().message);
}

namespace {

// The weights with a line added to their header, after `# levels`.
nn::WeightFile with_line(nn::WeightFile w, const std::string& line) {
  const auto at = w.architecture.find("# levels ");
  REQUIRE(at != std::string::npos);
  w.architecture.insert(w.architecture.find('\n', at) + 1, line + "\n");
  return w;
}

}  // namespace

TEST_CASE("learned tracker: the converged tests read their thresholds from the weights and fail an answer") {
  const nn::WeightFile shipped = shipped_weights();
  // The shipped weights carry the agreement test's threshold (training/calibrate_sharpness.py
  // --test agreement) and, since it replaced it (docs/history.md, session 20), no sharpness threshold.
  auto agree = iclk::DeepAligner::max_disagreement(shipped);
  REQUIRE(agree.ok());
  CHECK(agree.value() == doctest::Approx(1.25));
  auto none = iclk::DeepAligner::min_sharpness(shipped);
  REQUIRE(none.ok());
  CHECK(none.value() == 0.0);
  const nn::WeightFile weights = with_line(shipped, "# min-sharpness 1.020");
  auto threshold = iclk::DeepAligner::min_sharpness(weights);
  REQUIRE(threshold.ok());
  CHECK(threshold.value() == doctest::Approx(1.020));
  const nn::WeightFile vectors = load("tests/data/nn/deep_parity.tlw");
  const Pair p = pair_of(vectors, 0);
  auto run = [&](double min_sharpness, double max_disagreement) {
    iclk::TrackerOptions o = parity_options();  // the answer PyTorch also reaches
    o.min_sharpness = min_sharpness;
    o.max_disagreement_px = max_disagreement;
    auto D = iclk::DeepAligner::create(weights, p.ref.width(), p.ref.height(), o, 1);
    REQUIRE(D.ok());
    return D.value()->align(p.ref.view(), p.depth.view(), p.live.view(), p.K, iclk::SE3<float>::identity());
  };
  // A right same-year answer sits in a narrow valley: its residual 2 px away is higher, and a
  // start 2 px away in u and v comes back to it.
  const auto right = run(0, 0);  // the weights' thresholds
  CHECK(right.converged);
  CHECK(right.sharpness >= threshold.value());
  CHECK(right.disagreement_px <= agree.value());
  MESSAGE("same year: sharpness " << right.sharpness << ", the second start settles " << right.disagreement_px << " px away");
  // Asked for more than the answer has, either test reports it as failed, with the prior
  // returned; a negative threshold turns a test off and the answer stands.
  for (const auto& strict : {run(right.sharpness * 1.01, -1), run(-1, right.disagreement_px * 0.99)}) {
    CHECK_FALSE(strict.converged);
    CHECK(std::string(strict.reason).rfind("ambiguous", 0) == 0);
    CHECK(strict.params.t.norm() == 0.0f);
  }
  CHECK_FALSE(right.unconfirmed);
  // The agreement test alone failing keeps the answer it measured as unconfirmed (a track with
  // no velocity yet may start from it), its covariance scaled by the square of how many times
  // the threshold the second start settled away: here 1 / 0.99. The sharpness test's failure
  // keeps none.
  CHECK_FALSE(run(right.sharpness * 1.01, -1).unconfirmed);
  const auto unsure = run(-1, right.disagreement_px * 0.99);
  REQUIRE(unsure.unconfirmed);
  CHECK(unsure.unconfirmed_params.R == right.params.R);
  CHECK(unsure.unconfirmed_params.t == right.params.t);
  const double scale = 1 / (0.99 * 0.99);
  for (int i = 0; i < 6; ++i) CHECK(unsure.unconfirmed_covariance(i, i) == doctest::Approx(right.covariance(i, i) * scale).epsilon(1e-9));
  const auto off = run(-1, -1);
  CHECK(off.converged);
  // With its test off the sharpness probe does not run (0: not measured), and the answer is
  // the one the probe's run gave: the probe only measures.
  CHECK(off.sharpness == 0);
  CHECK(off.params.R == right.params.R);
  CHECK(off.params.t == right.params.t);
  // A weight file with a malformed threshold or start is refused, naming the line.
  for (const char* line : {"# min-sharpness nan", "# max-disagreement-px 0", "# agree-px 0", "# agree-px 11"}) {
    auto refused = iclk::DeepAligner::create(with_line(shipped, line), p.ref.width(), p.ref.height(), options(), 1);
    REQUIRE_FALSE(refused.ok());
    CHECK(refused.error().message.find(line) != std::string::npos);
  }
}

TEST_CASE("learned tracker: the agreement test starts where the weight file's threshold was calibrated") {
  // The threshold is calibrated for one start (training/calibrate_sharpness.py --agree-px),
  // which a file carries as `# agree-px`; a file without the line, as both shipped files
  // (session 55 took the default file's 1 px start of session 54 back), starts kAgreePx away.
  for (const char* path : {"weights/deep_iclk_s16w64.tlw", "weights/deep_iclk_s16.tlw"}) {
    CAPTURE(path);
    auto start = iclk::DeepAligner::agree_px(load(path));
    REQUIRE(start.ok());
    CHECK(start.value() == iclk::DeepAligner::kAgreePx);
  }
  const nn::WeightFile s16 = load("weights/deep_iclk_s16.tlw");
  // The file's start reaches the tracker: the same run as the options' start, and another
  // measure than kAgreePx's (a second start from elsewhere stops elsewhere).
  const nn::WeightFile vectors = load("tests/data/nn/deep_parity.tlw");
  const Pair p = pair_of(vectors, 0);
  auto run = [&](const nn::WeightFile& w, double agree_px) {
    iclk::TrackerOptions o = parity_options();
    o.agree_px = agree_px;
    o.max_disagreement_px = -1;  // measured, not tested
    auto D = iclk::DeepAligner::create(w, p.ref.width(), p.ref.height(), o, 1);
    REQUIRE(D.ok());
    return D.value()->align(p.ref.view(), p.depth.view(), p.live.view(), p.K, iclk::SE3<float>::identity());
  };
  const auto by_file = run(with_line(s16, "# agree-px 0.5"), 0);
  const auto by_options = run(s16, 0.5);
  const auto by_default = run(s16, 0);
  REQUIRE(by_file.converged);
  CHECK(by_file.disagreement_px == by_options.disagreement_px);
  CHECK(by_file.disagreement_px != by_default.disagreement_px);
  CHECK(by_file.params.t == by_default.params.t);  // the answer itself is the same
}

TEST_CASE("learned tracker: with an attitude reference the agreement test takes the file's attitude threshold") {
  constexpr double kDeg = 3.14159265358979323846 / 180;
  // The shipped file carries both (training/calibrate_sharpness.py --test agreement-attitude);
  // a tilt prior of at most kAttitudeTiltPriorDeg takes the attitude one, a rough pose's (the
  // default 3 degrees) or none the plain one.
  const nn::WeightFile shipped = shipped_weights();
  auto threshold = [](const nn::WeightFile& w, double tilt_prior_deg) {
    auto t = iclk::DeepAligner::max_disagreement(w, tilt_prior_deg * kDeg);
    REQUIRE(t.ok());
    return t.value();
  };
  CHECK(threshold(shipped, 0) == doctest::Approx(1.25));
  CHECK(threshold(shipped, 3) == doctest::Approx(1.25));
  CHECK(threshold(shipped, 1.01) == doctest::Approx(1.25));
  CHECK(threshold(shipped, 1) == doctest::Approx(1.35));
  CHECK(threshold(shipped, 0.5) == doctest::Approx(1.35));
  // A file without the line (s16, the firmware's) keeps its plain threshold with an IMU too.
  const nn::WeightFile s16 = load("weights/deep_iclk_s16.tlw");
  CHECK(threshold(s16, 0.5) == threshold(s16, 0));
  CHECK(threshold(s16, 0) > 0);
  // The tracker tests with it: an attitude threshold the answer does not meet fails the right
  // answer only where the tilt prior is an attitude reference's (no up vector is set, so the
  // prior itself does not act and the answer is the same).
  const nn::WeightFile strict = with_line(s16, "# max-disagreement-px-attitude 1e-9");
  const nn::WeightFile vectors = load("tests/data/nn/deep_parity.tlw");
  const Pair p = pair_of(vectors, 0);
  const auto rough = align_with_priors(strict, p, 3 * kDeg, 0), imu = align_with_priors(strict, p, 0.5 * kDeg, 0);
  REQUIRE(rough.disagreement_px > 1e-9);  // this synthetic pair's second start settles 2e-6 px away
  CHECK(rough.converged);
  CHECK_FALSE(imu.converged);
  CHECK(std::string(imu.reason).rfind("ambiguous", 0) == 0);
  CHECK(imu.disagreement_px == rough.disagreement_px);
  // A malformed attitude threshold is refused, naming the line.
  const std::string bad = "# max-disagreement-px-attitude 0";
  auto refused = iclk::DeepAligner::create(with_line(s16, bad), p.ref.width(), p.ref.height(), options(), 1);
  REQUIRE_FALSE(refused.ok());
  CHECK(refused.error().message.find(bad) != std::string::npos);
}

TEST_CASE("learned tracker: with an attitude reference and an altimeter the agreement test takes the file's threshold for both") {
  constexpr double kDeg = 3.14159265358979323846 / 180;
  // The shipped file's third threshold (training/calibrate_sharpness.py --test
  // agreement-attitude-altimeter) takes over where the tilt prior is an attitude reference's
  // and the altitude prior at most kAltimeterPriorM; an altimeter without an attitude
  // reference, or a looser one, leaves the threshold the tilt prior alone gives.
  const nn::WeightFile shipped = shipped_weights();
  auto threshold = [](const nn::WeightFile& w, double tilt_prior_deg, double altitude_prior_m) {
    auto t = iclk::DeepAligner::max_disagreement(w, tilt_prior_deg * kDeg, altitude_prior_m);
    REQUIRE(t.ok());
    return t.value();
  };
  const double bound = iclk::DeepAligner::kAltimeterPriorM;
  CHECK(threshold(shipped, 0.5, 2) == doctest::Approx(1.60));
  CHECK(threshold(shipped, 1, bound) == doctest::Approx(1.60));
  CHECK(threshold(shipped, 0.5, bound * 1.01) == doctest::Approx(1.35));
  CHECK(threshold(shipped, 0.5, 0) == doctest::Approx(1.35));
  CHECK(threshold(shipped, 3, 2) == doctest::Approx(1.25));
  CHECK(threshold(shipped, 0, 2) == doctest::Approx(1.25));
  // A file without the line keeps the attitude's (or its plain) threshold.
  const nn::WeightFile s16 = load("weights/deep_iclk_s16.tlw");
  CHECK(threshold(s16, 0.5, 2) == threshold(s16, 0.5, 0));
  // The tracker tests with it: a threshold the answer does not meet fails the right answer
  // only with both priors (no up vector or height is set, so neither prior acts and the
  // answer is the same).
  const nn::WeightFile strict = with_line(s16, "# max-disagreement-px-attitude-altimeter 1e-9");
  const nn::WeightFile vectors = load("tests/data/nn/deep_parity.tlw");
  const Pair p = pair_of(vectors, 0);
  const auto imu = align_with_priors(strict, p, 0.5 * kDeg, 0), both = align_with_priors(strict, p, 0.5 * kDeg, 2);
  REQUIRE(imu.disagreement_px > 1e-9);
  CHECK(imu.converged);
  CHECK_FALSE(both.converged);
  CHECK(std::string(both.reason).rfind("ambiguous", 0) == 0);
  CHECK(both.disagreement_px == imu.disagreement_px);
  const std::string bad = "# max-disagreement-px-attitude-altimeter nan";
  auto refused = iclk::DeepAligner::create(with_line(s16, bad), p.ref.width(), p.ref.height(), options(), 1);
  REQUIRE_FALSE(refused.ok());
  CHECK(refused.error().message.find(bad) != std::string::npos);
}
