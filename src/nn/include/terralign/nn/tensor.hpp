// Feature maps as the kernels want them: height x width x channels (channels fastest),
// channels padded to a multiple of 16 (zeros; the widest kernel writes 16 at a time), and a halo of kHalo zero pixels on every side
// so that a 3x3 convolution with dilation <= kHalo reads its neighbours without bounds
// checks. Allocated once, at planning time.
#pragma once

#include <cstddef>
#include <vector>

namespace terralign::nn {

constexpr int kHalo = 4;        // the largest dilation a plan accepts
constexpr int kChannelBlock = 16;

struct Tensor {
  int h = 0, w = 0, c = 0;      // logical size
  int cp = 0;                   // channel stride (c rounded up to 16)
  std::ptrdiff_t row = 0;       // floats between rows
  std::vector<float> storage;   // (h + 2 halo) x (w + 2 halo) x cp, zero-initialised

  void allocate(int height, int width, int channels) {
    h = height;
    w = width;
    c = channels;
    cp = (channels + kChannelBlock - 1) / kChannelBlock * kChannelBlock;
    row = static_cast<std::ptrdiff_t>(width + 2 * kHalo) * cp;
    storage.assign(static_cast<std::size_t>(height + 2 * kHalo) * static_cast<std::size_t>(row), 0.0f);
  }
  float* at(int y, int x) { return storage.data() + (y + kHalo) * row + static_cast<std::ptrdiff_t>(x + kHalo) * cp; }
  const float* at(int y, int x) const {
    return storage.data() + (y + kHalo) * row + static_cast<std::ptrdiff_t>(x + kHalo) * cp;
  }
};

}  // namespace terralign::nn
