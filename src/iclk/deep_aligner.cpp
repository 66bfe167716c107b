#include <terralign/iclk/deep_aligner.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <sstream>
#include <utility>

#include <terralign/geo/float_environment.hpp>
#include <terralign/geo/number_text.hpp>

namespace terralign::iclk {
namespace {

// Lv et al.'s colour normalisation, as training/deep_iclk.py.
constexpr float kMean[3] = {0.4914f, 0.4822f, 0.4465f};
constexpr float kStd[3] = {0.2023f, 0.1994f, 0.2010f};

double elapsed_ms(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// The value of a "# key value" comment line of the architecture text, if any.
bool comment_value(const nn::WeightFile& weights, const std::string& key, std::string& line, double& value) {
  std::istringstream in(weights.architecture);
  const std::string prefix = "# " + key + " ";
  while (std::getline(in, line)) {
    if (line.compare(0, prefix.size(), prefix) != 0) continue;
    // The value is the first word after the key (geo::parse_double: whatever the locale).
    const std::size_t from = std::min(line.find_first_not_of(' ', prefix.size()), line.size());
    const auto v = geo::parse_double(line.substr(from, line.find(' ', from) - from));
    value = v.ok() ? v.value() : NAN;
    return true;
  }
  return false;
}

// Bilinear resize of one channel, PyTorch's interpolate(size, align_corners = False): the
// source coordinate of output pixel i is (i + 0.5) in / out - 0.5, clamped at 0. Row y of
// the output.
void resize_bilinear_row(const ImageF& in, ImageF& out, int w, int h, int y) {
  auto src = [](int i, int n_in, int n_out, int& i0, int& i1, float& f) {
    float s = (static_cast<float>(i) + 0.5f) * (static_cast<float>(n_in) / static_cast<float>(n_out)) - 0.5f;
    s = std::max(s, 0.0f);
    i0 = std::min(static_cast<int>(s), n_in - 1);
    i1 = std::min(i0 + 1, n_in - 1);
    f = s - static_cast<float>(i0);
  };
  int ya, yb;
  float fy;
  src(y, in.height(), h, ya, yb, fy);
  for (int x = 0; x < w; ++x) {
    int xa, xb;
    float fx;
    src(x, in.width(), w, xa, xb, fx);
    const float a = in.at(xa, ya), b = in.at(xb, ya), c = in.at(xa, yb), d = in.at(xb, yb);
    out.at(x, y) = (1.0f - fy) * ((1.0f - fx) * a + fx * b) + fy * ((1.0f - fx) * c + fx * d);
  }
}

}  // namespace

Result<double> DeepAligner::input_scale(const nn::WeightFile& weights) {
  std::string line;
  double s = 0.5;
  if (comment_value(weights, "input-scale", line, s) && !(s > 0 && s <= 1))
    return Error{weights.name + ": '" + line + "': the input scale must be in (0, 1]"};
  return s;
}

Result<int> DeepAligner::levels(const nn::WeightFile& weights) {
  std::string line;
  double n = 4;
  if (comment_value(weights, "levels", line, n) && !(n >= 1 && n <= kMaxLevels && n == std::floor(n)))
    return Error{weights.name + ": '" + line + "': levels must be an integer in [1, " + std::to_string(kMaxLevels) + "]"};
  return static_cast<int>(n);
}

Result<double> DeepAligner::min_sharpness(const nn::WeightFile& weights) {
  std::string line;
  double v = 0;
  if (comment_value(weights, "min-sharpness", line, v) && !(v >= 0 && v <= 10))
    return Error{weights.name + ": '" + line + "': the sharpness threshold must be in [0, 10]"};
  return v;
}

Result<double> DeepAligner::max_disagreement(const nn::WeightFile& weights, double tilt_prior_rad,
                                             double altitude_prior_m) {
  std::string line;
  double plain = 0, attitude = 0, altimeter = 0;
  for (auto [key, v] : {std::pair{"max-disagreement-px", &plain}, std::pair{"max-disagreement-px-attitude", &attitude},
                        std::pair{"max-disagreement-px-attitude-altimeter", &altimeter}})
    if (comment_value(weights, key, line, *v) && !(*v > 0 && *v <= 100))
      return Error{weights.name + ": '" + line + "': the agreement threshold must be in (0, 100] pixels"};
  const bool attitude_reference =
      tilt_prior_rad > 0 && tilt_prior_rad <= kAttitudeTiltPriorDeg * (3.14159265358979323846 / 180);
  const bool altimeter_reference = altitude_prior_m > 0 && altitude_prior_m <= kAltimeterPriorM;
  if (attitude_reference && altimeter_reference && altimeter > 0) return altimeter;
  return attitude_reference && attitude > 0 ? attitude : plain;
}

Result<double> DeepAligner::agree_px(const nn::WeightFile& weights) {
  std::string line;
  double v = kAgreePx;
  if (comment_value(weights, "agree-px", line, v) && !(v > 0 && v <= 10))
    return Error{weights.name + ": '" + line + "': the agreement test's start must be in (0, 10] pixels"};
  return v;
}

Result<std::unique_ptr<DeepAligner>> DeepAligner::create(const nn::WeightFile& weights, int width, int height,
                                                         const iclk::TrackerOptions& options, int threads,
                                                         int use_levels, ThreadPool* pool) {
  const FloatEnvironmentScope float_environment;
  TERRALIGN_TRY_ASSIGN(int levels, DeepAligner::levels(weights));
  if (use_levels < 0 || use_levels > levels)
    return Error{weights.name + ": " + std::to_string(use_levels) + " levels asked of weights with " +
                 std::to_string(levels)};
  if (use_levels > 0) levels = use_levels;
  if ((width >> (levels - 1)) < 8 || (height >> (levels - 1)) < 8)
    return Error{"the learned tracker's working size " + std::to_string(width) + " x " + std::to_string(height) +
                 " is too small for " + std::to_string(levels) + " levels (the coarsest must be at least 8 x 8)"};
  std::unique_ptr<DeepAligner> D(new DeepAligner);
  D->width_ = width;
  D->height_ = height;
  D->levels_ = levels;
  // The encoder and the M-estimators run one after the other and their outputs are copied
  // out at once: one buffer holds the tensors of all of them (the largest network's need).
  D->pool_ = given_or_own(pool, std::max(1, threads), D->own_pool_);
  threads = D->pool_->threads();
  Encoder& enc = D->enc_[0];
  TERRALIGN_TRY_ASSIGN(enc.net, nn::Network::plan(weights, "encoder", width, height, threads, nn::Simd::Auto,
                                                  nn::Memory::External, D->pool_));
  enc.in = enc.net->input("x");
  if (const nn::Tensor* x = enc.in; !x || x->c != 3)
    return Error{weights.name + ": the encoder must take x, 3 channels of normalised RGB" +
                 (x ? " (this one takes " + std::to_string(x->c) + ")" : std::string(" (it has no input x)"))};
  // The channels of every level are f0's: 1, 2 or 4 (the solvers built, tracker.cpp).
  if (const nn::Tensor* f0 = enc.net->output("f0")) {
    if (f0->c != 1 && f0->c != 2 && f0->c != 4)
      return Error{weights.name + ": the encoder's features have " + std::to_string(f0->c) +
                   " channels a level; the learned tracker runs 1, 2 or 4"};
    D->channels_ = f0->c;
  }
  const int C = D->channels_;
  for (int l = 0; l < levels; ++l) {
    const std::string name = "f" + std::to_string(l);
    const nn::Tensor* f = enc.out[static_cast<std::size_t>(l)] = enc.net->output(name);
    if (!f || f->c != C || f->w != width >> l || f->h != height >> l)
      return Error{weights.name + ": the encoder must output " + name + ", " + std::to_string(C) + " channel(s) of " +
                   std::to_string(width >> l) + " x " + std::to_string(height >> l)};
    // The last encoder step the finest l + 1 levels need.
    D->enc_until_[static_cast<std::size_t>(l)] =
        std::max(l > 0 ? D->enc_until_[static_cast<std::size_t>(l - 1)] : -1, enc.net->step_of(name));
    auto& m = D->mest_[static_cast<std::size_t>(l)];
    TERRALIGN_TRY_ASSIGN(m, nn::Network::plan(weights, "mestimator", width >> l, height >> l, threads, nn::Simd::Auto,
                                              nn::Memory::External, D->pool_));
    const nn::Tensor* x = D->mest_in_[static_cast<std::size_t>(l)] = m->input("x");
    const nn::Tensor* w = D->mest_out_[static_cast<std::size_t>(l)] = m->output("w");
    if (!x || x->c != 4 || !w || w->c != 1)
      return Error{weights.name + ": the mestimator must take x (4 channels) and output w (1 channel)"};
    D->ref_f_[static_cast<std::size_t>(l)].resize(width >> l, height >> l, C);
    D->live_f_[static_cast<std::size_t>(l)].resize(width >> l, height >> l, C);
    D->w_[static_cast<std::size_t>(l)].resize(width >> l, height >> l, 1);
    D->ref_v_[static_cast<std::size_t>(l)] = D->ref_f_[static_cast<std::size_t>(l)].view();
    D->live_v_[static_cast<std::size_t>(l)] = D->live_f_[static_cast<std::size_t>(l)].view();
  }
  std::size_t floats = enc.net->external_floats();
  for (int l = 0; l < levels; ++l) floats = std::max(floats, D->mest_[static_cast<std::size_t>(l)]->external_floats());
  D->scratch_.assign(floats + 16, 0.0f);
  float* base = D->scratch_.data();
  while (reinterpret_cast<std::uintptr_t>(base) % 64 != 0) ++base;
  enc.net->bind(base);
  for (int l = 0; l < levels; ++l) D->mest_[static_cast<std::size_t>(l)]->bind(base);
  if (threads == 2) {
    // The live image's encoder, run beside enc_[0] (encode_pair): the same network in memory
    // of its own, as enc_[0]'s description was checked above.
    Encoder& live = D->enc_[1];
    TERRALIGN_TRY_ASSIGN(live.net, nn::Network::plan(weights, "encoder", width, height, threads, nn::Simd::Auto,
                                                     nn::Memory::Shared, D->pool_));
    live.in = live.net->input("x");
    for (int l = 0; l < levels; ++l) live.out[static_cast<std::size_t>(l)] = live.net->output("f" + std::to_string(l));
    for (auto& solo : D->solo_) solo = std::make_unique<ThreadPool>(1);
  }
  D->up_.resize(width, height, 1);  // used at each level's size, as the top-left part
  iclk::TrackerOptions o = options;
  o.levels = levels;
  o.normalize = true;
  o.block.fill(1);
  o.robust = iclk::Robust::None;
  if (o.agree_px == 0) {
    TERRALIGN_TRY_ASSIGN(o.agree_px, DeepAligner::agree_px(weights));
  }
  if (o.min_step_px == 0) o.min_step_px = kMinStepPx;
  if (o.coarse_search_px == 0) o.coarse_search_px = kCoarseSearchPx;
  if (o.coarse_search_yaw_deg == 0) o.coarse_search_yaw_deg = kCoarseSearchYawDeg;
  if (o.coarse_search_px < 0) o.coarse_search_px = 0;  // no search at all
  if (o.min_sharpness == 0) {
    TERRALIGN_TRY_ASSIGN(o.min_sharpness, DeepAligner::min_sharpness(weights));
  }
  if (o.max_disagreement_px == 0) {
    TERRALIGN_TRY_ASSIGN(o.max_disagreement_px, DeepAligner::max_disagreement(weights, o.tilt_prior_rad, o.altitude_prior_m));
  }
  // The sharpness probe (four finest-level residuals, about 2 % of a pair) runs where its test
  // is on, or where the caller asks for the measure (probe_px > 0: eval); negative: never.
  if (o.probe_px == 0 && o.min_sharpness > 0) o.probe_px = kProbePx;
  // Every pixel of four levels: enough work per iteration for the threads to pay off
  // (unlike the sparse classical selection); chunked sums keep the result thread-count free.
  o.threads = threads;
  if (C == 1) D->tracker_ = std::make_unique<iclk::Tracker<float, Warp, 1>>(width, height, o, D->pool_);
  else if (C == 2) D->tracker_ = std::make_unique<iclk::Tracker<float, Warp, 2>>(width, height, o, D->pool_);
  else D->tracker_ = std::make_unique<iclk::Tracker<float, Warp, 4>>(width, height, o, D->pool_);
  return D;
}

void DeepAligner::set_iterations(int n) {
  update_options([n](iclk::TrackerOptions& o) { o.iterations = n; });
}

void DeepAligner::set_ground_floor_m(double m) {
  update_options([m](iclk::TrackerOptions& o) { o.ground_floor_m = m; });
}

void DeepAligner::encode(const Encoder& e, ThreadPool& pool, ImageView<const float> rgb,
                         std::array<ImageF, kMaxLevels>& out, int levels) {
  nn::Tensor* x = e.in;
  for_rows(pool, height_, [&](int y) {
    const float* s = rgb.row(y);
    for (int i = 0; i < width_; ++i, s += 3) {
      float* p = x->at(y, i);
      for (int c = 0; c < 3; ++c) p[c] = (s[c] / 255.0f - kMean[c]) / kStd[c];
    }
  });
  e.net->forward_until(enc_until_[static_cast<std::size_t>(levels - 1)], pool);
  for (int l = 0; l < levels; ++l) {
    const nn::Tensor* f = e.out[static_cast<std::size_t>(l)];
    ImageF& o = out[static_cast<std::size_t>(l)];
    for_rows(pool, f->h, [&](int y) {
      for (int i = 0; i < f->w; ++i)
        for (int c = 0; c < channels_; ++c) o.at(i, y, c) = f->at(y, i)[c];
    });
  }
}

void DeepAligner::encode_pair(ImageView<const float> ref_rgb, ImageView<const float> live_rgb) {
  if (!enc_[1].net) {
    encode(enc_[0], *pool_, ref_rgb, ref_f_, levels_);
    encode(enc_[0], *pool_, live_rgb, live_f_, levels_);
    return;
  }
  // Task 0 on the calling thread, task 1 on the pool's other (ThreadPool::run).
  struct Job {
    DeepAligner* self;
    ImageView<const float> rgb[2];
  } job{this, {ref_rgb, live_rgb}};
  pool_->run(2, [](void* c, int i) {
    auto* j = static_cast<Job*>(c);
    DeepAligner& d = *j->self;
    const auto k = static_cast<std::size_t>(i);
    d.encode(d.enc_[k], *d.solo_[k], j->rgb[k], k == 0 ? d.ref_f_ : d.live_f_, d.levels_);
  }, &job);
}

void DeepAligner::weights(int level, ImageView<const float> abs_r, ImageView<const float> ref,
                          ImageView<const float> live, ImageView<float> out) {
  const auto t0 = std::chrono::steady_clock::now();
  nn::Network& m = *mest_[static_cast<std::size_t>(level)];
  nn::Tensor* x = mest_in_[static_cast<std::size_t>(level)];
  const int w = abs_r.width, h = abs_r.height;
  // The previous (coarser) level's weights (as kept: the networks share their memory)
  // resized to this level (bilinear, align_corners = False); ones at the coarsest level.
  const bool coarsest = level == levels_ - 1;
  // Several channels: the M-estimator sees their means (and abs_r is their RMS residual).
  const float inv = 1.0f / static_cast<float>(channels_);
  auto mean = [this, inv](ImageView<const float> f, int i, int y) {
    if (channels_ == 1) return f.at(i, y);
    float s = 0;
    for (int c = 0; c < channels_; ++c) s += f.at(i, y, c);
    return s * inv;
  };
  for_rows(*pool_, h, [&](int y) {
    if (!coarsest) resize_bilinear_row(w_[static_cast<std::size_t>(level + 1)], up_, w, h, y);
    for (int i = 0; i < w; ++i) {
      float* p = x->at(y, i);
      p[0] = abs_r.at(i, y);
      p[1] = mean(ref, i, y);
      p[2] = mean(live, i, y);
      p[3] = coarsest ? 1.0f : up_.at(i, y);
    }
  });
  m.forward();
  const nn::Tensor* wt = mest_out_[static_cast<std::size_t>(level)];
  ImageF& keep = w_[static_cast<std::size_t>(level)];
  for_rows(*pool_, h, [&](int y) {
    for (int i = 0; i < w; ++i) out.at(i, y) = keep.at(i, y) = wt->at(y, i)[0];
  });
  ms_mest_ += elapsed_ms(t0);
}

const iclk::TrackResult<DeepAligner::Warp>& DeepAligner::align(ImageView<const float> ref_rgb,
                                                               ImageView<const float> ref_depth,
                                                               ImageView<const float> live_rgb,
                                                               const iclk::Pinhole<float>& K,
                                                               const iclk::SE3<float>& init) {
  TERRALIGN_ASSERT(live_rgb.width == width_ && live_rgb.height == height_ && live_rgb.channels == 3,
                   "DeepAligner::align: a live image of another size than the aligner was built for");
  return align_all(ref_rgb, ref_depth, &live_rgb, K, init);
}

const iclk::TrackResult<DeepAligner::Warp>& DeepAligner::align_to(ImageView<const float> ref_rgb,
                                                                  ImageView<const float> ref_depth,
                                                                  const iclk::Pinhole<float>& K,
                                                                  const iclk::SE3<float>& init) {
  TERRALIGN_ASSERT(live_encoded_, "DeepAligner::align_to: no align() has encoded a live image yet");
  return align_all(ref_rgb, ref_depth, nullptr, K, init);
}

const iclk::TrackResult<DeepAligner::Warp>& DeepAligner::align_all(ImageView<const float> ref_rgb,
                                                                   ImageView<const float> ref_depth,
                                                                   const ImageView<const float>* live_rgb,
                                                                   const iclk::Pinhole<float>& K,
                                                                   const iclk::SE3<float>& init) {
  TERRALIGN_ASSERT(ref_rgb.width == width_ && ref_rgb.height == height_ && ref_rgb.channels == 3,
                   "DeepAligner::align, align_to: a reference of another size than the aligner was built for");
  const FloatEnvironmentScope float_environment;
  const auto t0 = std::chrono::steady_clock::now();
  if (live_rgb) encode_pair(ref_rgb, *live_rgb);
  else encode(enc_[0], *pool_, ref_rgb, ref_f_, levels_);
  live_encoded_ = true;
  ms_encoder_ = elapsed_ms(t0);
  ms_mest_ = 0;
  return std::visit(
      [&](auto& t) -> const iclk::TrackResult<Warp>& {
        // Without a live image the solver keeps the live levels of its last alignment, which
        // are live_f_'s: a refine() in between runs fewer levels and leaves them alone.
        return t->align_levels(ref_v_.data(), ref_depth, live_rgb ? live_v_.data() : nullptr, K, init, this);
      },
      tracker_);
}

const iclk::TrackResult<DeepAligner::Warp>& DeepAligner::refine(ImageView<const float> ref_rgb,
                                                                ImageView<const float> ref_depth,
                                                                const iclk::Pinhole<float>& K, int levels,
                                                                bool learned_weights, bool agreement) {
  TERRALIGN_ASSERT(ref_rgb.width == width_ && ref_rgb.height == height_ && ref_rgb.channels == 3,
                   "DeepAligner::refine: an image of another size than the aligner was built for");
  const FloatEnvironmentScope float_environment;
  const auto t0 = std::chrono::steady_clock::now();
  levels = std::max(1, std::min(levels, levels_));
  encode(enc_[0], *pool_, ref_rgb, ref_f_, levels);  // the finest levels alone: the others do not run
  ms_encoder_ = elapsed_ms(t0);
  ms_mest_ = 0;
  return std::visit(
      [&](auto& t) -> const iclk::TrackResult<Warp>& {
        const iclk::TrackerOptions keep = t->options();
        iclk::TrackerOptions o = iclk::refinement_options(keep, levels);
        if (agreement) {
          o.agree_px = keep.agree_px;
          o.max_disagreement_px = keep.max_disagreement_px;
        }
        t->set_options(o);
        // The live levels are the last align()'s, already in the solver.
        // Without the M-estimator every pixel weighs 1 (the options' robust loss is None).
        const auto& r = t->align_levels(ref_v_.data(), ref_depth, nullptr, K, iclk::SE3<float>::identity(),
                                        learned_weights ? this : nullptr);
        t->set_options(keep);
        return r;
      },
      tracker_);
}

}  // namespace terralign::iclk
