// Maps from their manifest: layers and DEM read through GeoTIFF / image files.
#include <terralign/geo/map.hpp>

#include <algorithm>
#include <cmath>

#include <nlohmann/json.hpp>

#include <terralign/geo/file.hpp>
#include <terralign/geo/image_io.hpp>
#include <terralign/geo/number_text.hpp>

#include "json_util.hpp"

namespace terralign::geo {
namespace {

std::string resolve_path(const std::string& base_dir, const std::string& file) {
  if (!file.empty() && file[0] == '/') return file;
  if (base_dir.empty()) return file;
  return base_dir + "/" + file;
}

std::string dir_of(const std::string& path) {
  const auto slash = path.find_last_of('/');
  return slash == std::string::npos ? std::string() : path.substr(0, slash);
}

bool ends_with_ci(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  for (std::size_t i = 0; i < suffix.size(); ++i)
    if (std::tolower(static_cast<unsigned char>(s[s.size() - suffix.size() + i])) != suffix[i]) return false;
  return true;
}

// A raster as named in the manifest, with its geotransform and CRS resolved.
struct LoadedRaster {
  GeoRaster raster;
  GeoTransform transform;
};

Result<LoadedRaster> load_raster(const nlohmann::json& spec, const std::string& base_dir,
                                 const std::string& where, const MapLoadOptions& opt) {
  TERRALIGN_TRY_ASSIGN(const std::string file, json_string(spec, "file", where));
  const std::string path = resolve_path(base_dir, file);
  LoadedRaster out;
  TERRALIGN_TRY_ASSIGN(const auto bytes, read_file(path));
  if (looks_like_tiff(bytes.data(), bytes.size())) {
    TERRALIGN_TRY_ASSIGN(out.raster, read_geotiff_memory(bytes.data(), bytes.size(), path, opt.limits));
  } else if (ends_with_ci(path, ".tif") || ends_with_ci(path, ".tiff")) {
    return Error{path + ": not a TIFF file (no 'II*' or 'MM*' signature)"};
  } else {
    TERRALIGN_TRY_ASSIGN(ImageU8 img, decode_image(bytes.data(), bytes.size(), path, 4,
                                                   opt.limits.max_bytes / 4));
    if (img.width() > opt.limits.max_side || img.height() > opt.limits.max_side)
      return Error{path + ": " + std::to_string(img.width()) + " x " + std::to_string(img.height()) +
                   " raster exceeds the limit of " + std::to_string(opt.limits.max_side) + " pixels a side"};
    out.raster.width = img.width();
    out.raster.height = img.height();
    out.raster.bands = 4;
    out.raster.has_alpha = true;
    out.raster.u8 = std::move(img);
  }
  if (spec.contains("transform")) {
    const auto& t = spec["transform"];
    if (!t.is_array() || t.size() != 6)
      return Error{where + ": 'transform' must be an array of 6 numbers (GDAL order)"};
    std::array<double, 6> c{};
    for (std::size_t i = 0; i < 6; ++i) {
      if (!t[i].is_number()) return Error{where + ": 'transform' must hold numbers"};
      c[i] = t[i].get<double>();
    }
    auto gt = GeoTransform::from_gdal(c);
    if (!gt.ok()) return with_context(where + ": transform", gt.error());
    out.transform = gt.value();
  } else if (out.raster.transform) {
    out.transform = *out.raster.transform;
  } else {
    const std::string wf = find_world_file(path);
    if (wf.empty())
      return Error{path + ": no geotransform: no GeoTIFF tags, no world file beside it (.pgw, .jgw, "
                   ".tfw, .wld) and no \"transform\" in the manifest"};
    TERRALIGN_TRY_ASSIGN(out.transform, read_world_file(wf));
  }
  return out;
}

Result<Layer> make_layer(const std::string& name, const std::string& path, LoadedRaster&& lr) {
  GeoRaster& r = lr.raster;
  if (r.sample != SampleType::U8)
    return Error{path + ": orthoimage layer has " + std::string(to_string(r.sample)) +
                 " samples; layers must be uint8 (RGB, RGBA or 4-band with NIR)"};
  if (r.bands == 2)
    return Error{path + ": orthoimage layer has 2 bands; expected 1 (grey), 3 (RGB), 4 (RGBA or RGB+NIR)"};
  Layer L;
  L.name = name;
  L.path = path;
  L.transform = lr.transform;
  L.extent = L.transform.extent(r.width, r.height);
  L.rgba.resize(r.width, r.height, 4);
  const int nb = r.bands;
  // A fourth band is alpha only if the file says so AND it is a mask (0 and 255 only):
  // NAIP files label their near-infrared band as alpha.
  bool alpha = r.has_alpha && nb >= 4;
  if (alpha) {
    const std::uint8_t* p = r.u8.data();
    for (std::size_t i = 0, n = r.u8.size() / static_cast<std::size_t>(nb); i < n && alpha; ++i)
      alpha = p[i * static_cast<std::size_t>(nb) + 3] == 0 || p[i * static_cast<std::size_t>(nb) + 3] == 255;
  }
  const bool has_nodata = r.nodata.has_value() && std::isfinite(*r.nodata);
  const double nod = has_nodata ? *r.nodata : 0;
  const std::uint8_t* src = r.u8.data();
  std::uint8_t* dst = L.rgba.data();
  const std::size_t n = static_cast<std::size_t>(r.width) * static_cast<std::size_t>(r.height);
  std::int64_t valid = 0;
  for (std::size_t i = 0; i < n; ++i, src += nb, dst += 4) {
    const std::uint8_t R = src[0], G = nb >= 3 ? src[1] : src[0], B = nb >= 3 ? src[2] : src[0];
    bool ok = !alpha || src[3] != 0;
    if (has_nodata && R == nod && G == nod && B == nod) ok = false;
    dst[0] = R;
    dst[1] = G;
    dst[2] = B;
    dst[3] = ok ? 255 : 0;
    valid += ok;
  }
  if (valid == 0) return Error{path + ": layer '" + name + "' has no valid pixels (all no-data)"};
  L.valid_pixels = valid;
  r.u8 = ImageU8();  // free the source copy
  return L;
}

Result<Dem> make_dem(const std::string& path, LoadedRaster&& lr) {
  GeoRaster& r = lr.raster;
  Dem d;
  d.constant = false;
  d.path = path;
  d.transform = lr.transform;
  d.extent = d.transform.extent(r.width, r.height);
  if (r.bands != 1)
    return Error{path + ": DEM has " + std::to_string(r.bands) + " bands; expected 1"};
  d.heights.resize(r.width, r.height, 1);
  const bool has_nodata = r.nodata.has_value() && std::isfinite(*r.nodata);
  const double nod = has_nodata ? *r.nodata : 0;
  double lo = INFINITY, hi = -INFINITY;
  for (std::size_t i = 0; i < d.heights.size(); ++i) {
    float v = r.sample == SampleType::U8 ? static_cast<float>(r.u8.data()[i]) : r.f32.data()[i];
    if (has_nodata && v == static_cast<float>(nod)) v = NAN;
    // Heights beyond +-20 km are not terrain: treat as no data (e.g. -3.4e38 fill values).
    if (std::isfinite(v) && std::abs(v) > 20000.0f) v = NAN;
    d.heights.data()[i] = v;
    if (std::isfinite(v)) {
      lo = std::min(lo, static_cast<double>(v));
      hi = std::max(hi, static_cast<double>(v));
    }
  }
  if (!(lo <= hi)) return Error{path + ": DEM is all no-data (no finite height in " +
                                std::to_string(r.width) + " x " + std::to_string(r.height) + " posts)"};
  d.min_height = lo;
  d.max_height = hi;
  return d;
}

// A raster's stated error in metres: absent 0 (not known), else finite in [0, 1000].
Result<double> optional_sigma(const nlohmann::json& spec, const char* key, const std::string& where) {
  if (!spec.contains(key)) return 0.0;
  TERRALIGN_TRY_ASSIGN(const double s, json_number(spec, key, where));
  if (!(s >= 0 && s <= 1000))
    return Error{where + ": '" + key + "' " + format_double(s) + " m must lie in [0, 1000]"};
  return s;
}

}  // namespace

Result<Map> parse_map(const std::string& text, const std::string& name, const std::string& base_dir,
                      const MapLoadOptions& opt) {
  TERRALIGN_TRY_ASSIGN(const nlohmann::json j, parse_json_text(text, name));
  TERRALIGN_TRY(check_keys(j, {"crs", "dem", "layers", "name", "description"}, name));
  Map map;
  map.path = name;
  bool crs_given = false;
  if (j.contains("crs") && !j["crs"].is_null()) {
    TERRALIGN_TRY_ASSIGN(const std::string crs_text, json_string(j, "crs", name));
    auto crs = Crs::parse(crs_text);
    if (!crs.ok()) return with_context(name + ": crs", crs.error());
    map.crs = crs.value();
    crs_given = true;
  }
  // The CRS every raster must agree with: the manifest's, else the first raster's.
  std::string crs_source = crs_given ? "the manifest's crs" : "";
  auto agree = [&](const CrsSpec& spec, const std::string& what) -> Status {
    if (!spec.present()) return Ok{};
    auto c = spec.resolve();
    if (!c.ok()) return with_context(what, c.error());
    if (crs_source.empty()) {
      map.crs = c.value();
      crs_source = what;
      return Ok{};
    }
    if (!c.value().same_as(map.crs))
      return Error{name + ": rasters in different CRSs: " + what + " is " + c.value().name() + ", " +
                   crs_source + " is " + map.crs.name()};
    return Ok{};
  };

  if (!j.contains("dem")) return Error{name + ": missing 'dem' ({\"file\": ...} or {\"constant\": height})"};
  const auto& dem = j["dem"];
  const std::string dem_where = name + ": dem";
  TERRALIGN_TRY(check_keys(dem, {"file", "constant", "transform", "vertical_sigma_m"}, dem_where));
  if (dem.contains("constant")) {
    if (dem.contains("file")) return Error{dem_where + ": give either 'file' or 'constant', not both"};
    TERRALIGN_TRY_ASSIGN(map.dem.constant_height, json_number(dem, "constant", dem_where));
    if (std::abs(map.dem.constant_height) > 20000)
      return Error{dem_where + ": constant height " + format_double(map.dem.constant_height) + " m is outside +-20000"};
    map.dem.constant = true;
    map.dem.min_height = map.dem.max_height = map.dem.constant_height;
    map.dem.extent = Extent{-INFINITY, -INFINITY, INFINITY, INFINITY};
  } else {
    TERRALIGN_TRY_ASSIGN(auto lr, load_raster(dem, base_dir, dem_where, opt));
    const std::string path = resolve_path(base_dir, dem["file"].get<std::string>());
    TERRALIGN_TRY(agree(lr.raster.crs, "DEM " + path));
    TERRALIGN_TRY_ASSIGN(map.dem, make_dem(path, std::move(lr)));
  }
  TERRALIGN_TRY_ASSIGN(map.dem.vertical_sigma_m, optional_sigma(dem, "vertical_sigma_m", dem_where));

  if (!j.contains("layers")) return Error{name + ": missing 'layers'"};
  const auto& layers = j["layers"];
  if (!layers.is_array() || layers.empty())
    return Error{name + ": 'layers' must be a non-empty array of {\"name\", \"file\"}"};
  for (std::size_t i = 0; i < layers.size(); ++i) {
    const std::string where = name + ": layers[" + std::to_string(i) + "]";
    TERRALIGN_TRY(check_keys(layers[i], {"name", "file", "transform", "registration_sigma_m"}, where));
    TERRALIGN_TRY_ASSIGN(const std::string lname, json_string(layers[i], "name", where));
    if (lname.empty() || lname.find_first_of("/\\,") != std::string::npos)
      return Error{where + ": layer name '" + lname + "' must be non-empty without '/', '\\' or ','"};
    if (map.find_layer(lname)) return Error{where + ": layer name '" + lname + "' is used twice"};
    TERRALIGN_TRY_ASSIGN(auto lr, load_raster(layers[i], base_dir, where, opt));
    const std::string path = resolve_path(base_dir, layers[i]["file"].get<std::string>());
    TERRALIGN_TRY(agree(lr.raster.crs, "layer '" + lname + "' (" + path + ")"));
    TERRALIGN_TRY_ASSIGN(Layer L, make_layer(lname, path, std::move(lr)));
    TERRALIGN_TRY_ASSIGN(L.registration_sigma_m, optional_sigma(layers[i], "registration_sigma_m", where));
    map.layers.push_back(std::move(L));
  }
  if (map.common_extent().empty())
    return Error{name + ": the layers (and DEM) have no area in common"};
  return map;
}

Result<Map> load_map(const std::string& manifest_path, const MapLoadOptions& options) {
  TERRALIGN_TRY_ASSIGN(const auto bytes, read_file(manifest_path, std::size_t{16} << 20));
  return parse_map(std::string(bytes.begin(), bytes.end()), manifest_path, dir_of(manifest_path), options);
}

}  // namespace terralign::geo
