#include <terralign/geo/geotiff.hpp>

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>

#include <tiffio.h>

#include <terralign/geo/file.hpp>
#include <terralign/geo/number_text.hpp>

namespace terralign::geo {
namespace {

// GeoTIFF 1.1 and GDAL tags.
constexpr ttag_t kModelPixelScale = 33550;
constexpr ttag_t kModelTiepoint = 33922;
constexpr ttag_t kModelTransformation = 34264;
constexpr ttag_t kGeoKeyDirectory = 34735;
constexpr ttag_t kGeoDoubleParams = 34736;
constexpr ttag_t kGeoAsciiParams = 34737;
constexpr ttag_t kGdalNodata = 42113;

const TIFFFieldInfo kGeoFields[] = {
    {kModelPixelScale, TIFF_VARIABLE2, TIFF_VARIABLE2, TIFF_DOUBLE, FIELD_CUSTOM, 1, 1, const_cast<char*>("ModelPixelScale")},
    {kModelTiepoint, TIFF_VARIABLE2, TIFF_VARIABLE2, TIFF_DOUBLE, FIELD_CUSTOM, 1, 1, const_cast<char*>("ModelTiepoint")},
    {kModelTransformation, TIFF_VARIABLE2, TIFF_VARIABLE2, TIFF_DOUBLE, FIELD_CUSTOM, 1, 1, const_cast<char*>("ModelTransformation")},
    {kGeoKeyDirectory, TIFF_VARIABLE2, TIFF_VARIABLE2, TIFF_SHORT, FIELD_CUSTOM, 1, 1, const_cast<char*>("GeoKeyDirectory")},
    {kGeoDoubleParams, TIFF_VARIABLE2, TIFF_VARIABLE2, TIFF_DOUBLE, FIELD_CUSTOM, 1, 1, const_cast<char*>("GeoDoubleParams")},
    {kGeoAsciiParams, -1, -1, TIFF_ASCII, FIELD_CUSTOM, 1, 0, const_cast<char*>("GeoAsciiParams")},
    {kGdalNodata, -1, -1, TIFF_ASCII, FIELD_CUSTOM, 1, 0, const_cast<char*>("GDALNoDataValue")},
};

TIFFExtendProc g_parent_extender = nullptr;

void geo_tag_extender(TIFF* tif) {
  TIFFMergeFieldInfo(tif, kGeoFields, sizeof kGeoFields / sizeof kGeoFields[0]);
  if (g_parent_extender) g_parent_extender(tif);
}

void register_geo_tags() {
  static std::once_flag once;
  std::call_once(once, [] { g_parent_extender = TIFFSetTagExtender(geo_tag_extender); });
}

// libtiff reads through these from a buffer in memory.
struct MemoryFile {
  const std::uint8_t* data;
  toff_t size;
  toff_t pos;
};

tmsize_t mem_read(thandle_t h, void* buf, tmsize_t n) {
  auto* m = static_cast<MemoryFile*>(h);
  if (n < 0 || m->pos >= m->size) return 0;
  const toff_t avail = m->size - m->pos;
  const toff_t take = std::min<toff_t>(avail, static_cast<toff_t>(n));
  std::memcpy(buf, m->data + m->pos, static_cast<std::size_t>(take));
  m->pos += take;
  return static_cast<tmsize_t>(take);
}
tmsize_t mem_write(thandle_t, void*, tmsize_t) { return -1; }
toff_t mem_seek(thandle_t h, toff_t off, int whence) {
  auto* m = static_cast<MemoryFile*>(h);
  toff_t base = whence == SEEK_SET ? 0 : whence == SEEK_CUR ? m->pos : m->size;
  if (whence != SEEK_SET && whence != SEEK_CUR && whence != SEEK_END) return static_cast<toff_t>(-1);
  // Offsets are unsigned; a "negative" offset wraps. Refuse positions past 2^62.
  const toff_t target = base + off;
  if (target > (toff_t{1} << 62)) return static_cast<toff_t>(-1);
  m->pos = target;
  return m->pos;
}
int mem_close(thandle_t) { return 0; }
toff_t mem_size(thandle_t h) { return static_cast<MemoryFile*>(h)->size; }
int mem_map(thandle_t, void**, toff_t*) { return 0; }
void mem_unmap(thandle_t, void*, toff_t) {}

// Keeps the first libtiff error message of a read, for our own message.
struct ErrorSink {
  std::string first;
};
int tiff_error(TIFF*, void* user, const char* module, const char* fmt, va_list ap) {
  auto* sink = static_cast<ErrorSink*>(user);
  if (sink->first.empty()) {
    char buf[512];
    std::vsnprintf(buf, sizeof buf, fmt, ap);
    sink->first = std::string(module ? module : "libtiff") + ": " + buf;
  }
  return 1;
}
int tiff_warning(TIFF*, void*, const char*, const char*, va_list) { return 1; }

template <class T>
bool get_array(TIFF* tif, ttag_t tag, std::vector<T>& out) {
  std::uint32_t count = 0;
  T* values = nullptr;
  if (TIFFGetField(tif, tag, &count, &values) != 1 || !values) return false;
  out.assign(values, values + count);
  return true;
}

bool get_ascii(TIFF* tif, ttag_t tag, std::string& out) {
  char* s = nullptr;
  if (TIFFGetField(tif, tag, &s) != 1 || !s) return false;
  out = s;
  return true;
}

struct GeoKeys {
  std::vector<std::uint16_t> dir;
  std::vector<double> doubles;
  // Returns the SHORT value of a key stored inline (location 0).
  std::optional<int> short_key(int id) const {
    for (std::size_t k = 4; k + 3 < dir.size(); k += 4)
      if (dir[k] == id && dir[k + 1] == 0) return dir[k + 3];
    return std::nullopt;
  }
  std::optional<double> double_key(int id) const {
    for (std::size_t k = 4; k + 3 < dir.size(); k += 4)
      if (dir[k] == id && dir[k + 1] == kGeoDoubleParams) {
        const std::size_t at = dir[k + 3];
        if (dir[k + 2] >= 1 && at < doubles.size()) return doubles[at];
      }
    return std::nullopt;
  }
};

CrsSpec crs_from_geokeys(const GeoKeys& keys) {
  CrsSpec spec;
  const int model = keys.short_key(1024).value_or(0);  // GTModelTypeGeoKey
  if (model == 2) {                                     // geographic
    spec.geographic = true;
    spec.epsg = keys.short_key(2048).value_or(0);
    spec.note = "geographic (latitude/longitude) model";
    return spec;
  }
  const int projected = keys.short_key(3072).value_or(0);  // ProjectedCSTypeGeoKey
  if (projected != 0 && projected != 32767) {
    spec.epsg = projected;
    spec.note = "EPSG:" + std::to_string(projected);
    return spec;
  }
  const int transform = keys.short_key(3075).value_or(0);  // ProjCoordTransGeoKey
  if (projected == 32767 && transform == 1) {              // user-defined transverse Mercator
    TransverseMercatorParams p;
    p.lat0_deg = keys.double_key(3081).value_or(keys.double_key(3089).value_or(0.0));
    p.lon0_deg = keys.double_key(3080).value_or(keys.double_key(3088).value_or(0.0));
    p.k0 = keys.double_key(3092).value_or(keys.double_key(3093).value_or(1.0));
    p.false_easting = keys.double_key(3082).value_or(keys.double_key(3090).value_or(0.0));
    p.false_northing = keys.double_key(3083).value_or(keys.double_key(3091).value_or(0.0));
    const int geog = keys.short_key(2048).value_or(0);
    if (geog == 4269 || keys.short_key(2050).value_or(0) == 6269) p.inv_f = 298.257222101;
    if (auto a = keys.double_key(2057)) p.a = *a;
    if (auto f = keys.double_key(2059)) p.inv_f = *f;
    spec.tm = p;
    spec.note = "user-defined transverse Mercator";
    return spec;
  }
  if (projected == 32767) spec.note = "user-defined projection (only transverse Mercator is supported)";
  return spec;
}

Result<GeoTransform> geotransform_from_tags(TIFF* tif, const std::string& name, bool& found) {
  found = false;
  std::vector<double> scale, tie, matrix;
  if (get_array(tif, kModelTransformation, matrix)) {
    if (matrix.size() < 16)
      return Error{name + ": ModelTransformation has " + std::to_string(matrix.size()) + " values, needs 16"};
    found = true;
    auto gt = GeoTransform::from_gdal({matrix[3], matrix[0], matrix[1], matrix[7], matrix[4], matrix[5]});
    if (!gt.ok()) return with_context(name + ": ModelTransformation", gt.error());
    return gt;
  }
  const bool has_scale = get_array(tif, kModelPixelScale, scale);
  const bool has_tie = get_array(tif, kModelTiepoint, tie);
  if (!has_scale && !has_tie) return Error{name + ": no geotransform tags"};
  if (!has_scale || scale.size() < 2)
    return Error{name + ": ModelTiepoint without a ModelPixelScale (3 values) is not supported"};
  if (!has_tie || tie.size() < 6)
    return Error{name + ": ModelPixelScale without a ModelTiepoint (6 values)"};
  found = true;
  const double sx = scale[0], sy = scale[1];
  auto gt = GeoTransform::from_gdal({tie[3] - tie[0] * sx, sx, 0.0, tie[4] + tie[1] * sy, 0.0, -sy});
  if (!gt.ok()) return with_context(name + ": ModelPixelScale/ModelTiepoint", gt.error());
  return gt;
}

struct TiffCloser {
  void operator()(TIFF* t) const { TIFFClose(t); }
};

template <class Src>
void copy_samples(const std::uint8_t* src_bytes, std::size_t n, std::uint8_t* dst_u8, float* dst_f,
                  std::ptrdiff_t dst_step) {
  for (std::size_t i = 0; i < n; ++i) {
    Src v;
    std::memcpy(&v, src_bytes + i * sizeof(Src), sizeof(Src));
    if (dst_u8) dst_u8[static_cast<std::ptrdiff_t>(i) * dst_step] = static_cast<std::uint8_t>(v);
    else dst_f[static_cast<std::ptrdiff_t>(i) * dst_step] = static_cast<float>(v);
  }
}

}  // namespace

const char* to_string(SampleType t) {
  switch (t) {
    case SampleType::U8: return "uint8";
    case SampleType::I16: return "int16";
    case SampleType::U16: return "uint16";
    case SampleType::F32: return "float32";
  }
  return "?";
}

Result<Crs> CrsSpec::resolve() const {
  if (geographic)
    return Error{"the raster is in a geographic CRS (" + note +
                 "); terralign maps need a projected metric CRS"};
  if (tm) return Crs::transverse_mercator(*tm);
  if (epsg) return Crs::from_epsg(epsg);
  if (!note.empty()) return Error{note};
  return Crs::local();
}

bool looks_like_tiff(const std::uint8_t* d, std::size_t n) {
  if (n < 4) return false;
  const bool le = d[0] == 'I' && d[1] == 'I' && (d[2] == 42 || d[2] == 43) && d[3] == 0;
  const bool be = d[0] == 'M' && d[1] == 'M' && d[2] == 0 && (d[3] == 42 || d[3] == 43);
  return le || be;
}

Result<GeoRaster> read_geotiff(const std::string& path, const RasterLimits& limits) {
  TERRALIGN_TRY_ASSIGN(auto bytes, read_file(path));
  return read_geotiff_memory(bytes.data(), bytes.size(), path, limits);
}

Result<GeoRaster> read_geotiff_memory(const std::uint8_t* data, std::size_t size,
                                      const std::string& name, const RasterLimits& limits) {
  if (!looks_like_tiff(data, size))
    return Error{name + ": not a TIFF file (no 'II*' or 'MM*' signature)"};
  register_geo_tags();
  MemoryFile mem{data, static_cast<toff_t>(size), 0};
  ErrorSink sink;
  TIFFOpenOptions* opts = TIFFOpenOptionsAlloc();
  TIFFOpenOptionsSetErrorHandlerExtR(opts, tiff_error, &sink);
  TIFFOpenOptionsSetWarningHandlerExtR(opts, tiff_warning, nullptr);
  // A corrupt header must not make libtiff allocate gigabytes. At most what tmsize_t holds: in
  // a 32-bit process 2^31 would wrap to a negative limit.
  TIFFOpenOptionsSetMaxSingleMemAlloc(
      opts, static_cast<tmsize_t>(std::clamp<std::int64_t>(
                limits.max_bytes, std::int64_t{16} << 20,
                std::min<std::int64_t>(std::int64_t{1} << 31, std::numeric_limits<tmsize_t>::max()))));
  std::unique_ptr<TIFF, TiffCloser> tif(TIFFClientOpenExt(name.c_str(), "rm", &mem, mem_read, mem_write,
                                                          mem_seek, mem_close, mem_size, mem_map,
                                                          mem_unmap, opts));
  TIFFOpenOptionsFree(opts);
  auto fail = [&](const std::string& what) {
    return Error{name + ": " + what + (sink.first.empty() ? "" : " (" + sink.first + ")")};
  };
  if (!tif) return fail("cannot read TIFF header (truncated or corrupt)");
  TIFF* t = tif.get();

  std::uint32_t w = 0, h = 0;
  std::uint16_t spp = 1, bps = 1, fmt = SAMPLEFORMAT_UINT, planar = PLANARCONFIG_CONTIG;
  std::uint16_t photometric = PHOTOMETRIC_MINISBLACK, compression = COMPRESSION_NONE;
  TIFFGetField(t, TIFFTAG_IMAGEWIDTH, &w);
  TIFFGetField(t, TIFFTAG_IMAGELENGTH, &h);
  TIFFGetFieldDefaulted(t, TIFFTAG_SAMPLESPERPIXEL, &spp);
  TIFFGetFieldDefaulted(t, TIFFTAG_BITSPERSAMPLE, &bps);
  TIFFGetFieldDefaulted(t, TIFFTAG_SAMPLEFORMAT, &fmt);
  TIFFGetFieldDefaulted(t, TIFFTAG_PLANARCONFIG, &planar);
  TIFFGetFieldDefaulted(t, TIFFTAG_COMPRESSION, &compression);
  TIFFGetField(t, TIFFTAG_PHOTOMETRIC, &photometric);

  if (w == 0 || h == 0)
    return Error{name + ": " + std::to_string(w) + " x " + std::to_string(h) + " raster has no pixels"};
  if (w > limits.max_side || h > limits.max_side)
    return Error{name + ": " + std::to_string(w) + " x " + std::to_string(h) +
                 " raster exceeds the limit of " + std::to_string(limits.max_side) + " pixels a side"};
  if (spp < 1 || spp > 16) return Error{name + ": " + std::to_string(spp) + " bands is not supported (1-16)"};

  GeoRaster r;
  if (bps == 8 && fmt == SAMPLEFORMAT_UINT) r.sample = SampleType::U8;
  else if (bps == 16 && fmt == SAMPLEFORMAT_INT) r.sample = SampleType::I16;
  else if (bps == 16 && fmt == SAMPLEFORMAT_UINT) r.sample = SampleType::U16;
  else if (bps == 32 && fmt == SAMPLEFORMAT_IEEEFP) r.sample = SampleType::F32;
  else {
    const char* kind = fmt == SAMPLEFORMAT_INT ? "signed integer" : fmt == SAMPLEFORMAT_IEEEFP ? "float" : "unsigned integer";
    return Error{name + ": unsupported sample format: " + std::to_string(bps) + "-bit " + kind +
                 " (supported: uint8, int16, uint16, float32)"};
  }
  if (photometric == PHOTOMETRIC_PALETTE) return Error{name + ": palette (colour-mapped) TIFF is not supported"};
  if (!TIFFIsCODECConfigured(compression))
    return Error{name + ": compression scheme " + std::to_string(compression) + " is not supported by this libtiff"};
  if (photometric == PHOTOMETRIC_YCBCR) {
    if (compression != COMPRESSION_JPEG) return Error{name + ": YCbCr TIFF without JPEG compression is not supported"};
    TIFFSetField(t, TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB);
  }
  const std::size_t bytes_per_sample = bps / 8u;
  const std::int64_t decoded = std::int64_t{w} * h * spp * static_cast<std::int64_t>(bytes_per_sample);
  if (decoded > limits.max_bytes)
    return Error{name + ": " + std::to_string(w) + " x " + std::to_string(h) + " x " + std::to_string(spp) +
                 " raster needs " + std::to_string(decoded) + " bytes, over the limit of " +
                 std::to_string(limits.max_bytes)};

  std::uint16_t n_extra = 0;
  std::uint16_t* extra = nullptr;
  if (TIFFGetField(t, TIFFTAG_EXTRASAMPLES, &n_extra, &extra) == 1 && extra && n_extra > 0 && spp >= 4) {
    // Band 3 (0-based) is alpha when the extra sample describing it says so; the extra
    // samples are the last n_extra bands.
    const int idx = 3 - (static_cast<int>(spp) - static_cast<int>(n_extra));
    r.has_alpha = idx >= 0 && idx < n_extra &&
                  (extra[idx] == EXTRASAMPLE_ASSOCALPHA || extra[idx] == EXTRASAMPLE_UNASSALPHA);
  }
  r.width = static_cast<int>(w);
  r.height = static_cast<int>(h);
  r.bands = spp;
  if (r.sample == SampleType::U8) r.u8.resize(r.width, r.height, spp);
  else r.f32.resize(r.width, r.height, spp);

  // Copies n samples of one band (or all bands when interleaved) into the output at
  // (x, y), band `band`, `step` samples apart.
  auto store = [&](const std::uint8_t* src, std::size_t n, int x, int y, int band, std::ptrdiff_t step) {
    const std::size_t at = (static_cast<std::size_t>(y) * w + static_cast<std::size_t>(x)) * spp + static_cast<std::size_t>(band);
    std::uint8_t* d8 = r.sample == SampleType::U8 ? r.u8.data() + at : nullptr;
    float* df = r.sample == SampleType::U8 ? nullptr : r.f32.data() + at;
    switch (r.sample) {
      case SampleType::U8: copy_samples<std::uint8_t>(src, n, d8, df, step); break;
      case SampleType::I16: copy_samples<std::int16_t>(src, n, d8, df, step); break;
      case SampleType::U16: copy_samples<std::uint16_t>(src, n, d8, df, step); break;
      case SampleType::F32: copy_samples<float>(src, n, d8, df, step); break;
    }
  };

  const bool separate = planar == PLANARCONFIG_SEPARATE && spp > 1;
  const int planes = separate ? spp : 1;
  const std::size_t px_samples = separate ? 1 : spp;  // samples per pixel within one buffer
  if (TIFFIsTiled(t)) {
    std::uint32_t tw = 0, th = 0;
    TIFFGetField(t, TIFFTAG_TILEWIDTH, &tw);
    TIFFGetField(t, TIFFTAG_TILELENGTH, &th);
    if (tw == 0 || th == 0 || tw > 65536 || th > 65536) return fail("bad tile size " + std::to_string(tw) + " x " + std::to_string(th));
    const tmsize_t tile_bytes = TIFFTileSize(t);
    const std::size_t need = std::size_t{tw} * th * px_samples * bytes_per_sample;
    if (tile_bytes <= 0 || static_cast<std::size_t>(tile_bytes) < need) return fail("inconsistent tile size");
    // A tile may be larger than the raster (its edge tiles are padded), but one buffer of it
    // must fit the same limit as the raster: a header naming 65536 x 65536 tiles over a small
    // image would otherwise allocate gigabytes (found by fuzz_geotiff).
    if (static_cast<std::int64_t>(tile_bytes) > limits.max_bytes)
      return fail("tiles of " + std::to_string(tw) + " x " + std::to_string(th) + " need " + std::to_string(tile_bytes) +
                  " bytes each, over the limit of " + std::to_string(limits.max_bytes));
    std::vector<std::uint8_t> buf(static_cast<std::size_t>(tile_bytes));
    for (int p = 0; p < planes; ++p)
      for (std::uint32_t ty = 0; ty < h; ty += th)
        for (std::uint32_t tx = 0; tx < w; tx += tw) {
          const std::uint32_t tile = TIFFComputeTile(t, tx, ty, 0, static_cast<std::uint16_t>(p));
          if (TIFFReadEncodedTile(t, tile, buf.data(), tile_bytes) < 0)
            return fail("cannot decode tile " + std::to_string(tile) + " (truncated or corrupt data)");
          const std::uint32_t cols = std::min(tw, w - tx), rows = std::min(th, h - ty);
          for (std::uint32_t yy = 0; yy < rows; ++yy)
            store(buf.data() + std::size_t{yy} * tw * px_samples * bytes_per_sample, cols * px_samples,
                  static_cast<int>(tx), static_cast<int>(ty + yy), p, separate ? spp : 1);
        }
  } else {
    std::uint32_t rps = h;
    TIFFGetFieldDefaulted(t, TIFFTAG_ROWSPERSTRIP, &rps);
    rps = std::max<std::uint32_t>(1, std::min(rps, h));
    const tmsize_t strip_bytes = TIFFStripSize(t);
    const std::size_t need = std::size_t{rps} * w * px_samples * bytes_per_sample;
    if (strip_bytes <= 0 || static_cast<std::size_t>(strip_bytes) < need) return fail("inconsistent strip size");
    if (static_cast<std::int64_t>(strip_bytes) > limits.max_bytes)
      return fail("strips of " + std::to_string(strip_bytes) + " bytes, over the limit of " + std::to_string(limits.max_bytes));
    std::vector<std::uint8_t> buf(static_cast<std::size_t>(strip_bytes));
    const std::uint32_t strips_per_plane = (h + rps - 1) / rps;
    for (int p = 0; p < planes; ++p)
      for (std::uint32_t s = 0; s < strips_per_plane; ++s) {
        const std::uint32_t strip = static_cast<std::uint32_t>(p) * strips_per_plane + s;
        if (TIFFReadEncodedStrip(t, strip, buf.data(), strip_bytes) < 0)
          return fail("cannot decode strip " + std::to_string(strip) + " (truncated or corrupt data)");
        const std::uint32_t y0 = s * rps, rows = std::min(rps, h - y0);
        store(buf.data(), std::size_t{rows} * w * px_samples, 0, static_cast<int>(y0), p, separate ? spp : 1);
      }
  }

  // Geo-referencing.
  bool found = false;
  auto gt = geotransform_from_tags(t, name, found);
  GeoKeys keys;
  get_array(t, kGeoKeyDirectory, keys.dir);
  get_array(t, kGeoDoubleParams, keys.doubles);
  if (found) {
    if (!gt.ok()) return gt.error();
    std::array<double, 6> c = gt.value().gdal();
    r.pixel_is_point = keys.short_key(1025).value_or(1) == 2;  // GTRasterTypeGeoKey
    if (r.pixel_is_point) {  // the tie point is a pixel centre: move to the outer corner
      c[0] -= 0.5 * c[1] + 0.5 * c[2];
      c[3] -= 0.5 * c[4] + 0.5 * c[5];
    }
    auto moved = GeoTransform::from_gdal(c);
    if (!moved.ok()) return with_context(name, moved.error());
    r.transform = moved.value();
  }
  if (!keys.dir.empty()) r.crs = crs_from_geokeys(keys);
  std::string nodata;
  if (get_ascii(t, kGdalNodata, nodata)) {
    while (!nodata.empty() && (nodata.back() == ' ' || nodata.back() == '\0')) nodata.pop_back();
    if (nodata == "nan" || nodata == "NaN" || nodata == "-nan") r.nodata = NAN;
    else {
      auto v = parse_double(nodata);
      if (!v.ok()) return with_context(name + ": GDAL_NODATA", v.error());
      r.nodata = v.value();
    }
  }
  return r;
}

}  // namespace terralign::geo
