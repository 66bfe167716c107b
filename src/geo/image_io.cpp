#include <terralign/geo/image_io.hpp>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <vector>

#include <stb/stb_image.h>
#include <stb/stb_image_write.h>

#include <terralign/geo/file.hpp>
#include <terralign/geo/number_text.hpp>

namespace terralign::geo {

Result<ImageU8> decode_image(const std::uint8_t* data, std::size_t size, const std::string& name,
                             int channels, std::int64_t max_pixels) {
  TERRALIGN_ASSERT(channels == 1 || channels == 3 || channels == 4, "decode_image: channels");
  if (size == 0) return Error{name + ": empty file"};
  if (size > static_cast<std::size_t>(std::numeric_limits<int>::max()))
    return Error{name + ": file is over 2 GiB"};
  int w = 0, h = 0, n = 0;
  if (!stbi_info_from_memory(data, static_cast<int>(size), &w, &h, &n))
    return Error{name + ": not a readable PNG/JPEG/BMP image (" + stbi_failure_reason() + ")"};
  if (w <= 0 || h <= 0)
    return Error{name + ": " + std::to_string(w) + " x " + std::to_string(h) + " image has no pixels"};
  if (std::int64_t{w} * h > max_pixels)
    return Error{name + ": " + std::to_string(w) + " x " + std::to_string(h) +
                 " image exceeds the limit of " + std::to_string(max_pixels) + " pixels"};
  if (stbi_is_16_bit_from_memory(data, static_cast<int>(size)))
    return Error{name + ": 16-bit images are not supported here (8-bit sRGB expected)"};
  unsigned char* px = stbi_load_from_memory(data, static_cast<int>(size), &w, &h, &n, channels);
  if (!px) return Error{name + ": cannot decode image (" + stbi_failure_reason() + ")"};
  ImageU8 img(w, h, channels);
  std::memcpy(img.data(), px, img.size());
  stbi_image_free(px);
  return img;
}

Result<ImageU8> load_image(const std::string& path, int channels, std::int64_t max_pixels) {
  TERRALIGN_TRY_ASSIGN(auto bytes, read_file(path));
  return decode_image(bytes.data(), bytes.size(), path, channels, max_pixels);
}

Status save_png(const std::string& path, ImageView<const std::uint8_t> image) {
  if (image.empty()) return Error{path + ": refusing to write an empty image"};
  if (image.channels < 1 || image.channels > 4)
    return Error{path + ": " + std::to_string(image.channels) + " channels cannot be written as PNG"};
  std::vector<std::uint8_t> out;
  auto sink = [](void* ctx, void* d, int n) {
    auto* v = static_cast<std::vector<std::uint8_t>*>(ctx);
    v->insert(v->end(), static_cast<std::uint8_t*>(d), static_cast<std::uint8_t*>(d) + n);
  };
  if (!stbi_write_png_to_func(sink, &out, image.width, image.height, image.channels, image.data,
                              static_cast<int>(image.stride)))
    return Error{path + ": PNG encoding failed"};
  return write_file_atomic(path, out.data(), out.size());
}

Result<ImageF> decode_pfm(const std::uint8_t* data, std::size_t size, const std::string& name) {
  // Header: three whitespace-separated tokens, then exactly one whitespace byte.
  std::size_t pos = 0;
  auto token = [&](std::string& out) {
    while (pos < size && std::isspace(data[pos])) ++pos;
    out.clear();
    while (pos < size && !std::isspace(data[pos]) && out.size() < 64) out.push_back(static_cast<char>(data[pos++]));
    return !out.empty();
  };
  std::string magic, ws, hs, scales;
  if (!token(magic) || (magic != "Pf" && magic != "PF")) return Error{name + ": not a PFM file (magic must be 'Pf' or 'PF')"};
  if (!token(ws) || !token(hs) || !token(scales)) return Error{name + ": truncated PFM header"};
  if (pos >= size || !std::isspace(data[pos])) return Error{name + ": truncated PFM header"};
  ++pos;
  char* end = nullptr;
  const long w = std::strtol(ws.c_str(), &end, 10);
  if (*end) return Error{name + ": PFM width '" + ws + "' is not an integer"};
  const long h = std::strtol(hs.c_str(), &end, 10);
  if (*end) return Error{name + ": PFM height '" + hs + "' is not an integer"};
  const auto parsed = parse_double(scales);
  const double scale = parsed.ok() ? parsed.value() : 0;
  if (scale == 0 || !std::isfinite(scale)) return Error{name + ": PFM scale '" + scales + "' is not a non-zero number"};
  if (w <= 0 || h <= 0 || w > 65536 || h > 65536)
    return Error{name + ": PFM size " + ws + " x " + hs + " is outside 1..65536"};
  const int ch = magic == "PF" ? 3 : 1;
  const std::size_t need = static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * ch * 4;
  if (size - pos < need)
    return Error{name + ": PFM data has " + std::to_string(size - pos) + " bytes, needs " + std::to_string(need)};
  const bool little = scale < 0;
  ImageF img(static_cast<int>(w), static_cast<int>(h), 1);
  for (long y = 0; y < h; ++y) {
    const std::uint8_t* row = data + pos + static_cast<std::size_t>(h - 1 - y) * static_cast<std::size_t>(w) * ch * 4;
    for (long x = 0; x < w; ++x) {
      std::uint8_t b[4];
      std::memcpy(b, row + static_cast<std::size_t>(x) * ch * 4, 4);  // first channel
      const std::uint32_t u = little ? (std::uint32_t{b[0]} | std::uint32_t{b[1]} << 8 | std::uint32_t{b[2]} << 16 | std::uint32_t{b[3]} << 24)
                                     : (std::uint32_t{b[3]} | std::uint32_t{b[2]} << 8 | std::uint32_t{b[1]} << 16 | std::uint32_t{b[0]} << 24);
      float f;
      std::memcpy(&f, &u, 4);
      img.at(static_cast<int>(x), static_cast<int>(y)) = f;
    }
  }
  return img;
}

Result<ImageF> read_pfm(const std::string& path) {
  TERRALIGN_TRY_ASSIGN(auto bytes, read_file(path));
  return decode_pfm(bytes.data(), bytes.size(), path);
}

Status save_pfm(const std::string& path, ImageView<const float> image) {
  if (image.empty() || image.channels != 1) return Error{path + ": PFM writer takes a non-empty 1-channel image"};
  std::string out = "Pf\n" + std::to_string(image.width) + " " + std::to_string(image.height) + "\n-1.0\n";
  const std::size_t at = out.size();
  out.resize(at + static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height) * 4);
  for (int y = 0; y < image.height; ++y) {
    const float* src = image.row(image.height - 1 - y);
    for (int x = 0; x < image.width; ++x) {
      std::uint32_t u;
      std::memcpy(&u, &src[x], 4);
      const std::uint8_t b[4] = {static_cast<std::uint8_t>(u), static_cast<std::uint8_t>(u >> 8),
                                 static_cast<std::uint8_t>(u >> 16), static_cast<std::uint8_t>(u >> 24)};
      std::memcpy(&out[at + (static_cast<std::size_t>(y) * static_cast<std::size_t>(image.width) + static_cast<std::size_t>(x)) * 4], b, 4);
    }
  }
  return write_file_atomic(path, out.data(), out.size());
}

}  // namespace terralign::geo
