// terralign on a microcontroller-class core: the learned tracker (and the classical one) at
// 188 x 120 on a Cortex-M7 without an OS, threads, exceptions or RTTI, every allocation
// served from one caller-provided buffer whose high-water mark is the stated working memory.
//
// The map (two NAIP years, 320 x 320 crops at 5 m, a constant DEM) and the weights (CMake's
// TERRALIGN_FW_WEIGHTS, s16) are linked into flash (blobs.S). For each test pose the "camera"
// image is a render of the 2016 or the 2017 layer at the true pose (there is no camera under
// QEMU); the localiser renders the 2016 layer at a prior a few metres and half a degree off (a
// tracking prior) and aligns. Printed per frame: the position and angle error before and
// after, converged; then the memory. Exit status 0 only if no frame allocated, none failed
// with an error, and on the same-year frames both trackers at least halved the median position
// error (QEMU's instruction counts are not cycle times: no speed is claimed here).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>
#include <terralign/nn/weights.hpp>
#include <terralign/raster/renderer.hpp>

#include "arena.hpp"
#include "localizer.hpp"
#include "semihosting.hpp"

using namespace terralign;

extern "C" const std::uint8_t fw_weights[], fw_weights_end[];
extern "C" const std::uint8_t fw_naip_2016[], fw_naip_2017[];

namespace fw {
std::size_t stack_high_water();
}

namespace {

// The caller-provided buffer: every heap byte of the program comes from here (arena.cpp).
constexpr std::size_t kArenaBytes = TERRALIGN_FW_ARENA_BYTES;
alignas(16) __attribute__((section(".arena"))) unsigned char g_arena[kArenaBytes];

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
  return a.q_W_C.angularDistance(b.q_W_C) * 180.0 / 3.14159265358979323846;
}

struct Run {
  const char* name = "";
  std::size_t arena_after_setup = 0;
  std::vector<double> before[2], after[2];  // live 2016 (same year as the map), 2017
  int converged[2] = {0, 0}, errors = 0;
  long frame_allocations = 0;
};

}  // namespace

// Called by the reset handler before the static constructors (the C++ library's allocate).
extern "C" void firmware_init() { fw::arena_init(g_arena, kArenaBytes); }

