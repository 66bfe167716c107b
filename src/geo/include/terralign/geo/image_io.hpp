// Image files: PNG / JPEG through stb_image, PNG writing through stb_image_write, and PFM
// (portable float map) for depth.
#pragma once

#include <cstdint>
#include <string>

#include <terralign/geo/image.hpp>
#include <terralign/geo/result.hpp>

namespace terralign::geo {

// The default limit of load_image and decode_image: 2^30 pixels, or 2^27 in a 32-bit process
// (at 4 channels, 512 MiB of its 2-4 GiB of address space).
inline constexpr std::int64_t kMaxImagePixels = sizeof(void*) >= 8 ? std::int64_t{1} << 30 : std::int64_t{1} << 27;

// Loads an 8-bit image with `channels` channels (1, 3 or 4; stb converts), refusing one
// larger than max_pixels.
Result<ImageU8> load_image(const std::string& path, int channels = 3, std::int64_t max_pixels = kMaxImagePixels);
Result<ImageU8> decode_image(const std::uint8_t* data, std::size_t size, const std::string& name,
                             int channels = 3, std::int64_t max_pixels = kMaxImagePixels);

// Writes a PNG (1, 3 or 4 channels) atomically: a failed write leaves any old file intact.
Status save_png(const std::string& path, ImageView<const std::uint8_t> image);

// PFM: "Pf" (1 channel) or "PF" (3 channels), little- or big-endian by the sign of the scale
// line, rows stored bottom-up as the format defines. We read and write 1 channel.
Result<ImageF> read_pfm(const std::string& path);
Result<ImageF> decode_pfm(const std::uint8_t* data, std::size_t size, const std::string& name);
// Writes little-endian, bottom-up rows, NaN kept as NaN.
Status save_pfm(const std::string& path, ImageView<const float> image);

}  // namespace terralign::geo
