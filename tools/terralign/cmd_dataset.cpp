// terralign dataset: training pairs from the renderer, for the learned tracker.
#include <cmath>
#include <cstdio>

#include <terralign/geo/file.hpp>
#include <terralign/geo/image_io.hpp>
#include <terralign/geo/number_text.hpp>

#include "args.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "localizer.hpp"
#include "output_folder.hpp"
#include "sampling.hpp"

namespace terralign::cli {
namespace {

// Photometric augmentation of a query image, seeded: exposure gain U[0.8, 1.2], white
// balance gains U[0.9, 1.1] per channel, a 3x3 box blur with probability 0.3, Gaussian noise
// of sigma U[0, 3] grey levels. These stand for the changes between a real camera and a map.
void augment(ImageU8& img, Rng& rng) {
  const double exposure = rng.uniform(0.8, 1.2);
  double wb[3];
  for (double& g : wb) g = exposure * rng.uniform(0.9, 1.1);
  const bool blur = rng.uniform() < 0.3;
  const double sigma = rng.uniform(0, 3);
  if (blur) box_blur(img, 1);
  for (int y = 0; y < img.height(); ++y)
    for (int x = 0; x < img.width(); ++x)
      for (int c = 0; c < 3; ++c) {
        const double v = img.at(x, y, c) * wb[c] + sigma * rng.normal();
        img.at(x, y, c) = static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L));
      }
}

}  // namespace

