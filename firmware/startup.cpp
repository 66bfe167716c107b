// Reset and fault handlers and the vector table for a Cortex-M7 without an OS: enable the
// FPU, copy .data, clear .bss, paint the stack (for its high-water mark), hand the working-memory
// buffer over (firmware_init), run the static constructors, call firmware_main (main.cpp), exit through semihosting with main's status.
#include <cstdint>
#include <cstring>

#include "semihosting.hpp"

extern "C" {
extern std::uint32_t __data_load, __data_start, __data_end, __bss_start, __bss_end, __stack_top, __stack_limit;
void __libc_init_array();
void firmware_init();
int firmware_main();
void Reset_Handler();
void Fault_Handler();
}

namespace fw {
constexpr std::uint32_t kStackPaint = 0x5A5AA5A5u;

// Bytes of the stack that were ever written (the paint overwritten), from the bottom up.
std::size_t stack_high_water() {
  const std::uint32_t* p = &__stack_limit;
  while (p < &__stack_top && *p == kStackPaint) ++p;
  return static_cast<std::size_t>(reinterpret_cast<const char*>(&__stack_top) - reinterpret_cast<const char*>(p));
}
}  // namespace fw

extern "C" void Reset_Handler() {
  // CPACR: full access to coprocessors 10 and 11 (the FPU) before any floating point.
  volatile std::uint32_t& cpacr = *reinterpret_cast<volatile std::uint32_t*>(0xE000ED88u);
  cpacr = cpacr | (0xFu << 20);
  asm volatile("dsb\n isb" ::: "memory");
  for (std::uint32_t *s = &__data_load, *d = &__data_start; d < &__data_end;) *d++ = *s++;
  for (std::uint32_t* d = &__bss_start; d < &__bss_end;) *d++ = 0;
  // Paint the stack below the current frame (256 bytes of margin under the stack pointer).
  std::uintptr_t sp;
  asm volatile("mov %0, sp" : "=r"(sp));
  for (std::uint32_t* p = &__stack_limit; reinterpret_cast<std::uintptr_t>(p) + 256 < sp; ++p) *p = fw::kStackPaint;
  firmware_init();  // the working-memory buffer, before static constructors allocate
  __libc_init_array();
  fw::exit(firmware_main());
}

// What crti / crtbegin would define (the image is linked without start files): the DSO
// handle static destructors register against, and empty _init / _fini for newlib.
extern "C" {
void* __dso_handle = nullptr;
void _init() {}
void _fini() {}
}

extern "C" void Fault_Handler() {
  fw::write("firmware: hard fault\n");
  fw::exit(99);
}

// Initial stack pointer, reset, NMI, HardFault, MemManage, BusFault, UsageFault.
__attribute__((section(".isr_vector"), used)) const void* const vector_table[] = {
    &__stack_top,
    reinterpret_cast<const void*>(&Reset_Handler),
    reinterpret_cast<const void*>(&Fault_Handler),
    reinterpret_cast<const void*>(&Fault_Handler),
    reinterpret_cast<const void*>(&Fault_Handler),
    reinterpret_cast<const void*>(&Fault_Handler),
    reinterpret_cast<const void*>(&Fault_Handler),
};
