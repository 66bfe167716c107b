// The working memory: one caller-provided buffer from which every allocation of the program
// is served (malloc and operator new both land here, the C library's included), so that its
// high-water mark is the whole heap the localiser needs. First fit over an address-ordered
// free list with coalescing (set-up allocates and frees; the frame loop must not allocate:
// allocations are counted).
#pragma once

#include <cstddef>

namespace fw {

struct ArenaStats {
  std::size_t capacity = 0, used = 0, peak = 0;
  long allocations = 0;
};

void arena_init(void* buffer, std::size_t bytes);
const ArenaStats& arena_stats();

}  // namespace fw
