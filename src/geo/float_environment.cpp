#include <terralign/geo/float_environment.hpp>

#include <cstring>

#if defined(__ARM_ARCH_PROFILE) && __ARM_ARCH_PROFILE == 'M'
#define TERRALIGN_FPSCR 1  // bare metal: newlib's <fenv.h> implements nothing for ARM
#else
#include <cfenv>
#if defined(__SSE__) || defined(__x86_64__)
#define TERRALIGN_MXCSR 1  // SSE's control register: FTZ, DAZ and the trap masks
#include <xmmintrin.h>
#endif
#if defined(__arm__) && defined(__ARM_FP)
#define TERRALIGN_ARM32_FPSCR 1  // 32-bit ARM Linux: FPSCR's FZ, DN and AHP beside <fenv.h>
#endif
#endif

namespace terralign {
namespace {

#if defined(TERRALIGN_FPSCR) || defined(TERRALIGN_ARM32_FPSCR)
// FPSCR's RMode (bits 22-23, 0: to nearest), FZ (24), DN (25) and AHP (26).
constexpr std::uint32_t kModeBits = (3u << 22) | (1u << 24) | (1u << 25) | (1u << 26);

std::uint32_t read_fpscr() {
#if defined(__ARM_FP)
  std::uint32_t v;
  __asm__ volatile("vmrs %0, fpscr" : "=r"(v));
  return v;
#else
  return 0;  // no FPU: software floating point rounds to nearest and keeps subnormals
#endif
}

void write_fpscr([[maybe_unused]] std::uint32_t v) {
#if defined(__ARM_FP)
  __asm__ volatile("vmsr fpscr, %0" : : "r"(v) : "memory");
#endif
}
#endif
#if !defined(TERRALIGN_FPSCR)
static_assert(sizeof(std::fenv_t) <= 64, "FloatEnvironmentScope::saved_ is too small for this C library's fenv_t");

#if defined(TERRALIGN_MXCSR)
constexpr unsigned kMxcsrFlushBits = 0x8040u;  // FTZ (bit 15) and DAZ (bit 6)
#endif
#if defined(__aarch64__)
// FPCR's FZ16 (bit 19), FZ (24), DN (25) and AHP (26): glibc's FE_DFL_ENV keeps DN and AHP.
constexpr std::uint64_t kFpcrModeBits = (1ull << 19) | (1ull << 24) | (1ull << 25) | (1ull << 26);

std::uint64_t read_fpcr() {
  std::uint64_t v;
  __asm__ volatile("mrs %0, fpcr" : "=r"(v));
  return v;
}

void write_fpcr(std::uint64_t v) { __asm__ volatile("msr fpcr, %0" : : "r"(v) : "memory"); }
#endif
#endif

}  // namespace

FloatEnvironmentScope::FloatEnvironmentScope() noexcept {
#if defined(TERRALIGN_FPSCR)
  const std::uint32_t fpscr = read_fpscr();
  std::memcpy(saved_, &fpscr, sizeof fpscr);
  write_fpscr(fpscr & ~kModeBits);
#else
  std::fenv_t env;
  std::fegetenv(&env);
  std::memcpy(saved_, &env, sizeof env);
  std::fesetenv(FE_DFL_ENV);
#if defined(TERRALIGN_MXCSR)
  _mm_setcsr(_mm_getcsr() & ~kMxcsrFlushBits);
#endif
#if defined(__aarch64__)
  write_fpcr(read_fpcr() & ~kFpcrModeBits);
#endif
#if defined(TERRALIGN_ARM32_FPSCR)
  write_fpscr(read_fpscr() & ~kModeBits);  // glibc's FE_DFL_ENV clears them; another's need not
#endif
#endif
}

FloatEnvironmentScope::~FloatEnvironmentScope() {
#if defined(TERRALIGN_FPSCR)
  std::uint32_t fpscr;
  std::memcpy(&fpscr, saved_, sizeof fpscr);
  write_fpscr(fpscr);
#else
  std::fenv_t env;
  std::memcpy(&env, saved_, sizeof env);
  std::fesetenv(&env);
#endif
}

bool float_environment_is_default() noexcept {
#if defined(TERRALIGN_FPSCR)
  return (read_fpscr() & kModeBits) == 0;
#else
  bool ok = std::fegetround() == FE_TONEAREST;
#if defined(TERRALIGN_MXCSR)
  // The exception masks (bits 7-12) all set: no SSE trap.
  ok = ok && (_mm_getcsr() & kMxcsrFlushBits) == 0 && (_mm_getcsr() & 0x1f80u) == 0x1f80u;
#endif
#if defined(__aarch64__)
  // The trap enables (IOE..IXE, bits 8-12, and IDE, bit 15) clear.
  ok = ok && (read_fpcr() & (kFpcrModeBits | (0x1fu << 8) | (1u << 15))) == 0;
#endif
#if defined(TERRALIGN_ARM32_FPSCR)
  // FZ, DN and AHP clear, and the trap enables (IOE..IXE, bits 8-12, and IDE, bit 15).
  ok = ok && (read_fpscr() & (kModeBits | (0x1fu << 8) | (1u << 15))) == 0;
#endif
  return ok;
#endif
}

HostileFloatEnvironment::HostileFloatEnvironment() noexcept {
#if defined(TERRALIGN_FPSCR)
  write_fpscr(read_fpscr() | (1u << 22) | (1u << 24) | (1u << 25));  // RMode +inf, FZ, DN
#else
  std::fesetround(FE_UPWARD);
#if defined(TERRALIGN_MXCSR)
  // Unmask invalid (bit 7) and divide-by-zero (bit 9): SSE traps on them.
  _mm_setcsr((_mm_getcsr() | kMxcsrFlushBits) & ~((1u << 7) | (1u << 9)));
#endif
#if defined(__aarch64__)
  // FZ and DN, and the trap enables IOE (bit 8) and DZE (bit 9): a core without traps keeps
  // those two zero.
  write_fpcr(read_fpcr() | (1ull << 24) | (1ull << 25) | (1ull << 8) | (1ull << 9));
#endif
#if defined(TERRALIGN_ARM32_FPSCR)
  // The same bits of FPSCR: FZ, DN, IOE and DZE (ARMv7-A cores without traps keep those zero).
  write_fpscr(read_fpscr() | (1u << 24) | (1u << 25) | (1u << 8) | (1u << 9));
#endif
#endif
}

HostileFloatEnvironment::~HostileFloatEnvironment() = default;

const char* HostileFloatEnvironment::description() noexcept {
#if defined(TERRALIGN_FPSCR)
#if defined(__ARM_FP)
  return "rounding upward, flush to zero, default NaN";
#else
  return "nothing (no FPU)";
#endif
#elif defined(TERRALIGN_MXCSR)
  return "rounding upward, flush to zero and denormals are zero, traps on FE_INVALID and FE_DIVBYZERO";
#elif defined(__aarch64__) || defined(TERRALIGN_ARM32_FPSCR)
  return "rounding upward, flush to zero, default NaN, traps on FE_INVALID and FE_DIVBYZERO where the core has them";
#else
  return "rounding upward";
#endif
}

}  // namespace terralign
