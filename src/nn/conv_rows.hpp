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

template <class V>
inline void conv3x3_rows(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1) {
  constexpr int NP = V::kTilePixels;
  TERRALIGN_DEBUG_ASSERT(w.block == V::kBlock, "conv3x3_rows: weights packed for another kernel");
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
