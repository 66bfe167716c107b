// terralign flight: a synthetic flight over a map, rendered from one layer, for tracking.
#include <cmath>
#include <cstdio>
#include <fstream>

#include <terralign/geo/file.hpp>
#include <terralign/geo/image_io.hpp>
#include <terralign/geo/number_text.hpp>
#include <terralign/geo/numeric.hpp>

#include "args.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "localizer.hpp"
#include "output_folder.hpp"
#include "sampling.hpp"

namespace terralign::cli {
namespace {

constexpr double kPi = 3.14159265358979323846;
// The most frames a flight writes (--duration x --rate): 752 x 480 PNG frames, about a terabyte.
constexpr int kMaxFrames = 1000000;

struct Waypoint {
  double x, y;
};

Result<std::vector<Waypoint>> path_points(const std::string& path, const geo::Extent& e, double margin) {
  std::vector<Waypoint> pts;
  const double x0 = e.min_x + margin, x1 = e.max_x - margin, y0 = e.min_y + margin, y1 = e.max_y - margin;
  const std::string half_footprint = "half the footprint, " + geo::format_double(std::round(margin)) + " m";
  if (!(x1 > x0 && y1 > y0))
    return Error{"the map is too small for a flight at this altitude (no room inside a margin of " + half_footprint + ")"};
  if (path == "lawnmower") {
    const int legs = 3;
    for (int k = 0; k <= legs; ++k) {
      const double y = y1 - (y1 - y0) * k / legs;
      if (k % 2 == 0) {
        pts.push_back({x0, y});
        pts.push_back({x1, y});
      } else {
        pts.push_back({x1, y});
        pts.push_back({x0, y});
      }
    }
  } else if (path == "circle") {
    const double cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1), r = 0.5 * std::min(x1 - x0, y1 - y0);
    for (int k = 0; k <= 72; ++k) {
      double s, c;
      sin_cos(2 * kPi * k / 72, s, c);
      pts.push_back({cx + r * c, cy + r * s});
    }
  } else {
    std::ifstream in(path);
    if (!in) return Error{path + ": cannot open the path file (or say lawnmower or circle)"};
    std::string line;
    int n = 0;
    while (std::getline(in, line)) {
      ++n;
      if (line.empty() || line[0] == '#') continue;
      const auto xy = finite_numbers(line, ' ', 2);
      if (!xy)
        return Error{path + ":" + std::to_string(n) + ": expected 'x y' map coordinates, got '" + line + "'"};
      // Inside the box the camera's view stays on the map from, checked before any frame is
      // drawn: a path that left it failed at its first frame off the map, with the frames
      // before it written over whatever the folder held. The box is convex, so every leg
      // between two waypoints inside it stays inside; its edges are printed rounded inwards.
      const double x = (*xy)[0], y = (*xy)[1];
      if (!(x >= x0 && x <= x1 && y >= y0 && y <= y1))
        return Error{path + ":" + std::to_string(n) + ": waypoint (" + geo::format_double(x) + ", " + geo::format_double(y) +
                     ") is outside x " + geo::format_double(std::ceil(x0)) + " .. " + geo::format_double(std::floor(x1)) +
                     ", y " + geo::format_double(std::ceil(y0)) + " .. " + geo::format_double(std::floor(y1)) +
                     ", where a flight at this altitude sees only the map (its extent less " + half_footprint + ")"};
      pts.push_back(Waypoint{x, y});
    }
    if (pts.size() < 2) return Error{path + ": a path needs at least 2 waypoints"};
  }
  return pts;
}

}  // namespace

