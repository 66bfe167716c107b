// The learned tracker: the encoder (src/nn) turns the reference and the live image into a
// pyramid of features (one channel a level, or 2 or 4: the weight file's `mean fL IN G`, each
// channel normalised on its own, one weight a pixel for all of them), the M-estimator (src/nn)
// weights each pixel when a level starts, and the inverse-compositional LM (src/iclk) aligns
// coarse to fine. The same
// mathematics as training/deep_iclk.py, which trains the weights (tests/test_deep_iclk.cpp
// checks the final pose against PyTorch's).
//
// Part of iclk (it links nn): the learned tracker is onboard code, built for every target
// the solver is (a microcontroller included: firmware/).
//
// It works at the weight file's input scale (`# input-scale 0.5`: half the camera's size),
// the size the network was trained at, with the weight file's number of levels (`# levels
// 5`; the encoder outputs f0 .. f<levels-1>, level l of size (w >> l) x (h >> l)).
// Everything is sized by create(); align() allocates nothing.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include <terralign/geo/image.hpp>
#include <terralign/geo/result.hpp>
#include <terralign/iclk/tracker.hpp>
#include <terralign/nn/network.hpp>
#include <terralign/nn/weights.hpp>

namespace terralign::iclk {

class DeepAligner : public iclk::LevelWeights {
 public:
  using Warp = iclk::SE3DepthWarp<float>;
  static constexpr int kMaxLevels = 6;
  // The sharpness test (iclk::TrackResult::sharpness, measured kProbePx finest-level pixels
  // away): its threshold comes from the weight file (`# min-sharpness X`, written by
  // training/calibrate_sharpness.py for those weights: the features of each network differ)
  // unless the options set one (a negative min_sharpness turns it off); weights without the
  // line have no test. The measure is taken where the test is on or the options' probe_px
  // asks for it (0 in TrackResult::sharpness otherwise).
  static constexpr double kProbePx = 2.0;
  // The agreement test (iclk::TrackResult::disagreement_px: where a second start some working
  // pixels away in u and in v settles, after up to 10 finest-level steps): its threshold
  // likewise comes from the weight file (`# max-disagreement-px X`, written by
  // training/calibrate_sharpness.py --test agreement) unless the options set one (negative:
  // off, still measured). The start's offset is the one the threshold was calibrated with:
  // the file's `# agree-px X` (calibrate_sharpness.py --agree-px), kAgreePx where it has none
  // (every shipped file), unless the options set one. On the calibration seed (11) a start
  // 2 px away in each axis separated right from wrong answers of 2009 -> 2020 best by AUC
  // (0.86; 1.5 px 0.86, 3 px 0.85, 5 px too far to come back, 0.42), where the sharpness
  // test's AUC is 0.55-0.58 (README). A start 1 px away (session 54) kept as many right
  // answers of the sample's ten year pairs as 2 px where both pass as many wrong ones, and
  // passed more wrong ones on ground the tracker cannot place (session 55, README "The
  // agreement test's start").
  static constexpr double kAgreePx = 2.0;
  // With an attitude reference, a tilt prior (iclk::TrackerOptions::tilt_prior_rad) of at most
  // kAttitudeTiltPriorDeg, the agreement threshold is the file's `# max-disagreement-px-attitude
  // X` where it has one (calibrate_sharpness.py --test agreement-attitude: the widest threshold
  // whose passed answers of 2009 -> 2020 with an IMU's tilt, seed 11, are right as often as
  // the plain threshold's without it), else its `# max-disagreement-px`. Held to an IMU's tilt
  // the tracker trades less tilt for shift, and its wrong answers' second starts drift further:
  // on the calibration poses (1000) the plain 1.25 px passes 98.9 % right answers without the
  // IMU, 99.6 % with it; 1.35 px passes 99.3 % with it (README, "The agreement test with an
  // attitude reference", session 59). A rough pose's tilt (the default 3 degrees) is not one.
  static constexpr double kAttitudeTiltPriorDeg = 1.0;
  // With an altimeter too, an altitude prior (iclk::TrackerOptions::altitude_prior_m) of at
  // most kAltimeterPriorM, the file's `# max-disagreement-px-attitude-altimeter X` where it has
  // one (calibrate_sharpness.py --test agreement-attitude-altimeter, the same rule with
  // `--altimeter 2` added), else the attitude's. Held to the height as well, the right answers
  // settle tighter still: on the calibration poses (1000) 1.60 px passes 879 right and 9 wrong
  // answers with both, the attitude's 1.35 px 797 and 4 (README, "With an altimeter", session
  // 76). An altimeter alone keeps the plain threshold (its own would be 1.30 px: 706 right and 7
  // wrong against 1.25 px's 681 and 6).
  static constexpr double kAltimeterPriorM = 5.0;
  // The coarse search before the first step (TrackerOptions::coarse_search_px and _yaw_deg),
  // unless the options set it (coarse_search_px negative: none): shifts of up to 2
  // coarsest-level pixels, turns of up to 4 degrees. On the calibration seed (11) the shifts
  // took success within 5 px from 89.5 to 91 % (2016 -> 2017; 3 and 4 px did no better) and
  // the turns to 92.5 % (README).
  // The finest level's stop on a step's image motion (iclk::TrackerOptions::min_step_px, in
  // working pixels) unless the options set one (negative: never). Eval, 200 poses of seed 7
  // on each of NAIP 2016/2016, 2016/2017, 2009/2020 and Christchurch 000121: 8-15 % fewer
  // iterations; answers moved by 0.01 px median (full-size 2-D EPE, 0.12 at most), their
  // positions by 3 mm median same year, 0.3-0.4 m across years on NAIP (3.6 m at most, at
  // 700-900 m) and 5 cm on Christchurch (at 100-140 m), under 0.15 of their stated sigma. No
  // converged flag changed, and two answers 4.99 px off crossed to 5.03-5.04. 0.005 px saved
  // 5-12 %; 0.02 px 10-18 % but failed two right answers, whose agreement test's second start
  // then stopped short (session 43).
  static constexpr double kMinStepPx = 0.01;
  static constexpr int kCoarseSearchPx = 2;
  static constexpr double kCoarseSearchYawDeg = 4.0;

