// The thread pool's cost per run(): how long a call with small tasks takes when the workers
// spin briefly between runs (the default) and when they sleep at once (the peer, in the same
// run). The tracker and the networks call run() a hundred times or more a frame, so this is paid per call.
// Then the cost of a FloatEnvironmentScope, which every onboard entry opens (some 24 a frame),
// against the cheapest 2-thread run() above (the pipeline pays a hundred or more a frame).
//   build/release/bench/bench_pool
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <vector>

#include <terralign/geo/float_environment.hpp>
#include <terralign/geo/thread_pool.hpp>

using namespace terralign;

namespace {

struct Work {
  std::vector<float> data;
  std::vector<double> sums;
  int chunk;
};

// Microseconds per run() of `tasks` tasks each summing `chunk` floats; median of 7 batches.
double us_per_run(ThreadPool& pool, Work& w, int tasks, int runs) {
  std::vector<double> per;
  for (int b = 0; b < 7; ++b) {
    const auto t0 = std::chrono::steady_clock::now();
    for (int r = 0; r < runs; ++r)
      pool.run(tasks, [](void* c, int i) {
        auto* x = static_cast<Work*>(c);
        double s = 0;
        const float* p = x->data.data() + static_cast<std::size_t>(i) * static_cast<std::size_t>(x->chunk);
        for (int k = 0; k < x->chunk; ++k) s += p[k];
        x->sums[static_cast<std::size_t>(i)] += s;
      }, &w);
    per.push_back(std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count() / runs);
  }
  std::sort(per.begin(), per.end());
  return per[3];
}

}  // namespace

// Nanoseconds per FloatEnvironmentScope opened and closed; median of 7 batches.
double ns_per_scope(int scopes) {
  std::vector<double> per;
  for (int b = 0; b < 7; ++b) {
    const auto t0 = std::chrono::steady_clock::now();
    for (int r = 0; r < scopes; ++r) {
      const FloatEnvironmentScope scope;
      __asm__ volatile("" : : : "memory");  // keep each scope's calls in the loop
    }
    per.push_back(std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0).count() / scopes);
  }
  std::sort(per.begin(), per.end());
  return per[3];
}

int main() {
  std::printf("| tasks per run x floats per task | 1 thread us/run | 2 threads, spin then sleep | 2 threads, sleep at once | sleep / spin |\n");
  std::printf("|---|---|---|---|---|\n");
  ThreadPool one(1), spin(2, true), sleep(2, false);
  double cheapest_us = 0;
  for (const auto& [tasks, chunk] : {std::pair{2, 16}, std::pair{16, 1024}, std::pair{64, 4096}}) {
    Work w{std::vector<float>(static_cast<std::size_t>(tasks) * static_cast<std::size_t>(chunk), 1.0f),
           std::vector<double>(static_cast<std::size_t>(tasks)), chunk};
    const int runs = 2000;
    const double a = us_per_run(one, w, tasks, runs), b = us_per_run(spin, w, tasks, runs), c = us_per_run(sleep, w, tasks, runs);
    std::printf("| %d x %d | %.2f | %.2f | %.2f | %.1fx |\n", tasks, chunk, a, b, c, c / b);
    if (tasks == 2) cheapest_us = b;
  }
  const double scope_ns = ns_per_scope(200000);
  std::printf("\nFloatEnvironmentScope, opened and closed: %.0f ns, %.3fx a 2-thread run() of 2 x 16 (spin then sleep)\n", scope_ns,
              scope_ns / (1000 * cheapest_us));
  return 0;
}
