// The solver's three kernels alone (src/iclk/evaluate_kernels.hpp) on one pyramid level,
// against their scalar twins in the same run: the Jacobian set-up (a level's start, with the
// finest level's sums), the residual with its J^T w r sums (each iteration), and J^T W J (each
// iteration). This machine's vector build (AVX2 on x86-64, NEON on aarch64) is checked to give
// the scalar twin's bits before it is timed. Levels: the learned tracker's finest (376 x 240,
// two feature channels, every pixel: its runs of eight on a row) and the classical tracker's
// (752 x 480, grey, every second pixel of every second row: groups gathered).
//   build/release/bench/bench_solver_kernels
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <vector>

#include <terralign/geo/cpu.hpp>
#include <terralign/iclk/tracker.hpp>

#include "../src/iclk/evaluate_kernels.hpp"

using namespace terralign;
using namespace terralign::iclk::detail;
using Clock = std::chrono::steady_clock;

namespace {

struct Kernels {
  const char* name;
  Se3JacobianFn jacobians;
  Se3EvalFn residual;
  OuterSumsFn outer;
};

struct LevelCase {
  const char* name;
  int W, H, C, step;  // picks every step-th pixel of every step-th row
};

// One level's arrays, laid out as Tracker::write_band and evaluate() use them.
struct Level {
  int W, H, C, n = 0;
  std::vector<float> ref, depth, live;
  std::vector<int> xs, ys;
  std::vector<float> pu, pv, px, py, pz, val, jac, w, r;
  std::vector<unsigned char> ok;
  std::vector<int> out;
  Se3FinestSums sums{};

  Level(const LevelCase& c, std::mt19937& rng) : W(c.W), H(c.H), C(c.C) {
    std::uniform_real_distribution<float> U(0, 1);
    ref.resize(static_cast<std::size_t>(W) * H * C);
    live.resize(ref.size());
    depth.resize(static_cast<std::size_t>(W) * H);
    // Smooth-ish texture (a sum of two waves and noise) over 700-900 m of depth.
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        depth[static_cast<std::size_t>(y) * W + x] = 800.0f + 100.0f * std::sin(0.01f * static_cast<float>(x + 2 * y));
        for (int ch = 0; ch < C; ++ch) {
          const float v = std::sin(0.21f * static_cast<float>(x + 3 * ch)) + std::cos(0.17f * static_cast<float>(y)) + 0.2f * U(rng);
          ref[(static_cast<std::size_t>(y) * W + x) * C + ch] = v;
          live[static_cast<std::size_t>(ch) * W * H + static_cast<std::size_t>(y) * W + x] = v + 0.1f * U(rng);
        }
      }
    for (int y = 1; y < H - 1; y += c.step)
      for (int x = 1; x < W - 1; x += c.step) {
        xs.push_back(x);
        ys.push_back(y);
      }
    n = static_cast<int>(xs.size());
    const std::size_t N = static_cast<std::size_t>(n);
    for (auto* v : {&pu, &pv, &px, &py, &pz, &w}) v->resize(N);
    val.resize(N * C);
    r.resize(N * C);
    jac.resize(N * C * 6);
    ok.resize(N);
    out.resize(N);
    for (auto& x : w) x = 0.5f + U(rng);
  }

  // Every picked pixel's set-up, eight at a time.
  void jacobians(Se3JacobianFn fn, float fx, float fy, float cx, float cy) {
    const Se3JacobianInput in{ref.data(), depth.data(), W, C, fx, fy, cx, cy};
    sums = {};
    for (int i = 0; i < n; i += kLanes) {
      Se3JacobianGroup g;
      g.pu = pu.data() + i;
      g.pv = pv.data() + i;
      g.px = px.data() + i;
      g.py = py.data() + i;
      g.pz = pz.data() + i;
      g.val = val.data() + i;
      g.plane = n;
      for (int a = 0; a < 6; ++a) g.jac[a] = jac.data() + static_cast<std::size_t>(a) * C * n + i;
      g.jac_plane = n;
      fn(in, xs.data() + i, ys.data() + i, std::min(kLanes, n - i), g, &sums);
    }
  }

  // One iteration's residuals and sums over every pixel, in the tracker's chunks.
  float residuals(Se3EvalFn fn, float fx, float fy, float cx, float cy) {
    Se3EvalInput in{};
    in.px = px.data();
    in.py = py.data();
    in.pz = pz.data();
    in.val = val.data();
    in.w = w.data();
    for (int a = 0; a < 6; ++a) in.jac[a] = jac.data() + static_cast<std::size_t>(a) * C * n;
    in.live = live.data();
    in.stride = W;
    in.channels = C;
    in.plane = n;
    in.jac_plane = n;
    in.live_plane = static_cast<std::ptrdiff_t>(W) * H;
    in.width = W;
    in.height = H;
    // A pose 0.2 degrees and a few metres from the reference's.
    const float a = 0.0035f, ca = std::cos(a), sa = std::sin(a);
    const float R[9] = {ca, -sa, 0, sa, ca, 0, 0, 0, 1};
    std::copy(R, R + 9, in.R);
    in.t[0] = 3.0f;
    in.t[1] = -2.0f;
    in.t[2] = 1.0f;
    in.fx = fx;
    in.fy = fy;
    in.cx = cx;
    in.cy = cy;
    in.out = out.data();
    float total = 0;
    for (int i0 = 0; i0 < n; i0 += 2048) {
      Se3EvalSums s;
      fn(in, i0, std::min(n, i0 + 2048), r.data(), ok.data(), s);
      for (float c : s.cost) total += c;
    }
    return total;
  }

