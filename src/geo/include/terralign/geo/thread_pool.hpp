// A fixed pool of worker threads (shared by the renderer and the inference engine) for per-frame work split into independent tasks.
//
// run(n, fn, ctx) calls fn(ctx, i) for every task i in [0, n); task i always runs on thread
// i % threads (the caller's thread is thread 0), so which thread does what is fixed, and
// since tasks write disjoint outputs the result never depends on the thread count or on
// scheduling. Threads are created in the constructor; run() allocates nothing.
//
// Waking a sleeping thread costs tens of microseconds (a futex and, in a virtual machine,
// an inter-processor interrupt), and the tracker and the networks call run() a hundred times
// or more a frame (once per solver step, once per layer); so a worker that has finished
// spins for a short while (1500 pauses: some tens of microseconds) watching for the next run
// before it sleeps, and the caller likewise spins before sleeping on the workers' completion.
#pragma once

#include <memory>

#if !defined(TERRALIGN_NO_THREADS)
#include <atomic>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>
#endif

namespace terralign {

// The alignment of data that one thread of a pool writes while another writes its neighbour
// (per-thread scratch, per-task partial sums): a cache line, since a line written by two
// cores moves between them on every write. A build without threads has no such sharing, and
// a microcontroller's allocator gives 16 bytes.
#if defined(TERRALIGN_NO_THREADS)
constexpr int kUnsharedAlign = 16;
#else
constexpr int kUnsharedAlign = 64;
#endif

class ThreadPool {
 public:
  using Task = void (*)(void* ctx, int index);

  // spin = false: sleep at once between runs (no busy waiting, slower to wake).
  explicit ThreadPool(int threads, bool spin = true);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int threads() const { return threads_; }
  void run(int tasks, Task fn, void* ctx);

 private:
  int threads_;
#if !defined(TERRALIGN_NO_THREADS)
  int spin_iterations_;
  void worker(int id);
  void do_tasks(int id);
  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable start_cv_, done_cv_;
  std::atomic<long> generation_{0};
  std::atomic<int> pending_{0};
  bool stop_ = false;  // guarded by mutex_
  Task fn_ = nullptr;
  void* ctx_ = nullptr;
  int tasks_ = 0;
#endif
};

// The pool a component runs on: the caller's `given`, which the caller keeps alive, or else a
// pool of `threads` of its own, created in `own` (the component's member, declared before
// whatever runs on it).
inline ThreadPool* given_or_own(ThreadPool* given, int threads, std::unique_ptr<ThreadPool>& own) {
  if (given) return given;
  own = std::make_unique<ThreadPool>(threads);
  return own.get();
}

// Calls fn(y) for y in [0, rows), split into fixed blocks of `block` rows over the pool's
// threads (each row is written by one call only, so the bytes do not depend on the thread
// count). Allocates nothing.
template <class F>
void for_rows(ThreadPool& pool, int rows, F fn, int block = 64) {
  struct Ctx {
    F* fn;
    int rows, block;
  } ctx{&fn, rows, block};
  pool.run((rows + block - 1) / block, [](void* c, int i) {
    auto* x = static_cast<Ctx*>(c);
    const int end = x->rows < (i + 1) * x->block ? x->rows : (i + 1) * x->block;
    for (int y = i * x->block; y < end; ++y) (*x->fn)(y);
  }, &ctx);
}

}  // namespace terralign
