// The 3x3 convolution (stride 1, padding = dilation), written once against a vector
// wrapper V (VecScalar, VecAvx2, VecAvx512, VecNeon). Included by conv_<isa>.cpp.
//
// Two kernels. The direct one: register blocking of NP output pixels of one row x NB blocks
// of V::kBlock output channels; for every tap and input channel, one broadcast of the input
// value per pixel and one load of the weights per vector feed NP x NB x NV multiply-adds.
// Winograd's F(2x2, 3x3) (kernels.hpp) for the layers that suit it: the same register tile,
// over NT tiles of 2 x 2 outputs instead of NP pixels and 16 transformed taps instead of 9.
// Both read the halo (zeros) at borders.
#pragma once

#include <algorithm>
#include <type_traits>

#include <terralign/geo/assert.hpp>
#include <terralign/nn/kernels.hpp>

#include "simd_scalar.hpp"  // Winograd's transform of the channels a vector leaves over

namespace terralign::nn {

template <class V>
inline V activate(V v, Act act) {
  if (act == Act::Elu) return elu(v);
  if (act == Act::Relu) return relu(v);
  return v;
}

// The register tile's inner product: for input channels [0, cin), the values a[p * stride +
// ci] of NP pixels (or tiles) times the weights of NB blocks of output channels (wp[b] + ci *
// kBlock), added into acc. One broadcast a value and one load a weight vector feed
// NP x NB x NV multiply-adds. CIN > 0: cin is CIN, known to the compiler, which unrolls the
// loop (the same operations in the same order).
template <class V, int NP, int NB, int CIN = 0>
inline void tile_products(V (&acc)[NP][NB * (V::kBlock / V::kWidth)], const float* a, std::ptrdiff_t stride,
                          const float* const* wp, int cin) {
  constexpr int BLK = V::kBlock, NV = BLK / V::kWidth;
  if constexpr (CIN > 0) cin = CIN;
  for (int ci = 0; ci < cin; ++ci) {
    V wv[NB * NV];
    for (int b = 0; b < NB; ++b)
      for (int j = 0; j < NV; ++j) wv[b * NV + j] = V::load(wp[b] + ci * BLK + j * V::kWidth);
    for (int p = 0; p < NP; ++p) {
      const V x = V::set1(a[p * stride + ci]);
      for (int k = 0; k < NB * NV; ++k) acc[p][k] = fmadd(x, wv[k], acc[p][k]);
    }
  }
}

template <class V, int NP, int NB, int CIN>
inline void conv_tile(const Tensor& in, const ConvWeights& w, Tensor& out, int y, int x, int block) {
  constexpr int BLK = V::kBlock;
  constexpr int NV = BLK / V::kWidth;  // vectors per block of channels
  V acc[NP][NB * NV];
  for (int b = 0; b < NB; ++b)
    for (int j = 0; j < NV; ++j) {
      const V bias = V::load(w.bias.data() + (block + b) * BLK + j * V::kWidth);
      for (int p = 0; p < NP; ++p) acc[p][b * NV + j] = bias;
    }
  const int d = w.dilation, cin = w.cin, cp = in.cp;
  for (int ky = 0; ky < 3; ++ky)
    for (int kx = 0; kx < 3; ++kx) {
      const float* ip = in.at(y + (ky - 1) * d, x + (kx - 1) * d);
      const float* wp[NB];
      for (int b = 0; b < NB; ++b)
        wp[b] = w.packed.data() + (static_cast<std::size_t>(block + b) * 9 + static_cast<std::size_t>(ky * 3 + kx)) * static_cast<std::size_t>(cin) * BLK;
      tile_products<V, NP, NB, CIN>(acc, ip, cp, wp, cin);
    }
  for (int p = 0; p < NP; ++p) {
    float* op = out.at(y, x + p) + block * BLK;
    for (int k = 0; k < NB * NV; ++k) {
      activate(acc[p][k], w.act).store(op + k * V::kWidth);
    }
  }
}

// One output channel (the M-estimator's last layer): the vectors run along the input
// channels, so no lane computes a padded output channel (a block of 8 or 16 would be 1/8 or
// 1/16 useful). Reads only the input's `cin` channels: groups of V::kWidth, then the rest
// one by one; NP pixels at a time for independent chains. The lanes are summed in a fixed
// order (each wrapper's hsum), so the result depends on the kernel, not on the row split.
template <class V, int NP>
inline void conv1_tile(const Tensor& in, const ConvWeights& w, Tensor& out, int y, int x) {
  constexpr int W = V::kWidth;
  const int d = w.dilation, cin = w.cin, cp = in.cp, groups = cin / W;
  V acc[NP];
  float rest[NP];
  for (int p = 0; p < NP; ++p) {
    acc[p] = V::set1(0.0f);
    rest[p] = 0.0f;
  }
  for (int ky = 0; ky < 3; ++ky)
    for (int kx = 0; kx < 3; ++kx) {
      const float* ip = in.at(y + (ky - 1) * d, x + (kx - 1) * d);
      const float* wp = w.taps.data() + static_cast<std::size_t>(ky * 3 + kx) * static_cast<std::size_t>(cin);
      for (int g = 0; g < groups; ++g) {
        const V wv = V::load(wp + g * W);
        for (int p = 0; p < NP; ++p) acc[p] = fmadd(V::load(ip + p * cp + g * W), wv, acc[p]);
      }
      for (int ci = groups * W; ci < cin; ++ci)
        for (int p = 0; p < NP; ++p) rest[p] += ip[p * cp + ci] * wp[ci];
    }
  for (int p = 0; p < NP; ++p) {
    const V v = activate(V::set1(w.bias[0] + (hsum(acc[p]) + rest[p])), w.act);
    float* op = out.at(y, x + p);
    // The padded channels the block kernel would have written: zeros (see below).
    for (int k = 0; k < V::kBlock; k += W) V::set1(0.0f).store(op + k);
    op[0] = lane0(v);
  }
}

// Every block of w's output channels, kTileBlocks at a time, the rest in pairs where the tile
// is wider than two, then one by one: f(std::integral_constant<int, NB>, first block).
template <class V, class F>
inline void for_block_groups(const ConvWeights& w, F&& f) {
  constexpr int NB = V::kTileBlocks;
  const int blocks = (w.cout + V::kBlock - 1) / V::kBlock;
  int block = 0;
  for (; block + NB <= blocks; block += NB) f(std::integral_constant<int, NB>{}, block);
  for (; NB > 2 && block + 2 <= blocks; block += 2) f(std::integral_constant<int, 2>{}, block);
  for (; block < blocks; ++block) f(std::integral_constant<int, 1>{}, block);
}

// The direct kernel over NP output pixels from x of row y, every block of output channels
// (CIN: as tile_products()).
template <class V, int NP, int CIN = 0>
inline void conv_pixels(const Tensor& in, const ConvWeights& w, Tensor& out, int y, int x) {
  for_block_groups<V>(w, [&](auto nb, int block) { conv_tile<V, NP, decltype(nb)::value, CIN>(in, w, out, y, x, block); });
}

template <class V, int CIN>
inline void conv_row_cin(const Tensor& in, const ConvWeights& w, Tensor& out, int y) {
  constexpr int NP = V::kTilePixels;
  int x = 0;
  for (; x + NP <= out.w; x += NP) conv_pixels<V, NP, CIN>(in, w, out, y, x);
  for (; x < out.w; ++x) conv_pixels<V, 1, CIN>(in, w, out, y, x);
}

// The direct kernel over one output row. Layers of 3, 4 and 8 inputs (the encoder's and the
// M-estimator's first layers, and the small networks' 8-channel levels, all below Winograd's
// kWinogradMinCin) have their channel loop unrolled: with so few channels its counting was a
// large part of each tap's work (session 68: 5-22 % of these layers' time on AVX2).
template <class V>
inline void conv_row(const Tensor& in, const ConvWeights& w, Tensor& out, int y) {
  switch (w.cin) {
    case 3: conv_row_cin<V, 3>(in, w, out, y); break;
    case 4: conv_row_cin<V, 4>(in, w, out, y); break;
    case 8: conv_row_cin<V, 8>(in, w, out, y); break;
    default: conv_row_cin<V, 0>(in, w, out, y);
  }
}

// Winograd, step 1: the input transform B^T d B of NT tiles (top-left outputs (y, xs[t])),
// into U[e][t][ci] for the 16 transformed taps e = 4 i + j. B^T's rows combine a tile's input
// rows (0 - 2), (1 + 2), (2 - 1), (1 - 3), and its columns the same way; input row/column i of
// a tile is y + (i - 1) d / x + (i - 1) d. Additions only: every build gives the same bits.
template <class V>
inline void winograd_combine(const V* d, V* u, int stride) {
  u[0] = d[0] - d[2 * stride];
  u[stride] = d[stride] + d[2 * stride];
  u[2 * stride] = d[2 * stride] - d[stride];
  u[3 * stride] = d[stride] - d[3 * stride];
}

// One tile's transform for T::kWidth channels from p (input row stride `row`, column
// stride `step`) into u (taps `tap` floats apart). T: the kernel's wrapper, or VecScalar for
// the channels left over (the same operations).
template <class T>
inline void winograd_transform(const float* p, std::ptrdiff_t row, std::ptrdiff_t step, float* u, std::ptrdiff_t tap) {
  T v[16], r[16];
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) v[4 * i + j] = T::load(p + i * row + j * step);
  for (int j = 0; j < 4; ++j) winograd_combine(v + j, r + j, 4);          // rows
  for (int i = 0; i < 4; ++i) winograd_combine(r + 4 * i, v + 4 * i, 1);  // columns
  for (int e = 0; e < 16; ++e) v[e].store(u + e * tap);
}

