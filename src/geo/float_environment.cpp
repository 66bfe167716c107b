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
#if defined(__aarch64__) || (defined(__arm__) && defined(__ARM_FP))
#define TERRALIGN_ARM_LINUX 1  // FPCR's or FPSCR's FZ, DN and AHP beside <fenv.h>
#endif
#endif

namespace terralign {
namespace {

#if defined(TERRALIGN_FPSCR) || defined(TERRALIGN_ARM_LINUX)
// ARM's control register, FPSCR on 32-bit cores and FPCR on AArch64, places these alike: RMode
// (bits 22-23, 0: to nearest), FZ (24), DN (25), AHP (26), AArch64's FZ16 (19), and the trap
// enables IOE..IXE (8-12) and IDE (15).
#if defined(__aarch64__)
using ArmControl = std::uint64_t;
constexpr ArmControl kModeBits = (3u << 22) | (1u << 24) | (1u << 25) | (1u << 26) | (1u << 19);
#else
using ArmControl = std::uint32_t;
constexpr ArmControl kModeBits = (3u << 22) | (1u << 24) | (1u << 25) | (1u << 26);
#endif
constexpr ArmControl kTrapBits = (0x1fu << 8) | (1u << 15);

ArmControl read_arm_control() {
  ArmControl v = 0;  // no FPU: software floating point rounds to nearest and keeps subnormals
#if defined(__aarch64__)
  __asm__ volatile("mrs %0, fpcr" : "=r"(v));
#elif defined(__ARM_FP)
  __asm__ volatile("vmrs %0, fpscr" : "=r"(v));
#endif
  return v;
}

void write_arm_control([[maybe_unused]] ArmControl v) {
#if defined(__aarch64__)
  __asm__ volatile("msr fpcr, %0" : : "r"(v) : "memory");
#elif defined(__ARM_FP)
  __asm__ volatile("vmsr fpscr, %0" : : "r"(v) : "memory");
#endif
}
#endif
#if !defined(TERRALIGN_FPSCR)
static_assert(sizeof(std::fenv_t) <= 64, "FloatEnvironmentScope::saved_ is too small for this C library's fenv_t");
#endif
#if defined(TERRALIGN_MXCSR)
constexpr unsigned kMxcsrFlushBits = 0x8040u;  // FTZ (bit 15) and DAZ (bit 6)
#endif

}  // namespace

FloatEnvironmentScope::FloatEnvironmentScope() noexcept {
#if defined(TERRALIGN_FPSCR)
  const ArmControl fpscr = read_arm_control();
  std::memcpy(saved_, &fpscr, sizeof fpscr);
  write_arm_control(fpscr & ~kModeBits);
#else
  std::fenv_t env;
  std::fegetenv(&env);
  std::memcpy(saved_, &env, sizeof env);
  std::fesetenv(FE_DFL_ENV);
#if defined(TERRALIGN_MXCSR)
  _mm_setcsr(_mm_getcsr() & ~kMxcsrFlushBits);
#endif
#if defined(TERRALIGN_ARM_LINUX)
  // glibc's FE_DFL_ENV keeps AArch64's DN and AHP (32-bit ARM's it clears; another C library's
  // need not).
  write_arm_control(read_arm_control() & ~kModeBits);
#endif
#endif
}

FloatEnvironmentScope::~FloatEnvironmentScope() {
#if defined(TERRALIGN_FPSCR)
  ArmControl fpscr;
  std::memcpy(&fpscr, saved_, sizeof fpscr);
  write_arm_control(fpscr);
#else
  std::fenv_t env;
  std::memcpy(&env, saved_, sizeof env);
  std::fesetenv(&env);
#endif
}

bool float_environment_is_default() noexcept {
#if defined(TERRALIGN_FPSCR)
  return (read_arm_control() & kModeBits) == 0;
#else
  bool ok = std::fegetround() == FE_TONEAREST;
#if defined(TERRALIGN_MXCSR)
  // The exception masks (bits 7-12) all set: no SSE trap.
  ok = ok && (_mm_getcsr() & kMxcsrFlushBits) == 0 && (_mm_getcsr() & 0x1f80u) == 0x1f80u;
#endif
#if defined(TERRALIGN_ARM_LINUX)
  ok = ok && (read_arm_control() & (kModeBits | kTrapBits)) == 0;
#endif
  return ok;
#endif
}

HostileFloatEnvironment::HostileFloatEnvironment() noexcept {
#if defined(TERRALIGN_FPSCR)
  // RMode toward +infinity, FZ and DN.
  write_arm_control(read_arm_control() | (1u << 22) | (1u << 24) | (1u << 25));
#else
  std::fesetround(FE_UPWARD);
#if defined(TERRALIGN_MXCSR)
  // Unmask invalid (bit 7) and divide-by-zero (bit 9): SSE traps on them.
  _mm_setcsr((_mm_getcsr() | kMxcsrFlushBits) & ~((1u << 7) | (1u << 9)));
#endif
#if defined(TERRALIGN_ARM_LINUX)
  // FZ and DN, and the trap enables IOE (bit 8) and DZE (bit 9): a core without traps (most
  // ARMv7-A cores) keeps those two zero.
  write_arm_control(read_arm_control() | (1u << 24) | (1u << 25) | (1u << 8) | (1u << 9));
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
#elif defined(TERRALIGN_ARM_LINUX)
  return "rounding upward, flush to zero, default NaN, traps on FE_INVALID and FE_DIVBYZERO where the core has them";
#else
  return "rounding upward";
#endif
}

}  // namespace terralign
