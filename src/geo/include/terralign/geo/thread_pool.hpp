// A fixed pool of worker threads (shared by the renderer and the inference engine) for per-frame work split into independent tasks.
//
// run(n, fn, ctx) calls fn(ctx, i) for every task i in [0, n); task i always runs on thread
// i % threads (the caller's thread is thread 0), so which thread does what is fixed, and
// since tasks write disjoint outputs the result never depends on the thread count or on
// scheduling. Threads are created in the constructor; run() allocates nothing.
#pragma once

#if !defined(TERRALIGN_NO_THREADS)
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>
#endif

namespace terralign {

class ThreadPool {
 public:
  using Task = void (*)(void* ctx, int index);

  explicit ThreadPool(int threads);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int threads() const { return threads_; }
  void run(int tasks, Task fn, void* ctx);

 private:
  int threads_;
#if !defined(TERRALIGN_NO_THREADS)
  void worker(int id);
  void do_tasks(int id);
  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable start_cv_, done_cv_;
  long generation_ = 0;
  int pending_ = 0;
  bool stop_ = false;
  Task fn_ = nullptr;
  void* ctx_ = nullptr;
  int tasks_ = 0;
#endif
};

}  // namespace terralign
