#include <terralign/nn/kernels.hpp>

#include <algorithm>
#include <cmath>

#include <terralign/geo/assert.hpp>
#include <terralign/geo/cpu.hpp>

#include "simd_scalar.hpp"  // kExpShifter, pow2_of_shifted

namespace terralign::nn {

bool nn_cpu_has_avx2() {
#if defined(TERRALIGN_NN_AVX2)
  return cpu_features().avx2_fma;
#else
  return false;
#endif
}

bool nn_cpu_has_neon() {
#if defined(TERRALIGN_NN_NEON)
  return true;
#else
  return false;
#endif
}

bool nn_cpu_has_avx512() {
#if defined(TERRALIGN_NN_AVX2)
  return cpu_features().avx512f;
#else
  return false;
#endif
}

bool winograd_suits(int cin, int cout) { return cin >= kWinogradMinCin && cout > 1; }

int conv_row_align(const ConvWeights& w) { return w.winograd.empty() ? 1 : w.winograd_tile * w.dilation; }

std::size_t conv_scratch_floats(const ConvWeights& w) {
  if (w.winograd.empty()) return 0;
  // U: T x T taps x tiles x cin; M: T x T taps x tiles x channels; the patches: tiles x T x T x cin.
  return 2 * winograd_u_floats(w.winograd_tile, w.cin) + winograd_m_floats(w.winograd_tile, w.block);
}

ConvWeights pack_conv(const float* oihw, const float* bias, int cin, int cout, int dilation, Act act, int block,
                      int winograd_tile) {
  TERRALIGN_ASSERT(winograd_tile == 0 || winograd_tile == 2 || winograd_tile == 4, "pack_conv: Winograd's tile is 0 (direct), 2 or 4");
  ConvWeights w;
  w.block = block;
  w.cin = cin;
  w.cout = cout;
  w.dilation = dilation;
  w.act = act;
  const int blocks = (cout + block - 1) / block;
  const std::size_t B = static_cast<std::size_t>(block);
  const bool winograd = winograd_tile > 0 && winograd_suits(cin, cout);
  w.bias.assign(static_cast<std::size_t>(blocks) * B, 0.0f);
  for (int co = 0; co < cout; ++co) w.bias[static_cast<std::size_t>(co)] = bias ? bias[co] : 0.0f;
  if (!winograd) {  // Winograd's layers keep only their transformed filters (below)
    w.packed.assign(static_cast<std::size_t>(blocks) * 9 * static_cast<std::size_t>(cin) * B, 0.0f);
    for (int co = 0; co < cout; ++co)
      for (int ci = 0; ci < cin; ++ci)
        for (int k = 0; k < 9; ++k)
          w.packed[((static_cast<std::size_t>(co / block) * 9 + static_cast<std::size_t>(k)) * static_cast<std::size_t>(cin) + static_cast<std::size_t>(ci)) * B + static_cast<std::size_t>(co % block)] =
              oihw[(static_cast<std::size_t>(co) * static_cast<std::size_t>(cin) + static_cast<std::size_t>(ci)) * 9 + static_cast<std::size_t>(k)];
  }
  if (winograd) {
    // U = G g G^T per filter, in double, rounded once. F(2x2)'s G has rows (1, 0, 0),
    // (1, 1, 1) / 2, (1, -1, 1) / 2, (0, 0, 1); F(4x4)'s (Lavin and Gray) (1/4, 0, 0),
    // -(1, 1, 1) / 6, -(1, -1, 1) / 6, (1/24, 1/12, 1/6), (1/24, -1/12, 1/6), (0, 0, 1).
    constexpr double G2[4][3] = {{1, 0, 0}, {0.5, 0.5, 0.5}, {0.5, -0.5, 0.5}, {0, 0, 1}};
    constexpr double G4[6][3] = {{0.25, 0, 0},           {-1.0 / 6, -1.0 / 6, -1.0 / 6}, {-1.0 / 6, 1.0 / 6, -1.0 / 6},
                                 {1.0 / 24, 1.0 / 12, 1.0 / 6}, {1.0 / 24, -1.0 / 12, 1.0 / 6},  {0, 0, 1}};
    const int T = winograd_tile + 2;
    auto G = [&](int i, int k) { return winograd_tile == 4 ? G4[i][k] : G2[i][k]; };
    w.winograd_tile = winograd_tile;
    const std::size_t taps = static_cast<std::size_t>(T * T);
    w.winograd.assign(static_cast<std::size_t>(blocks) * taps * static_cast<std::size_t>(cin) * B, 0.0f);
    for (int co = 0; co < cout; ++co)
      for (int ci = 0; ci < cin; ++ci) {
        const float* g = oihw + (static_cast<std::size_t>(co) * static_cast<std::size_t>(cin) + static_cast<std::size_t>(ci)) * 9;
        for (int i = 0; i < T; ++i)
          for (int j = 0; j < T; ++j) {
            double u = 0;
            for (int ky = 0; ky < 3; ++ky)
              for (int kx = 0; kx < 3; ++kx) u += G(i, ky) * static_cast<double>(g[ky * 3 + kx]) * G(j, kx);
            w.winograd[((static_cast<std::size_t>(co / block) * taps + static_cast<std::size_t>(i * T + j)) * static_cast<std::size_t>(cin) + static_cast<std::size_t>(ci)) * B + static_cast<std::size_t>(co % block)] =
                static_cast<float>(u);
          }
      }
  }
  if (cout == 1) {
    w.taps.resize(9 * static_cast<std::size_t>(cin));
    for (int ci = 0; ci < cin; ++ci)
      for (int k = 0; k < 9; ++k)
        w.taps[static_cast<std::size_t>(k) * static_cast<std::size_t>(cin) + static_cast<std::size_t>(ci)] = oihw[static_cast<std::size_t>(ci) * 9 + static_cast<std::size_t>(k)];
  }
  return w;
}

void avgpool2_rows(const Tensor& in, Tensor& out, int y0, int y1) {
  for (int y = y0; y < y1; ++y)
    for (int x = 0; x < out.w; ++x) {
      const float* a = in.at(2 * y, 2 * x);
      const float* b = in.at(2 * y, 2 * x + 1);
      const float* c = in.at(2 * y + 1, 2 * x);
      const float* d = in.at(2 * y + 1, 2 * x + 1);
      float* o = out.at(y, x);
      for (int k = 0; k < in.c; ++k) o[k] = ((a[k] + b[k]) + (c[k] + d[k])) * 0.25f;
    }
}

void mean_channels_rows(const Tensor& in, Tensor& out, int y0, int y1) {
  // out.c groups of in.c / out.c consecutive channels, each averaged (one group: all of them).
  // double: the mean of 128 channels keeps float's full precision. Each pixel's sum is one
  // chain of dependent adds in channel order; eight pixels' chains run side by side (the same
  // bits as one pixel at a time, at a fraction of the latency).
  const int group = in.c / out.c;
  const float inv = 1.0f / static_cast<float>(group);
  constexpr int kPixels = 8;
  const std::ptrdiff_t cp = in.cp;
  for (int y = y0; y < y1; ++y) {
    int x = 0;
    for (; x + kPixels <= out.w; x += kPixels) {
      const float* p = in.at(y, x);
      for (int g = 0; g < out.c; ++g, p += group) {
        double s[kPixels] = {};
        for (int k = 0; k < group; ++k)
          for (int l = 0; l < kPixels; ++l) s[l] += p[l * cp + k];
        for (int l = 0; l < kPixels; ++l) out.at(y, x + l)[g] = static_cast<float>(s[l]) * inv;
      }
    }
    for (; x < out.w; ++x) {
      const float* p = in.at(y, x);
      for (int g = 0; g < out.c; ++g, p += group) {
        double s = 0;
        for (int k = 0; k < group; ++k) s += p[k];
        out.at(y, x)[g] = static_cast<float>(s) * inv;
      }
    }
  }
}

namespace {

// exp(x) for x <= 0 in plain multiplies and adds, so the same bits on every machine (libm's
// expf is the C library's to its last bit; and std::fma, a library call where the file is
// built without FMA, made this 3-5x the time of expf). x = n ln2 + r, |r| <= ln2 / 2: n from
// x log2(e) + (1.5 2^23 + 127) (expm1_neg_avx2's trick, whose word shifted left by 23 is 2^n),
// r with ln2 in two parts (Cody and Waite: n ln2_hi is exact for |n| < 512), exp(r) to degree
// 7 by Horner (truncation 5e-9). Below -87 it stays exp(-87) (1.6e-38); a NaN stays NaN.
float exp_neg(float x) {
  x = -87.0f > x ? -87.0f : x;
  const float nb = x * 1.44269504088896341f + kExpShifter;
  const float n = nb - kExpShifter;
  const float r = (x - n * 0.693145751953125f) - n * 1.42860682030941723212e-6f;
  float p = 1.0f / 5040.0f;
  p = p * r + 1.0f / 720.0f;
  p = p * r + 1.0f / 120.0f;
  p = p * r + 1.0f / 24.0f;
  p = p * r + 1.0f / 6.0f;
  p = p * r + 0.5f;
  p = p * r + 1.0f;
  p = p * r + 1.0f;
  return p * pow2_of_shifted(nb);
}

// 1 / (1 + exp(-x)) from e = exp(-|x|) <= 1: 1 / (1 + e) for x >= 0, e / (1 + e) below, where
// e carries all the precision.
float sigmoid(float x) {
  const float e = exp_neg(-std::abs(x));
  return x >= 0.0f ? 1.0f / (1.0f + e) : e / (1.0f + e);
}

}  // namespace

void sigmoid_rows(const Tensor& in, Tensor& out, int y0, int y1) {
  for (int y = y0; y < y1; ++y)
    for (int x = 0; x < out.w; ++x) {
      const float* p = in.at(y, x);
      float* o = out.at(y, x);
      for (int k = 0; k < in.c; ++k) o[k] = sigmoid(p[k]);
    }
}

void upsample2_rows(const Tensor& in, Tensor& out, int y0, int y1) {
  // Source coordinate of output pixel i: (i + 0.5) / 2 - 0.5, clamped at 0 (PyTorch,
  // align_corners = False); the far neighbour is clamped to the last pixel.
  auto src = [](int i, int n, int& i0, int& i1, float& f) {
    float s = (static_cast<float>(i) + 0.5f) * 0.5f - 0.5f;
    s = std::max(s, 0.0f);
    i0 = std::min(static_cast<int>(s), n - 1);
    i1 = std::min(i0 + 1, n - 1);
    f = s - static_cast<float>(i0);
  };
  for (int y = y0; y < y1; ++y) {
    int ya, yb;
    float fy;
    src(y, in.h, ya, yb, fy);
    for (int x = 0; x < out.w; ++x) {
      int xa, xb;
      float fx;
      src(x, in.w, xa, xb, fx);
      const float *a = in.at(ya, xa), *b = in.at(ya, xb), *c = in.at(yb, xa), *d = in.at(yb, xb);
      float* o = out.at(y, x);
      for (int k = 0; k < in.c; ++k)
        o[k] = (1.0f - fy) * ((1.0f - fx) * a[k] + fx * b[k]) + fy * ((1.0f - fx) * c[k] + fx * d[k]);
    }
  }
}

void concat_rows(const Tensor* const* ins, int n, Tensor& out, int y0, int y1) {
  for (int y = y0; y < y1; ++y)
    for (int x = 0; x < out.w; ++x) {
      float* o = out.at(y, x);
      for (int i = 0; i < n; ++i) {
        const float* p = ins[i]->at(y, x);
        std::copy(p, p + ins[i]->c, o);
        o += ins[i]->c;
      }
    }
}

}  // namespace terralign::nn
