#include <terralign/geo/file.hpp>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <sys/stat.h>
#include <unistd.h>

namespace terralign::geo {

Result<std::vector<std::uint8_t>> read_file(const std::string& path, std::size_t max_bytes) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0)
    return Error{path + ": cannot open (" + std::strerror(errno) + ")"};
  if (S_ISDIR(st.st_mode)) return Error{path + ": is a directory, not a file"};
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) return Error{path + ": cannot open (" + std::strerror(errno) + ")"};
  std::vector<std::uint8_t> bytes;
  std::uint8_t buf[1 << 16];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) {
    if (bytes.size() + n > max_bytes) {
      std::fclose(f);
      return Error{path + ": file is larger than the limit of " + std::to_string(max_bytes) + " bytes"};
    }
    bytes.insert(bytes.end(), buf, buf + n);
  }
  const bool failed = std::ferror(f) != 0;
  std::fclose(f);
  if (failed) return Error{path + ": read error"};
  return bytes;
}

namespace {

std::string temporary_name(const std::string& path) { return path + ".tmp-" + std::to_string(::getpid()); }

}  // namespace

Status check_writable(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode)) return Error{path + ": is a directory, not a file"};
  const std::string tmp = temporary_name(path);
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) return Error{path + ": cannot write (" + std::strerror(errno) + ")"};
  std::fclose(f);
  std::remove(tmp.c_str());
  return Ok{};
}

Status write_file_atomic(const std::string& path, const void* data, std::size_t size) {
  const std::string tmp = temporary_name(path);
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) return Error{path + ": cannot write (" + std::strerror(errno) + ")"};
  const bool written = size == 0 || std::fwrite(data, 1, size, f) == size;
  const bool closed = std::fclose(f) == 0;
  if (!written || !closed) {
    std::remove(tmp.c_str());
    return Error{path + ": write failed (disk full?)"};
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    std::remove(tmp.c_str());
    return Error{path + ": cannot replace (" + why + ")"};
  }
  return Ok{};
}

}  // namespace terralign::geo