int run_dataset(const std::vector<std::string>& argv) {
  auto args = Args::parse(argv, {"map", "camera", "count", "seed", "out", "altitude", "tilt", "split-fraction", "scale", "layers"},
                          {"no-augment"});
  if (!args.ok()) return usage_error("dataset", args.error());
  for (const char* k : {"map", "camera", "count", "seed", "out"})
    if (!args->has(k)) return usage_error("dataset", Error{std::string("missing required option --") + k});
  auto count = args->get_int("count", 0, 1, 1000000);
  auto seed = args->get_int("seed", 0, 0, 1 << 30);
  auto tilt = args->get_double_in("tilt", 10, {0, 60}, "degrees");
  auto fraction = args->get_double_in("split-fraction", 0.2, {0, 1, true, true});
  auto scale = args->get_double_in("scale", 1.0, {0, 4, true});
  for (const auto* r : {&count, &seed})
    if (!r->ok()) return usage_error("dataset", r->error());
  for (const auto* r : {&tilt, &fraction, &scale})
    if (!r->ok()) return usage_error("dataset", r->error());
  const auto altitude = altitude_range(args.value(), {700, 900});
  if (!altitude.ok()) return usage_error("dataset", altitude.error());
  const auto [lo, hi] = altitude.value();
  auto map = geo::load_map(args->get("map"));
  if (!map.ok()) return fail(map.error());
  auto cam_in = geo::load_camera(args->get("camera"));
  if (!cam_in.ok()) return fail(cam_in.error());
  geo::CameraModel cam = pinhole_of(cam_in.value());
  const double s = scale.value();
  cam = cam.scaled(s, static_cast<int>(std::lround(cam.width * s)), static_cast<int>(std::lround(cam.height * s)));
  std::vector<std::string> layers;
  if (args->get("layers", "all") == "all") {
    for (const auto& L : map->layers) layers.push_back(L.name);
  } else {
    layers = split_commas(args->get("layers"));
    for (const auto& n : layers)
      if (!map->find_layer(n)) return fail(Error{"no layer named '" + n + "' (layers: " + map->layer_names() + ")"});
  }
  raster::RenderOptions ro;
  auto renderer = raster::Renderer::create(map.value(), cam, ro);
  if (!renderer.ok()) return fail(renderer.error());
  auto view = renderer.value()->make_output(layers);
  if (!view.ok()) return fail(view.error());

  // Spatially disjoint areas: validation is a strip at the east (or north, if the map is
  // taller than wide) end of the common extent, training the rest; every footprint lies
  // wholly inside its area, so no ground is in both.
  const geo::Extent all = map->common_extent();
  const bool by_x = all.width() >= all.height();
  const double split_at = by_x ? all.max_x - fraction.value() * all.width() : all.max_y - fraction.value() * all.height();
  const geo::Extent train_area = by_x ? geo::Extent{all.min_x, all.min_y, split_at, all.max_y}
                                      : geo::Extent{all.min_x, all.min_y, all.max_x, split_at};
  const geo::Extent val_area = by_x ? geo::Extent{split_at, all.min_y, all.max_x, all.max_y}
                                    : geo::Extent{all.min_x, split_at, all.max_x, all.max_y};
  const int n_val = std::max(1, static_cast<int>(std::lround(count.value() * fraction.value())));
  const int n_train = std::max(0, count.value() - n_val);
  auto train = sample_poses(map.value(), cam, train_area, n_train, static_cast<std::uint64_t>(seed.value()), lo, hi, tilt.value());
  if (!train.ok()) return fail(with_context("training area", train.error()));
  auto val = sample_poses(map.value(), cam, val_area, n_val, static_cast<std::uint64_t>(seed.value()) + 1, lo, hi, tilt.value());
  if (!val.ok())
    return fail(with_context(std::string("validation area (the ") + (by_x ? "eastern " : "northern ") +
                                 geo::format_double(fraction.value()) + " of the map; fly lower or give a larger --split-fraction)",
                             val.error()));

  const std::string out = args->get("out");
  // Written whole or not at all: an earlier data set in --out stays as it was (its index naming
  // its own samples) until this one is complete, and then none of its samples is left.
  auto staged = OutputFolder::open(out, {"train", "val", "index.csv"});
  if (!staged.ok()) return fail(staged.error());
  for (const char* d : {"train", "val"})
    if (auto st = ensure_dir(staged->path(d)); !st.ok()) return fail(st.error());
  std::string index =
      "split,pose,ref_layer,query_layer,ref_image,ref_depth,query_image,width,height,fx,fy,cx,cy,altitude,"
      "t_x,t_y,t_z,q_w,q_x,q_y,q_z,prior,truth\n";
  const bool aug = !args->has("no-augment");
  const int total = n_train + n_val;
  int done = 0;
  for (int part = 0; part < 2; ++part) {
    const std::vector<Sample>& samples = part == 0 ? train.value() : val.value();
    const std::string split = part == 0 ? "train" : "val";
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const Sample& smp = samples[i];
      char id[24];
      std::snprintf(id, sizeof id, "%06zu", i);
      const std::string dir = staged->path(split + "/" + id);
      if (auto st = ensure_dir(dir); !st.ok()) return fail(st.error());
      // The reference: every layer at the prior, with its depth (NaN where no terrain).
      if (auto st = renderer.value()->render(smp.prior, view.value()); !st.ok())
        return fail(Error{split + " pose " + id + ": " + st.error().message});
      for (std::size_t l = 0; l < layers.size(); ++l)
        if (auto st = geo::save_png(dir + "/ref_" + layers[l] + ".png", view->rgb[l].view()); !st.ok()) return fail(st.error());
      if (auto st = geo::save_pfm(dir + "/ref_depth.pfm", view->depth.view()); !st.ok()) return fail(st.error());
      // The query: every layer at the truth, augmented.
      if (auto st = renderer.value()->render(smp.truth, view.value()); !st.ok())
        return fail(Error{split + " pose " + id + ": " + st.error().message});
      Rng rng{static_cast<std::uint64_t>(seed.value()) * 1000003u + static_cast<std::uint64_t>(part) * 7919u + i};
      for (std::size_t l = 0; l < layers.size(); ++l) {
        ImageU8 q = view->rgb[l];
        if (aug) augment(q, rng);
        if (auto st = geo::save_png(dir + "/query_" + layers[l] + ".png", q.view()); !st.ok()) return fail(st.error());
      }
      // T_query_ref = T_C1_W T_W_Cref: maps reference-camera points into the query camera.
      const geo::Pose rel = smp.truth.inverse() * smp.prior;
      char rel_txt[256];
      std::snprintf(rel_txt, sizeof rel_txt, "%.6f,%.6f,%.6f,%.9f,%.9f,%.9f,%.9f", rel.t_W_C.x(), rel.t_W_C.y(), rel.t_W_C.z(),
                    rel.q_W_C.w(), rel.q_W_C.x(), rel.q_W_C.y(), rel.q_W_C.z());
      char geom[160];
      std::snprintf(geom, sizeof geom, "%d,%d,%.9g,%.9g,%.9g,%.9g,%.3f", cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                    smp.altitude);
      const std::string where = split + "," + id + ",";
      const std::string prefix = split + "/" + id + "/";
      for (const auto& a : layers)
        for (const auto& b : layers)
          index += where + a + "," + b + "," + prefix + "ref_" + a + ".png," + prefix + "ref_depth.pfm," + prefix + "query_" + b +
                   ".png," + geom + "," + rel_txt + ",\"" + geo::format_pose(smp.prior) + "\",\"" + geo::format_pose(smp.truth) + "\"\n";
      ++done;
      const int w = 40, bar = done * w / total;
      std::fprintf(stderr, "\r[%.*s%*s] %d/%d", bar, "========================================", w - bar, "", done, total);
    }
  }
  std::fprintf(stderr, "\n");
  if (auto st = geo::write_file_atomic(staged->path("index.csv"), index.data(), index.size()); !st.ok()) return fail(st.error());
  if (auto st = staged->commit(); !st.ok()) return fail(st.error());
  std::printf("%s/index.csv: %d training and %d validation poses, %zu layers, %zu pairs; validation %s of %s = %.1f\n",
              out.c_str(), n_train, n_val, layers.size(), static_cast<std::size_t>(total) * layers.size() * layers.size(),
              by_x ? "east" : "north", by_x ? "x" : "y", split_at);
  return 0;
}

}  // namespace terralign::cli