int run_flight(const std::vector<std::string>& argv) {
  auto args = Args::parse(argv, {"map", "camera", "layer", "path", "speed", "rate", "out", "altitude", "duration", "noise",
                                 "blur", "exposure", "seed", "tilt", "imu-tilt", "altimeter"}, {});
  if (!args.ok()) return usage_error("flight", args.error());
  for (const char* k : {"map", "camera", "layer", "path", "speed", "rate", "out"})
    if (!args->has(k)) return usage_error("flight", Error{std::string("missing required option --") + k});
  auto speed = args->get_double_in("speed", 20, {0, 1000, true}, "m/s");
  // At most 1000 Hz: list.txt's and truth.txt's times, in microseconds, stay apart.
  auto rate = args->get_double_in("rate", 2, {0, 1000, true}, "Hz");
  auto altitude = args->get_double_in("altitude", 800, {0, INFINITY, true}, "m");
  auto duration = args->get_double_in("duration", 60, {0, INFINITY, true}, "s");
  auto tilt = args->get_double_in("tilt", 0, {0, 60}, "degrees");
  auto imu_tilt = args->get_double_in("imu-tilt", 0, {0, 10}, "degrees");
  auto altimeter = args->get_double_in("altimeter", 0, {0, 1000}, "m");
  auto degradation = parse_degradation(args.value());
  auto seed = args->get_int("seed", 1, 0, 1 << 30);
  for (auto* r : {&speed, &rate, &altitude, &duration, &tilt, &imu_tilt, &altimeter})
    if (!r->ok()) return usage_error("flight", r->error());
  if (!degradation.ok()) return usage_error("flight", degradation.error());
  if (!seed.ok()) return usage_error("flight", seed.error());
  const double frame_count = std::floor(duration.value() * rate.value());
  if (!(frame_count >= 1 && frame_count <= kMaxFrames))
    return usage_error("flight", Error{"--duration " + geo::format_double(duration.value()) + " s at --rate " +
                                       geo::format_double(rate.value()) + " Hz is " +
                                       geo::format_double(frame_count) + " frames; a flight has 1 to " +
                                       std::to_string(kMaxFrames)});
  auto map = geo::load_map(args->get("map"));
  if (!map.ok()) return fail(map.error());
  auto cam_in = geo::load_camera(args->get("camera"));
  if (!cam_in.ok()) return fail(cam_in.error());
  const geo::CameraModel cam = cam_in.value();
  raster::RenderOptions ro;
  auto renderer = raster::Renderer::create(map.value(), cam, ro);
  if (!renderer.ok()) return fail(renderer.error());
  auto frame = renderer.value()->make_output({args->get("layer")});
  if (!frame.ok()) return fail(frame.error());
  double tilt_sin, tilt_cos;
  sin_cos(tilt.value() * kPi / 180, tilt_sin, tilt_cos);
  const double half_footprint = altitude.value() * hypot_exact(cam.width / cam.fx, cam.height / cam.fy) / 2 * 1.2 +
                                altitude.value() * tilt_sin / tilt_cos;
  auto pts = path_points(args->get("path"), map->common_extent(), half_footprint);
  if (!pts.ok()) return fail(pts.error());
  const std::string out = args->get("out");
  // The flight is written whole or not at all: an earlier flight in --out stays as it was until
  // this one is complete, and then no file of it is left (its attitude.txt, say).
  auto staged = OutputFolder::open(out, {"frames", "list.txt", "truth.txt", "attitude.txt", "altimeter.txt"});
  if (!staged.ok()) return fail(staged.error());
  if (auto st = ensure_dir(staged->path("frames")); !st.ok()) return fail(st.error());

  Rng rng{static_cast<std::uint64_t>(seed.value())};
  // The attitude reference's errors: a second stream, so the frames do not depend on it.
  Rng imu{static_cast<std::uint64_t>(seed.value()) ^ 0x1e5a7c3b9d2f4601ULL};
  // The altimeter's: a third.
  Rng baro{static_cast<std::uint64_t>(seed.value()) ^ 0x7b3d9e1f05a2c468ULL};
  std::string list, truth, attitude, altimeter_lines;
  const int frames = static_cast<int>(frame_count);
  std::size_t leg = 0;
  double along = 0;  // metres along the current leg
  for (int i = 0; i < frames; ++i) {
    // Advance along the path by speed / rate per frame.
    if (i > 0) along += speed.value() / rate.value();
    while (leg + 1 < pts->size()) {
      const Waypoint& a = (*pts)[leg];
      const Waypoint& b = (*pts)[leg + 1];
      const double len = hypot_exact(b.x - a.x, b.y - a.y);
      if (along <= len) break;
      along -= len;
      ++leg;
    }
    if (leg + 1 >= pts->size()) break;  // the path ended before the duration
    const Waypoint& a = (*pts)[leg];
    const Waypoint& b = (*pts)[leg + 1];
    const double len = std::max(hypot_exact(b.x - a.x, b.y - a.y), 1e-9);
    const double x = a.x + (b.x - a.x) * along / len, y = a.y + (b.y - a.y) * along / len;
    const double heading = atan2_portable(b.x - a.x, b.y - a.y) * 180 / kPi;  // clockwise from north
    const double ground = map->dem.height_at(x, y);
    const geo::Pose T = geo::pose_from_ypr({x, y, (std::isfinite(ground) ? ground : 0.0) + altitude.value()}, heading, 0, 0,
                                           geo::tilted_mount(tilt.value()));
    if (auto s = renderer.value()->render(T, frame.value()); !s.ok()) return fail(Error{"frame " + std::to_string(i) + ": " + s.error().message});
    ImageU8 img = frame->rgb[0];
    degrade(img, degradation.value(), rng);
    char name[64];
    std::snprintf(name, sizeof name, "frames/%06d.png", i);
    if (auto s = geo::save_png(staged->path(name), img.view()); !s.ok()) return fail(s.error());
    char line[256];
    const double t = i / rate.value();
    std::snprintf(line, sizeof line, "%.6f %s\n", t, name);
    list += line;
    std::snprintf(line, sizeof line, "%.6f ", t);
    truth += line + geo::format_pose(T) + "\n";
    if (imu_tilt.value() > 0) {
      const Eigen::Quaterniond q = attitude_reading(T.q_W_C, imu, imu_tilt.value());
      std::snprintf(line, sizeof line, "%.6f %.9f %.9f %.9f %.9f\n", t, q.w(), q.x(), q.y(), q.z());
      attitude += line;
    }
    if (altimeter.value() > 0) {
      std::snprintf(line, sizeof line, "%.6f %.4f\n", t, T.t_W_C.z() + baro.normal() * altimeter.value());
      altimeter_lines += line;
    }
    std::fprintf(stderr, "\rframe %d/%d", i + 1, frames);
  }
  std::fprintf(stderr, "\n");
  if (auto s = geo::write_file_atomic(staged->path("list.txt"), list.data(), list.size()); !s.ok()) return fail(s.error());
  if (auto s = geo::write_file_atomic(staged->path("truth.txt"), truth.data(), truth.size()); !s.ok()) return fail(s.error());
  if (imu_tilt.value() > 0)
    if (auto s = geo::write_file_atomic(staged->path("attitude.txt"), attitude.data(), attitude.size()); !s.ok())
      return fail(s.error());
  if (altimeter.value() > 0)
    if (auto s = geo::write_file_atomic(staged->path("altimeter.txt"), altimeter_lines.data(), altimeter_lines.size()); !s.ok())
      return fail(s.error());
  if (auto s = staged->commit(); !s.ok()) return fail(s.error());
  std::printf("%s/list.txt, %s/truth.txt%s%s\n", out.c_str(), out.c_str(), imu_tilt.value() > 0 ? ", attitude.txt" : "",
              altimeter.value() > 0 ? ", altimeter.txt" : "");
  return 0;
}

}  // namespace terralign::cli