  // width x height: the working size (the images align() takes). `options`: the tracker's;
  // levels, block and normalize are set here (the weights' levels, every pixel, normalised
  // features).
  // `levels` > 0 uses that many of the weights' levels (fewer: a small image whose coarsest
  // level would be under 8 pixels); 0 all of them.
  // `pool`: the caller's pool to run on (its thread count replaces `threads`; as
  // nn::Network::plan's: it outlives the aligner and no one else runs on it meanwhile), such
  // as the renderer's of the same pipeline; else the aligner starts a pool of its own.
  static Result<std::unique_ptr<DeepAligner>> create(const nn::WeightFile& weights, int width, int height,
                                                     const iclk::TrackerOptions& options, int threads,
                                                     int levels = 0, ThreadPool* pool = nullptr);
  // The input scale a weight file asks for (0.5 when it says nothing) and its levels (4).
  static Result<double> input_scale(const nn::WeightFile& weights);
  static Result<int> levels(const nn::WeightFile& weights);
  static Result<double> min_sharpness(const nn::WeightFile& weights);  // 0: none
  // The agreement threshold for a tilt prior of `tilt_prior_rad` and an altitude prior of
  // `altitude_prior_m` (0: none; see kAttitudeTiltPriorDeg and kAltimeterPriorM); 0: none.
  static Result<double> max_disagreement(const nn::WeightFile& weights, double tilt_prior_rad = 0,
                                         double altitude_prior_m = 0);
  static Result<double> agree_px(const nn::WeightFile& weights);  // kAgreePx where none

  // ref_rgb, live_rgb: 3-channel, 0..255; ref_depth: metres, NaN where none; K: pinhole of
  // the working size; init: T_live_ref to start from.
  const iclk::TrackResult<Warp>& align(ImageView<const float> ref_rgb, ImageView<const float> ref_depth,
                                       ImageView<const float> live_rgb, const iclk::Pinhole<float>& K,
                                       const iclk::SE3<float>& init);
  // Aligns the last align()'s live image to another reference (another layer of the map, from
  // the same start): as align(), but the live image's features are the last align()'s, not
  // encoded again, which is the live half of the encoder's time. The answer is align()'s with
  // that live image, bit for bit.
  const iclk::TrackResult<Warp>& align_to(ImageView<const float> ref_rgb, ImageView<const float> ref_depth,
                                          const iclk::Pinhole<float>& K, const iclk::SE3<float>& init);
  // Aligns again from a reference rendered where the last align() or refine() ended (its
  // depth and the same K): the reference is encoded anew, the live image's features are the
  // last align()'s, and only the finest `levels` levels run, from the identity, with no coarse
  // search (the start is a pixel or so from the answer). The learned minimum trades a tilt for
  // a shift a little (the weakest direction of a nadir view): answers started 0.8 degree of tilt
  // from their reference kept 0.09-0.16 degree of it, and a reference rendered at the answer
  // takes most of that out (docs/history.md, "Session 29").
  // `learned_weights` false: every pixel weighs the same, and the M-estimator (at the finest
  // level about a third of a pass's time) does not run; for answers whose image already agrees
  // with the map, where it has nothing to reject (the localizer's kRefineUniformMaxResidual).
  // `agreement` true: the pass keeps the agreement test of the options (agree_px,
  // max_disagreement_px; no other converged test), as a second look at an answer that failed
  // it runs (cli::Localizer::set_second_look); its failure is the test's, with the answer
  // unconfirmed (iclk::TrackResult::unconfirmed).
  const iclk::TrackResult<Warp>& refine(ImageView<const float> ref_rgb, ImageView<const float> ref_depth,
                                        const iclk::Pinhole<float>& K, int levels, bool learned_weights = true,
                                        bool agreement = false);
  void set_iterations(int n);
  // The map's own error on the ground (iclk::TrackerOptions::ground_floor_m), for a caller
  // that aligns to references of several layers, each with its own.
  void set_ground_floor_m(double m);
  // The world's up in the reference camera (iclk::Tracker::set_up), for the tilt prior.
  void set_up(const Eigen::Vector3d& up_in_reference, const Eigen::Vector3d& tilt = Eigen::Vector3d::Zero()) {
    std::visit([&](auto& t) { t->set_up(up_in_reference, tilt); }, tracker_);
  }
  // The altimeter's height above the reference camera (iclk::Tracker::set_height).
  void set_height(double height) {
    std::visit([&](auto& t) { t->set_height(height); }, tracker_);
  }
  int level_count() const { return levels_; }
  int channels() const { return channels_; }  // feature channels a level
  // The weights of each level from the last align() (level 0 finest), for figures and tests.
  const ImageF& weights_of(int level) const { return w_[static_cast<std::size_t>(level)]; }
  double ms_encoder() const { return ms_encoder_; }
  double ms_mestimator() const { return ms_mest_; }

