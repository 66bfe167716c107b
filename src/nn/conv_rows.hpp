// The 3x3 convolution (stride 1, padding = dilation), written once against a vector
// wrapper V (VecScalar or VecAvx2). Included by conv_scalar.cpp and conv_avx2.cpp.
//
// Register blocking: NP output pixels of one row x NB blocks of V::kBlock output channels;
// for every tap and input channel, one broadcast of the input value per pixel and one load of
// the weights per vector feed NP x NB x NV multiply-adds. Reads the halo (zeros) at borders.
#pragma once

#include <algorithm>

#include <terralign/geo/assert.hpp>
#include <terralign/nn/kernels.hpp>

namespace terralign::nn {

template <class V, int NP, int NB>
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
      for (int ci = 0; ci < cin; ++ci) {
        V wv[NB * NV];
        for (int b = 0; b < NB; ++b)
          for (int j = 0; j < NV; ++j) wv[b * NV + j] = V::load(wp[b] + ci * BLK + j * V::kWidth);
        for (int p = 0; p < NP; ++p) {
          const V a = V::set1(ip[p * cp + ci]);
          for (int k = 0; k < NB * NV; ++k) acc[p][k] = fmadd(a, wv[k], acc[p][k]);
        }
      }
    }
  for (int p = 0; p < NP; ++p) {
    float* op = out.at(y, x + p) + block * BLK;
    for (int k = 0; k < NB * NV; ++k) {
      V v = acc[p][k];
      if (w.act == Act::Elu) v = elu(v);
      else if (w.act == Act::Relu) v = relu(v);
      v.store(op + k * V::kWidth);
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
    V v = V::set1(w.bias[0] + (hsum(acc[p]) + rest[p]));
    if (w.act == Act::Elu) v = elu(v);
    else if (w.act == Act::Relu) v = relu(v);
    float* op = out.at(y, x + p);
    // The padded channels the block kernel would have written: zeros (see below).
    for (int k = 0; k < V::kBlock; k += W) V::set1(0.0f).store(op + k);
    op[0] = lane0(v);
  }
}

template <class V>
inline void conv3x3_rows(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1) {
  constexpr int NP = V::kTilePixels;
  TERRALIGN_DEBUG_ASSERT(w.block == V::kBlock, "conv3x3_rows: weights packed for another kernel");
  if (w.cout == 1 && w.taps.size() == 9 * static_cast<std::size_t>(w.cin)) {  // (bench_nn clears taps for the peer)
    for (int y = y0; y < y1; ++y) {
      int x = 0;
      for (; x + 4 <= out.w; x += 4) conv1_tile<V, 4>(in, w, out, y, x);
      for (; x < out.w; ++x) conv1_tile<V, 1>(in, w, out, y, x);
    }
    return;
  }
  const int blocks = (w.cout + V::kBlock - 1) / V::kBlock;
  constexpr int NB = V::kTileBlocks;
  for (int y = y0; y < y1; ++y) {
    int block = 0;
    for (; block + NB <= blocks; block += NB) {
      int x = 0;
      for (; x + NP <= out.w; x += NP) conv_tile<V, NP, NB>(in, w, out, y, x, block);
      for (; x < out.w; ++x) conv_tile<V, 1, NB>(in, w, out, y, x, block);
    }
    // The remaining blocks: in pairs where the tile is wider than two, then one by one.
    for (; NB > 2 && block + 2 <= blocks; block += 2) {
      int x = 0;
      for (; x + NP <= out.w; x += NP) conv_tile<V, NP, 2>(in, w, out, y, x, block);
      for (; x < out.w; ++x) conv_tile<V, 1, 2>(in, w, out, y, x, block);
    }
    for (; block < blocks; ++block) {
      int x = 0;
      for (; x + NP <= out.w; x += NP) conv_tile<V, NP, 1>(in, w, out, y, x, block);
      for (; x < out.w; ++x) conv_tile<V, 1, 1>(in, w, out, y, x, block);
    }
    // Padded output channels must stay zero: the next layer reads only cin channels, but
    // mean and concat read cp; the bias of padded channels is zero, and ELU(0) = 0.
  }
}

}  // namespace terralign::nn
