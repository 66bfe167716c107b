// terralign info: what a map holds.
#include <cmath>
#include <cstdio>

#include <nlohmann/json.hpp>

#include <terralign/geo/map.hpp>

#include "args.hpp"
#include "commands.hpp"
#include "common.hpp"

namespace terralign::cli {

int run_info(const std::vector<std::string>& argv) {
  auto args = Args::parse(argv, {"map"}, {"json"});
  if (!args.ok()) return usage_error("info", args.error());
  auto map_path = args->required("map");
  if (!map_path.ok()) return usage_error("info", map_path.error());
  auto map = geo::load_map(map_path.value());
  if (!map.ok()) return fail(map.error());
  const geo::Map& m = map.value();

  nlohmann::json j;
  j["map"] = m.path;
  j["crs"] = m.crs.name();
  if (m.crs.epsg()) j["epsg"] = m.crs.epsg();
  auto extent_json = [](const geo::Extent& e) {
    return nlohmann::json{{"min_x", e.min_x}, {"min_y", e.min_y}, {"max_x", e.max_x}, {"max_y", e.max_y},
                          {"width_m", e.width()}, {"height_m", e.height()}};
  };
  if (m.dem.constant) {
    j["dem"] = {{"constant", m.dem.constant_height}};
  } else {
    j["dem"] = {{"file", m.dem.path},
                {"width", m.dem.heights.width()},
                {"height", m.dem.heights.height()},
                {"resolution_m", m.dem.transform.pixel_size_x()},
                {"min_height", m.dem.min_height},
                {"max_height", m.dem.max_height},
                {"extent", extent_json(m.dem.extent)}};
  }
  j["dem"]["vertical_sigma_m"] = m.dem.vertical_sigma_m;  // 0: not stated
  for (const auto& L : m.layers) {
    const double total = static_cast<double>(L.rgba.width()) * L.rgba.height();
    j["layers"].push_back({{"name", L.name},
                           {"file", L.path},
                           {"width", L.rgba.width()},
                           {"height", L.rgba.height()},
                           {"resolution_m", {L.transform.pixel_size_x(), L.transform.pixel_size_y()}},
                           {"geotransform", L.transform.gdal()},
                           {"extent", extent_json(L.extent)},
                           {"valid_fraction", static_cast<double>(L.valid_pixels) / total},
                           {"registration_sigma_m", L.registration_sigma_m}});
  }
  const geo::Extent common = m.common_extent();
  j["common_extent"] = extent_json(common);
  if (!m.crs.is_local()) {
    const double cx = 0.5 * (common.min_x + common.max_x), cy = 0.5 * (common.min_y + common.max_y);
    const double h = m.dem.height_at(cx, cy);
    auto g = m.crs.to_geodetic(cx, cy, std::isfinite(h) ? h : 0.0);
    if (g.ok()) j["common_centre_lat_lon"] = {g->lat_deg, g->lon_deg};
  }

  if (args->has("json")) {
    std::printf("%s\n", j.dump(2).c_str());
    return 0;
  }
  std::printf("map      %s\ncrs      %s\n", m.path.c_str(), m.crs.name().c_str());
  if (m.dem.constant)
    std::printf("dem      constant height %.3f m\n", m.dem.constant_height);
  else
    std::printf("dem      %s: %d x %d posts at %.3f m, heights %.2f .. %.2f m\n", m.dem.path.c_str(),
                m.dem.heights.width(), m.dem.heights.height(), m.dem.transform.pixel_size_x(),
                m.dem.min_height, m.dem.max_height);
  if (m.dem.vertical_sigma_m > 0) std::printf("         heights good to %.2f m (1 sigma)\n", m.dem.vertical_sigma_m);
  std::printf("layers   %zu\n", m.layers.size());
  for (const auto& L : m.layers) {
    const double total = static_cast<double>(L.rgba.width()) * L.rgba.height();
    std::printf("  %-10s %5d x %-5d  %.3f m/px  x %.2f .. %.2f  y %.2f .. %.2f  valid %.1f %%  %s\n",
                L.name.c_str(), L.rgba.width(), L.rgba.height(), L.transform.pixel_size_x(),
                L.extent.min_x, L.extent.max_x, L.extent.min_y, L.extent.max_y,
                100.0 * static_cast<double>(L.valid_pixels) / total, L.path.c_str());
    if (L.registration_sigma_m > 0)
      std::printf("             placed on the ground to %.2f m per axis (1 sigma)\n", L.registration_sigma_m);
  }
  std::printf("covered by every layer%s: x %.2f .. %.2f, y %.2f .. %.2f (%.1f x %.1f m)\n",
              m.dem.constant ? "" : " and the DEM", common.min_x, common.max_x, common.min_y,
              common.max_y, common.width(), common.height());
  if (j.contains("common_centre_lat_lon"))
    std::printf("centre   lat %.7f, lon %.7f\n", j["common_centre_lat_lon"][0].get<double>(),
                j["common_centre_lat_lon"][1].get<double>());
  return 0;
}

}  // namespace terralign::cli
