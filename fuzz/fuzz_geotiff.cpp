// GeoTIFF reader: any bytes give a raster or an error, never a crash or a huge allocation.
#include <cstdint>

#include <terralign/geo/geotiff.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  terralign::geo::RasterLimits limits;
  limits.max_side = 4096;
  limits.max_bytes = 64 << 20;
  auto r = terralign::geo::read_geotiff_memory(data, size, "fuzz.tif", limits);
  if (r.ok()) (void)r->crs.resolve();
  return 0;
}
