// Whole-file reads and atomic writes.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <terralign/geo/result.hpp>

namespace terralign::geo {

// Reads a whole file; refuses one over max_bytes.
Result<std::vector<std::uint8_t>> read_file(const std::string& path,
                                            std::size_t max_bytes = std::size_t{4} << 30);

// Writes to path + ".tmp-<pid>" and renames it over path, so that a failed or interrupted
// write never leaves a half file where a good one was.
Status write_file_atomic(const std::string& path, const void* data, std::size_t size);

}  // namespace terralign::geo