extern "C" int firmware_main() {
  const std::size_t startup_bytes = fw::arena_stats().used;
  fw::print("terralign firmware: Cortex-M7, 188 x 120, working-memory buffer %u bytes\n",
            static_cast<unsigned>(kArenaBytes));

  geo::Map map;
  map.dem.constant = true;
  map.dem.constant_height = 570.0;
  map.dem.extent = geo::Extent{-INFINITY, -INFINITY, INFINITY, INFINITY};
  map.layers.push_back(make_layer("2016", fw_naip_2016, 486650.6, 5208246.2));
  map.layers.push_back(make_layer("2017", fw_naip_2017, 486652.0, 5208248.0));
  const std::size_t map_bytes = fw::arena_stats().used - startup_bytes;

  // The paper's 752 x 480 camera at a quarter of its size: the same field of view, 4.9 m a
  // pixel from 800 m (the network was trained at half size, 2.5 m; at this size it runs at
  // full resolution on its four finest levels).
  geo::CameraModel cam;
  cam.width = 188;
  cam.height = 120;
  cam.fx = cam.fy = 651.2 / 4;
  cam.cx = (375.5 + 0.5) / 4 - 0.5;
  cam.cy = (239.5 + 0.5) / 4 - 0.5;

  auto weights = nn::parse_weights(fw_weights, static_cast<std::size_t>(fw_weights_end - fw_weights), TERRALIGN_FW_WEIGHTS_NAME);
  if (!weights.ok()) {
    fw::print("firmware: %s\n", weights.error().message.c_str());
    return 2;
  }
  const std::size_t weights_bytes = fw::arena_stats().used - startup_bytes - map_bytes;

  // The camera stand-in: a renderer of both years (same year: the solver's own accuracy;
  // across years: the map's change).
  raster::RenderOptions ro;
  ro.threads = 1;
  ro.max_triangles = kMaxTriangles;
  auto camera_renderer = raster::Renderer::create(map, cam, ro);
  if (!camera_renderer.ok()) {
    fw::print("firmware: %s\n", camera_renderer.error().message.c_str());
    return 2;
  }
  auto live = camera_renderer.value()->make_output({"2016", "2017"});
  if (!live.ok()) return 2;
  const std::size_t harness_bytes = fw::arena_stats().used - startup_bytes - map_bytes - weights_bytes;

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

  Run runs[2];
  runs[0].name = "learned (" TERRALIGN_FW_WEIGHTS_NAME ", full size, 4 levels)";
  runs[1].name = "classical (4 levels)";
  for (int m = 0; m < 2; ++m) {
    Run& run = runs[m];
    const std::size_t before_setup = fw::arena_stats().used;
    iclk::TrackerOptions opt;
    opt.iterations = 20;
    opt.threads = 1;
    cli::LocalizerSizes sizes;
    sizes.input_scale = 1.0;
    sizes.levels = 4;
    sizes.max_triangles = kMaxTriangles;
    auto loc = cli::Localizer::create(map, cam, "2016", opt, 1, m == 0 ? &weights.value() : nullptr, sizes);
    if (!loc.ok()) {
      fw::print("firmware: %s: %s\n", run.name, loc.error().message.c_str());
      return 2;
    }
    loc.value()->set_refinement(cli::kDefaultRefinePasses);  // as the command line runs it
    loc.value()->set_second_look(cli::kDefaultSecondLook, cli::kDefaultSecondLookMaxDisagreement);
    run.arena_after_setup = fw::arena_stats().used - before_setup;
    fw::print("\n%s: set-up took %u bytes of working memory\n", run.name, static_cast<unsigned>(run.arena_after_setup));
    for (int year = 0; year < 2; ++year)
      for (const Case& c : cases) {
        if (!camera_renderer.value()->render(c.truth, live.value()).ok()) {
          ++run.errors;
          continue;
        }
        const long a0 = fw::arena_stats().allocations;
        auto out = loc.value()->localize(live.value().rgb[static_cast<std::size_t>(year)].view(), c.prior);
        run.frame_allocations += fw::arena_stats().allocations - a0;
        if (!out.ok()) {
          fw::print("  error: %s\n", out.error().message.c_str());
          ++run.errors;
          continue;
        }
        const double e0 = (c.prior.t_W_C - c.truth.t_W_C).norm(), e1 = (out->T_W_C.t_W_C - c.truth.t_W_C).norm();
        run.before[year].push_back(e0);
        run.after[year].push_back(e1);
        run.converged[year] += out->converged;
        fw::print("  %s: position error %6.2f m -> %6.2f m, angle %5.2f -> %5.2f deg, %s, %d iterations\n",
                  year == 0 ? "2016" : "2017", e0, e1, angle_deg(c.prior, c.truth), angle_deg(out->T_W_C, c.truth),
                  out->reason, out->iterations);
      }
    // The localiser is released here; its last-in memory goes back to the buffer.
  }

  const fw::ArenaStats& a = fw::arena_stats();
  fw::print("\nworking memory (one buffer, every heap byte): peak %u of %u bytes\n", static_cast<unsigned>(a.peak),
            static_cast<unsigned>(a.capacity));
  fw::print("  C++ library start-up %u, map (two 320 x 320 RGBA layers) %u, weights %u, the test's camera renderer %u\n",
            static_cast<unsigned>(startup_bytes), static_cast<unsigned>(map_bytes), static_cast<unsigned>(weights_bytes),
            static_cast<unsigned>(harness_bytes));
  for (const Run& r : runs)
    fw::print("  %s: set-up %u bytes, allocations per frame %ld\n", r.name, static_cast<unsigned>(r.arena_after_setup),
              r.frame_allocations);
  fw::print("stack high-water %u bytes\n", static_cast<unsigned>(fw::stack_high_water()));

  auto median = [](std::vector<double> v) {
    if (v.empty()) return std::nan("");
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  bool ok = true;
  for (const Run& r : runs) {
    for (int year = 0; year < 2; ++year)
      fw::print("%s, live %s on the 2016 map: median position error %.2f m -> %.2f m, %d of %u converged\n", r.name,
                year == 0 ? "2016" : "2017", median(r.before[year]), median(r.after[year]), r.converged[year],
                static_cast<unsigned>(r.after[year].size()));
    ok = ok && r.frame_allocations == 0 && r.errors == 0 && median(r.after[0]) < 0.5 * median(r.before[0]);
  }
  fw::print(ok ? "firmware: PASS\n" : "firmware: FAIL\n");
  return ok ? 0 : 1;
}
