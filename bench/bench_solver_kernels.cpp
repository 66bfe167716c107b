// The solver's three kernels alone (src/iclk/evaluate_kernels.hpp) on one pyramid level,
// against their scalar twins in the same run: the Jacobian set-up (a level's start, with the
// finest level's sums), the residual with its J^T w r sums (each iteration), and J^T W J (each
// iteration). This machine's vector builds (AVX2 on x86-64, and where the CPU has AVX-512 the
// residual's sixteen-pixel build beside AVX2's other two; NEON on aarch64) are checked to give
// the scalar twin's bits before they are timed. Levels: the learned tracker's finest (376 x 240,
// two feature channels, every pixel: its runs of eight on a row) and the classical tracker's
// (752 x 480, grey, every second pixel of every second row: groups gathered).
//   build/release/bench/bench_solver_kernels
#include <algorithm>
#include <array>
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
  if (cpu_features().avx512f) kernels.push_back({"avx512", se3_jacobians_avx2, evaluate_se3_avx512, outer_sums_avx2});
#elif defined(TERRALIGN_ICLK_NEON)
  kernels.push_back({"neon", se3_jacobians_neon, evaluate_se3_neon, outer_sums_neon});
#endif
  if (kernels.size() < 2) {
    std::printf("bench_solver_kernels: no vector build of the solver's kernels on this CPU\n");
    return 0;
  }
  const LevelCase cases[] = {{"learned finest level, 376 x 240, 2 channels, every pixel", 376, 240, 2, 1},
                             {"classical finest level, 752 x 480, grey, every 2nd pixel and row", 752, 480, 1, 2}};
  const std::size_t K = kernels.size();
  std::printf("| level | kernel |");
  for (const Kernels& k : kernels) std::printf(" %s ms |", k.name);
  for (std::size_t k = 1; k < K; ++k) std::printf(" %s / %s |", kernels[k - 1].name, kernels[k].name);
  std::printf("\n|---|---|");
  for (std::size_t k = 1; k < 2 * K; ++k) std::printf("---|");
  std::printf("\n");
  std::mt19937 rng(4);
  for (const LevelCase& c : cases) {
    // Copies of one level, one a kernel build, so the outputs can be compared.
    const Level level(c, rng);
    std::vector<Level> L(K, level);
    const float fx = 0.9f * static_cast<float>(c.W), fy = fx, cx = 0.5f * static_cast<float>(c.W - 1),
                cy = 0.5f * static_cast<float>(c.H - 1);
    // The same bits first.
    std::vector<float> cost(K);
    std::vector<OuterSums> h(K);
    for (std::size_t k = 0; k < K; ++k) {
      L[k].jacobians(kernels[k].jacobians, fx, fy, cx, cy);
      cost[k] = L[k].residuals(kernels[k].residual, fx, fy, cx, cy);
      h[k] = L[k].outer(kernels[k].outer);
    }
    for (std::size_t k = 1; k < K; ++k)
      if (L[0].jac != L[k].jac || L[0].val != L[k].val || std::memcmp(&L[0].sums, &L[k].sums, sizeof L[0].sums) != 0 ||
          L[0].r != L[k].r || L[0].ok != L[k].ok || std::memcmp(&cost[0], &cost[k], sizeof cost[0]) != 0 ||
          std::memcmp(&h[0], &h[k], sizeof h[0]) != 0) {
        std::fprintf(stderr, "bench_solver_kernels: the %s kernels differ from the scalar ones (%s)\n", kernels[k].name, c.name);
        return 1;
      }
    // Best of 15 batches of 5 calls per kernel, the builds in turn within each batch so that a
    // change in the machine's speed falls on all alike, each on the first copy (the same bits
    // as every other's, above): copies at other addresses timed one kernel 1.3x apart.
    const char* names[3] = {"Jacobians (set-up)", "residuals (an iteration)", "J^T W J (an iteration)"};
    std::vector<std::array<double, 3>> best(K, {1e30, 1e30, 1e30});
    volatile float sink = 0;
    for (int batch = 0; batch < 15; ++batch)
      for (std::size_t k = 0; k < K; ++k) {
        const Kernels& B = kernels[k];
        auto t0 = Clock::now();
        for (int rep = 0; rep < 5; ++rep) L[0].jacobians(B.jacobians, fx, fy, cx, cy);
        best[k][0] = std::min(best[k][0], seconds_since(t0) / 5);
        t0 = Clock::now();
        for (int rep = 0; rep < 5; ++rep) sink = sink + L[0].residuals(B.residual, fx, fy, cx, cy);
        best[k][1] = std::min(best[k][1], seconds_since(t0) / 5);
        t0 = Clock::now();
        for (int rep = 0; rep < 5; ++rep) sink = sink + static_cast<float>(L[0].outer(B.outer).h[0][0]);
        best[k][2] = std::min(best[k][2], seconds_since(t0) / 5);
      }
    for (int q = 0; q < 3; ++q) {
      std::printf("| %s (%d pixels) | %s |", c.name, L[0].n, names[q]);
      for (std::size_t k = 0; k < K; ++k) std::printf(" %.3f |", 1e3 * best[k][static_cast<std::size_t>(q)]);
      for (std::size_t k = 1; k < K; ++k)
        std::printf(" %.2f |", best[k - 1][static_cast<std::size_t>(q)] / best[k][static_cast<std::size_t>(q)]);
      std::printf("\n");
    }
    std::fflush(stdout);
  }
  return 0;
}
