#include "alloc_counter.hpp"

#include <atomic>
#include <cstdlib>
#include <new>

namespace {
// Counts every allocation in the process (any thread): a frame's worker threads included.
std::atomic<long> g_allocations{0};
std::atomic<int> g_active{0};
}  // namespace

void* operator new(std::size_t n) {
  if (g_active.load(std::memory_order_relaxed) > 0) g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace terralign::test {

AllocationCounter::AllocationCounter() : start_(g_allocations.load()) { g_active.fetch_add(1); }
AllocationCounter::~AllocationCounter() { g_active.fetch_sub(1); }
long AllocationCounter::allocations() const { return g_allocations.load() - start_; }

}  // namespace terralign::test
