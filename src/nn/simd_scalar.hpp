// The one-lane scalar vector wrapper: the scalar build of every kernel.
#pragma once

#include <cmath>

namespace terralign::nn {

struct VecScalar {
  static constexpr int kWidth = 1;
  static constexpr int kBlock = 8;       // output channels a weight block holds
  static constexpr int kTilePixels = 6;  // output pixels a register tile holds
  static constexpr int kTileBlocks = 2;  // weight blocks a register tile holds
  float v;
  static VecScalar load(const float* p) { return {*p}; }
  static VecScalar set1(float x) { return {x}; }
  void store(float* p) const { *p = v; }
  friend VecScalar operator+(VecScalar a, VecScalar b) { return {a.v + b.v}; }
  friend VecScalar operator-(VecScalar a, VecScalar b) { return {a.v - b.v}; }
  friend VecScalar fmadd(VecScalar a, VecScalar b, VecScalar c) { return {a.v * b.v + c.v}; }
  friend VecScalar elu(VecScalar a) { return {a.v > 0.0f ? a.v : std::expm1(a.v)}; }
  friend VecScalar relu(VecScalar a) { return {a.v > 0.0f ? a.v : 0.0f}; }
  friend float lane0(VecScalar a) { return a.v; }
  friend float hsum(VecScalar a) { return a.v; }
};

}  // namespace terralign::nn
