// terralign align: one camera image against the map, from a prior pose.
#include <chrono>
#include <cstdio>
#include <optional>

#include <nlohmann/json.hpp>

#include <terralign/geo/file.hpp>
#include <terralign/geo/geotiff.hpp>
#include <terralign/geo/image_io.hpp>

#include "args.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "localizer.hpp"

namespace terralign::cli {

Result<ImageU8> load_rgb(const std::string& path) {
  TERRALIGN_TRY_ASSIGN(const auto bytes, geo::read_file(path));
  if (!geo::looks_like_tiff(bytes.data(), bytes.size())) return geo::decode_image(bytes.data(), bytes.size(), path, 3);
  TERRALIGN_TRY_ASSIGN(geo::GeoRaster r, geo::read_geotiff_memory(bytes.data(), bytes.size(), path));
  if (r.sample != geo::SampleType::U8 || r.bands == 2)
    return Error{path + ": camera image must be 8-bit grey or RGB, found " + std::to_string(r.bands) + " bands of " +
                 geo::to_string(r.sample)};
  ImageU8 img(r.width, r.height, 3);
  for (int y = 0; y < r.height; ++y)
    for (int x = 0; x < r.width; ++x)
      for (int c = 0; c < 3; ++c) img.at(x, y, c) = r.u8.at(x, y, r.bands >= 3 ? c : 0);
  return img;
}

Result<iclk::Robust> parse_robust(const std::string& s) {
  if (s == "none") return iclk::Robust::None;
  if (s == "huber") return iclk::Robust::Huber;
  if (s == "tukey") return iclk::Robust::Tukey;
  return Error{"--robust '" + s + "' must be none, huber or tukey"};
}

nlohmann::json pose_json(const geo::Pose& p) {
  return {p.t_W_C.x(), p.t_W_C.y(), p.t_W_C.z(), p.q_W_C.w(), p.q_W_C.x(), p.q_W_C.y(), p.q_W_C.z()};
}

int run_align(const std::vector<std::string>& argv) {
  auto args = Args::parse(argv, {"map", "camera", "image", "prior", "layer", "method", "iterations", "robust", "threads", "weights",
                                 "tilt-prior", "altitude-prior", "registration-floor", "registration-floor-per-residual", "refine", "refine-levels", "refine-max-residual", "refine-uniform", "second-look", "second-look-max-disagreement", "min-sharpness",
                                 "max-disagreement", "agree-px", "coarse-search", "min-step"}, {});
  if (!args.ok()) return usage_error("align", args.error());
  for (const char* k : {"map", "camera", "image", "prior", "layer"})
    if (!args->has(k)) return usage_error("align", Error{std::string("missing required option --") + k});
  const std::string method = args->get("method", "classic");
  if (method != "classic" && method != "nn") return usage_error("align", Error{"--method '" + method + "' must be classic or nn"});
  auto iters = args->get_int("iterations", 20, 1, 1000);
  if (!iters.ok()) return usage_error("align", iters.error());
  auto threads = args->get_int("threads", 2, 1, 64);
  if (!threads.ok()) return usage_error("align", threads.error());
  auto robust = parse_robust(args->get("robust", "none"));
  if (!robust.ok()) return usage_error("align", robust.error());
  auto prior = geo::parse_pose(args->get("prior"));
  if (!prior.ok()) return fail(prior.error());
  auto topt = parse_tracker_options(args.value());
  if (!topt.ok()) return usage_error("align", topt.error());
  auto refine = parse_refine(args.value());
  if (!refine.ok()) return usage_error("align", refine.error());

  const auto t0 = std::chrono::steady_clock::now();
  auto map = geo::load_map(args->get("map"));
  if (!map.ok()) return fail(map.error());
  auto cam = geo::load_camera(args->get("camera"));
  if (!cam.ok()) return fail(cam.error());
  auto image = load_rgb(args->get("image"));
  if (!image.ok()) return fail(image.error());
  if (image->width() != cam->width || image->height() != cam->height)
    return fail(Error{args->get("image") + ": image is " + std::to_string(image->width()) + " x " +
                      std::to_string(image->height()) + ", the camera " + args->get("camera") + " is " +
                      std::to_string(cam->width) + " x " + std::to_string(cam->height)});
  const std::vector<std::string> layers = split_commas(args->get("layer"));
  for (const std::string& name : layers)
    if (!map->find_layer(name))
      return fail(Error{"--layer: no layer named '" + name + "' in " + args->get("map") + " (layers: " + map->layer_names() + ")"});
  ImageU8 live = cam->model == geo::DistortionModel::None ? std::move(image.value()) : undistort(image->view(), cam.value());
  iclk::TrackerOptions opt = topt.value();
  opt.iterations = iters.value();
  opt.robust = robust.value();
  std::optional<nn::WeightFile> weights;
  if (method == "nn") {
    auto w = learned_weights(args.value());
    if (!w.ok()) return fail(w.error());
    weights = std::move(w.value());
  }
  auto loc = Localizer::create(map.value(), pinhole_of(cam.value()), layers, opt, threads.value(),
                               weights ? &*weights : nullptr);
  if (!loc.ok()) return fail(loc.error());
  refine->apply(*loc.value());
  const double ms_load = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  auto out = loc.value()->localize(live.view(), prior.value());
  if (!out.ok()) return fail(out.error());
  nlohmann::json j;
  j["pose"] = pose_json(out->T_W_C);
  nlohmann::json cov = nlohmann::json::array();
  for (int r = 0; r < 6; ++r) {
    nlohmann::json row = nlohmann::json::array();
    for (int c = 0; c < 6; ++c) row.push_back(out->covariance(r, c));
    cov.push_back(row);
  }
  j["covariance"] = cov;
  j["covariance_frame"] = "[dtheta_x, dtheta_y, dtheta_z (rad, world axes, left of R_W_C), dx, dy, dz (m, camera centre)]";
  j["converged"] = out->converged;
  j["reason"] = out->reason;
  j["layer"] = layers[static_cast<std::size_t>(out->layer)];  // the answer's (where none converged, the last tried)
  j["layers_tried"] = out->layers_tried;
  // Each layer tried, in order: where the answer is a later layer's, why the ones before it
  // were not taken.
  nlohmann::json attempts = nlohmann::json::array();
  for (int i = 0; i < out->layers_tried; ++i) {
    const LayerAttempt& a = loc.value()->attempts()[i];
    attempts.push_back({{"layer", layers[static_cast<std::size_t>(i)]},
                        {"converged", a.converged},
                        {"reason", a.reason},
                        {"iterations", a.iterations},
                        {"residual_final", a.residual_final},
                        {"disagreement_px", a.disagreement_px},
                        {"sharpness", a.sharpness}});
  }
  j["attempts"] = attempts;
  j["iterations"] = out->iterations;
  j["residual_final"] = out->residual_final;  // the last pass's (eval's JSON has it per pose too)
  // Re-rendered passes after the first (--refine), and of them the learned tracker's without
  // its M-estimator (an answer whose image already agreed with the map).
  j["refinements"] = out->refinements;
  j["uniform_refinements"] = out->uniform_refinements;
  // The converged tests' measures (0 where not measured; where the second start failed, null).
  j["disagreement_px"] = out->disagreement_px;
  // The learned tracker's second look (--second-look), where it ran: whether it confirmed the
  // answer, and its own agreement test's measure (null where its second start failed).
  if (!std::isnan(out->second_look_disagreement_px)) {
    j["second_look"] = out->second_look;
    j["second_look_disagreement_px"] = std::isfinite(out->second_look_disagreement_px)
                                           ? nlohmann::json(out->second_look_disagreement_px)
                                           : nlohmann::json(nullptr);
  }
  j["sharpness"] = out->sharpness;
  j["residual_correlation"] = out->residual_correlation;
  j["covariance_inflation"] = out->covariance_inflation;
  j["method"] = method;
  j["ms"] = {{"load", ms_load}, {"render", out->ms_render}, {"encoder", out->ms_encoder}, {"pyramid", out->ms_pyramid},
             {"jacobian", out->ms_jacobian}, {"mestimator", out->ms_mestimator}, {"iterations", out->ms_iterations},
             {"align", out->ms_encoder + out->ms_pyramid + out->ms_jacobian + out->ms_iterations}};
  if (!map->crs.is_local()) {
    auto g = map->crs.to_geodetic(out->T_W_C.t_W_C.x(), out->T_W_C.t_W_C.y(), out->T_W_C.t_W_C.z());
    if (g.ok()) j["lat_lon_height"] = {g->lat_deg, g->lon_deg, g->height};
  }
  std::printf("%s\n", j.dump(2).c_str());
  return out->converged ? 0 : 3;
}

}  // namespace terralign::cli
