// A map: orthoimage layers (one per year, each with its own grid) over an elevation model,
// in one projected frame, described by a JSON manifest:
//
//   {"crs": "EPSG:26914",                        (optional where the rasters carry it;
//                                                  "local" or absent: a local metric frame)
//    "dem": {"file": "dem.tif"} | {"constant": 450.0},
//    "layers": [{"name": "2009", "file": "naip_2009.tif"},
//               {"name": "2016", "file": "a.png", "transform": [x0, dx, 0, y0, 0, -dy]}]}
//
// Paths are relative to the manifest (or absolute). A PNG / JPEG raster takes its
// geotransform from a "transform" array (GDAL order) or a world file beside it.
// How well a raster sits on the ground, where it is known: a layer's "registration_sigma_m"
// (one sigma per horizontal axis of where it places the ground over a camera's view, against
// where the ground is) and the DEM's "vertical_sigma_m". A pose found against the map is off
// by as much (the localizer's covariance counts them); absent: 0, not known.
#pragma once

#include <string>
#include <vector>

#include <terralign/geo/crs.hpp>
#include <terralign/geo/geotiff.hpp>
#include <terralign/geo/geotransform.hpp>
#include <terralign/geo/image.hpp>
#include <terralign/geo/result.hpp>

namespace terralign::geo {

struct Layer {
  std::string name;
  std::string path;
  ImageU8 rgba;              // 4 channels; alpha 0 where the layer has no data
  GeoTransform transform;
  Extent extent;
  std::int64_t valid_pixels = 0;
  double registration_sigma_m = 0;  // per horizontal axis; 0: not stated
};

struct Dem {
  bool constant = true;
  double constant_height = 0;  // metres, when constant
  std::string path;
  ImageF heights;              // NaN where the DEM has no data
  GeoTransform transform;
  Extent extent;               // infinite for a constant DEM
  double min_height = 0, max_height = 0;
  double vertical_sigma_m = 0;  // one sigma of its heights; 0: not stated

  // Bilinear height at map (x, y); NaN outside the DEM or next to a no-data post.
  double height_at(double x, double y) const;
};

struct Map {
  std::string path;
  Crs crs;
  Dem dem;
  std::vector<Layer> layers;

  const Layer* find_layer(const std::string& name) const;
  Layer* find_layer(const std::string& name) {
    return const_cast<Layer*>(static_cast<const Map*>(this)->find_layer(name));
  }
  // Where every layer (and a gridded DEM) has coverage: the intersection of their extents.
  Extent common_extent() const;
  // Names of the layers, comma-separated, for messages.
  std::string layer_names() const;
};

struct MapLoadOptions {
  RasterLimits limits;
};

Result<Map> load_map(const std::string& manifest_path, const MapLoadOptions& options = {});
// The manifest from text; relative paths resolve against `base_dir`.
Result<Map> parse_map(const std::string& json_text, const std::string& name,
                      const std::string& base_dir, const MapLoadOptions& options = {});

}  // namespace terralign::geo
