// Renderer throughput: frames per second at several image sizes, nadir and 45 degrees
// oblique, over the sample NAIP map and a large synthetic map (4096^2 texture, 1025^2 DEM
// over 1 km^2; and, as a control, the same with its bumps turned, see large_map()), with 1
// and 2 threads. Each figure is the median of timed batches. Where
// Mesa's llvmpipe is installed (libosmesa6-dev), the same scenes at 752 x 480 are drawn by it
// too (LP_NUM_THREADS=2, colour and depth read back) in the same run, the two in turn nine
// times: speed ratio (median and range of the rounds) and PSNR.
// A third table renders the same views over a small and a 20000^2-texel, 4096^2-post map of
// one procedural world (not with --quick; alone with --map-size). With --kernels alone: each
// scene at 752 x 480 on one thread by the scalar kernels and by this machine's vector ones
// (AVX2 / AVX-512 on x86-64, NEON on aarch64), in turn seven times, after checking that both
// give the same bytes: the vector build's speed-up a frame and in each stage.
//   build/release/bench/bench_render [--quick | --map-size | --kernels]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>
#include <terralign/raster/renderer.hpp>

#if defined(TERRALIGN_BENCH_OSMESA)
#include "gl_peer.hpp"
#endif

using namespace terralign;

namespace {

// Rolling ground with 3 m bumps 24 posts apart. Their crests run along the posts' diagonal
// from (i + 1, j) to (i, j + 1) (the map the table was first measured on); with
// `crests_north_south` (a control) they run down the DEM's columns, where neither of a
// quad's diagonals follows them (TerrainChunk::anti).
geo::Map large_map(bool crests_north_south = false) {
  geo::Map m;
  m.path = "(synthetic 4096^2 texture, 1025^2 DEM, 1 km^2)";
  const int n = 1025;
  m.dem.constant = false;
  m.dem.transform = geo::GeoTransform::north_up(0, 1000, 1000.0 / n, 1000.0 / n);
  m.dem.extent = m.dem.transform.extent(n, n);
  m.dem.heights.resize(n, n, 1);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      m.dem.heights.at(i, j) = static_cast<float>(200 + 40 * std::sin(i * 0.013) * std::cos(j * 0.011) +
                                                  3 * std::sin(crests_north_south ? i * 0.263 : i * 0.2 + j * 0.17));
  m.dem.min_height = 157;
  m.dem.max_height = 243;
  geo::Layer L;
  L.name = "tex";
  const int t = 4096;
  L.transform = geo::GeoTransform::north_up(0, 1000, 1000.0 / t, 1000.0 / t);
  L.extent = L.transform.extent(t, t);
  L.rgba.resize(t, t, 4);
  for (int y = 0; y < t; ++y)
    for (int x = 0; x < t; ++x) {
      std::uint8_t* p = &L.rgba.at(x, y, 0);
      p[0] = static_cast<std::uint8_t>(x * 7 + y);
      p[1] = static_cast<std::uint8_t>((x ^ y) >> 3);
      p[2] = static_cast<std::uint8_t>(y * 3);
      p[3] = 255;
    }
  L.valid_pixels = static_cast<std::int64_t>(t) * t;
  m.layers.push_back(std::move(L));
  return m;
}

// A square map cut from one procedural world of 0.25 m texels and 1.25 m DEM posts: `tex`
// texels and `posts` posts a side, centred on world (0, 0), so a small map is an exact crop
// of a large one (the same ground, texels and heights where both have them). The texture
// has detail at every scale (an XOR pattern of texel indices over smooth colour fields); the
// ground rolls by 40 m with 2 m bumps, so the LOD keeps a fine mesh near the camera.
geo::Map world_crop(int tex, int posts) {
  geo::Map m;
  const double texel = 0.25, post = 1.25;
  m.path = "(procedural world, " + std::to_string(tex) + "^2 texture, " + std::to_string(posts) + "^2 DEM)";
  m.dem.constant = false;
  m.dem.transform = geo::GeoTransform::north_up(-0.5 * posts * post, 0.5 * posts * post, post, post);
  m.dem.extent = m.dem.transform.extent(posts, posts);
  m.dem.heights.resize(posts, posts, 1);
  double lo = INFINITY, hi = -INFINITY;
  for (int j = 0; j < posts; ++j)
    for (int i = 0; i < posts; ++i) {
      const double x = (i + 0.5 - 0.5 * posts) * post, y = (0.5 * posts - j - 0.5) * post;
      const double h = 300 + 40 * std::sin(x * 0.0021) * std::cos(y * 0.0017) + 2 * std::sin(x * 0.23 + y * 0.19);
      m.dem.heights.at(i, j) = static_cast<float>(h);
      lo = std::min(lo, h);
      hi = std::max(hi, h);
    }
  m.dem.min_height = lo;
  m.dem.max_height = hi;
  geo::Layer L;
  L.name = "tex";
  L.transform = geo::GeoTransform::north_up(-0.5 * tex * texel, 0.5 * tex * texel, texel, texel);
  L.extent = L.transform.extent(tex, tex);
  L.rgba.resize(tex, tex, 4);
  const int o = -tex / 2;  // world texel index of the crop's first texel
  for (int y = 0; y < tex; ++y)
    for (int x = 0; x < tex; ++x) {
      const int gx = x + o, gy = y + o;
      std::uint8_t* p = &L.rgba.at(x, y, 0);
      p[0] = static_cast<std::uint8_t>(((gx ^ gy) & 63) + 96 + 60 * std::sin(gx * 0.003));
      p[1] = static_cast<std::uint8_t>(((gx * 3 ^ gy) & 31) + 110 + 50 * std::cos(gy * 0.0021));
      p[2] = static_cast<std::uint8_t>(((gx + gy) & 15) + 100 + 40 * std::sin((gx + gy) * 0.0007));
      p[3] = 255;
    }
  L.valid_pixels = static_cast<std::int64_t>(tex) * tex;
  m.layers.push_back(std::move(L));
  return m;
}

// The paper's 752 x 480 camera (f = 651.2 px) scaled to w x h.
geo::CameraModel paper_camera(int w, int h) {
  geo::CameraModel cam;
  cam.width = w;
  cam.height = h;
  cam.fx = cam.fy = 651.2 * w / 752.0;
  cam.cx = (w - 1) / 2.0;
  cam.cy = (h - 1) / 2.0;
  return cam;
}

#if defined(TERRALIGN_BENCH_OSMESA)
// Alternations of terralign and llvmpipe per scene: nine, so that a slow period of a few
// seconds (one run of session 25 had a round at 8.8x between rounds at 21x) moves the
// median little.
constexpr int kPeerRounds = 9;
#endif

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Frames per second (median of five timed batches) and the median per-stage times of the
// frames (geometry + binning; visibility, resolve and, for a pinhole camera, shading; shading
// of a distorted camera) in `stage_ms`.
double fps(raster::Renderer& r, raster::RenderOutput& out, const geo::Pose& T, int frames, double stage_ms[3] = nullptr) {
  std::vector<double> per, geo_ms, raster_ms, shade_ms;
  raster::RenderStats st;
  if (stage_ms) std::fill(stage_ms, stage_ms + 3, NAN);  // a failed render prints NaN stages
  if (!r.render(T, out, &st).ok()) return -1;
  for (int b = 0; b < 5; ++b) {
    const auto t0 = std::chrono::steady_clock::now();
    for (int i = 0; i < frames; ++i) {
      (void)r.render(T, out, &st);
      geo_ms.push_back(st.ms_geometry);
      raster_ms.push_back(st.ms_raster);
      shade_ms.push_back(st.ms_shade);
    }
    per.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / frames);
  }
  if (stage_ms) {
    stage_ms[0] = median(geo_ms);
    stage_ms[1] = median(raster_ms);
    stage_ms[2] = median(shade_ms);
  }
  return 1.0 / median(per);
}