template <class V, int NT>
inline void winograd_input(const Tensor& in, const ConvWeights& w, int y, const int* xs, float* U) {
  const int d = w.dilation, cin = w.cin;
  const std::ptrdiff_t row = in.row * d, step = static_cast<std::ptrdiff_t>(d) * in.cp;
  const std::ptrdiff_t tap = static_cast<std::ptrdiff_t>(NT) * cin;  // floats between U's taps
  for (int t = 0; t < NT; ++t) {
    const float* p = in.at(y - d, xs[t] - d);
    float* u = U + static_cast<std::ptrdiff_t>(t) * cin;
    int c = 0;
    for (; c + V::kWidth <= cin; c += V::kWidth) winograd_transform<V>(p + c, row, step, u + c, tap);
    for (; c < cin; ++c) winograd_transform<VecScalar>(p + c, row, step, u + c, tap);
  }
}

// Winograd, step 2, for NB blocks of output channels from `block`: the 16 products of U and
// the transformed filters (a register tile each, tile_products()) into M[e][t][channel], then the
// output transform A^T m A (A^T's rows: 0 + 1 + 2, 1 - 2 - 3), the bias and the activation.
template <class V, int NT, int NB>
inline void winograd_block(const ConvWeights& w, const float* U, int block, float* M, Tensor& out, int y, const int* xs) {
  constexpr int BLK = V::kBlock, W = V::kWidth, NV = BLK / W, K = NB * NV;
  const int cin = w.cin, d = w.dilation;
  for (int e = 0; e < 16; ++e) {
    V acc[NT][K];
    for (int t = 0; t < NT; ++t)
      for (int k = 0; k < K; ++k) acc[t][k] = V::set1(0.0f);
    const float* wp[NB];
    for (int b = 0; b < NB; ++b)
      wp[b] = w.winograd.data() + (static_cast<std::size_t>(block + b) * 16 + static_cast<std::size_t>(e)) * static_cast<std::size_t>(cin) * BLK;
    tile_products<V, NT, NB>(acc, U + static_cast<std::ptrdiff_t>(e) * NT * cin, cin, wp, cin);
    for (int t = 0; t < NT; ++t)
      for (int k = 0; k < K; ++k) acc[t][k].store(M + ((e * NT + t) * K + k) * W);
  }
  for (int t = 0; t < NT; ++t)
    for (int k = 0; k < K; ++k) {
      V m[16], c[8];
      for (int e = 0; e < 16; ++e) m[e] = V::load(M + ((e * NT + t) * K + k) * W);
      for (int i = 0; i < 4; ++i) {  // columns of each row
        c[2 * i] = (m[4 * i] + m[4 * i + 1]) + m[4 * i + 2];
        c[2 * i + 1] = (m[4 * i + 1] - m[4 * i + 2]) - m[4 * i + 3];
      }
      const int ch = block * BLK + k * W;
      const V bias = V::load(w.bias.data() + ch);
      for (int j = 0; j < 2; ++j) {  // then rows, per output column
        const V top = (c[j] + c[2 + j]) + c[4 + j], bottom = (c[2 + j] - c[4 + j]) - c[6 + j];
        activate(top + bias, w.act).store(out.at(y, xs[t] + j * d) + ch);
        activate(bottom + bias, w.act).store(out.at(y + d, xs[t] + j * d) + ch);
      }
    }
}

