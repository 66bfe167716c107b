// The residual kernel of the solver's iterations for the 6-DoF warp with depth (the hot loop
// of every tracker in terralign): warp each selected reference pixel into the live level,
// sample each of its channels bilinearly, and sum J^T w r, w r^2 and w over pixels and
// channels (the channels of a pixel one after another, in channel order).
//
// Sums run in eight float lanes, pixel i of [i0, i1) in lane (i - i0) mod 8, and every
// operation is a separate IEEE operation (no FMA contraction, correctly rounded division):
// the scalar twin, the AVX2 and AVX-512 (x86-64) and the NEON (aarch64) builds give the same
// bits, so a result does not depend on the CPU's ISA. A pixel that leaves the image (or lies behind the camera) adds +0 to its lane.
#pragma once

#include <cstddef>
#include <cstring>

#include <terralign/iclk/tracker.hpp>

namespace terralign::iclk::detail {

constexpr int kLanes = 8;

struct Se3EvalInput {
  const float *px, *py, *pz;  // reference points in the reference camera
  const float* val;           // reference values
  const float* w;             // weights (one a pixel)
  const float* jac[6];        // Jacobian rows, one array per parameter
  const float* live;          // live level, row-major
  std::ptrdiff_t stride;      // floats per live row
  // Channels: val, the residuals r, jac and live hold one plane per channel, channel c's at
  // c times these offsets (floats) from channel 0's.
  int channels = 1;
  std::ptrdiff_t plane = 0, jac_plane = 0, live_plane = 0;
  int width, height;          // live level size
  float R[9], t[3];           // T_live_ref, row-major rotation
  float fx, fy, cx, cy;
  int* out;                   // where the pixels that do not land are listed, in order
};

struct Se3EvalSums {
  float g[6][kLanes];
  float cost[kLanes];
  float wsum[kLanes];
  int valid;
  int n_out;  // entries written to out: i1 - i0 - valid
};

// The vector builds' `ok` bytes: eight lanes' mask bits (lane k's in bit k) as eight bytes of
// 0 or 1 at ok.
inline void spread_mask8(unsigned bits, unsigned char* ok) {
  const unsigned long long one_bit = (static_cast<unsigned long long>(bits & 0xFFu) * 0x0101010101010101ULL) & 0x8040201008040201ULL;
  const unsigned long long spread = ((one_bit + 0x7F7F7F7F7F7F7F7FULL) & 0x8080808080808080ULL) >> 7;
  std::memcpy(ok, &spread, 8);
}

// Pixels [i0, i1): writes r[i + c plane] (0 where the pixel did not land), ok[i] and the list
// of those that did not, fills `sums` (wsum counts a pixel's weight once per channel)
// (the signature is detail::Se3EvalFn, declared with the tracker).

void evaluate_se3_scalar(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& sums);
#if defined(TERRALIGN_ICLK_AVX2)
void evaluate_se3_avx2(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& sums);
// Sixteen pixels at once, the same bits (CPUs with AVX-512 F).
void evaluate_se3_avx512(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& sums);
#endif
#if defined(TERRALIGN_ICLK_NEON)
void evaluate_se3_neon(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& sums);
#endif

// The set-up of a level for the 6-DoF warp with depth (Tracker::write_band): at each of up to
// kLanes selected reference pixels (x[l], y[l]), lane l, the point X = (d (u - cx) / fx,
// d (v - cy) / fy, d) of its depth d, its image motion dW = d(u, v) / d xi
// (SE3DepthWarp::d_warp_d_xi, each entry the same IEEE operations as that 2 x 3 by 3 x 6
// product's nonzero terms), and per channel the Sobel / 8 gradient (gx, gy), the Jacobian row
// gx dW_u + gy dW_v and the pixel's value. Each pixel needs depth at (x, y) and its eight
// neighbours inside the level; the same bits from every build.
struct Se3JacobianInput {
  const float* ref;    // the level's reference, `channels` interleaved, row-major
  const float* depth;  // the level's depth, row-major
  int width;           // pixels a row
  int channels = 1;
  float fx, fy, cx, cy;
};

struct Se3JacobianGroup {
  // Written at [0, count) (the tracker's arrays at the group's first pixel): the pixel, the
  // point, per channel c the value at val + c plane and parameter a's Jacobian at
  // jac[a] + c jac_plane.
  float *pu, *pv, *px, *py, *pz;
  float* val;
  float* jac[6];
  std::ptrdiff_t plane = 0, jac_plane = 0;
};

// The finest level's sums over the selected pixels (Tracker::write_band), lane l of a group
// into lane l: motion[e] += dW_u,a dW_u,b + dW_v,a dW_v,b for the lower half's e-th (a, b)
// (row by row), and dW_a's product with each registration-floor mode of the pixel's offset
// (mu, mv) = (u - cx, v - cy): floor[a][m] over u {1, 0, -mv, mu, mu^2, mu mv} and
// v {0, 1, mu, mv, mu mv, mv^2}, as (dW_u m_u + dW_v m_v) with the radial mode's dot product
// mu dW_u + mv dW_v taken once. Lanes past count add +0.
struct Se3FinestSums {
  float motion[21][kLanes];
  float floor[6][6][kLanes];
};

// `sums`: the finest level's, added to (nullptr at the other levels).
void se3_jacobians_scalar(const Se3JacobianInput& in, const int* x, const int* y, int count, Se3JacobianGroup& out,
                          Se3FinestSums* sums);
#if defined(TERRALIGN_ICLK_AVX2)
void se3_jacobians_avx2(const Se3JacobianInput& in, const int* x, const int* y, int count, Se3JacobianGroup& out,
                        Se3FinestSums* sums);
#endif
#if defined(TERRALIGN_ICLK_NEON)
void se3_jacobians_neon(const Se3JacobianInput& in, const int* x, const int* y, int count, Se3JacobianGroup& out,
                        Se3FinestSums* sums);
#endif

// J^T W J of one channel over pixels [i0, i1), added to `h` (the signature is
// detail::OuterSumsFn): entry k of the lower half (row by row: (0,0), (1,0), (1,1), ...) of
// pixel i goes to lane (i - i0) mod kOuterLanes, as (w_i J_ia) J_ib in double. A pixel whose
// weight is not > 0 adds +0, whatever its Jacobian holds.
void outer_sums_scalar(const float* const* jac, const float* w, int i0, int i1, OuterSums& h);
// Likewise over the pixels index[0 .. count), index[k] in lane k mod kOuterLanes
// (detail::OuterSumsAtFn): the pixels that left the image, in evaluate().
void outer_sums_at_scalar(const float* const* jac, const float* w, const int* index, int count, OuterSums& h);
#if defined(TERRALIGN_ICLK_AVX2)
void outer_sums_avx2(const float* const* jac, const float* w, int i0, int i1, OuterSums& h);
void outer_sums_at_avx2(const float* const* jac, const float* w, const int* index, int count, OuterSums& h);
#endif
#if defined(TERRALIGN_ICLK_NEON)
void outer_sums_neon(const float* const* jac, const float* w, int i0, int i1, OuterSums& h);
void outer_sums_at_neon(const float* const* jac, const float* w, const int* index, int count, OuterSums& h);
#endif

}  // namespace terralign::iclk::detail