  OuterSums outer(OuterSumsFn fn) const {
    OuterSums h{};
    for (int ch = 0; ch < C; ++ch) {
      const float* J[6];
      for (int a = 0; a < 6; ++a) J[a] = jac.data() + static_cast<std::size_t>(a) * C * n + static_cast<std::size_t>(ch) * n;
      for (int i0 = 0; i0 < n; i0 += 2048) fn(J, w.data(), i0, std::min(n, i0 + 2048), h);
    }
    return h;
  }
};

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

}  // namespace

int main() {
  std::vector<Kernels> kernels{{"scalar", se3_jacobians_scalar, evaluate_se3_scalar, outer_sums_scalar}};
#if defined(TERRALIGN_ICLK_AVX2)
  if (cpu_features().avx2_fma) kernels.push_back({"avx2", se3_jacobians_avx2, evaluate_se3_avx2, outer_sums_avx2});
#elif defined(TERRALIGN_ICLK_NEON)
  kernels.push_back({"neon", se3_jacobians_neon, evaluate_se3_neon, outer_sums_neon});
#endif
  if (kernels.size() < 2) {
    std::printf("bench_solver_kernels: no vector build of the solver's kernels on this CPU\n");
    return 0;
  }
  const LevelCase cases[] = {{"learned finest level, 376 x 240, 2 channels, every pixel", 376, 240, 2, 1},
                             {"classical finest level, 752 x 480, grey, every 2nd pixel and row", 752, 480, 1, 2}};
  std::printf("| level | kernel | %s ms | %s ms | %s / %s |\n|---|---|---|---|---|\n", kernels[0].name, kernels[1].name,
              kernels[0].name, kernels[1].name);
  std::mt19937 rng(4);
  for (const LevelCase& c : cases) {
    // Two copies of one level, one a kernel build, so the outputs can be compared.
    const Level level(c, rng);
    Level L[2] = {level, level};
    const float fx = 0.9f * static_cast<float>(c.W), fy = fx, cx = 0.5f * static_cast<float>(c.W - 1),
                cy = 0.5f * static_cast<float>(c.H - 1);
    // The same bits first.
    float cost[2];
    OuterSums h[2];
    for (int k = 0; k < 2; ++k) {
      L[k].jacobians(kernels[static_cast<std::size_t>(k)].jacobians, fx, fy, cx, cy);
      cost[k] = L[k].residuals(kernels[static_cast<std::size_t>(k)].residual, fx, fy, cx, cy);
      h[k] = L[k].outer(kernels[static_cast<std::size_t>(k)].outer);
    }
    if (L[0].jac != L[1].jac || L[0].val != L[1].val || std::memcmp(&L[0].sums, &L[1].sums, sizeof L[0].sums) != 0 ||
        L[0].r != L[1].r || L[0].ok != L[1].ok || std::memcmp(&cost[0], &cost[1], sizeof cost[0]) != 0 ||
        std::memcmp(&h[0], &h[1], sizeof h[0]) != 0) {
      std::fprintf(stderr, "bench_solver_kernels: the %s kernels differ from the scalar ones (%s)\n", kernels[1].name, c.name);
      return 1;
    }
    // Best of 15 batches of 5 calls per kernel, the builds in turn within each batch so that a
    // change in the machine's speed falls on both alike.
    const char* names[3] = {"Jacobians (set-up)", "residuals (an iteration)", "J^T W J (an iteration)"};
    double best[3][2] = {{1e30, 1e30}, {1e30, 1e30}, {1e30, 1e30}};
    volatile float sink = 0;
    for (int batch = 0; batch < 15; ++batch)
      for (int k = 0; k < 2; ++k) {
        const Kernels& K = kernels[static_cast<std::size_t>(k)];
        auto t0 = Clock::now();
        for (int rep = 0; rep < 5; ++rep) L[k].jacobians(K.jacobians, fx, fy, cx, cy);
        best[0][k] = std::min(best[0][k], seconds_since(t0) / 5);
        t0 = Clock::now();
        for (int rep = 0; rep < 5; ++rep) sink = sink + L[k].residuals(K.residual, fx, fy, cx, cy);
        best[1][k] = std::min(best[1][k], seconds_since(t0) / 5);
        t0 = Clock::now();
        for (int rep = 0; rep < 5; ++rep) sink = sink + static_cast<float>(L[k].outer(K.outer).h[0][0]);
        best[2][k] = std::min(best[2][k], seconds_since(t0) / 5);
      }
    for (int q = 0; q < 3; ++q)
      std::printf("| %s (%d pixels) | %s | %.3f | %.3f | %.2f |\n", c.name, L[0].n, names[q], 1e3 * best[q][0], 1e3 * best[q][1],
                  best[q][0] / best[q][1]);
    std::fflush(stdout);
  }
  return 0;
}