// NT tiles of rows y and y + d, in the caller's scratch (conv_scratch_floats()).
template <class V, int NT>
inline void winograd_tiles(const Tensor& in, const ConvWeights& w, Tensor& out, int y, const int* xs, float* scratch) {
  constexpr int BLK = V::kBlock, NB = V::kTileBlocks;
  static_assert(NT <= kWinogradTiles && NB * BLK <= kWinogradChannels, "conv_scratch_floats() sizes a smaller tile");
  float* U = scratch;
  float* M = scratch + (16 * static_cast<std::ptrdiff_t>(kWinogradTiles) * w.cin + 15) / 16 * 16;
  winograd_input<V, NT>(in, w, y, xs, U);
  for_block_groups<V>(w, [&](auto nb, int block) { winograd_block<V, NT, decltype(nb)::value>(w, U, block, M, out, y, xs); });
}

// Winograd over rows [y0, y1): pairs (y, y + d) with y mod 2d < d both inside the band run as
// tiles; a row whose partner is outside the image (or the band) and a column whose partner is
// outside the image run the direct kernel.
template <class V>
inline void winograd_rows(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch) {
  constexpr int NT = V::kTilePixels;
  const int d = w.dilation;
  for (int y = y0; y < y1; ++y) {
    const bool top = y % (2 * d) < d;
    const int partner = top ? y + d : y - d;
    if (partner < y0 || partner >= y1) {
      conv_row<V>(in, w, out, y);
      continue;
    }
    if (!top) continue;  // its pair ran with the row above
    int xs[NT];
    int n = 0;
    for (int x = 0; x < out.w; ++x) {
      if (x % (2 * d) >= d) continue;  // the right column of a tile
      if (x + d >= out.w) {
        conv_pixels<V, 1>(in, w, out, y, x);
        conv_pixels<V, 1>(in, w, out, y + d, x);
        continue;
      }
      xs[n++] = x;
      if (n == NT) {
        winograd_tiles<V, NT>(in, w, out, y, xs, scratch);
        n = 0;
      }
    }
    for (int t = 0; t < n; ++t) winograd_tiles<V, 1>(in, w, out, y, xs + t, scratch);
  }
}

template <class V>
inline void conv3x3_rows(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch) {
  TERRALIGN_DEBUG_ASSERT(w.block == V::kBlock, "conv3x3_rows: weights packed for another kernel");
  if (w.cout == 1 && w.taps.size() == 9 * static_cast<std::size_t>(w.cin)) {  // (bench_nn clears taps for the peer)
    for (int y = y0; y < y1; ++y) {
      int x = 0;
      for (; x + 4 <= out.w; x += 4) conv1_tile<V, 4>(in, w, out, y, x);
      for (; x < out.w; ++x) conv1_tile<V, 1>(in, w, out, y, x);
    }
    return;
  }
  // Padded output channels must stay zero: the next layer reads only cin channels, but mean
  // and concat read cp; the bias and the weights of padded channels are zero, and ELU(0) = 0.
  if (!w.winograd.empty()) {
    TERRALIGN_ASSERT(scratch, "conv3x3_rows: Winograd's layer without scratch memory");
    winograd_rows<V>(in, w, out, y0, y1, scratch);
    return;
  }
  for (int y = y0; y < y1; ++y) conv_row<V>(in, w, out, y);
}

}  // namespace terralign::nn
