// GeoTIFF reading through libtiff.
//
// Strips and tiles; uncompressed, deflate, LZW, JPEG (YCbCr decoded to RGB), PackBits;
// contiguous or separate planes. Samples: uint8 with 1, 3 or 4+ bands (orthoimages; the
// caller takes the first three as RGB), and int16, uint16 or float32 with one band
// (elevation). Geo-referencing from ModelPixelScale + ModelTiepoint or from
// ModelTransformation, with PixelIsPoint rasters moved half a pixel as GDAL does, the
// GDAL_NODATA tag, and the CRS from the GeoKey directory (an EPSG code, or a user-defined
// transverse Mercator).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <terralign/geo/crs.hpp>
#include <terralign/geo/geotransform.hpp>
#include <terralign/geo/image.hpp>
#include <terralign/geo/result.hpp>

namespace terralign::geo {

// Refuse rasters that would need more memory than the caller allows.
struct RasterLimits {
  std::int64_t max_side = 65536;                   // pixels, per axis
  // Decoded size, bytes: 2 GiB, or 512 MiB in a 32-bit process (whose 2-4 GiB of address
  // space must hold the file's bytes and the decoded raster at once).
  std::int64_t max_bytes = sizeof(void*) >= 8 ? std::int64_t{2} << 30 : std::int64_t{512} << 20;
};

enum class SampleType { U8, I16, U16, F32 };
const char* to_string(SampleType t);

// What the GeoKey directory says of the CRS.
struct CrsSpec {
  int epsg = 0;                                 // 0: none given
  std::optional<TransverseMercatorParams> tm;   // a user-defined transverse Mercator
  bool geographic = false;                      // the raster is in degrees (not usable)
  std::string note;                             // what was found, for messages
  bool present() const { return epsg != 0 || tm.has_value() || geographic; }
  Result<Crs> resolve() const;
};

struct GeoRaster {
  int width = 0, height = 0, bands = 0;
  bool has_alpha = false;  // the band after the colour bands is alpha (ExtraSamples), not e.g. NIR
  SampleType sample = SampleType::U8;
  ImageU8 u8;   // the pixels when sample == U8 (bands channels)
  ImageF f32;   // the pixels otherwise, converted to float (bands channels)
  std::optional<GeoTransform> transform;
  bool pixel_is_point = false;
  std::optional<double> nodata;
  CrsSpec crs;
};

Result<GeoRaster> read_geotiff(const std::string& path, const RasterLimits& limits = {});
// The same from bytes in memory; `name` is used in messages.
Result<GeoRaster> read_geotiff_memory(const std::uint8_t* data, std::size_t size,
                                      const std::string& name, const RasterLimits& limits = {});

// True if the bytes start with a TIFF or BigTIFF signature.
bool looks_like_tiff(const std::uint8_t* data, std::size_t size);

}  // namespace terralign::geo
