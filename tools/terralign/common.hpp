// Shared by the sub-commands: error reporting.
#pragma once

#include <cstdio>
#include <string>

#include <terralign/geo/result.hpp>

namespace terralign::cli {

inline int fail(const Error& e) {
  std::fprintf(stderr, "terralign: %s\n", e.message.c_str());
  return 1;
}

inline int usage_error(const char* command, const Error& e) {
  std::fprintf(stderr, "terralign %s: %s (see terralign %s --help)\n", command, e.message.c_str(), command);
  return 2;
}

}  // namespace terralign::cli
