#include <terralign/geo/thread_pool.hpp>

#include <algorithm>

#include <terralign/geo/float_environment.hpp>

namespace terralign {

#if defined(TERRALIGN_NO_THREADS)
// A build without threads (a microcontroller): every task on the caller's thread, in index
// order. Results are the same bytes as with threads (the callers' tasks are fixed tiles).
ThreadPool::ThreadPool(int, bool) : threads_(1) {}
ThreadPool::~ThreadPool() = default;
void ThreadPool::run(int tasks, Task fn, void* ctx) {
  for (int i = 0; i < tasks; ++i) fn(ctx, i);
}
#else
namespace {

// Pauses spent watching for work (or for the workers' completion) before sleeping: about
// 30-60 microseconds on current x86 and ARM cores.
constexpr int kSpinIterations = 1500;

inline void cpu_relax() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#elif defined(__aarch64__)
  __asm__ __volatile__("yield");
#endif
}

}  // namespace

ThreadPool::ThreadPool(int threads, bool spin) : threads_(std::max(1, threads)), spin_iterations_(spin ? kSpinIterations : 0) {
  workers_.reserve(static_cast<std::size_t>(threads_ - 1));
  for (int id = 1; id < threads_; ++id) workers_.emplace_back([this, id] { worker(id); });
}

ThreadPool::~ThreadPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  start_cv_.notify_all();
  for (auto& t : workers_) t.join();
}

void ThreadPool::do_tasks(int id) {
  for (int i = id; i < tasks_; i += threads_) fn_(ctx_, i);
}

void ThreadPool::run(int tasks, Task fn, void* ctx) {
  if (threads_ == 1 || tasks <= 1) {
    for (int i = 0; i < tasks; ++i) fn(ctx, i);
    return;
  }
  fn_ = fn;
  ctx_ = ctx;
  tasks_ = tasks;
  pending_.store(threads_ - 1, std::memory_order_relaxed);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    generation_.fetch_add(1, std::memory_order_release);  // publishes fn_, ctx_, tasks_
  }
  start_cv_.notify_all();
  do_tasks(0);
  for (int spin = 0; spin < spin_iterations_; ++spin) {
    if (pending_.load(std::memory_order_acquire) == 0) return;
    cpu_relax();
  }
  std::unique_lock<std::mutex> lock(mutex_);
  done_cv_.wait(lock, [this] { return pending_.load(std::memory_order_acquire) == 0; });
}

void ThreadPool::worker(int id) {
  // The caller's thread computes its tasks inside its entry's FloatEnvironmentScope; a worker
  // does so from its start, whatever the thread that made the pool had set.
  const FloatEnvironmentScope default_environment;
  long seen = 0;
  for (;;) {
    bool started = false;
    for (int spin = 0; spin < spin_iterations_ && !started; ++spin) {
      started = generation_.load(std::memory_order_acquire) != seen;
      if (!started) cpu_relax();
    }
    if (!started) {
      std::unique_lock<std::mutex> lock(mutex_);
      start_cv_.wait(lock, [&] { return stop_ || generation_.load(std::memory_order_acquire) != seen; });
      if (stop_) return;
    }
    seen = generation_.load(std::memory_order_acquire);
    do_tasks(id);
    if (pending_.fetch_sub(1, std::memory_order_acq_rel) == 1) {
      std::lock_guard<std::mutex> lock(mutex_);  // the caller may be between its check and its wait
      done_cv_.notify_one();
    }
  }
}

#endif

}  // namespace terralign
