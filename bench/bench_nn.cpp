// The inference engine on Lv et al.'s encoder: per layer and in total, milliseconds and
// achieved GFLOP/s as a fraction of this CPU's FMA peak (measured by an FMA loop in the same
// run), at 752x480 and 160x120, 1 and 2 threads; beside PyTorch on the CPU with two threads
// (training/bench_torch_encoder.py, where /usr/bin/python3 has torch), with the speed ratio.
// Then the shipped learned tracker's encoder and M-estimator per layer, the product's
// convolutions (Winograd's F(4x4)) against the direct kernel and F(2x2) in the same run, the
// encoder's two images of a pair at once (one a thread) against one after the other, F(4x4)
// against F(2x2) on single layers of s16w64's shapes (and ELU's share of each), and the
// M-estimator's one-output-channel last layer with the one-channel kernel against the block
// kernel.
//   build/release/bench/bench_nn [--tracker [WEIGHTS]]
// (--tracker: only the learned tracker's part; WEIGHTS: another weight file's networks in place
// of the shipped one's, e.g. a smaller network's before it is trained, whose time is its size's)
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <terralign/nn/kernels.hpp>
#include <terralign/nn/network.hpp>

#if defined(TERRALIGN_NN_AVX2)
#include <immintrin.h>
__attribute__((target("avx2,fma"))) static double fma_loop(long iters) {
  __m256 a[10];
  for (int i = 0; i < 10; ++i) a[i] = _mm256_set1_ps(static_cast<float>(i) * 1e-3f);
  const __m256 m = _mm256_set1_ps(0.999999f), c = _mm256_set1_ps(1e-7f);
  for (long k = 0; k < iters; ++k)
    for (int i = 0; i < 10; ++i) a[i] = _mm256_fmadd_ps(a[i], m, c);
  float s = 0, out[8];
  for (int i = 0; i < 10; ++i) {
    _mm256_storeu_ps(out, a[i]);
    s += out[0];
  }
  return s;
}
__attribute__((target("avx512f"))) static double fma_loop512(long iters) {
  __m512 a[12];
  for (int i = 0; i < 12; ++i) a[i] = _mm512_set1_ps(static_cast<float>(i) * 1e-3f);
  const __m512 m = _mm512_set1_ps(0.999999f), c = _mm512_set1_ps(1e-7f);
  for (long k = 0; k < iters; ++k)
    for (int i = 0; i < 12; ++i) a[i] = _mm512_fmadd_ps(a[i], m, c);
  float s = 0, out[16];
  for (int i = 0; i < 12; ++i) {
    _mm512_storeu_ps(out, a[i]);
    s += out[0];
  }
  return s;
}
#endif

using namespace terralign;

