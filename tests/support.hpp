// Test helpers: where the sample data lives, and the shared (AGPL) data sets that are read
// in place and may be absent.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <string>
#include <sys/stat.h>

namespace terralign::test {

inline std::string source_path(const std::string& rel) {
  return std::string(TERRALIGN_SOURCE_DIR) + "/" + rel;
}

// ../shared/data beside the checkout, or $TERRALIGN_SHARED_DATA; "" when absent.
inline std::string shared_data(const std::string& rel) {
  const char* env = std::getenv("TERRALIGN_SHARED_DATA");
  const std::string root = env ? std::string(env) : std::string(TERRALIGN_SOURCE_DIR) + "/../shared/data";
  const std::string p = root + "/" + rel;
  struct stat st {};
  return ::stat(p.c_str(), &st) == 0 ? p : std::string();
}

// A scratch folder for a test's output files.
inline std::string temp_dir() {
  static std::string dir = [] {
    char tmpl[] = "/tmp/terralign-test-XXXXXX";
    const char* d = ::mkdtemp(tmpl);
    return std::string(d ? d : "/tmp");
  }();
  return dir;
}

// A file's whole contents ("" when it cannot be read).
inline std::string read_text(const std::string& path) {
  std::string text;
  if (std::FILE* f = std::fopen(path.c_str(), "rb")) {
    char buf[4096];
    for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) text.append(buf, n);
    std::fclose(f);
  }
  return text;
}

inline void write_text(const std::string& path, const std::string& text) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return;
  std::fwrite(text.data(), 1, text.size(), f);
  std::fclose(f);
}

}  // namespace terralign::test

// Skips the rest of a test case with a message when a shared data set is missing.
#define TERRALIGN_REQUIRE_SHARED(path_var, rel)                                          \
  const std::string path_var = ::terralign::test::shared_data(rel);                      \
  if (path_var.empty()) {                                                                \
    MESSAGE("skipped: ../shared/data/" rel " is not present (set TERRALIGN_SHARED_DATA)"); \
    return;                                                                              \
  }
