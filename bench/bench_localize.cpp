// The whole localisation of one 752x480 camera image, render + align, as `terralign align`
// and `track` run it: the classical tracker (20 iterations per level) and the learned one
// (20 iterations per level, without and with one re-rendered refinement pass: on its default
// three levels, and on the finest under the classical bound, its scope before session 58;
// that pass would also be the second look at a first answer that failed the agreement test
// alone, where the command line's default cli::kDefaultSecondLook (off) turns it on) for each
// weight file given, on the same pairs (NAIP 2016 map,
// 2017 camera images, the eval protocol's priors: 700-900 m, tilt 10 deg, seed 3), 2 threads,
// each pair by every method in turn. Prints medians per stage, frames per second, and the
// ratio to the classical tracker.
// Then the peak resident memory of `terralign align` on the sample map, classic and nn, each
// a child process of a helper forked at the bench's start (wait4 of that one child).
//   build/release/bench/bench_localize [N] [--live-layer YEAR] [--layers A,B,...] [weights.tlw ...]
// (default: 20 pairs, the 2017 camera images, the shipped weights). --live-layer 2016 renders
// the camera images from the map's own year, where the refinement passes run under the
// classical bound too (a converged answer's final residual at most 1.0: same-year maps; across
// a year they seldom do).
// --layers adds a row over those reference layers (Localizer: the next is aligned to only
// where the one before did not converge) for the classical tracker and each weight file, e.g.
// --live-layer 2020 --layers 2016,2012,2009; its "layers tried" is the mean alignments an
// image, and "fallback frames" the count, median total ms, median encoder ms and median
// pyramid ms (the solver's levels built or copied) of the images aligned to more than one layer.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <terralign/geo/image_io.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/nn/weights.hpp>
#include <terralign/raster/renderer.hpp>

#include "localizer.hpp"
#include "sampling.hpp"

using namespace terralign;
using Clock = std::chrono::steady_clock;

namespace {
double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

#if defined(TERRALIGN_CLI)
// Runs shell commands for the bench from a process forked at its start, while the bench is
// small, and gives each command's peak resident memory. Linux keeps a forked child's
// high-water mark from before its exec in ru_maxrss, so a command the bench started itself
// once it held the map and the networks (std::system) reported the bench's size: 252-302 MiB
// for a `terralign align` whose own peak is 70-90 MiB (session 63, against GNU time).
class Spawner {
 public:
  Spawner() {
    int down[2], up[2];
    if (pipe(down) != 0 || pipe(up) != 0) return;
    pid_ = fork();
    if (pid_ == 0) {  // the helper: a line in, "peak_kib exit_code" out, until the pipe closes
      close(down[1]);
      close(up[0]);
      FILE* in = fdopen(down[0], "r");
      char line[4096];
      while (in && std::fgets(line, sizeof line, in)) {
        line[std::strcspn(line, "\n")] = 0;
        const pid_t c = fork();
        if (c == 0) {
          execl("/bin/sh", "sh", "-c", line, static_cast<char*>(nullptr));
          _exit(127);
        }
        int status = 0;
        rusage ru{};
        if (c < 0 || wait4(c, &status, 0, &ru) != c) ru.ru_maxrss = -1;
        char reply[64];
        const int n = std::snprintf(reply, sizeof reply, "%ld %d\n", static_cast<long>(ru.ru_maxrss),
                                    WIFEXITED(status) ? WEXITSTATUS(status) : -1);
        if (write(up[1], reply, static_cast<std::size_t>(n)) != n) break;
      }
      _exit(0);
    }
    close(down[0]);
    close(up[1]);
    if (pid_ < 0) return;
    to_ = fdopen(down[1], "w");
    from_ = fdopen(up[0], "r");
  }
  ~Spawner() {
    if (to_) std::fclose(to_);  // the helper's fgets ends
    if (from_) std::fclose(from_);
    if (pid_ > 0) waitpid(pid_, nullptr, 0);
  }
  // The command's peak resident memory in KiB and its exit code; false where the helper could
  // not run it.
  bool run(const std::string& cmd, long& peak_kib, int& code) {
    if (!to_ || !from_ || std::fprintf(to_, "%s\n", cmd.c_str()) < 0 || std::fflush(to_) != 0) return false;
    return std::fscanf(from_, "%ld %d", &peak_kib, &code) == 2 && peak_kib >= 0;
  }

 private:
  pid_t pid_ = -1;
  FILE* to_ = nullptr;
  FILE* from_ = nullptr;
};
#endif
}  // namespace

