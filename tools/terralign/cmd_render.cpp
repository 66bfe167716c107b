// terralign render: the reference views of a map from one pose or a list of poses.
#include <cmath>
#include <cstdio>
#include <fstream>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/image_io.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>
#include <terralign/raster/renderer.hpp>

#include "args.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "output_folder.hpp"

namespace terralign::cli {
namespace {

// A false-colour preview of depth: near bright, far dark, no terrain black.
ImageU8 depth_preview(const ImageF& depth) {
  float lo = INFINITY, hi = -INFINITY;
  for (float z : depth.pixels())
    if (z == z) {
      lo = std::min(lo, z);
      hi = std::max(hi, z);
    }
  ImageU8 img(depth.width(), depth.height(), 1, 0);
  const float span = hi > lo ? hi - lo : 1.0f;
  for (std::size_t k = 0; k < depth.size(); ++k) {
    const float z = depth.data()[k];
    if (z == z) img.data()[k] = static_cast<std::uint8_t>(255.0f - 223.0f * (z - lo) / span);
  }
  return img;
}

// The files of one view: the colour and valid mask of each layer drawn, the depth and its preview.
Status write_outputs(const OutputFolder& dir, const raster::RenderOutput& out) {
  for (std::size_t l = 0; l < out.layer_names.size(); ++l) {
    TERRALIGN_TRY(geo::save_png(dir.path(out.layer_names[l] + ".png"), out.rgb[l].view()));
    TERRALIGN_TRY(geo::save_png(dir.path(out.layer_names[l] + "_valid.png"), out.valid[l].view()));
  }
  TERRALIGN_TRY(geo::save_pfm(dir.path("depth.pfm"), out.depth.view()));
  const ImageU8 preview = depth_preview(out.depth);
  return geo::save_png(dir.path("depth.png"), preview.view());
}

// What a view's folder holds of it: every layer of the map, so that an earlier view's layers
// that this one does not draw (render --layers) go with the rest of it.
std::vector<std::string> view_entries(const geo::Map& map) {
  std::vector<std::string> e = {"depth.pfm", "depth.png"};
  for (const auto& layer : map.layers) {
    e.push_back(layer.name + ".png");
    e.push_back(layer.name + "_valid.png");
  }
  return e;
}

}  // namespace

int run_render(const std::vector<std::string>& argv) {
  auto args = Args::parse(argv, {"map", "camera", "pose", "poses", "layers", "out", "threads", "lod-error"}, {});
  if (!args.ok()) return usage_error("render", args.error());
  auto map_path = args->required("map");
  auto cam_path = args->required("camera");
  auto out_dir = args->required("out");
  if (!map_path.ok()) return usage_error("render", map_path.error());
  if (!cam_path.ok()) return usage_error("render", cam_path.error());
  if (!out_dir.ok()) return usage_error("render", out_dir.error());
  if (args->has("pose") == args->has("poses"))
    return usage_error("render", Error{"give exactly one of --pose or --poses"});
  auto threads = args->get_int("threads", 2, 1, 64);
  if (!threads.ok()) return usage_error("render", threads.error());
  auto lod = args->get_double_in("lod-error", 0.5, {0, INFINITY, true}, "px");
  if (!lod.ok()) return usage_error("render", lod.error());

  std::vector<geo::Pose> poses;
  if (args->has("pose")) {
    auto p = geo::parse_pose(args->get("pose"));
    if (!p.ok()) return fail(p.error());
    poses.push_back(p.value());
  } else {
    std::ifstream in(args->get("poses"));
    if (!in) return fail(Error{args->get("poses") + ": cannot open the pose list"});
    std::string line;
    int n = 0;
    while (std::getline(in, line)) {
      ++n;
      if (line.find_first_not_of(" \t\r") == std::string::npos || line[0] == '#') continue;
      auto p = geo::parse_pose(line);
      if (!p.ok()) return fail(Error{args->get("poses") + ":" + std::to_string(n) + ": " + p.error().message});
      poses.push_back(p.value());
    }
    if (poses.empty()) return fail(Error{args->get("poses") + ": no poses"});
  }
  auto map = geo::load_map(map_path.value());
  if (!map.ok()) return fail(map.error());
  auto cam = geo::load_camera(cam_path.value());
  if (!cam.ok()) return fail(cam.error());
  raster::RenderOptions opt;
  opt.threads = threads.value();
  opt.lod_error_px = lod.value();
  auto renderer = raster::Renderer::create(map.value(), cam.value(), opt);
  if (!renderer.ok()) return fail(renderer.error());
  const std::string layer_arg = args->get("layers", "all");
  auto out = renderer.value()->make_output(split_commas(layer_arg));
  if (!out.ok()) return fail(out.error());
  if (auto st = ensure_dir(out_dir.value()); !st.ok()) return fail(st.error());

  const std::vector<std::string> entries = view_entries(map.value());
  int failed = 0;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const std::string dir = poses.size() == 1 ? out_dir.value() : out_dir.value() + "/" + std::to_string(i);
    raster::RenderStats stats;
    auto st = renderer.value()->render(poses[i], out.value(), &stats);
    // A view's files replace an earlier view's in the folder together, or not at all.
    auto staged = OutputFolder::open(dir, entries);
    if (!staged.ok()) return fail(staged.error());
    if (!st.ok()) {
      std::fprintf(stderr, "terralign: pose %zu: %s\n", i, st.error().message.c_str());
      ++failed;
      // Nothing written for a failed view: no half results. In a batch DIR/<index>/ is this
      // list's pose, so an earlier batch's view there goes; one pose's DIR keeps its view.
      if (poses.size() > 1)
        if (auto c = staged->commit(); !c.ok()) return fail(c.error());
      continue;
    }
    if (auto w = write_outputs(staged.value(), out.value()); !w.ok()) return fail(w.error());
    if (auto c = staged->commit(); !c.ok()) return fail(c.error());
    if (poses.size() > 1) {
      const int width = 40, done = static_cast<int>((i + 1) * width / poses.size());
      std::fprintf(stderr, "\r[%.*s%*s] %zu/%zu", done, "========================================", width - done, "",
                   i + 1, poses.size());
    }
  }
  if (poses.size() > 1) std::fprintf(stderr, "\n");
  return failed == 0 ? 0 : 1;
}

}  // namespace terralign::cli