namespace {

// FMA peak of the widest vector unit the kernels use: AVX-512 (12 chains of 16 lanes) or
// AVX2 (10 chains of 8), best of 3 runs.
double peak_gflops(int threads, bool avx512) {
#if defined(TERRALIGN_NN_AVX2)
  if (!nn::nn_cpu_has_avx2()) return 0;
  const long iters = 40'000'000;
  double best = 0;
  for (int rep = 0; rep < 3; ++rep) {
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<std::thread> ts;
    std::vector<double> sink(static_cast<std::size_t>(threads));
    for (int t = 0; t < threads; ++t)
      ts.emplace_back([&, t] { sink[static_cast<std::size_t>(t)] = avx512 ? fma_loop512(iters) : fma_loop(iters); });
    for (auto& t : ts) t.join();
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const double flops = 2.0 * (avx512 ? 16 * 12 : 8 * 10) * static_cast<double>(iters) * threads;
    best = std::max(best, flops / s / 1e9);
  }
  return best;
#else
  (void)threads;
  (void)avx512;
  return 0;
#endif
}

double torch_ms(int w, int h, int threads) {
  char cmd[512];
  std::snprintf(cmd, sizeof cmd, "/usr/bin/python3 %s/training/bench_torch_encoder.py %d %d %d 2>/dev/null",
                TERRALIGN_SOURCE_DIR, w, h, threads);
  std::FILE* p = popen(cmd, "r");
  if (!p) return -1;
  char line[128] = {0};
  double ms = -1;
  if (std::fgets(line, sizeof line, p)) std::sscanf(line, "ms=%lf", &ms);
  pclose(p);
  return ms;
}

// The one-output-channel kernel (vectors along the input channels) against the block kernel
// (vectors along the output channels, 1 of 8 or 16 lanes useful) on the same layer in the
// same run: the learned tracker's last M-estimator layer, 16 -> 1 channels, at 376 x 240.
void one_channel_layer(nn::ConvRowsFn fn, int block, const char* simd) {
  const int w = 376, h = 240, cin = 16;
  nn::Tensor in, out;
  in.allocate(h, w, cin);
  out.allocate(h, w, 1);
  std::mt19937 rng(5);
  std::normal_distribution<float> n01(0, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < cin; ++c) in.at(y, x)[c] = n01(rng);
  std::vector<float> wt(9 * cin), bias{0.1f};
  for (auto& v : wt) v = n01(rng) * 0.2f;
  nn::ConvWeights one = nn::pack_conv(wt.data(), bias.data(), cin, 1, 1, nn::Act::None, block);
  nn::ConvWeights blk = one;
  blk.taps.clear();  // the block kernel
  auto best = [&](const nn::ConvWeights& cw) {
    double b = 1e9;
    for (int rep = 0; rep < 30; ++rep) {
      const auto t0 = std::chrono::steady_clock::now();
      fn(in, cw, out, 0, h, nullptr);  // one output channel: no scratch
      b = std::min(b, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    return b;
  };
  double a = 1e9, b = 1e9;
  for (int round = 0; round < 3; ++round) {  // alternated, best of all
    a = std::min(a, best(one));
    b = std::min(b, best(blk));
  }
  std::printf("16 -> 1 conv at %dx%d, 1 thread, %s: one-channel kernel %.3f ms, block kernel %.3f ms: %.1fx\n", w, h, simd, a,
              b, b / a);
}

// f(kernel, weight block, name) for every convolution kernel this build and CPU have.
template <class F>
void for_each_kernel(F&& f) {
  f(nn::conv3x3_rows_scalar, 8, "scalar");
#if defined(TERRALIGN_NN_AVX2)
  if (nn::nn_cpu_has_avx2()) f(nn::conv3x3_rows_avx2, 8, "avx2");
  if (nn::nn_cpu_has_avx512()) f(nn::conv3x3_rows_avx512, 16, "avx512");
#endif
#if defined(TERRALIGN_NN_NEON)
  f(nn::conv3x3_rows_neon, 8, "neon");
#endif
}

// Winograd's F(4x4) against F(2x2) and the direct kernel on one layer, one thread, in the same
// run, alternated: the shapes of s16w64's levels (64 -> 64 on the coarse ones, whose maps leave
// the most tiles reaching past the edges), ELU, dilation 2; and F(4x4) without the activation,
// whose difference is ELU's cost.
void winograd_layers(nn::ConvRowsFn fn, int block, const char* simd) {
  struct Shape {
    int w, h, c;
  };
  for (const Shape sh : {Shape{376, 240, 16}, Shape{188, 120, 32}, Shape{94, 60, 64}, Shape{47, 30, 64}, Shape{23, 15, 64}}) {
    nn::Tensor in, out;
    in.allocate(sh.h, sh.w, sh.c);
    out.allocate(sh.h, sh.w, sh.c);
    std::mt19937 rng(7);
    std::normal_distribution<float> n01(0, 1);
    for (int y = 0; y < sh.h; ++y)
      for (int x = 0; x < sh.w; ++x)
        for (int c = 0; c < sh.c; ++c) in.at(y, x)[c] = n01(rng);
    std::vector<float> wt(9 * static_cast<std::size_t>(sh.c) * static_cast<std::size_t>(sh.c)), bias(static_cast<std::size_t>(sh.c), 0.1f);
    for (auto& v : wt) v = n01(rng) * 0.1f;
    // direct, F(2x2), F(4x4), and F(4x4) without the activation (ELU's share of the layer)
    nn::ConvWeights cw[4];
    const int tiles[4] = {0, 2, 4, 4};
    std::size_t scratch_floats = 0;
    for (int k = 0; k < 4; ++k) {
      cw[k] = nn::pack_conv(wt.data(), bias.data(), sh.c, sh.c, 2, k == 3 ? nn::Act::None : nn::Act::Elu, block, tiles[k]);
      scratch_floats = std::max(scratch_floats, nn::conv_scratch_floats(cw[k]));
    }
    std::vector<float> scratch(scratch_floats + 16);
    float* aligned = scratch.data();
    while (reinterpret_cast<std::uintptr_t>(aligned) % 64 != 0) ++aligned;
    double ms[4] = {1e9, 1e9, 1e9, 1e9};
    for (int rep = 0; rep < 20; ++rep)
      for (int k = 0; k < 4; ++k) {
        const auto t0 = std::chrono::steady_clock::now();
        fn(in, cw[k], out, 0, sh.h, aligned);
        ms[k] = std::min(ms[k], std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      }
    std::printf("%d -> %d conv, dilation 2, at %dx%d, 1 thread, %s: direct %.3f ms, F(2x2) %.3f, F(4x4) %.3f: F(2x2) / F(4x4) %.2fx; "
                "F(4x4) without ELU %.3f: ELU %.0f %% of the layer\n",
                sh.c, sh.c, sh.w, sh.h, simd, ms[0], ms[1], ms[2], ms[1] / ms[2], ms[3], 100.0 * (ms[2] - ms[3]) / ms[2]);
  }
}

// One of the learned tracker's networks at 376 x 240 on 2 threads: the product's convolutions
// (Winograd's F(4x4) where it suits, kernels.hpp) against the direct kernel's and against
// F(2x2), per layer, the three passes
// alternated 25 times (this host's slow spells last seconds to minutes, so all see the same
// ones) and each layer's fastest pass.
bool tracker_network(const nn::WeightFile& weights, const char* path, const char* name) {
  auto product = nn::Network::plan(weights, name, 376, 240, 2);
  auto two = nn::Network::plan(weights, name, 376, 240, 2, nn::Simd::Auto, nn::Memory::Shared, nullptr, 2);
  auto direct = nn::Network::plan(weights, name, 376, 240, 2, nn::Simd::Auto, nn::Memory::Shared, nullptr, 0);
  if (!product.ok() || !two.ok() || !direct.ok()) return false;
  nn::Network* nets[3] = {direct.value().get(), two.value().get(), product.value().get()};
  std::vector<double> ms[3];
  for (nn::Network* n : nets) {
    n->forward();
    n->set_profiling(true);
  }
  for (int pass = 0; pass < 25; ++pass)
    for (int k = 0; k < 3; ++k) {
      nets[k]->forward();
      const auto st = nets[k]->step_times();
      if (ms[k].empty()) ms[k].assign(st.size(), 1e9);
      for (std::size_t i = 0; i < st.size(); ++i) ms[k][i] = std::min(ms[k][i], st[i].ms);
    }
  std::printf("learned tracker's %s (%s) at 376x240, 2 threads, %s, fastest of 25 alternated passes:\n\n"
              "| layer | op | tile | direct ms | F(2x2) ms | product ms | direct / product | F(2x2) / product |\n"
              "|---|---|---|---|---|---|---|---|\n",
              name, path, product.value()->simd_name());
  const auto st = product.value()->step_times();
  double total[3] = {0, 0, 0};
  auto ratio = [](double a, double b) { return b > 0 ? a / b : 0.0; };
  for (std::size_t i = 0; i < st.size(); ++i) {
    for (int k = 0; k < 3; ++k) total[k] += ms[k][i];
    const int m = st[i].winograd_tile;
    const std::string tile = m > 0 ? std::to_string(m) + "x" + std::to_string(m) : "";
    std::printf("| %s | %s | %s | %.3f | %.3f | %.3f | %.2f | %.2f |\n", st[i].name.c_str(), st[i].op.c_str(), tile.c_str(),
                ms[0][i], ms[1][i], ms[2][i], ratio(ms[0][i], ms[2][i]), ratio(ms[1][i], ms[2][i]));
  }
  std::printf("| all | | | %.3f | %.3f | %.3f | **%.2f** | **%.2f** |\n\n", total[0], total[1], total[2],
              ratio(total[0], total[2]), ratio(total[1], total[2]));
  return true;
}

// The learned tracker's first encoding of a pair (iclk::DeepAligner::encode_pair): the
// reference and the live image encoded at once, each on one thread of a two-thread pool,
// against one after the other, each split over both threads, alternated 25 times; fastest
// and median of each. Checks first that the two ways give the same bytes at every level.
bool encoder_pair(const nn::WeightFile& weights) {
  ThreadPool pool(2);
  ThreadPool solo[2] = {ThreadPool(1), ThreadPool(1)};
  std::unique_ptr<nn::Network> net[2];
  for (auto& n : net) {
    auto planned = nn::Network::plan(weights, "encoder", 376, 240, 2, nn::Simd::Auto, nn::Memory::Shared, &pool);
    if (!planned.ok()) return false;
    n = std::move(planned.value());
  }
  std::mt19937 rng(9);
  std::normal_distribution<float> n01(0, 1);
  for (auto& n : net) {
    nn::Tensor* x = n->input("x");
    for (int y = 0; y < x->h; ++y)
      for (int i = 0; i < x->w; ++i)
        for (int c = 0; c < 3; ++c) x->at(y, i)[c] = n01(rng);
  }
  auto split = [&] {
    for (auto& n : net) n->forward();
  };
  // Task i on thread i: network i on that thread's one-thread pool.
  struct Ctx {
    std::unique_ptr<nn::Network>* nets;
    ThreadPool* solo;
  } ctx{net, solo};
  auto at_once = [&] {
    pool.run(2, [](void* c, int i) {
      auto* x = static_cast<Ctx*>(c);
      x->nets[i]->forward_until(1 << 30, x->solo[i]);
    }, &ctx);
  };
  // The same bytes either way, every level of each network.
  auto features = [&](int k) {  // every level's output, f0, f1, ...
    std::vector<float> v;
    for (int l = 0; const nn::Tensor* f = net[k]->output("f" + std::to_string(l)); ++l)
      for (int y = 0; y < f->h; ++y)
        for (int i = 0; i < f->w; ++i) v.insert(v.end(), f->at(y, i), f->at(y, i) + f->c);
    return v;
  };
  split();
  const std::vector<float> a[2] = {features(0), features(1)};
  at_once();
  for (int k = 0; k < 2; ++k)
    if (std::memcmp(a[k].data(), features(k).data(), a[k].size() * sizeof(float)) != 0) {
      std::fprintf(stderr, "bench_nn: the encoder pair at once differs from one after the other\n");
      return false;
    }
  std::vector<double> ms[2];
  for (int pass = 0; pass < 25; ++pass)
    for (int k = 0; k < 2; ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      if (k == 0) split();
      else at_once();
      ms[k].push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
  for (auto& v : ms) std::sort(v.begin(), v.end());
  std::printf("learned tracker's encoder, two 376x240 images, 2 threads, %s, 25 alternated passes (fastest / median):\n"
              "  one after the other, each on both threads: %.2f / %.2f ms\n"
              "  at once, one image a thread:               %.2f / %.2f ms  (%.2fx / %.2fx; the same bytes)\n\n",
              net[0]->simd_name(), ms[0].front(), ms[0][12], ms[1].front(), ms[1][12], ms[0].front() / ms[1].front(),
              ms[0][12] / ms[1][12]);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  const bool tracker_only = argc > 1 && std::strcmp(argv[1], "--tracker") == 0;
  const char* tracker_weights = tracker_only && argc > 2 ? argv[2] : TERRALIGN_DEFAULT_WEIGHTS;
  auto weights = nn::read_weights(TERRALIGN_SOURCE_DIR "/weights/lv19_tum_abc.tlw");
  if (!weights.ok()) {
    std::fprintf(stderr, "%s\n", weights.error().message.c_str());
    return 1;
  }
  const bool wide = nn::nn_cpu_has_avx512();
  const double peak1 = peak_gflops(1, wide), peak2 = peak_gflops(2, wide);
  std::printf("FMA peak (%s, measured): %.1f GFLOP/s on 1 thread, %.1f on 2\n", wide ? "AVX-512" : "AVX2", peak1, peak2);
  std::printf("(GMAC and GFLOP/s count a direct convolution's 9 multiply-adds an output; the layers of 16 input\n"
              "channels or more run Winograd's F(4x4, 3x3), 2.25 of those 9, so they can exceed the FMA peak)\n\n");
  for (auto [w, h] : {std::pair<int, int>{752, 480}, {160, 120}}) {
    if (tracker_only) break;
    for (int threads : {1, 2}) {
      auto net = nn::Network::plan(weights.value(), "encoder", w, h, threads);
      if (!net.ok()) return 1;
      net.value()->forward();
      std::vector<double> totals;
      for (int rep = 0; rep < (w > 200 ? 3 : 20); ++rep) {
        const auto t0 = std::chrono::steady_clock::now();
        net.value()->forward();
        totals.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      }
      std::sort(totals.begin(), totals.end());
      const double ms = totals.front();
      const double peak = threads == 1 ? peak1 : peak2;
      const double gf = 2.0 * net.value()->macs() / (ms * 1e6);
      std::printf("encoder %dx%d, %d thread(s), %s: %.1f ms, %.2f GMAC, %.1f GFLOP/s = %.0f %% of peak\n", w, h, threads,
                  net.value()->simd_name(), ms, net.value()->macs() / 1e9, gf, peak > 0 ? 100 * gf / peak : 0.0);
      if (w == 752 && threads == 2) {
        net.value()->set_profiling(true);
        net.value()->forward();
        std::printf("\n| layer | op | ms | GFLOP/s | %% of peak |\n|---|---|---|---|---|\n");
        for (const auto& st : net.value()->step_times()) {
          const double g = st.macs > 0 ? 2.0 * st.macs / (st.ms * 1e6) : 0.0;
          std::printf("| %s | %s | %.2f | %.1f | %.0f |\n", st.name.c_str(), st.op.c_str(), st.ms, g, peak > 0 ? 100 * g / peak : 0.0);
        }
        std::printf("\n");
      }
      if (threads == 2) {
        const double t = torch_ms(w, h, 2);
        if (t > 0) std::printf("PyTorch (2 threads, best memory format) %dx%d: %.1f ms; terralign is %.2fx PyTorch's speed\n\n", w, h, t, t / ms);
        else std::printf("(PyTorch not available: /usr/bin/python3 with torch is needed for the comparison)\n\n");
      }
    }
  }
  // The learned tracker's two networks (the shipped file's, or WEIGHTS') at its working size
  // (376 x 240), per layer: Winograd's kernel (the product's) against the direct one, alternated
  // in the same run.
  auto tracker = nn::read_weights(tracker_weights);
  if (!tracker.ok()) {
    std::fprintf(stderr, "%s\n", tracker.error().message.c_str());
    return 1;
  }
  for (const char* name : {"encoder", "mestimator"})
    if (!tracker_network(tracker.value(), tracker_weights, name)) return 1;
  if (!encoder_pair(tracker.value())) return 1;
  std::printf("\n");
  for_each_kernel(winograd_layers);
  std::printf("\n");
  for_each_kernel(one_channel_layer);
  return 0;
}