int main(int argc, char** argv) {
#if defined(TERRALIGN_CLI)
  Spawner spawner;  // first, while the bench is small
#endif
  const int n = argc > 1 ? std::max(1, std::atoi(argv[1])) : 20;
  std::vector<std::string> files;
  std::string live_layer = "2017", layer_list;
  for (int i = 2; i < argc; ++i) {
    if (std::string(argv[i]) == "--live-layer" && i + 1 < argc) live_layer = argv[++i];
    else if (std::string(argv[i]) == "--layers" && i + 1 < argc) layer_list = argv[++i];
    else files.push_back(argv[i]);
  }
  if (files.empty()) files.push_back(TERRALIGN_DEFAULT_WEIGHTS);
  auto map = geo::load_map(TERRALIGN_SOURCE_DIR "/data/naip_west/map.json");
  auto cam = geo::load_camera(TERRALIGN_SOURCE_DIR "/data/cameras/uav_752x480.json");
  if (!map.ok() || !cam.ok()) {
    std::fprintf(stderr, "bench_localize: %s\n", (!map.ok() ? map.error() : cam.error()).message.c_str());
    return 1;
  }
  auto samples = cli::sample_poses(map.value(), cam.value(), map->common_extent(), n, 3, 700, 900, 10);
  if (!samples.ok()) return 1;
  // The camera images: 2017 (or --live-layer) at the true poses.
  auto qr = raster::Renderer::create(map.value(), cam.value());
  auto qo = qr.value()->make_output({live_layer});
  if (!qo.ok()) {
    std::fprintf(stderr, "bench_localize: --live-layer: %s\n", qo.error().message.c_str());
    return 1;
  }
  std::vector<ImageU8> live;
  for (const auto& s : samples.value()) {
    if (!qr.value()->render(s.truth, qo.value()).ok()) return 1;
    live.push_back(qo->rgb[0]);
  }
  // Every method set up first, then each pair localised by every method in turn: a slow spell
  // of this VM (minutes long) then slows all methods alike, and the ratios hold.
  struct Method {
    std::string name;
    std::unique_ptr<cli::Localizer> loc;
    std::vector<double> render, encoder, mest, setup, iterations, total;
    std::vector<double> steps;  // the solver's iterations, every pass and layer
    std::vector<double> fallback, fallback_encoder, fallback_pyramid;  // ms of the frames aligned to more than one layer
    int converged = 0, refined = 0, tried = 0;
  };
  std::vector<nn::WeightFile> weights;
  weights.reserve(files.size());
  for (const auto& f : files) {
    auto w = nn::read_weights(f);
    if (!w.ok()) {
      std::fprintf(stderr, "bench_localize: %s\n", w.error().message.c_str());
      return 1;
    }
    weights.push_back(std::move(w.value()));
  }
  std::vector<Method> methods;
  // Each tracker alone; the learned also with one refinement pass, on its own scope and on the
  // finest level under the classical bound; both over --layers.
  enum Variant { kAlone, kRefined, kRefinedFinest, kLayers };
  for (std::size_t m = 0; m <= files.size(); ++m)
    for (const Variant variant : {kAlone, kRefined, kRefinedFinest, kLayers}) {
      if (((variant == kRefined || variant == kRefinedFinest) && m == 0) || (variant == kLayers && layer_list.empty()))
        continue;
      const int refine = variant == kRefined || variant == kRefinedFinest;
      const std::size_t slash = m == 0 ? 0 : files[m - 1].find_last_of('/');
      const std::string tracker =
          m == 0 ? "classic:20" : "nn:20 " + files[m - 1].substr(slash == std::string::npos ? 0 : slash + 1);
      const std::string name = variant == kAlone     ? tracker
                               : variant == kRefined ? tracker + " --refine 1"
                               : variant == kRefinedFinest ? tracker + " --refine 1 --refine-levels 1 --refine-max-residual 1"
                                                           : tracker + " --layer " + layer_list;
      iclk::TrackerOptions opt;
      opt.iterations = 20;
      std::vector<std::string> layers{"2016"};
      if (variant == kLayers) {
        layers.clear();
        std::stringstream list(layer_list);
        for (std::string layer; std::getline(list, layer, ',');) layers.push_back(layer);
      }
      auto loc = cli::Localizer::create(map.value(), cam.value(), layers, opt, 2, m == 0 ? nullptr : &weights[m - 1]);
      if (!loc.ok()) {
        std::fprintf(stderr, "bench_localize: %s: %s\n", name.c_str(), loc.error().message.c_str());
        return 1;
      }
      loc.value()->set_refinement(refine);
      // The command line's default (it needs a pass).
      loc.value()->set_second_look(cli::kDefaultSecondLook, cli::kDefaultSecondLookMaxDisagreement);
      if (variant == kRefinedFinest) loc.value()->set_refinement_scope(cli::kRefineLevels, cli::kRefineMaxResidual);
      Method M;
      M.name = name;
      M.loc = std::move(loc.value());
      methods.push_back(std::move(M));
    }
  for (int rep = 0; rep < 2; ++rep)  // the first pass warms caches; the second is measured
    for (std::size_t i = 0; i < live.size(); ++i)
      for (Method& M : methods) {
        const auto t0 = Clock::now();
        auto out = M.loc->localize(live[i].view(), samples.value()[i].prior);
        const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
        if (!out.ok() || rep == 0) continue;
        M.render.push_back(out->ms_render);
        M.encoder.push_back(out->ms_encoder);
        M.mest.push_back(out->ms_mestimator);
        M.setup.push_back(out->ms_pyramid + out->ms_jacobian - out->ms_mestimator);
        M.iterations.push_back(out->ms_iterations);
        M.total.push_back(ms);
        M.steps.push_back(out->iterations);
        M.converged += out->converged;
        M.refined += out->refinements > 0;
        M.tried += out->layers_tried;
        if (out->layers_tried > 1) {
          M.fallback.push_back(ms);
          M.fallback_encoder.push_back(out->ms_encoder);
          M.fallback_pyramid.push_back(out->ms_pyramid);
        }
      }
  std::printf("752x480 camera, NAIP 2016 map, %s images, %d pairs, 2 threads, medians in ms\n\n", live_layer.c_str(), n);
  // An onboard budget is set by the slowest frame: its time (this VM's spells included) and
  // the solver's iterations, the work that varies from frame to frame (the slowest frame's in
  // brackets; median / most).
  std::printf("| method | render | encoders | M-estimator | solver set-up | solver iterations | total | slowest (its iterations) | iterations | frames/s | x classic | converged | refined | layers tried | fallback frames: median total (encoders, pyramids) |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  const double classic_total = median(methods[0].total);
  for (const Method& M : methods) {
    const double total = median(M.total);
    char fallback[64] = "-";
    if (!M.fallback.empty())
      std::snprintf(fallback, sizeof fallback, "%zu: %.1f (%.1f, %.1f)", M.fallback.size(), median(M.fallback),
                    median(M.fallback_encoder), median(M.fallback_pyramid));
    const std::size_t slowest =
        static_cast<std::size_t>(std::max_element(M.total.begin(), M.total.end()) - M.total.begin());
    const double most_steps = M.steps.empty() ? 0 : *std::max_element(M.steps.begin(), M.steps.end());
    std::printf("| %s | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f | %.1f (%.0f) | %.0f / %.0f | %.0f | %.2f | %d/%d | %d/%d | %.2f | %s |\n", M.name.c_str(),
                median(M.render), median(M.encoder), median(M.mest), median(M.setup), median(M.iterations), total,
                M.total.empty() ? 0.0 : M.total[slowest], M.total.empty() ? 0.0 : M.steps[slowest], median(M.steps), most_steps, 1000.0 / total, total / classic_total, M.converged, n, M.refined, n,
                static_cast<double>(M.tried) / static_cast<double>(std::max<std::size_t>(M.total.size(), 1)), fallback);
  }
#if defined(TERRALIGN_CLI)
  // Peak RSS of the command-line program on one localisation (the first pair), each method in
  // its own child of the spawner.
  char pose[256];
  const auto& pr = samples.value()[0].prior;
  std::snprintf(pose, sizeof pose, "%.6f %.6f %.6f %.9f %.9f %.9f %.9f", pr.t_W_C.x(), pr.t_W_C.y(), pr.t_W_C.z(), pr.q_W_C.w(),
                pr.q_W_C.x(), pr.q_W_C.y(), pr.q_W_C.z());
  const std::string img = "/tmp/bench_localize_live.png";
  if (!geo::save_png(img, live[0].view()).ok()) return 1;
  std::printf("\npeak resident memory of terralign align (752x480, sample map):\n");
  for (const char* method : {"classic", "nn"}) {
    const std::string cmd = std::string(TERRALIGN_CLI) + " align --map " TERRALIGN_SOURCE_DIR "/data/naip_west/map.json --camera " +
                            TERRALIGN_SOURCE_DIR "/data/cameras/uav_752x480.json --layer 2016 --image " + img + " --prior \"" + pose +
                            "\" --method " + method + " > /dev/null 2>&1";
    long peak_kib = 0;
    int code = 0;  // terralign align: 3 = ran, did not converge
    if (!spawner.run(cmd, peak_kib, code)) {
      std::fprintf(stderr, "bench_localize: could not run %s\n", cmd.c_str());
      return 1;
    }
    std::printf("  %-8s %.1f MiB (exit %d%s)\n", method, static_cast<double>(peak_kib) / 1024.0, code,
                code == 3 ? ": ran, not converged" : "");
  }
#endif
  return 0;
}
