// Images: a non-owning view and an owning image, row-major, interleaved channels.
//
// Pixel (x, y) channel c of a view lives at data[y * stride + x * channels + c], with the
// stride in elements. Pixel centres are at integer coordinates (OpenCV convention).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <terralign/geo/assert.hpp>

namespace terralign {

template <class T>
struct ImageView {
  T* data = nullptr;
  int width = 0;
  int height = 0;
  int channels = 1;
  std::ptrdiff_t stride = 0;  // elements between the starts of two rows

  bool empty() const { return width <= 0 || height <= 0; }
  T* row(int y) const {
    TERRALIGN_DEBUG_ASSERT(y >= 0 && y < height, "ImageView::row out of range");
    return data + static_cast<std::ptrdiff_t>(y) * stride;
  }
  T& at(int x, int y, int c = 0) const {
    TERRALIGN_DEBUG_ASSERT(x >= 0 && x < width && c >= 0 && c < channels,
                           "ImageView::at out of range");
    return row(y)[static_cast<std::ptrdiff_t>(x) * channels + c];
  }
  operator ImageView<const T>() const {  // NOLINT: implicit on purpose
    return ImageView<const T>{data, width, height, channels, stride};
  }
};

// Owns its pixels. Allocates only in the constructor and resize().
template <class T>
class Image {
 public:
  Image() = default;
  Image(int width, int height, int channels = 1, T fill = T{}) {
    resize(width, height, channels, fill);
  }

  void resize(int width, int height, int channels = 1, T fill = T{}) {
    TERRALIGN_ASSERT(width >= 0 && height >= 0 && channels >= 1, "Image::resize: bad size");
    width_ = width;
    height_ = height;
    channels_ = channels;
    pixels_.assign(static_cast<std::size_t>(width) * static_cast<std::size_t>(height) *
                       static_cast<std::size_t>(channels),
                   fill);
  }

  int width() const { return width_; }
  int height() const { return height_; }
  int channels() const { return channels_; }
  bool empty() const { return pixels_.empty(); }
  std::size_t size() const { return pixels_.size(); }
  T* data() { return pixels_.data(); }
  const T* data() const { return pixels_.data(); }
  std::vector<T>& pixels() { return pixels_; }
  const std::vector<T>& pixels() const { return pixels_; }

  T& at(int x, int y, int c = 0) { return view().at(x, y, c); }
  const T& at(int x, int y, int c = 0) const { return view().at(x, y, c); }

  ImageView<T> view() {
    return ImageView<T>{pixels_.data(), width_, height_, channels_,
                        static_cast<std::ptrdiff_t>(width_) * channels_};
  }
  ImageView<const T> view() const {
    return ImageView<const T>{pixels_.data(), width_, height_, channels_,
                              static_cast<std::ptrdiff_t>(width_) * channels_};
  }

 private:
  int width_ = 0;
  int height_ = 0;
  int channels_ = 1;
  std::vector<T> pixels_;
};

using ImageU8 = Image<std::uint8_t>;
using ImageF = Image<float>;

}  // namespace terralign
