// terralign's weight container (.tlw): an architecture text and named float32 tensors,
// versioned and checksummed. Written by training/tlw.py; the layout is documented there.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <terralign/geo/result.hpp>

namespace terralign::nn {

constexpr std::uint32_t kWeightFormatVersion = 1;

struct TensorData {
  std::string name;
  std::vector<int> shape;
  std::vector<float> data;
  std::size_t size() const { return data.size(); }
  std::string shape_text() const;
};

struct WeightFile {
  std::string name;            // for messages (the path)
  std::uint32_t version = 0;
  std::string architecture;    // see network.hpp
  std::vector<TensorData> tensors;
  const TensorData* find(const std::string& tensor) const;
};

// Refuses, each with the file, the tensor and the numbers: a truncated file, a wrong magic,
// another format version, a checksum mismatch, a non-float32 tensor, a tensor whose data runs
// past the block, and a file larger than max_bytes.
Result<WeightFile> read_weights(const std::string& path, std::size_t max_bytes = std::size_t{1} << 30);
Result<WeightFile> parse_weights(const std::uint8_t* data, std::size_t size, const std::string& name);

// The weight file's checksum, 64-bit FNV-1a over n bytes; h continues a hash over earlier bytes.
std::uint64_t fnv1a64(const void* p, std::size_t n, std::uint64_t h = 0xcbf29ce484222325ull);

}  // namespace terralign::nn