// --kernels: the scalar kernels against this machine's vector ones, each scene at 752 x 480 on
// one thread, the two renderers in turn seven times (this VM's speed drifts; each round's
// ratios compare two measurements taken back to back). Returns false where a render fails
// or the two renderers' bytes differ.
template <class Scene>
bool kernel_ratios(const Scene* scenes, int n_scenes) {
  constexpr int kRounds = 7;
  const geo::CameraModel cam = paper_camera(752, 480);
  std::printf("752x480, 1 thread: scalar kernels against the vector build (least .. most of %d rounds; ms: medians)\n\n"
              "| scene | view | vector build | scalar ms/frame | vector ms/frame | frame speed-up | geometry speed-up | raster + shade speed-up | triangles |\n"
              "|---|---|---|---|---|---|---|---|---|\n",
              kRounds);
  for (int si = 0; si < n_scenes; ++si)
    for (int view = 0; view < 2; ++view) {
      const Scene& s = scenes[si];
      const geo::Pose& T = view ? s.oblique : s.nadir;
      std::unique_ptr<raster::Renderer> r[2];
      raster::RenderOutput out[2];
      raster::RenderStats st[2];
      for (int b = 0; b < 2; ++b) {
        raster::RenderOptions opt;
        opt.threads = 1;
        if (b == 0) opt.simd = raster::RenderOptions::Simd::Scalar;
        auto made = raster::Renderer::create(*s.map, cam, opt);
        if (!made.ok()) return false;
        r[b] = std::move(made.value());
        auto o = r[b]->make_output({s.layer});
        if (!o.ok() || !r[b]->render(T, o.value(), &st[b]).ok()) return false;
        out[b] = std::move(o.value());
      }
      if (out[0].rgb[0].pixels() != out[1].rgb[0].pixels() ||
          std::memcmp(out[0].depth.data(), out[1].depth.data(), out[0].depth.size() * sizeof(float)) != 0) {
        std::fprintf(stderr, "%s: the scalar and %s renders differ\n", s.name, r[1]->simd_name());
        return false;
      }
      std::vector<double> ms[2], frame, geometry, raster;
      for (int round = 0; round < kRounds; ++round) {
        double stage[2][3], f[2];
        for (int b = 0; b < 2; ++b) {
          f[b] = fps(*r[b], out[b], T, 20, stage[b]);
          ms[b].push_back(1000.0 / f[b]);
        }
        frame.push_back(f[1] / f[0]);
        geometry.push_back(stage[0][0] / stage[1][0]);
        raster.push_back(stage[0][1] / stage[1][1]);
      }
      auto range = [](const std::vector<double>& v) {
        char buf[64];
        std::snprintf(buf, sizeof buf, "%.2fx (%.2f .. %.2f)", median(v), *std::min_element(v.begin(), v.end()),
                      *std::max_element(v.begin(), v.end()));
        return std::string(buf);
      };
      std::printf("| %s | %s | %s | %.3f | %.3f | %s | %s | %s | %d |\n", s.name, view ? "oblique 45" : "nadir", r[1]->simd_name(),
                  median(ms[0]), median(ms[1]), range(frame).c_str(), range(geometry).c_str(), range(raster).c_str(),
                  st[0].triangles);
      std::fflush(stdout);
    }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  const bool quick = argc > 1 && std::strcmp(argv[1], "--quick") == 0;
  const bool size_only = argc > 1 && std::strcmp(argv[1], "--map-size") == 0;
  const bool kernels_only = argc > 1 && std::strcmp(argv[1], "--kernels") == 0;
  auto sample = geo::load_map(TERRALIGN_SOURCE_DIR "/data/naip_west/map.json");
  if (!sample.ok()) {
    std::fprintf(stderr, "%s\n", sample.error().message.c_str());
    return 1;
  }
  const geo::Map big = large_map(), big_ns = large_map(true);
  struct Scene {
    const char* name;
    const geo::Map* map;
    geo::Pose nadir, oblique;
    const char* layer;
  };
  const Scene scenes[] = {
      {"sample NAIP (5 m/px, flat)", &sample.value(), geo::pose_from_ypr({487450, 5207437, 1370}, 0, 0, 0),
       geo::pose_from_ypr({487450, 5206400, 1370}, 0, 0, 0, geo::tilted_mount(45)), "2016"},
      {"synthetic 4096^2 tex, 1025^2 DEM", &big, geo::pose_from_ypr({500, 500, 600}, 0, 0, 0),
       geo::pose_from_ypr({500, 150, 500}, 0, 0, 0, geo::tilted_mount(45)), "tex"},
      {"synthetic, bumps' crests north-south", &big_ns, geo::pose_from_ypr({500, 500, 600}, 0, 0, 0),
       geo::pose_from_ypr({500, 150, 500}, 0, 0, 0, geo::tilted_mount(45)), "tex"},
  };
  if (kernels_only) return kernel_ratios(scenes, 3) ? 0 : 1;
  const int sizes[][2] = {{188, 120}, {376, 240}, {752, 480}, {1504, 960}};
  std::printf("| scene | view | size | threads | fps | ms/frame | geometry ms | raster (+ shade) ms | shade ms (distorted) | triangles |\n"
              "|---|---|---|---|---|---|---|---|---|---|\n");
  for (const auto& s : scenes)
    for (int view = 0; view < 2; ++view)
      for (const auto& sz : sizes) {
        if ((quick && sz[0] != 752) || size_only) continue;
        for (int threads : {1, 2}) {
          const geo::CameraModel cam = paper_camera(sz[0], sz[1]);
          raster::RenderOptions opt;
          opt.threads = threads;
          auto r = raster::Renderer::create(*s.map, cam, opt);
          if (!r.ok()) return 1;
          auto out = r.value()->make_output({s.layer});
          if (!out.ok()) return 1;
          const geo::Pose& T = view ? s.oblique : s.nadir;
          raster::RenderStats st;
          (void)r.value()->render(T, out.value(), &st);
          double stage[3];
          const double f = fps(*r.value(), out.value(), T, sz[0] >= 1504 ? 10 : 40, stage);
          std::printf("| %s | %s | %dx%d | %d | %.0f | %.3f | %.3f | %.3f | %.3f | %d |\n", s.name, view ? "oblique 45" : "nadir",
                      sz[0], sz[1], threads, f, 1000.0 / f, stage[0], stage[1], stage[2], st.triangles);
          std::fflush(stdout);
        }
      }
  // Map size: the same views over a 2000^2-texel, 400^2-post crop (500 m) and a 20000^2-texel,
  // 4096^2-post map (5 km, 1.6 GB of texture) of the same world; the footprints lie inside
  // the crop, so both draw the same ground. The issue asks for the same rate.
  if (!quick) {
    std::printf("\nMap size: 752x480, 2 threads, views about 260 m above the ground over the same ground\n\n"
                "| view | 2000^2 texture, 400^2 DEM fps | 20000^2 texture, 4096^2 DEM fps | large / small | triangles small / large | valid pixels small / large | renderer set-up s small / large |\n"
                "|---|---|---|---|---|---|---|\n");
    const geo::CameraModel cam = paper_camera(752, 480);
    const geo::Pose views[] = {geo::pose_from_ypr({0, 0, 560}, 0, 0, 0),
                               geo::pose_from_ypr({0, -100, 560}, 0, 0, 0, geo::tilted_mount(20))};
    double f[2][2] = {}, setup[2] = {};
    int tris[2][2] = {};
    long valid[2][2] = {};
    // Both renderers at once, timed in alternation (small, large, small, ...) so that a change
    // in this VM's speed during the run falls on both alike.
    const geo::Map maps[2] = {world_crop(2000, 400), world_crop(20000, 4096)};
    std::unique_ptr<raster::Renderer> r[2];
    raster::RenderOutput out[2];
    for (int size = 0; size < 2; ++size) {
      raster::RenderOptions opt;
      opt.threads = 2;
      const auto t0 = std::chrono::steady_clock::now();
      auto made = raster::Renderer::create(maps[size], cam, opt);
      setup[size] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (!made.ok()) return 1;
      r[size] = std::move(made.value());
      auto o = r[size]->make_output({"tex"});
      if (!o.ok()) return 1;
      out[size] = std::move(o.value());
    }
    for (int v = 0; v < 2; ++v) {
      std::vector<double> per[2];
      for (int size = 0; size < 2; ++size) {
        raster::RenderStats st;
        if (!r[size]->render(views[v], out[size], &st).ok()) return 1;
        tris[v][size] = st.triangles;
        for (std::uint8_t b : out[size].valid[0].pixels()) valid[v][size] += b != 0;
      }
      for (int batch = 0; batch < 7; ++batch)
        for (int size = 0; size < 2; ++size) {
          const auto t0 = std::chrono::steady_clock::now();
          for (int i = 0; i < 40; ++i) (void)r[size]->render(views[v], out[size]);
          per[size].push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / 40);
        }
      for (int size = 0; size < 2; ++size) f[v][size] = 1.0 / median(per[size]);
    }
    for (int v = 0; v < 2; ++v)
      std::printf("| %s | %.0f | %.0f | %.2f | %d / %d | %ld / %ld | %.1f / %.1f |\n", v ? "tilted 20 deg" : "nadir", f[v][0],
                  f[v][1], f[v][1] / f[v][0], tris[v][0], tris[v][1], valid[v][0], valid[v][1], setup[0], setup[1]);
    std::fflush(stdout);
  }
  if (size_only) return 0;