  void weights(int level, ImageView<const float> abs_r, ImageView<const float> ref, ImageView<const float> live,
               ImageView<float> out) override;

 private:
  DeepAligner() = default;
  // An encoder network and its tensors, looked up once: the input and each level's output.
  struct Encoder {
    std::unique_ptr<nn::Network> net;
    nn::Tensor* in = nullptr;
    std::array<const nn::Tensor*, kMaxLevels> out{};
  };
  // Encodes the finest `levels` levels of rgb by e on `pool` into out (the encoder stops at
  // the last step they need).
  void encode(const Encoder& e, ThreadPool& pool, ImageView<const float> rgb, std::array<ImageF, kMaxLevels>& out,
              int levels);
  // The reference into ref_f_ and the live image into live_f_, every level: at once, one
  // image a thread, where the pool has two threads (enc_[1] exists); else one after the
  // other, each on the whole pool.
  void encode_pair(ImageView<const float> ref_rgb, ImageView<const float> live_rgb);
  // align()'s and align_to()'s solve over every level; live_rgb null: the last live features.
  const iclk::TrackResult<Warp>& align_all(ImageView<const float> ref_rgb, ImageView<const float> ref_depth,
                                           const ImageView<const float>* live_rgb, const iclk::Pinhole<float>& K,
                                           const iclk::SE3<float>& init);
  bool live_encoded_ = false;  // an align() has encoded a live image (align_to() may run)
  // Changes the tracker's options in place (whichever channel count it was built for).
  template <class F>
  void update_options(F change) {
    std::visit(
        [&](auto& t) {
          auto o = t->options();
          change(o);
          t->set_options(o);
        },
        tracker_);
  }
  int width_ = 0, height_ = 0, levels_ = 0, channels_ = 1;
  // One pool for the encoder, the M-estimators and the solver, which run one after another:
  // the caller's or own_pool_ (declared first: it outlives them).
  std::unique_ptr<ThreadPool> own_pool_;
  ThreadPool* pool_ = nullptr;
  // enc_[0] encodes every reference, and the live image where enc_[1] does not exist. On a
  // pool of two threads enc_[1], with memory of its own, encodes the live image while enc_[0]
  // encodes the reference, each on one thread (solo_[i], a pool of one: the thread the task
  // runs on): the coarse levels' layers are too small to split well over two threads, and
  // each layer's hand-over costs a wait. The rows are computed as on the whole pool, so the
  // bytes are the same.
  std::array<Encoder, 2> enc_;
  std::array<std::unique_ptr<ThreadPool>, 2> solo_;
  std::array<int, kMaxLevels> enc_until_{};  // [l]: the last encoder step levels 0..l need
  std::array<std::unique_ptr<nn::Network>, kMaxLevels> mest_;
  // Each level's M-estimator input and output, looked up once.
  std::array<nn::Tensor*, kMaxLevels> mest_in_{};
  std::array<const nn::Tensor*, kMaxLevels> mest_out_{};
  std::vector<float> scratch_;  // the tensors of every network but enc_[1] (nn::Memory::External)
  std::array<ImageF, kMaxLevels> ref_f_, live_f_, w_;
  std::array<ImageView<const float>, kMaxLevels> ref_v_, live_v_;
  ImageF up_;
  // The solver for the weights' channel count.
  std::variant<std::unique_ptr<iclk::Tracker<float, Warp, 1>>, std::unique_ptr<iclk::Tracker<float, Warp, 2>>,
               std::unique_ptr<iclk::Tracker<float, Warp, 4>>>
      tracker_;
  double ms_encoder_ = 0, ms_mest_ = 0;
};

}  // namespace terralign::iclk
