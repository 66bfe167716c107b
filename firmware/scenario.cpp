#include "scenario.hpp"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <vector>

#include <terralign/geo/float_environment.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>
#include <terralign/nn/weights.hpp>
#include <terralign/raster/renderer.hpp>

#include "localizer.hpp"

using namespace terralign;

namespace fw {
namespace {

const Platform* g_platform = nullptr;

void print(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
void print(const char* fmt, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, fmt);
  std::vsnprintf(buf, sizeof buf, fmt, ap);
  va_end(ap);
  g_platform->write(buf);
}

constexpr int kCrop = 320;  // ortho pixels, 5 m each (firmware/data/README.md)
// The renderer's per-frame triangle bound (its buffers are sized for it): a flat or gently
// rolling DEM at 188 x 120 needs a few hundred; 4096 leaves room for relief.
constexpr int kMaxTriangles = 4096;

geo::Layer make_layer(const char* name, const std::uint8_t* rgb, double x0, double y0) {
  geo::Layer L;
  L.name = name;
  L.rgba.resize(kCrop, kCrop, 4);
  for (int i = 0; i < kCrop * kCrop; ++i) {
    std::memcpy(L.rgba.data() + 4 * i, rgb + 3 * i, 3);
    L.rgba.data()[4 * i + 3] = 255;
  }
  L.transform = geo::GeoTransform::north_up(x0, y0, 5.0, 5.0);
  L.extent = L.transform.extent(kCrop, kCrop);
  L.valid_pixels = kCrop * kCrop;
  return L;
}

double angle_deg(const geo::Pose& a, const geo::Pose& b) {
  return geo::rotation_angle(a.q_W_C * b.q_W_C.conjugate()) * 180.0 / 3.14159265358979323846;
}

// Everything of an answer a caller reads (pose, covariance, flag, iterations, reason), as
// FNV-1a: two machines that print the same hash gave the same answer to the bit.
std::uint64_t answer_hash(const cli::LocalizeOutput& out) {
  std::uint64_t h = nn::fnv1a64(out.T_W_C.t_W_C.data(), sizeof(double) * 3);
  h = nn::fnv1a64(out.T_W_C.q_W_C.coeffs().data(), sizeof(double) * 4, h);
  h = nn::fnv1a64(out.covariance.data(), sizeof(double) * 36, h);
  const unsigned char converged = out.converged ? 1 : 0;
  h = nn::fnv1a64(&converged, 1, h);
  h = nn::fnv1a64(&out.iterations, sizeof out.iterations, h);
  return nn::fnv1a64(out.reason, std::strlen(out.reason), h);
}

struct Run {
  const char* name = "";
  std::size_t arena_after_setup = 0;
  std::vector<double> before[2], after[2];  // live 2016 (same year as the map), 2017
  int converged[2] = {0, 0}, errors = 0;
  long frame_allocations = 0;
};

}  // namespace

int run_scenario(const Blobs& blobs, const Platform& platform) {
  g_platform = &platform;
  const bool buffer = platform.memory().capacity > 0;
  const std::size_t startup_bytes = platform.memory().used;
  if (buffer)
    print("terralign firmware: Cortex-M7, 188 x 120, working-memory buffer %u bytes\n",
          static_cast<unsigned>(platform.memory().capacity));
  else
    print("terralign firmware's test on the host, 188 x 120 (no working-memory buffer)\n");

  geo::Map map;
  map.dem.constant = true;
  map.dem.constant_height = 570.0;
  map.dem.extent = geo::Extent{-INFINITY, -INFINITY, INFINITY, INFINITY};
  map.layers.push_back(make_layer("2016", blobs.naip_2016, 486650.6, 5208246.2));
  map.layers.push_back(make_layer("2017", blobs.naip_2017, 486652.0, 5208248.0));
  const std::size_t map_bytes = platform.memory().used - startup_bytes;

  // The paper's 752 x 480 camera at a quarter of its size: the same field of view, 4.9 m a
  // pixel from 800 m (the network was trained at half size, 2.5 m; at this size it runs at
  // full resolution on its four finest levels).
  geo::CameraModel cam;
  cam.width = 188;
  cam.height = 120;
  cam.fx = cam.fy = 651.2 / 4;
  cam.cx = (375.5 + 0.5) / 4 - 0.5;
  cam.cy = (239.5 + 0.5) / 4 - 0.5;

  auto weights = nn::parse_weights(blobs.weights, blobs.weights_bytes, blobs.weights_name);
  if (!weights.ok()) {
    print("firmware: %s\n", weights.error().message.c_str());
    return 2;
  }
  const std::size_t weights_bytes = platform.memory().used - startup_bytes - map_bytes;

  // The camera stand-in: a renderer of both years (same year: the solver's own accuracy;
  // across years: the map's change).
  raster::RenderOptions ro;
  ro.threads = 1;
  ro.max_triangles = kMaxTriangles;
  auto camera_renderer = raster::Renderer::create(map, cam, ro);
  if (!camera_renderer.ok()) {
    print("firmware: %s\n", camera_renderer.error().message.c_str());
    return 2;
  }
  auto live = camera_renderer.value()->make_output({"2016", "2017"});
  if (!live.ok()) return 2;
  const std::size_t harness_bytes = platform.memory().used - startup_bytes - map_bytes - weights_bytes;

  // Test poses: 800 m above the ground near the crop's centre, headings around the compass.
  struct Case {
    geo::Pose truth, prior;
  };
  std::vector<Case> cases;
  const double cx = 487450.6, cy = 5207446.2, z = 570.0 + 800.0;
  const double off[4][4] = {{4, -3, 2, 0.5}, {-5, 2, -2, -0.4}, {3, 4, 1, 0.6}, {-3, -4, 2, -0.5}};
  for (int i = 0; i < 4; ++i) {
    const double yaw = 90.0 * i + 20.0;
    const geo::Pose truth = geo::pose_from_ypr({cx + 60.0 * i - 90.0, cy + 40.0 * (i % 2), z}, yaw, 1.0, -0.5);
    const geo::Pose prior = geo::pose_from_ypr({truth.t_W_C.x() + off[i][0], truth.t_W_C.y() + off[i][1], z + off[i][2]},
                                               yaw + off[i][3], 0.0, 0.0);
    cases.push_back({truth, prior});
  }

  // The localizers are set up and run in a floating-point environment no answer is made in
  // (terralign/geo/float_environment.hpp): each answer must still be the default
  // environment's. The host twin's are (the test "float environment: ..." compares the two
  // there), so a machine whose answers are the host's holds it too.
  print("set-up and frames in a hostile floating-point environment: %s\n", HostileFloatEnvironment::description());

  Run runs[2];
  char learned_name[96];
  std::snprintf(learned_name, sizeof learned_name, "learned (%s, full size, 4 levels)", blobs.weights_name);
  runs[0].name = learned_name;
  runs[1].name = "classical (4 levels)";
  for (int m = 0; m < 2; ++m) {
    Run& run = runs[m];
    const std::size_t before_setup = platform.memory().used;
    iclk::TrackerOptions opt;
    opt.iterations = 20;
    opt.threads = 1;
    cli::LocalizerSizes sizes;
    sizes.input_scale = 1.0;
    sizes.levels = 4;
    sizes.max_triangles = kMaxTriangles;
    auto loc = [&] {
      const HostileFloatEnvironment hostile;
      return cli::Localizer::create(map, cam, "2016", opt, 1, m == 0 ? &weights.value() : nullptr, sizes);
    }();
    if (!loc.ok()) {
      print("firmware: %s: %s\n", run.name, loc.error().message.c_str());
      return 2;
    }
    loc.value()->set_refinement(cli::kDefaultRefinePasses);  // as the command line runs it
    loc.value()->set_second_look(cli::kDefaultSecondLook, cli::kDefaultSecondLookMaxDisagreement);
    run.arena_after_setup = platform.memory().used - before_setup;
    if (buffer)
      print("\n%s: set-up took %u bytes of working memory\n", run.name, static_cast<unsigned>(run.arena_after_setup));
    else
      print("\n%s\n", run.name);
    for (int year = 0; year < 2; ++year)
      for (const Case& c : cases) {
        if (!camera_renderer.value()->render(c.truth, live.value()).ok()) {
          ++run.errors;
          continue;
        }
        const long a0 = platform.memory().allocations;
        auto out = [&] {
          const HostileFloatEnvironment hostile;
          return loc.value()->localize(live.value().rgb[static_cast<std::size_t>(year)].view(), c.prior);
        }();
        run.frame_allocations += platform.memory().allocations - a0;
        if (!out.ok()) {
          print("  error: %s\n", out.error().message.c_str());
          ++run.errors;
          continue;
        }
        const double e0 = (c.prior.t_W_C - c.truth.t_W_C).norm(), e1 = (out->T_W_C.t_W_C - c.truth.t_W_C).norm();
        run.before[year].push_back(e0);
        run.after[year].push_back(e1);
        run.converged[year] += out->converged;
        print("  %s: position error %6.2f m -> %6.2f m, angle %5.2f -> %5.2f deg, %s, %d iterations, answer %016llx\n",
              year == 0 ? "2016" : "2017", e0, e1, angle_deg(c.prior, c.truth), angle_deg(out->T_W_C, c.truth),
              out->reason, out->iterations, static_cast<unsigned long long>(answer_hash(out.value())));
      }
    // The localiser is released here; its last-in memory goes back to the buffer.
  }

  const ArenaStats& a = platform.memory();
  if (buffer) {
    print("\nworking memory (one buffer, every heap byte): peak %u of %u bytes\n", static_cast<unsigned>(a.peak),
          static_cast<unsigned>(a.capacity));
    print("  C++ library start-up %u, map (two 320 x 320 RGBA layers) %u, weights %u, the test's camera renderer %u\n",
          static_cast<unsigned>(startup_bytes), static_cast<unsigned>(map_bytes), static_cast<unsigned>(weights_bytes),
          static_cast<unsigned>(harness_bytes));
  } else {
    print("\nheap allocations (operator new, counted):\n");
  }
  for (const Run& r : runs)
    if (buffer)
      print("  %s: set-up %u bytes, allocations per frame %ld\n", r.name, static_cast<unsigned>(r.arena_after_setup),
            r.frame_allocations);
    else
      print("  %s: allocations per frame %ld\n", r.name, r.frame_allocations);
  if (platform.stack_high_water)
    print("stack high-water %u bytes\n", static_cast<unsigned>(platform.stack_high_water()));

  auto median = [](std::vector<double> v) {
    if (v.empty()) return std::nan("");
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  bool ok = true;
  for (const Run& r : runs) {
    for (int year = 0; year < 2; ++year)
      print("%s, live %s on the 2016 map: median position error %.2f m -> %.2f m, %d of %u converged\n", r.name,
            year == 0 ? "2016" : "2017", median(r.before[year]), median(r.after[year]), r.converged[year],
            static_cast<unsigned>(r.after[year].size()));
    ok = ok && r.frame_allocations == 0 && r.errors == 0 && median(r.after[0]) < 0.5 * median(r.before[0]);
  }
  print(ok ? "firmware: PASS\n" : "firmware: FAIL\n");
  return ok ? 0 : 1;
}

}  // namespace fw
