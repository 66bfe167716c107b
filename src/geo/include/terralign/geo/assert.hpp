// One assertion macro for programming errors (not for bad input: that is a Result).
//
// TERRALIGN_ASSERT is on unless TERRALIGN_DISABLE_ASSERTS is defined. A failure calls the
// handler, which by default prints the message and aborts; an embedding application may
// route it elsewhere (an onboard computer's fault log) with set_assert_handler().
// TERRALIGN_DEBUG_ASSERT is for bounds checks on hot paths: on only in debug builds.
#pragma once

namespace terralign {

using AssertHandler = void (*)(const char* expr, const char* message, const char* file,
                               int line);

// Installs a handler and returns the previous one. The handler must not return.
AssertHandler set_assert_handler(AssertHandler handler);

[[noreturn]] void assert_failed(const char* expr, const char* message, const char* file,
                                int line);

}  // namespace terralign

#ifdef TERRALIGN_DISABLE_ASSERTS
#define TERRALIGN_ASSERT(cond, msg) ((void)0)
#else
#define TERRALIGN_ASSERT(cond, msg) \
  ((cond) ? (void)0 : ::terralign::assert_failed(#cond, msg, __FILE__, __LINE__))
#endif

#ifndef NDEBUG
#define TERRALIGN_DEBUG_ASSERT(cond, msg) TERRALIGN_ASSERT(cond, msg)
#else
#define TERRALIGN_DEBUG_ASSERT(cond, msg) ((void)0)
#endif
