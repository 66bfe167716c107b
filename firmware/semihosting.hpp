// Arm semihosting (the debugger's, or QEMU's, console and exit): BKPT 0xAB with the
// operation in r0 and its argument in r1.
#pragma once

#include <cstdarg>
#include <cstdint>
#include <cstdio>

namespace fw {

inline std::uintptr_t semihost(std::uintptr_t op, const void* arg) {
  register std::uintptr_t r0 asm("r0") = op;
  register const void* r1 asm("r1") = arg;
  asm volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
  return r0;
}

// SYS_WRITE0: a NUL-terminated string to the console.
inline void write(const char* s) { semihost(0x04, s); }

inline void print(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
inline void print(const char* fmt, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, fmt);
  std::vsnprintf(buf, sizeof buf, fmt, ap);
  va_end(ap);
  write(buf);
}

// SYS_EXIT_EXTENDED: stop the machine with an exit status (QEMU exits with it).
[[noreturn]] inline void exit(int status) {
  const std::uintptr_t block[2] = {0x20026, static_cast<std::uintptr_t>(status)};  // ADP_Stopped_ApplicationExit
  semihost(0x20, block);
  for (;;) {
  }
}

}  // namespace fw
