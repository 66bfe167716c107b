// Counts heap allocations made on this thread while an AllocationCounter is alive
// (operator new is replaced in alloc_counter.cpp for the whole test binary).
#pragma once

namespace terralign::test {

class AllocationCounter {
 public:
  AllocationCounter();
  ~AllocationCounter();
  long allocations() const;

 private:
  long start_;
};

}  // namespace terralign::test
