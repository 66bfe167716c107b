// Inference kernels. Each is a pure function over tensors of a fixed size: no allocation, no
// hidden state; rows [y0, y1) of the output only, so callers split work by rows (a
// convolution's on multiples of conv_row_align(), below).
//
// The 3x3 convolution is written once (conv_rows.hpp) against a thin vector wrapper and
// built for the one-lane scalar wrapper, AVX2 + FMA, AVX-512F and NEON. They differ only in
// rounding (FMA versus multiply-then-add, and the ELU's exp): tests bound their difference.
#pragma once

#include <terralign/nn/tensor.hpp>

namespace terralign::nn {

enum class Act { None, Elu, Relu };

// Weights packed for the kernels: for each block of `block` output channels (8, or 16 for
// AVX-512), [3][3][cin][block] for the direct kernel, or Winograd's transformed filters.
struct ConvWeights {
  int cin = 0, cout = 0, dilation = 1, block = 8;
  Act act = Act::None;
  std::vector<float> packed;    // (cout / block rounded up) x 9 x cin x block; empty where
                                // Winograd's kernel runs the layer
  std::vector<float> bias;      // cout rounded up to block
  std::vector<float> taps;      // one output channel only: 9 x cin (tap-major), for the kernel
                                // whose vectors run along the input channels
  std::vector<float> winograd;  // where winograd_suits(): G g G^T of every filter, for each
                                // block [T x T][cin][block], T = winograd_tile + 2; empty: the
                                // direct kernel
  int winograd_tile = 4;        // Winograd's output tile, where `winograd` is not empty: 2 x 2
                                // or 4 x 4
};

// Winograd's F(m x m, 3x3) (Lavin and Gray, 2016): an m x m output tile from an (m + 2)^2
// input tile in (m + 2)^2 multiply-adds a channel pair instead of 9 m^2 (F(2x2): 16 for 36;
// F(4x4): 36 for 144), the input and the output transformed by additions (and for m = 4
// multiplications by powers of two). Used for layers of at least kWinogradMinCin input
// channels and more than one output channel: with fewer inputs the transforms cost more than
// they save (8 -> 8 at 376 x 240 on AVX-512, one thread, F(2x2): 3.1 ms against the direct
// kernel's 2.5; 16 -> 16: 3.0 against 4.2). The product runs F(4x4) (session 69, bench_nn's single
// layers of 16 to 64 channels, 23 x 15 to 376 x 240: 1.2-1.5x F(2x2)'s speed with AVX2,
// 1.5-1.7x with the scalar kernel; F(2x2) stays for benchmarks and tests). With dilation d a tile's outputs are (y + i d, x + j d), 0 <= i, j <
// m: rows are grouped from y with y mod m d < d (the same for columns), whatever the band, and
// every tile is computed whole (past the image's edge from zeros, stored only inside it), so
// the bytes do not depend on how the rows are split; bands on multiples of conv_row_align()
// compute no tile twice. F(4x4)'s transforms scale its terms by up to 8 x 5 x 5 (G's by 1/24
// and 1/6): its rounding is some ten times F(2x2)'s, still a few parts in a million of a
// layer's output. The transformed tiles live in scratch memory the caller gives,
// conv_scratch_floats() a thread: up to kWinogradTiles tiles (every vector wrapper's register
// tile) and winograd_channels() output channels at a time.
constexpr int kWinogradMinCin = 16;
constexpr int kWinogradTiles = 6;
// The output channels of a Winograd register tile for weights packed in blocks of `block`:
// AVX-512's four blocks of 16, the other wrappers' two blocks of 8.
constexpr int winograd_channels(int block) { return block == 16 ? 64 : 16; }
bool winograd_suits(int cin, int cout);
// Row splits of a convolution's output that keep its row groups whole (so that no tile is
// computed in two bands): multiples of this.
int conv_row_align(const ConvWeights& w);
// Floats of scratch one thread's call of the convolution needs (0: none): for Winograd's
// output tile `tile`, the transformed inputs U (rounded up to 16 floats), the products M, then
// the edge tiles' gathered patches (as many floats as U).
std::size_t conv_scratch_floats(const ConvWeights& w);
constexpr std::size_t winograd_u_floats(int tile, int cin) {
  return (static_cast<std::size_t>((tile + 2) * (tile + 2)) * kWinogradTiles * static_cast<std::size_t>(cin) + 15) / 16 * 16;
}
constexpr std::size_t winograd_m_floats(int tile, int block) {
  return static_cast<std::size_t>((tile + 2) * (tile + 2)) * kWinogradTiles * static_cast<std::size_t>(winograd_channels(block));
}

// From PyTorch's OIHW layout (cout x cin x 3 x 3) and a bias of cout.
// winograd_tile: Winograd's output tile where winograd_suits() (2 or 4), 0: the direct kernel.
ConvWeights pack_conv(const float* oihw, const float* bias, int cin, int cout, int dilation, Act act, int block = 8,
                      int winograd_tile = 4);

// `scratch`: conv_scratch_floats(w) floats of this thread's own (may be null where that is 0).
using ConvRowsFn = void (*)(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch);
void conv3x3_rows_scalar(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch);
#if defined(TERRALIGN_NN_AVX2)
void conv3x3_rows_avx2(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch);
void conv3x3_rows_avx512(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch);
#endif
#if defined(TERRALIGN_NN_NEON)
void conv3x3_rows_neon(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch);
#endif
bool nn_cpu_has_avx2();
bool nn_cpu_has_avx512();
bool nn_cpu_has_neon();  // an aarch64 build, or 32-bit ARM built for NEON and VFPv4

// 2x2 average pooling (floor sizes), mean over channels (out.c equal groups of consecutive
// channels, each to one; one group: all of them), sigmoid in place,
// bilinear 2x upsampling (PyTorch's align_corners = False, edges clamped), concatenation
// of channels. Rows [y0, y1) of the output.
void avgpool2_rows(const Tensor& in, Tensor& out, int y0, int y1);
void mean_channels_rows(const Tensor& in, Tensor& out, int y0, int y1);
void sigmoid_rows(const Tensor& in, Tensor& out, int y0, int y1);
void upsample2_rows(const Tensor& in, Tensor& out, int y0, int y1);
void concat_rows(const Tensor* const* ins, int n, Tensor& out, int y0, int y1);

}  // namespace terralign::nn
