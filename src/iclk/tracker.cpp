#include <terralign/iclk/tracker.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include <terralign/geo/cpu.hpp>
#include <terralign/geo/float_environment.hpp>
#include <terralign/geo/numeric.hpp>

#include "evaluate_kernels.hpp"

namespace terralign::iclk {
namespace {

using Clock = std::chrono::steady_clock;
double ms(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

// Whether two parameter sets are the same bits (an SE(3) pose or a homography's matrix).
template <class S>
bool same_params(const SE3<S>& a, const SE3<S>& b) {
  return a.R == b.R && a.t == b.t;
}
template <class M>
bool same_params(const M& a, const M& b) {
  return a == b;
}

// Zero mean, unit variance per channel over the pixels where `mask` (if given) is finite.
// One pass over the pixels sums every channel, each channel's sums in pixel order.
template <int C>
void normalize(ImageF& img, const ImageF* mask) {
  const std::size_t pixels = img.size() / C;
  float* d = img.data();
  const float* m = mask ? mask->data() : nullptr;
  double s[C] = {}, s2[C] = {};
  long n = 0;
  for (std::size_t k = 0; k < pixels; ++k) {
    if (m && !std::isfinite(m[k])) continue;
    for (int c = 0; c < C; ++c) {
      const double v = d[k * C + static_cast<std::size_t>(c)];
      s[c] += v;
      s2[c] += v * v;
    }
    ++n;
  }
  if (n < 2) return;
  double mean[C], inv[C];
  for (int c = 0; c < C; ++c) {
    mean[c] = s[c] / static_cast<double>(n);
    const double var = s2[c] / static_cast<double>(n) - mean[c] * mean[c];
    inv[c] = var > 1e-20 ? 1.0 / std::sqrt(var) : 1.0;
  }
  for (std::size_t k = 0; k < pixels; ++k)
    for (int c = 0; c < C; ++c) {
      float& v = d[k * C + static_cast<std::size_t>(c)];
      v = static_cast<float>((v - mean[c]) * inv[c]);
    }
}

// The covariance inflation f = ((1 + rho) / (1 - rho))^2 of a residual field whose
// neighbours correlate by rho, clamped to [0, 0.9] (TrackResult::covariance).
double inflation_of(double rho) {
  rho = std::min(std::max(rho, 0.0), 0.9);
  return ((1 + rho) / (1 - rho)) * ((1 + rho) / (1 - rho));
}

}  // namespace

void rgb_to_grey(ImageView<const std::uint8_t> rgb, ImageF& grey) {
  grey.resize(rgb.width, rgb.height, 1);
  for (int y = 0; y < rgb.height; ++y) {
    const std::uint8_t* s = rgb.row(y);
    for (int x = 0; x < rgb.width; ++x, s += rgb.channels)
      grey.at(x, y) = (0.299f * s[0] + 0.587f * s[1] + 0.114f * s[2]) / 255.0f;
  }
}

// The motion between two parameter sets, for the plausibility bound (SE(3) only).
template <class P>
struct SE3Log {
  static Vec6<double> of(const P&, const P&) { return Vec6<double>::Zero(); }
};
template <class S>
struct SE3Log<SE3<S>> {
  static Vec6<double> of(const SE3<S>& a, const SE3<S>& b) { return (a.inverse() * b).template cast<double>().log(); }
};

template <class S, class Warp, int C>
Tracker<S, Warp, C>::Tracker(int width, int height, const TrackerOptions& options, ThreadPool* pool)
    : opt_(options), width_(width), height_(height) {
  const FloatEnvironmentScope float_environment;
  opt_.levels = std::max(1, std::min(6, opt_.levels));
  int w = width, h = height;
  levels_.resize(static_cast<std::size_t>(opt_.levels));
  for (auto& L : levels_) {
    L.w = w;
    L.h = h;
    L.ref.resize(w, h, C);
    L.live.resize(w, h, C);
    if (kSe3Kernel && C > 1) L.live_planes.resize(w, h * C, 1);
    L.depth.resize(w, h, 1);
    L.abs_r.resize(w, h, 1);
    L.weight.resize(w, h, 1);
    w = std::max(1, w / 2);
    h = std::max(1, h / 2);
  }
  const std::size_t n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  for (auto* v : {&pu_, &pv_, &px_, &py_, &pz_, &w_}) v->resize(n);
  val_.resize(n * C);
  r_.resize(n * C);
  jac_.resize(n * C * DoF);
  jac_stride_ = n;
  abs_.resize(n);
  partials_.resize(n / kChunk + 1);
  if (kSe3Kernel) out_index_.resize(partials_.size() * kChunk);
  bands_.resize(kBands);
  pick_.resize(n);  // blocks of one pixel at the finest level at most
  pool_ = given_or_own(pool, std::max(1, opt_.threads), own_pool_);
  ok_.resize(n);
  pick_kernel();
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::pick_kernel() {
  se3_kernel_ = nullptr;
  jacobian_kernel_ = nullptr;
  if constexpr (kSe3Kernel) {
    se3_kernel_ = detail::evaluate_se3_scalar;
    jacobian_kernel_ = detail::se3_jacobians_scalar;
#if defined(TERRALIGN_ICLK_AVX2)
    if (opt_.simd && cpu_features().avx2_fma) {
      se3_kernel_ = cpu_features().avx512f ? detail::evaluate_se3_avx512 : detail::evaluate_se3_avx2;
      jacobian_kernel_ = detail::se3_jacobians_avx2;
    }
#elif defined(TERRALIGN_ICLK_NEON)
    if (opt_.simd) {
      se3_kernel_ = detail::evaluate_se3_neon;
      jacobian_kernel_ = detail::se3_jacobians_neon;
    }
#endif
  }
  outer_kernel_ = nullptr;
  outer_at_kernel_ = nullptr;
  if constexpr (kOuterKernel) {
    outer_kernel_ = detail::outer_sums_scalar;
    outer_at_kernel_ = detail::outer_sums_at_scalar;
#if defined(TERRALIGN_ICLK_AVX2)
    if (opt_.simd && cpu_features().avx2_fma) {
      outer_kernel_ = detail::outer_sums_avx2;
      outer_at_kernel_ = detail::outer_sums_at_avx2;
    }
#elif defined(TERRALIGN_ICLK_NEON)
    if (opt_.simd) {
      outer_kernel_ = detail::outer_sums_neon;
      outer_at_kernel_ = detail::outer_sums_at_neon;
    }
#endif
  }
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::set_options(const TrackerOptions& o) {
  const int levels = static_cast<int>(levels_.size());  // as built
  opt_ = o;
  opt_.levels = std::max(1, std::min(levels, o.levels));
  pick_kernel();
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::build_pyramids(ImageView<const float> ref, ImageView<const float> depth,
                                         const ImageView<const float>* live) {
  Level& L0 = levels_[0];
  for (int y = 0; y < L0.h; ++y) {
    std::copy(ref.row(y), ref.row(y) + L0.w * C, &L0.ref.at(0, y, 0));
    if (live) std::copy(live->row(y), live->row(y) + L0.w * C, &L0.live.at(0, y, 0));
    std::copy(depth.row(y), depth.row(y) + L0.w, &L0.depth.at(0, y, 0));
  }
  build_depth_pyramid();
  if (live)
    downsample_levels<true>();
  else
    downsample_levels<false>();
  normalize_levels(live != nullptr);
}

template <class S, class Warp, int C>
template <bool kLive>
void Tracker<S, Warp, C>::downsample_levels() {
  for (std::size_t l = 1; l < levels_in_use(); ++l) {
    const Level& A = levels_[l - 1];
    Level& B = levels_[l];
    for (int y = 0; y < B.h; ++y)
      for (int x = 0; x < B.w; ++x) {
        // Reference: the mean of the children with depth; live: the plain mean.
        int nd = 0;
        float f[C] = {}, g[C] = {};
        for (int k = 0; k < 4; ++k) {
          const int sx = std::min(2 * x + (k & 1), A.w - 1), sy = std::min(2 * y + (k >> 1), A.h - 1);
          if constexpr (kLive)
            for (int c = 0; c < C; ++c) g[c] += A.live.at(sx, sy, c);
          if (!std::isfinite(A.depth.at(sx, sy))) continue;
          ++nd;
          for (int c = 0; c < C; ++c) f[c] += A.ref.at(sx, sy, c);
        }
        for (int c = 0; c < C; ++c) {
          B.ref.at(x, y, c) = nd ? f[c] / static_cast<float>(nd) : 0.0f;
          if constexpr (kLive) B.live.at(x, y, c) = g[c] * 0.25f;
        }
      }
  }
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::normalize_levels(bool live) {
  if (opt_.normalize)
    for (std::size_t l = 0; l < levels_in_use(); ++l) {
      normalize<C>(levels_[l].ref, &levels_[l].depth);
      if (live) normalize<C>(levels_[l].live, nullptr);
    }
  if (!live) return;  // the earlier alignment's, normalised and in planes already
  live_ready_ = levels_in_use();
  if constexpr (kSe3Kernel && C > 1)  // the kernel's live planes, one channel each
    for (std::size_t l = 0; l < levels_in_use(); ++l)
      for (int c = 0; c < C; ++c) {
        Level& L = levels_[l];
        for (int y = 0; y < L.h; ++y) {
          float* row = &L.live_planes.at(0, c * L.h + y);
          for (int x = 0; x < L.w; ++x) row[x] = L.live.at(x, y, c);
        }
      }
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::build_depth_pyramid() {
  for (std::size_t l = 1; l < levels_in_use(); ++l) {
    const Level& A = levels_[l - 1];
    Level& B = levels_[l];
    for (int y = 0; y < B.h; ++y)
      for (int x = 0; x < B.w; ++x) {
        float d = 0;
        int nd = 0;
        for (int k = 0; k < 4; ++k) {
          const float dz = A.depth.at(std::min(2 * x + (k & 1), A.w - 1), std::min(2 * y + (k >> 1), A.h - 1));
          if (!std::isfinite(dz)) continue;
          d += dz;
          ++nd;
        }
        B.depth.at(x, y) = nd ? d / static_cast<float>(nd) : NAN;
      }
  }
}

template <class S, class Warp, int C>
int Tracker<S, Warp, C>::select_pixels(int level, const Pinhole<S>& K) {
  const Level& L = levels_[static_cast<std::size_t>(level)];
  pick_block_ = level < static_cast<int>(opt_.block.size()) ? std::max(1, opt_.block[static_cast<std::size_t>(level)]) : 1;
  // Blocks start at pixel 1 and leave the image's outer ring out (the Sobel needs it).
  const int rows = L.h > 2 ? (L.h - 2 + pick_block_ - 1) / pick_block_ : 0;
  pick_cols_ = L.w > 2 ? (L.w - 2 + pick_block_ - 1) / pick_block_ : 0;
  for (int b = 0; b < kBands; ++b) {
    Band& B = bands_[static_cast<std::size_t>(b)];
    B.row0 = rows * b / kBands;
    B.row1 = rows * (b + 1) / kBands;
  }
  struct Ctx {
    Tracker* t;
    int level;
    const Pinhole<S>* K;
  } ctx{this, level, &K};
  pool_->run(kBands, [](void* c, int b) {
    auto* x = static_cast<Ctx*>(c);
    x->t->pick_band(x->level, x->t->bands_[static_cast<std::size_t>(b)]);
  }, &ctx);
  int n = 0;
  for (auto& B : bands_) {
    B.offset = n;
    n += B.count;
  }
  pool_->run(kBands, [](void* c, int b) {
    auto* x = static_cast<Ctx*>(c);
    x->t->write_band(x->level, *x->K, x->t->bands_[static_cast<std::size_t>(b)]);
  }, &ctx);
  if (level == 0) {
    motion0_.setZero();
    floor0_.setZero();
    moments0_.fill(0);
    for (const auto& B : bands_) {
      motion0_ += B.motion;
      floor0_ += B.floor;
      for (std::size_t k = 0; k < moments0_.size(); ++k) moments0_[k] += B.moments[k];
    }
  }
  return n;
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::pick_band(int level, Band& band) {
  const Level& L = levels_[static_cast<std::size_t>(level)];
  const int block = pick_block_;
  auto usable = [&](int x, int y) {
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx)
        if (!std::isfinite(L.depth.at(x + dx, y + dy))) return false;
    return true;
  };
  band.count = 0;
  if (block == 1) {
    // Every pixel whose 3x3 neighbourhood has depth, without a branch per pixel (what the
    // loop below picks when blocks are single pixels).
    // 1 or 0 (an int, so the & below is plainly bitwise); NaN: 0.
    auto finite = [](float d) -> int { return std::abs(d) <= std::numeric_limits<float>::max(); };
    const ImageView<const float> D = L.depth.view();
    for (int row = band.row0; row < band.row1; ++row) {
      const int y = 1 + row;
      const float *a = D.row(y - 1), *b = D.row(y), *c = D.row(y + 1);
      int* pick = pick_.data() + static_cast<std::size_t>(row) * static_cast<std::size_t>(pick_cols_);
      int count = 0;
      for (int col = 0; col < pick_cols_; ++col) {
        const int x = 1 + col;
        int ok = 1;
        for (int dx = -1; dx <= 1; ++dx) ok = ok & finite(a[x + dx]) & finite(b[x + dx]) & finite(c[x + dx]);
        pick[col] = ok ? y * L.w + x : -1;
        count += ok;
      }
      band.count += count;
    }
    return;
  }
  for (int row = band.row0; row < band.row1; ++row) {
    const int by = 1 + row * block;
    for (int col = 0; col < pick_cols_; ++col) {
      const int bx = 1 + col * block;
      // The pixel of the block with the strongest gradient (every pixel when block == 1).
      int best_x = -1, best_y = -1;
      S best = S(-1);
      for (int y = by; y < std::min(by + block, L.h - 1); ++y)
        for (int x = bx; x < std::min(bx + block, L.w - 1); ++x) {
          // Rank by central differences (cheap); the full 3x3 check only for the winner.
          S m = S(0);
          if (block > 1) {
            if (!std::isfinite(L.depth.at(x, y))) continue;
            for (int c = 0; c < C; ++c) {
              const S gx = static_cast<S>(L.ref.at(x + 1, y, c)) - static_cast<S>(L.ref.at(x - 1, y, c));
              const S gy = static_cast<S>(L.ref.at(x, y + 1, c)) - static_cast<S>(L.ref.at(x, y - 1, c));
              m += gx * gx + gy * gy;
            }
          } else if (!usable(x, y)) {
            continue;
          }
          if (m > best) {
            best = m;
            best_x = x;
            best_y = y;
          }
        }
      const bool ok = best_x >= 0 && (block == 1 || usable(best_x, best_y));
      pick_[static_cast<std::size_t>(row) * static_cast<std::size_t>(pick_cols_) + static_cast<std::size_t>(col)] =
          ok ? best_y * L.w + best_x : -1;
      band.count += ok;
    }
  }
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::write_band(int level, const Pinhole<S>& K, Band& band) {
  const Level& L = levels_[static_cast<std::size_t>(level)];
  // Sobel / 8 of channel c at (x, y): the intensity gradient per pixel.
  auto sobel = [&](int x, int y, int c, S& gx, S& gy) {
    auto I = [&](int xx, int yy) { return static_cast<S>(L.ref.at(xx, yy, c)); };
    gx = (I(x + 1, y - 1) + S(2) * I(x + 1, y) + I(x + 1, y + 1) - I(x - 1, y - 1) - S(2) * I(x - 1, y) -
          I(x - 1, y + 1)) / S(8);
    gy = (I(x - 1, y + 1) + S(2) * I(x, y + 1) + I(x + 1, y + 1) - I(x - 1, y - 1) - S(2) * I(x, y - 1) -
          I(x + 1, y - 1)) / S(8);
  };
  band.motion.setZero();
  band.floor.setZero();
  band.moments.fill(0);
  // Finest level: motion0_'s share (dW^T dW, lower half) and floor0_'s (dW^T modes, the modes
  // of the registration floor), summed in S over lanes (the band's k-th pixel in lane k mod
  // kLanes, 8 pixels' dW gathered first so the sums vectorise), then in double in lane order.
  // In float each lane sums an eighth of a band's pixels (about 700 at 376 x 240): about
  // 1e-5 relative, far inside what rms_motion_px() and the floor are used for.
  constexpr int kLanes = 8, kPairs = DoF * (DoF + 1) / 2;
  S motion[kPairs][kLanes] = {}, floor_sum[DoF][kFloorModes][kLanes] = {};
  S wu[DoF][kLanes] = {}, wv[DoF][kLanes] = {}, mu[kLanes] = {}, mv[kLanes] = {};
  int lanes = 0;
  auto add_lanes = [&]() {
    for (int l = lanes; l < kLanes; ++l) {  // unused lanes add zero
      for (int a = 0; a < DoF; ++a) wu[a][l] = wv[a][l] = S(0);
      mu[l] = mv[l] = S(0);
    }
    int e = 0;
    for (int a = 0; a < DoF; ++a)
      for (int b = 0; b <= a; ++b, ++e)
        for (int l = 0; l < kLanes; ++l) motion[e][l] += wu[a][l] * wu[b][l] + wv[a][l] * wv[b][l];
    for (int a = 0; a < DoF; ++a)
      for (int l = 0; l < kLanes; ++l) {
        // modes: u {1, 0, -dv, du, du^2, du dv}, v {0, 1, du, dv, du dv, dv^2}
        const S radial = wu[a][l] * mu[l] + wv[a][l] * mv[l];
        floor_sum[a][0][l] += wu[a][l];
        floor_sum[a][1][l] += wv[a][l];
        floor_sum[a][2][l] += wv[a][l] * mu[l] - wu[a][l] * mv[l];
        floor_sum[a][3][l] += radial;
        floor_sum[a][4][l] += radial * mu[l];
        floor_sum[a][5][l] += radial * mv[l];
      }
    lanes = 0;
  };
  // Finest level: one pixel's moments (in double, pixel by pixel).
  auto add_moments = [&](S u, S v) {
    const double du = static_cast<double>(u - K.cx), dv = static_cast<double>(v - K.cy);
    const double r2 = du * du + dv * dv;
    band.moments[0] += du * du;
    band.moments[1] += dv * dv;
    band.moments[2] += du * dv;
    band.moments[3] += du * du * r2;
    band.moments[4] += dv * dv * r2;
  };
  int n = band.offset;
  const int* pick = pick_.data() + static_cast<std::size_t>(band.row0) * static_cast<std::size_t>(pick_cols_);
  const int blocks = (band.row1 - band.row0) * pick_cols_;
  if constexpr (kSe3Kernel) {
    // The kernel, eight pixels at a time (a group's lanes are the sums' lanes).
    detail::Se3JacobianInput in;
    in.ref = L.ref.data();
    in.depth = L.depth.data();
    in.width = L.w;
    in.channels = C;
    in.fx = K.fx;
    in.fy = K.fy;
    in.cx = K.cx;
    in.cy = K.cy;
    detail::Se3JacobianGroup group;
    group.plane = static_cast<std::ptrdiff_t>(jac_stride_);
    group.jac_plane = static_cast<std::ptrdiff_t>(jac_stride_) * DoF;
    detail::Se3FinestSums finest{};
    static_assert(kLanes == detail::kLanes && sizeof motion == sizeof finest.motion && sizeof floor_sum == sizeof finest.floor,
                  "the kernel's lanes are the sums' lanes: its sums are copied into them");
    int xs[kLanes], ys[kLanes], count = 0;
    auto flush = [&]() {
      group.pu = pu_.data() + n;
      group.pv = pv_.data() + n;
      group.px = px_.data() + n;
      group.py = py_.data() + n;
      group.pz = pz_.data() + n;
      group.val = val_.data() + n;
      for (int a = 0; a < DoF; ++a) group.jac[a] = &jac(n, 0, a);
      jacobian_kernel_(in, xs, ys, count, group, level == 0 ? &finest : nullptr);
      if (level == 0)
        for (int l = 0; l < count; ++l) add_moments(static_cast<S>(xs[l]), static_cast<S>(ys[l]));
      n += count;
      count = 0;
    };
    for (int k = 0; k < blocks; ++k) {
      if (pick[k] < 0) continue;
      xs[count] = pick[k] % L.w;
      ys[count] = pick[k] / L.w;
      if (++count == kLanes) flush();
    }
    if (count > 0) flush();
    std::memcpy(motion, finest.motion, sizeof motion);
    std::memcpy(floor_sum, finest.floor, sizeof floor_sum);
  } else {
    for (int k = 0; k < blocks; ++k) {
      if (pick[k] < 0) continue;
      const int x = pick[k] % L.w, y = pick[k] / L.w;
      const S d = static_cast<S>(L.depth.at(x, y));
      const S u = static_cast<S>(x), v = static_cast<S>(y);
      const Vec3<S> X(d * (u - K.cx) / K.fx, d * (v - K.cy) / K.fy, d);
      const typename Warp::Jac dW = Warp::d_warp_d_xi(X, u, v, K);
      if (level == 0) {
        for (int a = 0; a < DoF; ++a) {
          wu[a][lanes] = dW(0, a);
          wv[a][lanes] = dW(1, a);
        }
        mu[lanes] = u - K.cx;
        mv[lanes] = v - K.cy;
        if (++lanes == kLanes) add_lanes();
        add_moments(u, v);
      }
      for (int c = 0; c < C; ++c) {
        S gx, gy;
        sobel(x, y, c, gx, gy);
        for (int a = 0; a < DoF; ++a) jac(n, c, a) = gx * dW(0, a) + gy * dW(1, a);
        val_[at(static_cast<std::size_t>(n), c)] = static_cast<S>(L.ref.at(x, y, c));
      }
      pu_[static_cast<std::size_t>(n)] = u;
      pv_[static_cast<std::size_t>(n)] = v;
      px_[static_cast<std::size_t>(n)] = X.x();
      py_[static_cast<std::size_t>(n)] = X.y();
      pz_[static_cast<std::size_t>(n)] = X.z();
      ++n;
    }
  }
  if (level == 0) {
    if (lanes > 0) add_lanes();
    int e = 0;
    for (int a = 0; a < DoF; ++a) {
      for (int b = 0; b <= a; ++b, ++e)
        for (int l = 0; l < kLanes; ++l) band.motion(a, b) += static_cast<double>(motion[e][l]);
      for (int m = 0; m < kFloorModes; ++m)
        for (int l = 0; l < kLanes; ++l) band.floor(a, m) += static_cast<double>(floor_sum[a][m][l]);
    }
  }
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::hessian(int n, Eigen::Matrix<double, DoF, DoF>& H) {
  const int chunks = (n + kChunk - 1) / kChunk;
  struct Ctx {
    Tracker* t;
    int n;
  } ctx{this, n};
  pool_->run(chunks, [](void* c, int chunk) {
    auto* x = static_cast<Ctx*>(c);
    Partial& P = x->t->partials_[static_cast<std::size_t>(chunk)];  // its H_out as the chunk's sum
    P.H_out.setZero();
    const int i0 = chunk * kChunk, i1 = std::min(x->n, (chunk + 1) * kChunk);
    if constexpr (kOuterKernel) {
      x->t->outer_kernel_sum(P, i0, i1, nullptr, 0);
    } else {
      for (int i = i0; i < i1; ++i) x->t->add_outer(P, i);
    }
  }, &ctx);
  H.setZero();
  for (int i = 0; i < chunks; ++i) H += partials_[static_cast<std::size_t>(i)].H_out;
  H = H.template selfadjointView<Eigen::Lower>();
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::outer_kernel_sum(Partial& P, int i0, int i1, const int* index, int count) {
  if constexpr (kOuterKernel) {
    detail::OuterSums sums{};
    for (int c = 0; c < C; ++c) {
      const float* J[DoF];
      for (int a = 0; a < DoF; ++a) J[a] = &jac(0, c, a);
      if (index) outer_at_kernel_(J, w_.data(), index, count, sums);
      else outer_kernel_(J, w_.data(), i0, i1, sums);
    }
    int k = 0;
    for (int a = 0; a < DoF; ++a)
      for (int b = 0; b <= a; ++b, ++k)
        for (int l = 0; l < detail::kOuterLanes; ++l) P.H_out(a, b) += sums.h[k][l];
  }
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::evaluate_chunk(int chunk, int n, const Params& p, const Pinhole<S>& K) {
  Partial& P = partials_[static_cast<std::size_t>(chunk)];
  P.g.setZero();
  P.H_out.setZero();
  P.cost = 0;
  P.wsum = 0;
  P.valid = 0;
  const Level& Lv = *cur_level_;
  const int i0 = chunk * kChunk, i1 = std::min(n, (chunk + 1) * kChunk);
  if constexpr (kSe3Kernel) {
    detail::Se3EvalInput in;
    in.px = px_.data();
    in.py = py_.data();
    in.pz = pz_.data();
    in.w = w_.data();
    in.stride = Lv.w;
    in.width = Lv.w;
    in.height = Lv.h;
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) in.R[3 * a + b] = p.R(a, b);
      in.t[a] = p.t[a];
    }
    in.fx = K.fx;
    in.fy = K.fy;
    in.cx = K.cx;
    in.cy = K.cy;
    in.out = out_index_.data() + static_cast<std::size_t>(chunk) * kChunk;
    // Several channels: each its own plane (val_, r_, jac_ and the live planes).
    in.val = val_.data();
    for (int a = 0; a < DoF; ++a) in.jac[a] = &jac(0, 0, a);
    in.live = C == 1 ? Lv.live.data() : Lv.live_planes.data();
    in.channels = C;
    in.plane = static_cast<std::ptrdiff_t>(jac_stride_);  // at(i, c), jac(i, c, a)
    in.jac_plane = static_cast<std::ptrdiff_t>(jac_stride_) * DoF;
    in.live_plane = static_cast<std::ptrdiff_t>(Lv.w) * Lv.h;
    detail::Se3EvalSums sums;
    se3_kernel_(in, i0, i1, r_.data(), ok_.data(), sums);
    // Lanes combined in lane order, in double.
    for (int l = 0; l < detail::kLanes; ++l) {
      for (int a = 0; a < DoF; ++a) P.g[a] += static_cast<double>(sums.g[a][l]);
      P.cost += static_cast<double>(sums.cost[l]);
      P.wsum += static_cast<double>(sums.wsum[l]);
    }
    P.valid = sums.valid;
    if (sums.valid == i1 - i0) return;  // every pixel landed: nothing leaves H
    outer_kernel_sum(P, 0, 0, in.out, sums.n_out);
    return;
  }
  // Within a chunk the sums run in S (float: vectorisable, and 2048 terms lose less than the
  // residuals' own precision); chunks are combined in double.
  S g_s[DoF] = {};
  S cost_s = 0, wsum_s = 0;
  int valid = 0;
  for (int i = i0; i < i1; ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    S u, v;
    const Vec3<S> X(px_[k], py_[k], pz_[k]);
    bool inside = Warp::apply(p, X, pu_[k], pv_[k], K, u, v);
    inside = inside && u >= S(0) && v >= S(0) && u <= S(Lv.w - 1) && v <= S(Lv.h - 1);
    ok_[k] = inside;
    if (!inside) {
      add_outer(P, i);
      continue;
    }
    const int x0 = std::min(static_cast<int>(u), Lv.w - 2), y0 = std::min(static_cast<int>(v), Lv.h - 2);
    const S fx = u - S(x0), fy = v - S(y0);
    for (int c = 0; c < C; ++c) {
      const S a = static_cast<S>(Lv.live.at(x0, y0, c)), b = static_cast<S>(Lv.live.at(x0 + 1, y0, c));
      const S d = static_cast<S>(Lv.live.at(x0, y0 + 1, c)), e = static_cast<S>(Lv.live.at(x0 + 1, y0 + 1, c));
      const S live = (S(1) - fy) * ((S(1) - fx) * a + fx * b) + fy * ((S(1) - fx) * d + fx * e);
      const S r = live - val_[at(k, c)];
      r_[at(k, c)] = r;
      const S wr = w_[k] * r;
      for (int a2 = 0; a2 < DoF; ++a2) g_s[a2] += wr * jac(i, c, a2);
      cost_s += wr * r;
    }
    wsum_s += S(C) * w_[k];  // a weight per residual: cost / wsum is a mean per channel
    ++valid;
  }
  for (int a2 = 0; a2 < DoF; ++a2) P.g[a2] = static_cast<double>(g_s[a2]);
  P.cost = static_cast<double>(cost_s);
  P.wsum = static_cast<double>(wsum_s);
  P.valid = valid;
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::add_outer(Partial& P, int i) {
  const double w = static_cast<double>(w_[static_cast<std::size_t>(i)]);
  if (!(w > 0)) return;
  for (int c = 0; c < C; ++c)
    for (int a = 0; a < DoF; ++a)
      for (int b = 0; b <= a; ++b) P.H_out(a, b) += w * static_cast<double>(jac(i, c, a)) * static_cast<double>(jac(i, c, b));
}

template <class S, class Warp, int C>
int Tracker<S, Warp, C>::evaluate(int n, const Params& p, const Pinhole<S>& K, Eigen::Matrix<double, DoF, 1>& g,
                                  Eigen::Matrix<double, DoF, DoF>& H_out, double& cost, double& wsum) {
  // Fixed chunks of pixels, each summed by one thread, then the chunks summed in order: the
  // result does not depend on the thread count.
  const int chunks = (n + kChunk - 1) / kChunk;
  struct Ctx {
    Tracker* t;
    int n;
    const Params* p;
    const Pinhole<S>* K;
  } ctx{this, n, &p, &K};
  pool_->run(chunks, [](void* c, int i) {
    auto* x = static_cast<Ctx*>(c);
    x->t->evaluate_chunk(i, x->n, *x->p, *x->K);
  }, &ctx);
  g.setZero();
  H_out.setZero();
  cost = 0;
  wsum = 0;
  int valid = 0;
  for (int i = 0; i < chunks; ++i) {
    const Partial& P = partials_[static_cast<std::size_t>(i)];
    g += P.g;
    H_out += P.H_out;
    cost += P.cost;
    wsum += P.wsum;
    valid += P.valid;
  }
  H_out = H_out.template selfadjointView<Eigen::Lower>();
  return valid;
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::robust_weights(int n, const ImageView<const float>* weights, int level) {
  if (weights) {
    const ImageView<const float>& W = weights[level];
    for (int i = 0; i < n; ++i) {
      const float wv = W.at(static_cast<int>(pu_[static_cast<std::size_t>(i)]), static_cast<int>(pv_[static_cast<std::size_t>(i)]));
      w_[static_cast<std::size_t>(i)] = std::isfinite(wv) && wv > 0 ? static_cast<S>(wv) : S(0);
    }
    return;
  }
  std::fill(w_.begin(), w_.begin() + n, S(1));
}

template <class S, class Warp, int C>
const TrackResult<Warp>& Tracker<S, Warp, C>::align(ImageView<const float> ref, ImageView<const float> ref_depth,
                                                     ImageView<const float> live, const Pinhole<S>& K0,
                                                     const Params& init, const ImageView<const float>* weights) {
  TERRALIGN_ASSERT(live.width == width_ && live.height == height_ && live.channels == C,
                   "Tracker::align: the live image's size or channels differ from the tracker's");
  return build_and_solve(ref, ref_depth, &live, K0, init, weights);
}

template <class S, class Warp, int C>
const TrackResult<Warp>& Tracker<S, Warp, C>::align_to(ImageView<const float> ref, ImageView<const float> ref_depth,
                                                        const Pinhole<S>& K0, const Params& init,
                                                        const ImageView<const float>* weights) {
  TERRALIGN_ASSERT(live_ready_ >= levels_in_use(), "Tracker::align_to: no earlier alignment's live levels to keep");
  return build_and_solve(ref, ref_depth, nullptr, K0, init, weights);
}

template <class S, class Warp, int C>
const TrackResult<Warp>& Tracker<S, Warp, C>::build_and_solve(ImageView<const float> ref,
                                                               ImageView<const float> ref_depth,
                                                               const ImageView<const float>* live,
                                                               const Pinhole<S>& K0, const Params& init,
                                                               const ImageView<const float>* weights) {
  const FloatEnvironmentScope float_environment;
  TrackResult<Warp>& R = result_;
  R = TrackResult<Warp>{};
  R.params = init;
  TERRALIGN_ASSERT(ref.width == width_ && ref.height == height_ && ref_depth.width == width_ &&
                       ref_depth.height == height_ && ref.channels == C && ref_depth.channels == 1,
                   "Tracker::align, align_to: the reference's or depth's size or channels differ from the tracker's");
  const auto t0 = Clock::now();
  build_pyramids(ref, ref_depth, live);
  R.ms_pyramid = ms(t0, Clock::now());
  return solve(K0, init, weights, nullptr);
}

template <class S, class Warp, int C>
const TrackResult<Warp>& Tracker<S, Warp, C>::align_levels(const ImageView<const float>* ref_levels,
                                                            ImageView<const float> ref_depth,
                                                            const ImageView<const float>* live_levels,
                                                            const Pinhole<S>& K0, const Params& init,
                                                            LevelWeights* weights) {
  const FloatEnvironmentScope float_environment;
  TrackResult<Warp>& R = result_;
  R = TrackResult<Warp>{};
  R.params = init;
  TERRALIGN_ASSERT(ref_depth.width == width_ && ref_depth.height == height_ && ref_depth.channels == 1,
                   "Tracker::align_levels: depth size differs from the size the tracker was built for");
  const auto t0 = Clock::now();
  TERRALIGN_ASSERT(live_levels || live_ready_ >= levels_in_use(),
                   "Tracker::align_levels: no live levels given and no earlier alignment's to keep");
  for (std::size_t l = 0; l < levels_in_use(); ++l) {
    Level& L = levels_[l];
    const ImageView<const float>& A = ref_levels[l];
    TERRALIGN_ASSERT(A.width == L.w && A.height == L.h && A.channels == C,
                     "Tracker::align_levels: a level's reference features have the wrong size or channels");
    for (int y = 0; y < L.h; ++y) std::copy(A.row(y), A.row(y) + L.w * C, &L.ref.at(0, y, 0));
    if (!live_levels) continue;
    const ImageView<const float>& B = live_levels[l];
    TERRALIGN_ASSERT(B.width == L.w && B.height == L.h && B.channels == C,
                     "Tracker::align_levels: a level's live features have the wrong size or channels");
    for (int y = 0; y < L.h; ++y) std::copy(B.row(y), B.row(y) + L.w * C, &L.live.at(0, y, 0));
  }
  for (int y = 0; y < height_; ++y) std::copy(ref_depth.row(y), ref_depth.row(y) + width_, &levels_[0].depth.at(0, y, 0));
  build_depth_pyramid();
  normalize_levels(live_levels != nullptr);
  R.ms_pyramid = ms(t0, Clock::now());
  return solve(K0, init, nullptr, weights);
}

template <class S, class Warp, int C>
void Tracker<S, Warp, C>::learned_weights(int n, int level, const Params& p, const Pinhole<S>& K, LevelWeights& lw) {
  Level& L = levels_[static_cast<std::size_t>(level)];
  Eigen::Matrix<double, DoF, 1> g;
  Eigen::Matrix<double, DoF, DoF> Hout;
  double cost = 0, wsum = 0;
  std::fill(w_.begin(), w_.begin() + n, S(1));  // evaluate() reads w_; only r_ and ok_ are used here
  evaluate(n, p, K, g, Hout, cost, wsum);
  std::fill(L.abs_r.data(), L.abs_r.data() + L.abs_r.size(), 0.0f);
  for (int i = 0; i < n; ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    if (!ok_[k]) continue;
    double a = 0;  // the RMS over channels (one channel: |r|)
    for (int c = 0; c < C; ++c) a += static_cast<double>(r_[at(k, c)]) * static_cast<double>(r_[at(k, c)]);
    L.abs_r.at(static_cast<int>(pu_[k]), static_cast<int>(pv_[k])) = static_cast<float>(std::sqrt(a / C));
  }
  lw.weights(level, L.abs_r.view(), L.ref.view(), L.live.view(), L.weight.view());
  for (int i = 0; i < n; ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    const float wv = L.weight.at(static_cast<int>(pu_[k]), static_cast<int>(pv_[k]));
    w_[k] = std::isfinite(wv) && wv > 0 ? static_cast<S>(wv) : S(0);
  }
}

template <class S, class Warp, int C>
double Tracker<S, Warp, C>::channel_factor(int n) const {
  if constexpr (C == 1) {
    (void)n;
    return 1.0;
  } else {
    // The mean correlation of two channels' residuals over the used pixels that landed,
    // clamped to [0, 1]; Kish's design effect 1 + (C - 1) rho: C copies of one channel (rho 1)
    // carry one channel's information, independent channels (rho 0) C times it.
    double sab[C][C] = {};
    for (int i = 0; i < n; ++i) {
      const std::size_t k = static_cast<std::size_t>(i);
      if (!ok_[k] || !(w_[k] > 0)) continue;
      for (int a = 0; a < C; ++a)
        for (int b = 0; b <= a; ++b) sab[a][b] += static_cast<double>(r_[at(k, a)]) * static_cast<double>(r_[at(k, b)]);
    }
    double rho = 0;
    for (int a = 1; a < C; ++a)
      for (int b = 0; b < a; ++b)
        if (sab[a][a] > 0 && sab[b][b] > 0) rho += sab[a][b] / std::sqrt(sab[a][a] * sab[b][b]);
    rho = std::clamp(rho / (C * (C - 1) / 2), 0.0, 1.0);
    return 1.0 + (C - 1) * rho;
  }
}

template <class S, class Warp, int C>
double Tracker<S, Warp, C>::residual_correlation(int n) const {
  // Pixels are selected row of blocks by row of blocks, left to right: consecutive pixels on
  // the same row, at most two blocks apart, are horizontal neighbours at the sampling step.
  const int block = std::max(1, opt_.block[0]);
  double sab = 0, saa = 0, sbb = 0;
  for (int i = 0; i + 1 < n; ++i) {
    const std::size_t a = static_cast<std::size_t>(i), b = a + 1;
    if (!ok_[a] || !ok_[b] || pv_[a] != pv_[b] || pu_[b] - pu_[a] > S(2 * block)) continue;
    if (!(w_[a] > 0) || !(w_[b] > 0)) continue;
    for (int c = 0; c < C; ++c) {
      const double ra = static_cast<double>(r_[at(a, c)]);
      const double rb = static_cast<double>(r_[at(b, c)]);
      sab += ra * rb;
      saa += ra * ra;
      sbb += rb * rb;
    }
  }
  return saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : 0.0;
}

template <class S, class Warp, int C>
double Tracker<S, Warp, C>::mean_square_residual(int n) const {
  double sum = 0;
  long count = 0;
  for (int i = 0; i < n; ++i) {
    const std::size_t k = static_cast<std::size_t>(i);
    if (!ok_[k]) continue;
    for (int c = 0; c < C; ++c) {
      const double r = static_cast<double>(r_[at(k, c)]);
      sum += r * r;
    }
    ++count;
  }
  return count > 0 ? sum / (static_cast<double>(count) * C) : 0.0;
}

template <class S, class Warp, int C>
double Tracker<S, Warp, C>::rms_motion_px(const Vec6<double>& d, int n) const {
  if constexpr (Warp::kNeedsDepth) {
    const Eigen::Matrix<double, DoF, DoF> M = motion0_.template selfadjointView<Eigen::Lower>();
    return std::sqrt(std::max(d.dot(M * d), 0.0) / std::max(n, 1));
  } else {
    return INFINITY;
  }
}

template <class S, class Warp, int C>
typename Tracker<S, Warp, C>::Params Tracker<S, Warp, C>::shifted(const Params& p, double du, double dv, const Pinhole<S>& K) {
  // Rotations about the camera's y and x axes move the image by about f * angle pixels.
  Eigen::Matrix<S, DoF, 1> nudge = Eigen::Matrix<S, DoF, 1>::Zero();
  nudge[1] = static_cast<S>(du / static_cast<double>(K.fx));
  nudge[0] = static_cast<S>(dv / static_cast<double>(K.fy));
  Params q = p;
  Warp::update(q, nudge);
  return q;
}

template <class S, class Warp, int C>
typename Tracker<S, Warp, C>::Params Tracker<S, Warp, C>::coarse_search(int n, const Params& p, const Pinhole<S>& K) {
  Eigen::Matrix<double, DoF, 1> g;
  Eigen::Matrix<double, DoF, DoF> Hout;
  double cost = 0, wsum = 0;
  std::fill(w_.begin(), w_.begin() + n, S(1));  // evaluate() reads w_; the residuals are unweighted
  const int inside0 = evaluate(n, p, K, g, Hout, cost, wsum);
  Params best = p;
  double best_r = inside0 > 0 ? mean_square_residual(n) : INFINITY;
  const int k = opt_.coarse_search_px;
  const int turns = static_cast<int>(std::floor(opt_.coarse_search_yaw_deg / kCoarseYawStepDeg + 1e-9));
  for (int t = -turns; t <= turns; ++t)
    for (int dv = -k; dv <= k; ++dv)
      for (int du = -k; du <= k; ++du) {
        if (du == 0 && dv == 0 && t == 0) continue;
        Params q = shifted(p, du, dv, K);
        if (t != 0) {  // about the optical axis
          Eigen::Matrix<S, DoF, 1> turn = Eigen::Matrix<S, DoF, 1>::Zero();
          turn[2] = static_cast<S>(t * kCoarseYawStepDeg * EIGEN_PI / 180.0);
          Warp::update(q, turn);
        }
        const int inside = evaluate(n, q, K, g, Hout, cost, wsum);
        if (2 * inside < inside0) continue;  // compare over most of the same ground only
        const double r = mean_square_residual(n);
        if (r < best_r) {
          best_r = r;
          best = q;
        }
      }
  return best;
}

template <class S, class Warp, int C>
const TrackResult<Warp>& Tracker<S, Warp, C>::solve(const Pinhole<S>& K0, const Params& init,
                                                     const ImageView<const float>* weights, LevelWeights* level_weights) {
  TrackResult<Warp>& R = result_;
  auto fail = [&](const char* why) -> const TrackResult<Warp>& {
    R.params = init;
    R.converged = false;
    R.reason = why;
    R.covariance.setZero();
    return R;
  };
  Pinhole<S> K[6];
  K[0] = K0;
  for (int l = 1; l < opt_.levels; ++l) K[l] = K[l - 1].half();
  Params p = init;
  Eigen::Matrix<double, DoF, DoF> H, Hout, Hv;
  Eigen::Matrix<double, DoF, 1> g;
  double cost = 0, wsum = 0;
  // The tilt prior's information, (I - u u^T) / sigma^2 on the rotation, and the image
  // term's noise sigma^2 f that scales it into the units of H (set when a level starts).
  const bool tilt = Warp::kNeedsDepth && opt_.tilt_prior_rad > 0 && std::isfinite(opt_.tilt_prior_rad) &&
                    up_.allFinite() && up_.norm() > 0 && tilt_.allFinite();
  Eigen::Matrix3d tilt_info = Eigen::Matrix3d::Zero();
  if (tilt) {
    const Eigen::Vector3d u = up_.normalized();
    tilt_info = (Eigen::Matrix3d::Identity() - u * u.transpose()) / (opt_.tilt_prior_rad * opt_.tilt_prior_rad);
  }
  // The altitude prior: 1 / sigma^2 on the height of the live camera's centre along up.
  const bool altitude = Warp::kNeedsDepth && opt_.altitude_prior_m > 0 && std::isfinite(opt_.altitude_prior_m) &&
                        up_.allFinite() && up_.norm() > 0 && std::isfinite(altimeter_height_);
  const double altitude_info = altitude ? 1.0 / (opt_.altitude_prior_m * opt_.altitude_prior_m) : 0.0;
  // The height's error and its row of the Jacobian at q: the live centre in the reference
  // camera is c = t of q^-1, and the update q <- q exp(delta)^-1 moves it to exp(delta) c, so
  // d(u.c)/d[omega; v] = [(c x u)^T, u^T].
  auto height_row = [&](const Params& q, Eigen::Matrix<double, 1, DoF>& J) {
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    if constexpr (Warp::kNeedsDepth) c = q.inverse().t.template cast<double>();
    const Eigen::Vector3d u = up_.normalized();
    J.setZero();
    J.template head<3>() = c.cross(u).transpose();
    J.template tail<3>() = u.transpose();
    return u.dot(c) - altimeter_height_;
  };
  auto image_noise = [&](int n) {  // sigma^2 f of the last evaluate()
    return inflation_of(residual_correlation(n)) * channel_factor(n) * cost / std::max(wsum - DoF, 1.0);
  };
  double noise = 0;
  for (int level = opt_.levels - 1; level >= 0; --level) {
    cur_level_ = &levels_[static_cast<std::size_t>(level)];
    const auto tj = Clock::now();
    const int n = select_pixels(level, K[level]);
    if (Warp::kNeedsDepth && level == opt_.levels - 1 && opt_.coarse_search_px > 0 && n > 0) p = coarse_search(n, p, K[level]);
    if (level == opt_.levels - 1) R.coarse_start = p;
    robust_weights(n, weights, level);
    if (level_weights && n > 0) learned_weights(n, level, p, K[level], *level_weights);
    if (!weights && !level_weights && opt_.robust != Robust::None && n > 0) {
      // Robust weights from the residuals at the pose this level starts from, with the scale
      // 1.4826 x the median absolute residual of the pixels that land inside.
      evaluate(n, p, K[level], g, Hout, cost, wsum);
      auto norm_r = [&](int i) {
        double a = 0;
        for (int c = 0; c < C; ++c) {
          const double r = static_cast<double>(r_[at(static_cast<std::size_t>(i), c)]);
          a += r * r;
        }
        return std::sqrt(a);
      };
      int m = 0;
      for (int i = 0; i < n; ++i)
        if (ok_[static_cast<std::size_t>(i)]) abs_[static_cast<std::size_t>(m++)] = static_cast<S>(norm_r(i));
      if (m > 0) {
        std::nth_element(abs_.begin(), abs_.begin() + m / 2, abs_.begin() + m);
        const double sigma = std::max(1.4826 * static_cast<double>(abs_[static_cast<std::size_t>(m / 2)]), 1e-6);
        const double k = (opt_.robust == Robust::Huber ? 1.345 : 4.685) * sigma;
        for (int i = 0; i < n; ++i) {
          if (!ok_[static_cast<std::size_t>(i)]) continue;
          const double a = norm_r(i);
          double w;
          if (opt_.robust == Robust::Huber) {
            w = a <= k ? 1.0 : k / a;
          } else {
            const double q = a / k;
            w = q < 1.0 ? (1.0 - q * q) * (1.0 - q * q) : 0.0;
          }
          w_[static_cast<std::size_t>(i)] = static_cast<S>(w);
        }
      }
    }
    hessian(n, H);
    R.ms_jacobian += ms(tj, Clock::now());
    const auto ti = Clock::now();
    if (n < std::max(DoF * 4, level == 0 ? opt_.min_valid_pixels : 0)) {
      if (level == 0) return fail("too few reference pixels with depth and texture");
      continue;
    }
    // The median depth scales the translation bound (SE(3)); 1 for the homography.
    double depth_scale = 1.0;
    if (Warp::kNeedsDepth) {
      std::copy(pz_.begin(), pz_.begin() + n, r_.begin());
      std::nth_element(r_.begin(), r_.begin() + n / 2, r_.begin() + n);
      depth_scale = static_cast<double>(r_[static_cast<std::size_t>(n / 2)]);
    }
    // The cost at the initial parameters, with the finest level's weights. Where the finest
    // level starts there (one level, no search: a refinement pass), the first iteration's
    // evaluation is the same one and gives it.
    const bool init_from_first = level == 0 && opt_.iterations > 0 && same_params(p, init);
    if (level == 0 && !init_from_first) {
      evaluate(n, init, K[0], g, Hout, cost, wsum);
      R.cost_init = wsum > 0 ? cost / wsum : 0;
      R.residual_init = mean_square_residual(n);
    }
    // One LM step from q, with the residuals the last evaluate() left (g, Hout): q moves and
    // the step's size is returned (rad, and m per metre of median depth), or -1 with `why`
    // set when the step is not finite or exceeds the bound. `level_start`: the first step of
    // the level, which measures the image noise that weighs the tilt and altitude priors.
    // The last step, for its image motion (TrackerOptions::min_step_px).
    Eigen::Matrix<double, DoF, 1> delta;
    auto lm_step = [&](Params& q, bool level_start, const char*& why) -> double {
      Hv = H - Hout;
      Eigen::Matrix<double, DoF, DoF> A = Hv;
      A.diagonal() *= 1.0 + opt_.lambda;
      Eigen::Matrix<double, DoF, 1> rhs = g;
      if (level_start && (tilt || altitude)) noise = image_noise(n);
      if (tilt) {
        // Prior 1/2 e'^T P e' on the rotation e' = log(R_init^T R') - tilt_ after the step:
        // the update R' = R exp(-delta) gives e' = e - delta (first order), so P joins H and
        // P e joins g.
        const Eigen::Matrix3d P = noise * tilt_info;
        const Eigen::Vector3d e = SE3Log<Params>::of(init, q).template head<3>() - tilt_;
        A.template topLeftCorner<3, 3>() += P;
        rhs.template head<3>() += P * e;
      }
      if (altitude) {
        // Prior 1/2 w e'^2 on the height, e' = e + J delta after the step: w J^T J joins H and
        // -w J^T e joins g.
        Eigen::Matrix<double, 1, DoF> J;
        const double e = height_row(q, J);
        const double w = noise * altitude_info;
        A += w * J.transpose() * J;
        rhs -= w * e * J.transpose();
      }
      delta = A.ldlt().solve(rhs);
      if (!delta.allFinite()) {
        why = "numerical failure: the step is not finite";
        return -1;
      }
      if (Warp::kNeedsDepth ? delta.template head<3>().norm() > opt_.max_step_rotation ||
                                  delta.template segment<3>(DoF - 3).norm() > opt_.max_step_translation * depth_scale
                            : delta.norm() > opt_.max_step_rotation) {
        why = "diverged: a step exceeded the bound";
        return -1;
      }
      Warp::update(q, delta.template cast<S>());
      if (!Warp::kNeedsDepth) return delta.norm();
      return std::max(delta.template head<3>().norm(), delta.template segment<3>(DoF - 3).norm() / depth_scale);
    };
    // Whether the last step moved the finest level's image by less than min_step_px.
    auto still = [&] {
      if constexpr (Warp::kNeedsDepth)
        return level == 0 && opt_.min_step_px > 0 && rms_motion_px(delta, n) < opt_.min_step_px;
      return false;
    };
    for (int it = 0; it < opt_.iterations; ++it) {
      const int valid = evaluate(n, p, K[level], g, Hout, cost, wsum);
      if (level == 0 && it == 0) R.cost_start = wsum > 0 ? cost / wsum : 0;
      if (init_from_first && it == 0) {
        R.cost_init = R.cost_start;
        R.residual_init = mean_square_residual(n);
      }
      if (valid < std::max(DoF * 4, level == 0 ? opt_.min_valid_pixels : 0)) {
        if (level == 0) return fail("too few pixels land inside the live image");
        break;
      }
      const char* why = nullptr;
      const double step = lm_step(p, it == 0, why);
      if (why) return fail(why);
      ++R.iterations;
      if (step < opt_.step_tol || still()) break;
    }
    R.ms_iterations += ms(ti, Clock::now());
    if (level == 0) {
      const int valid = evaluate(n, p, K[0], g, Hout, cost, wsum);
      R.valid_pixels = valid;
      R.cost_final = wsum > 0 ? cost / wsum : 0;
      R.residual_final = mean_square_residual(n);
      Hv = H - Hout;
      if (valid < opt_.min_valid_pixels) return fail("too few pixels land inside the live image");
      // Information per unit of rotation and of translation / median depth, so that the
      // test does not depend on the units (rad against m at some altitude).
      Eigen::Matrix<double, DoF, DoF> Hs = Hv;
      if (Warp::kNeedsDepth) {
        Eigen::Matrix<double, DoF, 1> s = Eigen::Matrix<double, DoF, 1>::Ones();
        s.template tail<3>().setConstant(depth_scale);
        Hs = s.asDiagonal() * Hv * s.asDiagonal();
      }
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, DoF, DoF>> eig(Hs, Eigen::EigenvaluesOnly);
      const double emax = eig.eigenvalues().maxCoeff(), emin = eig.eigenvalues().minCoeff();
      if (!(emax > 0) || !(emin > opt_.min_information * emax))
        return fail("no texture: the image does not constrain every degree of freedom");
      if (R.cost_final > opt_.max_final_cost) return fail("poor match: the final residual is above max_final_cost");
      const Vec6<double> moved = SE3Log<Params>::of(init, p);  // the answer against the start (SE(3) only)
      if (R.cost_final > opt_.max_cost_ratio * R.cost_init) {
        // How far the answer lies from the start: the RMS image motion over the used pixels
        // of the parameter change (first order, M = sum dW^T dW). A start already at the
        // cost's minimum (TrackerOptions::still_px) is confirmed, not diverged from.
        double moved_px = INFINITY;
        if constexpr (Warp::kNeedsDepth) moved_px = rms_motion_px(moved, n);
        if (!(moved_px < opt_.still_px)) return fail("diverged: the final cost is above the cost at the initial pose");
      }
      if (Warp::kNeedsDepth) {
        if (moved.template head<3>().norm() > opt_.max_rotation ||
            moved.template tail<3>().norm() > opt_.max_translation * depth_scale)
          return fail("diverged: the pose moved implausibly far from the initial one");
      }
      const double sigma2 = cost / std::max(wsum - DoF, 1.0);
      R.residual_correlation = residual_correlation(n);
      R.covariance_inflation = inflation_of(R.residual_correlation) * channel_factor(n);
      // The registration floor (TrackerOptions::registration_floor_px): the whole-image
      // motions at floor_px, with the map's own error on the ground (ground_floor_m) seen at
      // the median depth, the keystones at the share of the residual past what a camera's
      // noise leaves (TrackerOptions::keystone_free_residual).
      const double ground_px = Warp::kNeedsDepth ? opt_.ground_floor_m * static_cast<double>(K[0].fx) / depth_scale : 0.0;
      const double floor_px = hypot_exact(
          std::max(opt_.registration_floor_px, opt_.registration_floor_per_residual_px * R.residual_final), ground_px);
      const double keystone_px =
          opt_.registration_floor_per_residual_px * std::max(R.residual_final - opt_.keystone_free_residual, 0.0);
      Eigen::Matrix<double, DoF, DoF> P = R.covariance_inflation * sigma2 * Hv.inverse();
      if (floor_px > 0 || keystone_px > 0) {
        const Eigen::Matrix<double, DoF, DoF> M = motion0_.template selfadjointView<Eigen::Lower>();
        const Eigen::Matrix<double, DoF, DoF> Mi = M.inverse();
        // Each mode's b_m = sum dW^T d_m for d_m of RMS 1 px over the used pixels, times its size.
        Eigen::Matrix<double, DoF, kFloorModes> B = floor0_;
        const double inv_n = 1.0 / std::max(n, 1);
        const double uu = moments0_[0] * inv_n, vv = moments0_[1] * inv_n, uv = moments0_[2] * inv_n;
        const double r_rms = std::sqrt(uu + vv);  // rotation and scale
        if (r_rms > 0) B.template middleCols<2>(2) /= r_rms;
        // The keystones less their means (which are a shift).
        B.col(4) -= uu * floor0_.col(0) + uv * floor0_.col(1);
        B.col(5) -= uv * floor0_.col(0) + vv * floor0_.col(1);
        const double k4 = std::sqrt(std::max(moments0_[3] * inv_n - uu * uu - uv * uv, 0.0));
        const double k5 = std::sqrt(std::max(moments0_[4] * inv_n - uv * uv - vv * vv, 0.0));
        B.col(4) *= k4 > 0 ? keystone_px / k4 : 0.0;
        B.col(5) *= k5 > 0 ? keystone_px / k5 : 0.0;
        B.template leftCols<4>() *= floor_px;
        P += Mi * B * B.transpose() * Mi;
      }
      // With the tilt and altitude priors' information: the image term's covariance (the floor
      // included) narrowed where an attitude reference knows the tilt, or an altimeter the
      // height, better.
      if (tilt || altitude) {
        Eigen::Matrix<double, DoF, DoF> info = P.inverse();
        if (tilt) info.template topLeftCorner<3, 3>() += tilt_info;
        if (altitude) {
          Eigen::Matrix<double, 1, DoF> J;
          height_row(p, J);
          info += altitude_info * J.transpose() * J;
        }
        P = info.inverse();
      }
      R.covariance = P;
      if (Warp::kNeedsDepth && opt_.probe_px > 0) {
        double least = INFINITY;
        for (int k = 0; k < 4; ++k) {
          const double px = (k & 1 ? -1.0 : 1.0) * opt_.probe_px;
          evaluate(n, shifted(p, k < 2 ? px : 0.0, k < 2 ? 0.0 : px, K[0]), K[0], g, Hout, cost, wsum);
          least = std::min(least, mean_square_residual(n));
        }
        R.sharpness = R.residual_final > 0 ? least / R.residual_final : 0.0;
        if (R.sharpness < opt_.min_sharpness) return fail("ambiguous: the image agreement is as good a few pixels away");
      }
      if constexpr (Warp::kNeedsDepth) {
        if (opt_.agree_px > 0) {
          // A second start nearby, the same weights and H: where it settles.
          const auto ta = Clock::now();
          Params q = shifted(p, opt_.agree_px, opt_.agree_px, K[0]);
          bool settled = true;
          for (int it = 0; it < opt_.agree_iterations && settled; ++it) {
            const char* why = nullptr;
            const bool inside = evaluate(n, q, K[0], g, Hout, cost, wsum) >= opt_.min_valid_pixels;
            const double step = inside ? lm_step(q, false, why) : -1.0;
            settled = step >= 0;
            if (settled && (step < opt_.step_tol || still())) break;
          }
          R.disagreement_px = settled ? rms_motion_px(SE3Log<Params>::of(p, q), n) : INFINITY;
          R.ms_iterations += ms(ta, Clock::now());
          if (opt_.max_disagreement_px > 0 && !(R.disagreement_px <= opt_.max_disagreement_px)) {
            const double scale = R.disagreement_px / opt_.max_disagreement_px;
            const Eigen::Matrix<double, DoF, DoF> scaled = R.covariance * (scale * scale);
            fail("ambiguous: a start nearby settles elsewhere");
            if (std::isfinite(scale)) {
              R.unconfirmed = true;
              R.unconfirmed_params = p;
              R.unconfirmed_covariance = scaled;
              R.unconfirmed_scale = scale;
            }
            return R;
          }
        }
      }
    }
  }
  R.params = p;
  R.converged = true;
  R.reason = "converged";
  return R;
}

template class Tracker<float, SE3DepthWarp<float>, 1>;
template class Tracker<float, SE3DepthWarp<float>, 2>;  // the learned tracker's feature channels
template class Tracker<float, SE3DepthWarp<float>, 4>;
template class Tracker<double, SE3DepthWarp<double>, 1>;
template class Tracker<float, HomographyWarp<float>, 1>;
template class Tracker<double, HomographyWarp<double>, 1>;

}  // namespace terralign::iclk
