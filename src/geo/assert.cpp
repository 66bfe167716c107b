#include <terralign/geo/assert.hpp>

#include <cstdio>
#include <cstdlib>

namespace terralign {
namespace {
void default_handler(const char* expr, const char* message, const char* file, int line) {
  std::fprintf(stderr, "terralign: assertion failed: %s (%s) at %s:%d\n", message, expr, file, line);
  std::abort();
}
AssertHandler g_handler = default_handler;
}  // namespace

AssertHandler set_assert_handler(AssertHandler handler) {
  AssertHandler old = g_handler;
  g_handler = handler ? handler : default_handler;
  return old;
}

void assert_failed(const char* expr, const char* message, const char* file, int line) {
  g_handler(expr, message, file, line);
  std::abort();  // a handler must not return
}

}  // namespace terralign