#if defined(TERRALIGN_BENCH_OSMESA)
  // The peer: Mesa llvmpipe (OpenGL on the CPU), same map, camera and pose, 2 threads each.
  std::printf("\n752x480, 2 threads each: terralign against Mesa llvmpipe (OSMesa, LP_NUM_THREADS=2, colour and depth read back)\n\n");
  std::printf("| scene | view | terralign fps | llvmpipe fps | terralign / llvmpipe (least .. most of %d rounds) | PSNR dB (pixels both cover) | llvmpipe triangles |\n|---|---|---|---|---|---|---|\n", kPeerRounds);
  for (const auto& s : scenes)
    for (int view = 0; view < 2; ++view) {
      const geo::CameraModel cam = paper_camera(752, 480);
      raster::RenderOptions opt;
      opt.threads = 2;
      auto r = raster::Renderer::create(*s.map, cam, opt);
      if (!r.ok()) return 1;
      auto out = r.value()->make_output({s.layer});
      if (!out.ok()) return 1;
      const geo::Pose& T = view ? s.oblique : s.nadir;
      // The two renderers in turn, kPeerRounds times: this VM's speed drifts by tens of per
      // cent within a minute, and each round's ratio compares two measurements taken back
      // to back. The medians of each renderer's rates and of the rounds' ratios are shown.
      std::vector<double> ours, theirs, ratios;
      bench::GlFrame g;
      for (int round = 0; round < kPeerRounds && g.error.empty(); ++round) {
        ours.push_back(fps(*r.value(), out.value(), T, 40));
        g = bench::gl_render(*s.map, s.layer, cam, T, 2, s.map == &sample.value() ? 10 : 3);
        theirs.push_back(g.fps);
        ratios.push_back(ours.back() / g.fps);
      }
      const double f = median(ours);
      if (!g.error.empty()) {
        std::printf("| %s | %s | %.0f | llvmpipe: %s | | | |\n", s.name, view ? "oblique 45" : "nadir", f, g.error.c_str());
        continue;
      }
      double se = 0;
      long n = 0;
      const auto& rgb = out.value().rgb[0];
      const auto& valid = out.value().valid[0];
      for (int y = 0; y < cam.height; ++y)
        for (int x = 0; x < cam.width; ++x) {
          const std::size_t o = static_cast<std::size_t>(y) * static_cast<std::size_t>(cam.width) + static_cast<std::size_t>(x);
          if (!valid.at(x, y) || !g.hit[o]) continue;
          for (int c = 0; c < 3; ++c) {
            const double d = static_cast<double>(rgb.at(x, y, c)) - g.rgb[3 * o + static_cast<std::size_t>(c)];
            se += d * d;
          }
          ++n;
        }
      const double psnr = n ? 10 * std::log10(255.0 * 255.0 / (se / (3.0 * static_cast<double>(n)))) : 0.0;
      std::printf("| %s | %s | %.0f | %.1f | %.1fx (%.1f .. %.1f) | %.1f (%.0f %% of pixels) | %ld |\n", s.name,
                  view ? "oblique 45" : "nadir", f, median(theirs), median(ratios), *std::min_element(ratios.begin(), ratios.end()),
                  *std::max_element(ratios.begin(), ratios.end()), psnr, 100.0 * static_cast<double>(n) / (cam.width * cam.height),
                  g.triangles);
      std::fflush(stdout);
    }
#else
  std::printf("\n(no Mesa llvmpipe peer: install libosmesa6-dev and reconfigure)\n");
#endif
  return 0;
}
