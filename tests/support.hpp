// Test helpers: where the sample data lives, and the shared (AGPL) data sets that are read
// in place and may be absent.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <system_error>
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

// A scratch folder for a test's output files, one a test process, removed with everything
// in it when the process exits normally (each ctest entry is a process; a flight's frames
// take about 10 MB). TERRALIGN_KEEP_TEST_FILES=1 keeps it to look at; a test that crashed
// leaves it too. Where no folder can be made the tests write into /tmp itself, which is
// never removed.
inline std::string temp_dir() {
  struct Scratch {
    std::string path;
    bool made = false;
    Scratch() {
      char tmpl[] = "/tmp/terralign-test-XXXXXX";
      const char* d = ::mkdtemp(tmpl);
      made = d != nullptr;
      path = made ? std::string(d) : std::string("/tmp");
    }
    ~Scratch() {
      const char* keep = std::getenv("TERRALIGN_KEEP_TEST_FILES");
      if (!made || (keep && *keep && std::string(keep) != "0")) return;
      std::error_code ec;
      std::filesystem::remove_all(path, ec);  // best effort: a leftover folder fails no test
    }
  };
  static const Scratch scratch;
  return scratch.path;
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
