#include "arena.hpp"

#include <cerrno>
#include <cstdint>
#include <cstddef>
#include <cstring>
#include <new>

#include "semihosting.hpp"

namespace fw {
namespace {

constexpr std::size_t kAlign = 16;  // what malloc promises here (Eigen asks for no more on this core)
// Every block, free or used, starts with a header; free blocks are chained by address.
struct Header {
  std::size_t size;  // bytes after the header (a multiple of kAlign)
  Header* next;      // free blocks only
  std::size_t used;  // bytes the caller asked for; 0 when free
  std::size_t spare;
};
static_assert(sizeof(Header) % kAlign == 0, "headers keep payloads aligned");

unsigned char* g_base = nullptr;
Header* g_free = nullptr;
ArenaStats g_stats;

std::size_t round_up(std::size_t n) { return (n + kAlign - 1) & ~(kAlign - 1); }

void* allocate(std::size_t n, std::size_t align = kAlign) {
  if (!g_base) {
    write("firmware: allocation before arena_init\n");
    exit(98);
  }
  if (align > kAlign) {
    print("firmware: an allocation aligned to %u bytes (this arena gives %u)\n", static_cast<unsigned>(align),
          static_cast<unsigned>(kAlign));
    exit(96);
  }
  const std::size_t need = round_up(n == 0 ? 1 : n);
  Header** link = &g_free;
  while (*link && (*link)->size < need) link = &(*link)->next;
  if (!*link) {
    print("firmware: the working-memory buffer is exhausted: %u bytes asked with %u of %u in use\n",
          static_cast<unsigned>(n), static_cast<unsigned>(g_stats.used), static_cast<unsigned>(g_stats.capacity));
    exit(97);
  }
  Header* h = *link;
  if (h->size >= need + sizeof(Header) + kAlign) {  // split: the rest stays free
    auto* rest = reinterpret_cast<Header*>(reinterpret_cast<unsigned char*>(h + 1) + need);
    rest->size = h->size - need - sizeof(Header);
    rest->next = h->next;
    rest->used = 0;
    h->size = need;
    *link = rest;
  } else {
    *link = h->next;
  }
  h->used = n == 0 ? 1 : n;
  g_stats.used += h->size + sizeof(Header);
  g_stats.peak = g_stats.used > g_stats.peak ? g_stats.used : g_stats.peak;
  ++g_stats.allocations;
  return h + 1;
}

Header* header_of(void* p) { return static_cast<Header*>(p) - 1; }

std::size_t size_of(void* p) { return header_of(p)->used; }

void release(void* p) {
  if (!p) return;
  Header* h = header_of(p);
  g_stats.used -= h->size + sizeof(Header);
  h->used = 0;
  // Insert by address, then merge with the neighbours.
  Header** link = &g_free;
  while (*link && *link < h) link = &(*link)->next;
  h->next = *link;
  *link = h;
  auto end_of = [](Header* b) { return reinterpret_cast<unsigned char*>(b + 1) + b->size; };
  if (h->next && end_of(h) == reinterpret_cast<unsigned char*>(h->next)) {
    h->size += sizeof(Header) + h->next->size;
    h->next = h->next->next;
  }
  if (link != &g_free) {
    auto* prev = reinterpret_cast<Header*>(reinterpret_cast<unsigned char*>(link) - offsetof(Header, next));
    if (end_of(prev) == reinterpret_cast<unsigned char*>(h)) {
      prev->size += sizeof(Header) + h->size;
      prev->next = h->next;
    }
  }
}

}  // namespace

void arena_init(void* buffer, std::size_t bytes) {
  g_base = static_cast<unsigned char*>(buffer);
  g_stats = ArenaStats{};
  g_stats.capacity = bytes;
  g_free = reinterpret_cast<Header*>(g_base);
  g_free->size = (bytes & ~(kAlign - 1)) - sizeof(Header);
  g_free->next = nullptr;
  g_free->used = 0;
}

const ArenaStats& arena_stats() { return g_stats; }

}  // namespace fw

// The C library's allocator, replaced (newlib's internals call the _r forms).
extern "C" {
void* malloc(std::size_t n) { return fw::allocate(n); }
void free(void* p) { fw::release(p); }
void* calloc(std::size_t n, std::size_t m) {
  if (m && n > static_cast<std::size_t>(-1) / m) return nullptr;
  void* p = fw::allocate(n * m);
  std::memset(p, 0, n * m);
  return p;
}
void* realloc(void* p, std::size_t n) {
  if (!p) return fw::allocate(n);
  const std::size_t old = fw::size_of(p);
  if (n <= old) return p;
  void* q = fw::allocate(n);
  std::memcpy(q, p, old);
  fw::release(p);
  return q;
}
void* memalign(std::size_t align, std::size_t n) { return fw::allocate(n, align < 16 ? 16 : align); }
void* _malloc_r(struct _reent*, std::size_t n) { return malloc(n); }
void _free_r(struct _reent*, void* p) { free(p); }
void* _calloc_r(struct _reent*, std::size_t n, std::size_t m) { return calloc(n, m); }
void* _realloc_r(struct _reent*, void* p, std::size_t n) { return realloc(p, n); }
void* _memalign_r(struct _reent*, std::size_t align, std::size_t n) { return memalign(align, n); }
}

void* operator new(std::size_t n) { return fw::allocate(n); }
void* operator new[](std::size_t n) { return fw::allocate(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept { return fw::allocate(n); }
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept { return fw::allocate(n); }
void operator delete(void* p) noexcept { fw::release(p); }
void operator delete[](void* p) noexcept { fw::release(p); }
void operator delete(void* p, std::size_t) noexcept { fw::release(p); }
void operator delete[](void* p, std::size_t) noexcept { fw::release(p); }
