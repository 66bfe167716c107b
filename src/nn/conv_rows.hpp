// The 3x3 convolution (stride 1, padding = dilation), written once against a vector
// wrapper V (VecScalar, VecAvx2, VecAvx512, VecNeon). Included by conv_<isa>.cpp.
//
// Two kernels. The direct one: register blocking of NP output pixels of one row x NB blocks
// of V::kBlock output channels; for every tap and input channel, one broadcast of the input
// value per pixel and one load of the weights per vector feed NP x NB x NV multiply-adds.
// Winograd's F(4x4, 3x3) (or F(2x2, 3x3), kernels.hpp) for the layers that suit it: the same
// register tile, over NT tiles of 4 x 4 (2 x 2) outputs instead of NP pixels and 36 (16)
// transformed taps instead of 9. Both read the halo (zeros) at borders; Winograd's tiles that
// reach past it read a gathered patch.
#pragma once

#include <algorithm>
#include <cmath>
#include <type_traits>

#include <terralign/geo/assert.hpp>
#include <terralign/nn/kernels.hpp>

#include "simd_scalar.hpp"  // Winograd's transform of the channels a vector leaves over; conv1_tile's sum

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
// 1/16 useful). Every build sums in the same eight lanes, V::Lanes8 (AVX-512's are AVX2's,
// NEON's two vectors, the scalar build's eight floats): lane l takes the channels l, l + 8, ..
// of every tap in turn, the channels past the last group of eight are one chain beside them,
// and the lanes are added in one order, ((0 + 4) + (2 + 6)) + ((1 + 5) + (3 + 7)). So the
// bits depend neither on the ISA nor on the row split. NP pixels at a time for independent
// chains.
template <class V, int NP>
inline void conv1_tile(const Tensor& in, const ConvWeights& w, Tensor& out, int y, int x) {
  using L = typename V::Lanes8;
  constexpr int W = L::kWidth, NV = 8 / W;
  static_assert(NV * W == 8, "the one-channel kernel's lanes are eight floats");
  const int d = w.dilation, cin = w.cin, cp = in.cp, groups = cin / 8;
  L acc[NP][NV];
  float rest[NP];
  for (int p = 0; p < NP; ++p) {
    for (int j = 0; j < NV; ++j) acc[p][j] = L::set1(0.0f);
    rest[p] = 0.0f;
  }
  for (int ky = 0; ky < 3; ++ky)
    for (int kx = 0; kx < 3; ++kx) {
      const float* ip = in.at(y + (ky - 1) * d, x + (kx - 1) * d);
      const float* wp = w.taps.data() + static_cast<std::size_t>(ky * 3 + kx) * static_cast<std::size_t>(cin);
      for (int g = 0; g < groups; ++g)
        for (int j = 0; j < NV; ++j) {
          const int c = g * 8 + j * W;
          const L wv = L::load(wp + c);
          for (int p = 0; p < NP; ++p) acc[p][j] = fmadd(L::load(ip + p * cp + c), wv, acc[p][j]);
        }
      for (int ci = groups * 8; ci < cin; ++ci)
        for (int p = 0; p < NP; ++p) rest[p] = fma_float(ip[p * cp + ci], wp[ci], rest[p]);
    }
  for (int p = 0; p < NP; ++p) {
    float l[8];
    for (int j = 0; j < NV; ++j) acc[p][j].store(l + j * W);
    const float sum = ((l[0] + l[4]) + (l[2] + l[6])) + ((l[1] + l[5]) + (l[3] + l[7]));
    float* op = out.at(y, x + p);
    // The padded channels the block kernel would have written: zeros (see below).
    for (int k = 0; k < V::kBlock; k += V::kWidth) V::set1(0.0f).store(op + k);
    op[0] = activate(VecScalar::set1(w.bias[0] + (sum + rest[p])), w.act).v;
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

// Winograd's F(m x m, 3x3), m = 2 or 4 (kernels.hpp): an m x m output tile from a T x T input
// tile, T = m + 2, through T x T transformed taps. Step 1, the input transform B^T d B of NT
// tiles (top-left outputs (y, x)), into U[e][t][ci] for the taps e = T i + j; input
// row/column i of a tile is y + (i - 1) d / x + (i - 1) d. B^T, applied to T values `stride`
// apart: for m = 2 its rows combine (0 - 2), (1 + 2), (2 - 1), (1 - 3); for m = 4 (Lavin and
// Gray's points 0, 1, -1, 2, -2) 4 (0 - 2) + (4 - 2), (4 - 4 x 2) +- (3 - 4 x 1),
// (4 - 2) +- 2 (3 - 1), 4 (1 - 3) + (5 - 3). Additions, and multiply-adds by powers of two,
// which round once with or without FMA: every build gives the same bits.
template <int M, class V>
inline void winograd_in(const V* d, V* u, int stride) {
  if constexpr (M == 2) {
    u[0] = d[0] - d[2 * stride];
    u[stride] = d[stride] + d[2 * stride];
    u[2 * stride] = d[2 * stride] - d[stride];
    u[3 * stride] = d[stride] - d[3 * stride];
  } else {
    static_assert(M == 4, "Winograd's output tile is 2 x 2 or 4 x 4");
    const V d0 = d[0], d1 = d[stride], d2 = d[2 * stride], d3 = d[3 * stride], d4 = d[4 * stride], d5 = d[5 * stride];
    const V four = V::set1(4.0f), minus_four = V::set1(-4.0f);
    const V t1 = fmadd(minus_four, d2, d4), t2 = fmadd(minus_four, d1, d3), t3 = d4 - d2, t31 = d3 - d1, t4 = t31 + t31;
    u[0] = fmadd(four, d0 - d2, t3);
    u[stride] = t1 + t2;
    u[2 * stride] = t1 - t2;
    u[3 * stride] = t3 + t4;
    u[4 * stride] = t3 - t4;
    u[5 * stride] = fmadd(four, d1 - d3, d5 - d3);
  }
}

// A^T, T values `stride` apart into m: for m = 2 (0 + 1) + 2, (1 - 2) - 3; for m = 4 with
// s = 1 + 2, t = 3 + 4, a = 1 - 2, b = 3 - 4: (0 + s) + t, a + 2 b, s + 4 t, (a + 8 b) + 5.
template <int M, class V>
inline void winograd_out(const V* m, int stride, V* o) {
  if constexpr (M == 2) {
    o[0] = (m[0] + m[stride]) + m[2 * stride];
    o[1] = (m[stride] - m[2 * stride]) - m[3 * stride];
  } else {
    const V s = m[stride] + m[2 * stride], a = m[stride] - m[2 * stride];
    const V t = m[3 * stride] + m[4 * stride], b = m[3 * stride] - m[4 * stride];
    o[0] = (m[0] + s) + t;
    o[1] = fmadd(V::set1(2.0f), b, a);
    o[2] = fmadd(V::set1(4.0f), t, s);
    o[3] = fmadd(V::set1(8.0f), b, a) + m[5 * stride];
  }
}

// One tile's transform for T::kWidth channels from p (input row stride `row`, column
// stride `step`) into u (taps `tap` floats apart). T: the kernel's wrapper, or VecScalar for
// the channels left over (the same operations).
template <class T, int M>
inline void winograd_transform(const float* p, std::ptrdiff_t row, std::ptrdiff_t step, float* u, std::ptrdiff_t tap) {
  constexpr int N = M + 2;
  T v[N * N], r[N * N];
  for (int i = 0; i < N; ++i)
    for (int j = 0; j < N; ++j) v[N * i + j] = T::load(p + i * row + j * step);
  for (int j = 0; j < N; ++j) winograd_in<M>(v + j, r + j, N);          // rows
  for (int i = 0; i < N; ++i) winograd_in<M>(r + N * i, v + N * i, 1);  // columns
  for (int e = 0; e < N * N; ++e) v[e].store(u + e * tap);
}

// A tile: its outputs' top-left column x, how many of its m columns are inside the image, and
// where its input is read (row stride `row`, column stride `step`): the input tensor, or a
// patch gathered with zeros outside the image where the tile reaches past the tensor's halo.
struct WinogradTile {
  int x, cols;
  const float* p;
  std::ptrdiff_t row, step;
};

template <class V, int M, int NT>
inline void winograd_input(const WinogradTile* tiles, int cin, float* U) {
  const std::ptrdiff_t tap = static_cast<std::ptrdiff_t>(NT) * cin;  // floats between U's taps
  for (int t = 0; t < NT; ++t) {
    const WinogradTile& tile = tiles[t];
    float* u = U + static_cast<std::ptrdiff_t>(t) * cin;
    int c = 0;
    for (; c + V::kWidth <= cin; c += V::kWidth) winograd_transform<V, M>(tile.p + c, tile.row, tile.step, u + c, tap);
    for (; c < cin; ++c) winograd_transform<VecScalar, M>(tile.p + c, tile.row, tile.step, u + c, tap);
  }
}

// Winograd, step 2, for NB blocks of output channels from `block`: the T x T products of U and
// the transformed filters (a register tile each, tile_products()) into M[e][t][channel], then the
// output transform A^T m A (rows, then columns), the bias and the activation, stored for the
// tile's rows [lo, hi) (rows y + i d) and its columns inside the image.
template <class V, int M, int NT, int NB>
inline void winograd_block(const ConvWeights& w, const float* U, int block, float* Mp, Tensor& out, int y, int lo, int hi,
                           const WinogradTile* tiles) {
  constexpr int BLK = V::kBlock, W = V::kWidth, NV = BLK / W, K = NB * NV, N = M + 2, E = N * N;
  const int cin = w.cin, d = w.dilation;
  for (int e = 0; e < E; ++e) {
    V acc[NT][K];
    for (int t = 0; t < NT; ++t)
      for (int k = 0; k < K; ++k) acc[t][k] = V::set1(0.0f);
    const float* wp[NB];
    for (int b = 0; b < NB; ++b)
      wp[b] = w.winograd.data() + (static_cast<std::size_t>(block + b) * E + static_cast<std::size_t>(e)) * static_cast<std::size_t>(cin) * BLK;
    tile_products<V, NT, NB>(acc, U + static_cast<std::ptrdiff_t>(e) * NT * cin, cin, wp, cin);
    for (int t = 0; t < NT; ++t)
      for (int k = 0; k < K; ++k) acc[t][k].store(Mp + ((e * NT + t) * K + k) * W);
  }
  for (int t = 0; t < NT; ++t)
    for (int k = 0; k < K; ++k) {
      V m[E], c[N * M];
      for (int e = 0; e < E; ++e) m[e] = V::load(Mp + ((e * NT + t) * K + k) * W);
      for (int i = 0; i < N; ++i) winograd_out<M>(m + N * i, 1, c + M * i);  // the columns of each row
      const int ch = block * BLK + k * W;
      const V bias = V::load(w.bias.data() + ch);
      for (int j = 0; j < tiles[t].cols; ++j) {  // then the rows, per output column
        V o[M];
        winograd_out<M>(c + j, M, o);
        for (int i = lo; i < hi; ++i) activate(o[i] + bias, w.act).store(out.at(y + i * d, tiles[t].x + j * d) + ch);
      }
    }
}

// NT tiles of rows y, y + d, .. y + (m - 1) d, in the caller's scratch (conv_scratch_floats():
// U, then M, then the patches).
template <class V, int M, int NT>
inline void winograd_tiles(const ConvWeights& w, Tensor& out, int y, int lo, int hi, const WinogradTile* tiles, float* scratch) {
  constexpr int BLK = V::kBlock, NB = V::kTileBlocks;
  static_assert(NT <= kWinogradTiles && NB * BLK <= winograd_channels(BLK), "conv_scratch_floats() sizes a smaller tile");
  float* U = scratch;
  float* Mp = scratch + winograd_u_floats(M, w.cin);
  winograd_input<V, M, NT>(tiles, w.cin, U);
  for_block_groups<V>(w, [&](auto nb, int block) { winograd_block<V, M, NT, decltype(nb)::value>(w, U, block, Mp, out, y, lo, hi, tiles); });
}

// Winograd over rows [y0, y1). Row groups (y, y + d, .. y + (m - 1) d) start at the rows y with
// y mod m d < d, and column groups the same way, whatever the band: every tile is whole (its
// rows and columns past the image computed from zeros, and not stored), so a tile gives the
// same bytes in whichever band computes it, and a band computes each tile it has a row of
// (bands on multiples of conv_row_align() share none). Tiles whose input reaches past the
// tensor's halo (at the bottom and right edges, for d > 1) read a patch gathered with zeros.
template <class V, int M>
inline void winograd_rows(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch) {
  constexpr int NT = V::kTilePixels, N = M + 2;
  const int d = w.dilation, span = M * d, cin = w.cin;
  const std::ptrdiff_t patch = static_cast<std::ptrdiff_t>(N) * N * cin;
  float* patches = scratch + winograd_u_floats(M, cin) + winograd_m_floats(M, w.block);
  const int end = std::min(y1, out.h);
  for (int y = y0; y < end; ++y) {
    const int first = y - (y % span) / d * d;  // the group's top row
    if (y != first && y - d >= y0) continue;   // the group ran with an earlier row of this band
    const int lo = (y - first) / d;
    int hi = lo;
    while (hi < M && first + hi * d < end) ++hi;
    const bool rows_readable = first + M * d < in.h + kHalo;
    WinogradTile tiles[NT];
    int n = 0;
    for (int x = 0; x < out.w; ++x) {
      if (x % span >= d) continue;  // another column of a tile
      WinogradTile& tile = tiles[n];
      tile.x = x;
      tile.cols = std::min(M, (out.w - 1 - x) / d + 1);
      if (rows_readable && x + M * d < in.w + kHalo) {
        tile.p = in.at(first - d, x - d);
        tile.row = in.row * d;
        tile.step = static_cast<std::ptrdiff_t>(d) * in.cp;
      } else {
        float* q = patches + n * patch;
        for (int i = 0; i < N; ++i)
          for (int j = 0; j < N; ++j) {
            const int r = first + (i - 1) * d, c = x + (j - 1) * d;
            float* o = q + (i * N + j) * cin;
            if (r < in.h && c < in.w) std::copy(in.at(r, c), in.at(r, c) + cin, o);
            else std::fill(o, o + cin, 0.0f);
          }
        tile.p = q;
        tile.row = static_cast<std::ptrdiff_t>(N) * cin;
        tile.step = cin;
      }
      if (++n == NT) {
        winograd_tiles<V, M, NT>(w, out, first, lo, hi, tiles, scratch);
        n = 0;
      }
    }
    for (int t = 0; t < n; ++t) winograd_tiles<V, M, 1>(w, out, first, lo, hi, tiles + t, scratch);
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
    if (w.winograd_tile == 4) winograd_rows<V, 4>(in, w, out, y0, y1, scratch);
    else winograd_rows<V, 2>(in, w, out, y0, y1, scratch);
    return;
  }
  for (int y = y0; y < y1; ++y) conv_row<V>(in, w, out, y);
}

}  // namespace terralign::nn
