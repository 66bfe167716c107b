// The residual kernel of the solver's iterations for the 6-DoF warp with depth on one
// channel (the hot loop of every tracker in terralign): warp each selected reference pixel
// into the live level, sample it bilinearly, and sum J^T w r, w r^2 and w.
//
// Sums run in eight float lanes, pixel i of [i0, i1) in lane (i - i0) mod 8, and every
// operation is a separate IEEE operation (no FMA contraction, correctly rounded division):
// the scalar twin and the AVX2 build give the same bits, so a result does not depend on the
// CPU's ISA. A pixel that leaves the image (or lies behind the camera) adds +0 to its lane.
#pragma once

#include <cstddef>

#include <terralign/iclk/tracker.hpp>

namespace terralign::iclk::detail {

constexpr int kLanes = 8;

struct Se3EvalInput {
  const float *px, *py, *pz;  // reference points in the reference camera
  const float* val;           // reference values
  const float* w;             // weights
  const float* jac[6];        // Jacobian rows, one array per parameter
  const float* live;          // live level, row-major
  std::ptrdiff_t stride;      // floats per live row
  int width, height;          // live level size
  float R[9], t[3];           // T_live_ref, row-major rotation
  float fx, fy, cx, cy;
};

struct Se3EvalSums {
  float g[6][kLanes];
  float cost[kLanes];
  float wsum[kLanes];
  int valid;
};

// Pixels [i0, i1): writes r[i] (0 where the pixel did not land) and ok[i], fills `sums`
// (the signature is detail::Se3EvalFn, declared with the tracker).

void evaluate_se3_scalar(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& sums);
#if defined(TERRALIGN_ICLK_AVX2)
void evaluate_se3_avx2(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& sums);
#endif

}  // namespace terralign::iclk::detail
