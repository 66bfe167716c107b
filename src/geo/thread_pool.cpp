#include <terralign/geo/thread_pool.hpp>

#include <algorithm>

namespace terralign {

#if defined(TERRALIGN_NO_THREADS)
// A build without threads (a microcontroller): every task on the caller's thread, in index
// order. Results are the same bytes as with threads (the callers' tasks are fixed tiles).
ThreadPool::ThreadPool(int) : threads_(1) {}
ThreadPool::~ThreadPool() = default;
void ThreadPool::run(int tasks, Task fn, void* ctx) {
  for (int i = 0; i < tasks; ++i) fn(ctx, i);
}
#else
ThreadPool::ThreadPool(int threads) : threads_(std::max(1, threads)) {
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
  {
    std::lock_guard<std::mutex> lock(mutex_);
    fn_ = fn;
    ctx_ = ctx;
    tasks_ = tasks;
    pending_ = threads_ - 1;
    ++generation_;
  }
  start_cv_.notify_all();
  do_tasks(0);
  std::unique_lock<std::mutex> lock(mutex_);
  done_cv_.wait(lock, [this] { return pending_ == 0; });
}

void ThreadPool::worker(int id) {
  long seen = 0;
  for (;;) {
    {
      std::unique_lock<std::mutex> lock(mutex_);
      start_cv_.wait(lock, [&] { return stop_ || generation_ != seen; });
      if (stop_) return;
      seen = generation_;
    }
    do_tasks(id);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (--pending_ == 0) done_cv_.notify_one();
    }
  }
}

#endif

}  // namespace terralign
