// Whole-file reads and atomic writes.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <terralign/geo/result.hpp>

namespace terralign::geo {

// The default limit of read_file: 4 GiB, or 1 GiB where size_t is 32 bits (a 32-bit process
// has 2-4 GiB of address space; 4 GiB would wrap to 0 there and refuse every file).
inline constexpr std::size_t kMaxFileBytes =
    sizeof(std::size_t) >= 8 ? static_cast<std::size_t>(std::uint64_t{4} << 30) : std::size_t{1} << 30;

// Reads a whole file; refuses one over max_bytes.
Result<std::vector<std::uint8_t>> read_file(const std::string& path, std::size_t max_bytes = kMaxFileBytes);

// Writes to path + ".tmp-<pid>" and renames it over path, so that a failed or interrupted
// write never leaves a half file where a good one was.
Status write_file_atomic(const std::string& path, const void* data, std::size_t size);

// Whether write_file_atomic(path, ...) could write there now: path is not a folder, and its
// temporary file can be made (and is removed again) in path's folder. For a program that
// writes its result after minutes of work, to refuse a mistyped path before the work.
Status check_writable(const std::string& path);

}  // namespace terralign::geo
