// Feature maps as the kernels want them: height x width x channels (channels fastest),
// a convolution's output with its channels padded to a multiple of 16 (zeros; the widest
// kernel writes 16 at a time; every kernel reads a pixel's channels at stride cp, so other
// tensors are packed), and a halo of kHalo zero pixels on every side
// so that a 3x3 convolution with dilation <= kHalo reads its neighbours without bounds
// checks. Allocated once, at planning time.
#pragma once

#include <algorithm>
#include <cstddef>
#include <vector>

namespace terralign::nn {

constexpr int kHalo = 4;        // the largest dilation a plan accepts
constexpr int kChannelBlock = 16;

struct Tensor {
  int h = 0, w = 0, c = 0;      // logical size
  int cp = 0;                   // channel stride (c rounded up to 16)
  std::ptrdiff_t row = 0;       // floats between rows
  std::vector<float> storage;   // owned pixels (allocate()); empty for a planned tensor that
                                // lives in its network's shared buffer (place())
  float* base = nullptr;        // (h + 2 halo) x (w + 2 halo) x cp floats

  Tensor() = default;
  // A copy owns its pixels, whether the original owns them or is placed.
  Tensor(const Tensor& o) : h(o.h), w(o.w), c(o.c), cp(o.cp), row(o.row) {
    if (o.base) storage.assign(o.base, o.base + o.floats());
    base = storage.empty() ? nullptr : storage.data();
  }
  Tensor(Tensor&& o) noexcept = default;  // a vector's buffer moves with it: base stays valid
  Tensor& operator=(const Tensor& o) {
    if (this != &o) *this = Tensor(o);
    return *this;
  }
  Tensor& operator=(Tensor&& o) noexcept = default;

  // Owned, zero-initialised. `padded`: channels rounded up to kChannelBlock, which a
  // convolution's output needs (it writes whole blocks); other tensors may be packed.
  void allocate(int height, int width, int channels, bool padded = true) {
    shape(height, width, channels, padded);
    storage.assign(floats(), 0.0f);
    base = storage.data();
  }
  // In memory the caller owns (a network's shared buffer): floats() floats at `memory`.
  void place(int height, int width, int channels, bool padded, float* memory) {
    shape(height, width, channels, padded);
    storage.clear();
    base = memory;
  }
  std::size_t floats() const {
    return static_cast<std::size_t>(h + 2 * kHalo) * static_cast<std::size_t>(w + 2 * kHalo) * static_cast<std::size_t>(cp);
  }
  float* at(int y, int x) { return base + (y + kHalo) * row + static_cast<std::ptrdiff_t>(x + kHalo) * cp; }
  const float* at(int y, int x) const { return base + (y + kHalo) * row + static_cast<std::ptrdiff_t>(x + kHalo) * cp; }
  // Zeros the halo (what a convolution reads as padding): needed when the memory is shared.
  void zero_halo() {
    const std::size_t band = static_cast<std::size_t>(kHalo) * static_cast<std::size_t>(row);
    std::fill(base, base + band, 0.0f);
    std::fill(base + static_cast<std::ptrdiff_t>(h + kHalo) * row, base + static_cast<std::ptrdiff_t>(h + kHalo) * row + static_cast<std::ptrdiff_t>(band), 0.0f);
    for (int y = 0; y < h; ++y) {
      float* r = base + (y + kHalo) * row;
      std::fill(r, r + kHalo * cp, 0.0f);
      std::fill(r + static_cast<std::ptrdiff_t>(w + kHalo) * cp, r + row, 0.0f);
    }
  }

 private:
  void shape(int height, int width, int channels, bool padded) {
    h = height;
    w = width;
    c = channels;
    cp = padded ? (channels + kChannelBlock - 1) / kChannelBlock * kChannelBlock : channels;
    row = static_cast<std::ptrdiff_t>(width + 2 * kHalo) * cp;
  }
};

}  // namespace terralign::nn
