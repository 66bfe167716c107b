#include <terralign/nn/weights.hpp>

#include <terralign/geo/file.hpp>

#include <cstdio>
#include <cstring>

namespace terralign::nn {
namespace {

constexpr char kMagic[8] = {'T', 'L', 'N', 'N', 'W', 'G', 'T', '\0'};

// Little-endian reads with bounds checks.
struct Reader {
  const std::uint8_t* p;
  std::size_t n, at = 0;
  bool take(void* out, std::size_t k) {
    if (k > n - at) return false;
    std::memcpy(out, p + at, k);
    at += k;
    return true;
  }
  template <class T>
  bool get(T& v) {
    std::uint8_t b[sizeof(T)];
    if (!take(b, sizeof(T))) return false;
    std::uint64_t u = 0;
    for (std::size_t i = 0; i < sizeof(T); ++i) u |= std::uint64_t{b[i]} << (8 * i);
    v = static_cast<T>(u);
    return true;
  }
};

}  // namespace

std::uint64_t fnv1a64(const void* p, std::size_t n, std::uint64_t h) {
  const auto* b = static_cast<const std::uint8_t*>(p);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= b[i];
    h *= 0x100000001b3ull;
  }
  return h;
}

std::string TensorData::shape_text() const {
  std::string s = "[";
  for (std::size_t i = 0; i < shape.size(); ++i) s += (i ? ", " : "") + std::to_string(shape[i]);
  return s + "]";
}

const TensorData* WeightFile::find(const std::string& tensor) const {
  for (const auto& t : tensors)
    if (t.name == tensor) return &t;
  return nullptr;
}

Result<WeightFile> parse_weights(const std::uint8_t* data, std::size_t size, const std::string& name) {
  WeightFile wf;
  wf.name = name;
  auto truncated = [&](const char* what) { return Error{name + ": truncated weight file (ends inside " + what + ")"}; };
  if (size < 8 + 4) return truncated("the header");
  if (std::memcmp(data, kMagic, 8) != 0) return Error{name + ": not a terralign weight file (magic is not TLNNWGT)"};
  if (size < 8 + 4 + 8) return truncated("the header");
  // The checksum first: everything after it can then trust the byte counts less, not more.
  std::uint64_t stored = 0;
  for (int i = 0; i < 8; ++i) stored |= std::uint64_t{data[size - 8 + static_cast<std::size_t>(i)]} << (8 * i);
  Reader r{data, size - 8};
  r.at = 8;
  if (!r.get(wf.version)) return truncated("the version");
  if (wf.version != kWeightFormatVersion)
    return Error{name + ": weight format version " + std::to_string(wf.version) + ", this build reads version " +
                 std::to_string(kWeightFormatVersion)};
  const std::uint64_t actual = fnv1a64(data, size - 8);
  std::uint32_t arch_len = 0;
  if (!r.get(arch_len)) return truncated("the architecture length");
  if (arch_len > size) return truncated("the architecture text");
  wf.architecture.resize(arch_len);
  if (!r.take(&wf.architecture[0], arch_len)) return truncated("the architecture text");
  std::uint32_t count = 0;
  if (!r.get(count)) return truncated("the tensor count");
  if (count > 100000) return Error{name + ": " + std::to_string(count) + " tensors is implausible (corrupt file?)"};
  struct Entry {
    std::uint64_t offset, bytes;
  };
  std::vector<Entry> entries;
  for (std::uint32_t i = 0; i < count; ++i) {
    std::uint16_t nlen = 0;
    TensorData t;
    if (!r.get(nlen)) return truncated("a tensor name");
    t.name.resize(nlen);
    if (nlen && !r.take(&t.name[0], nlen)) return truncated("a tensor name");
    std::uint8_t dtype = 0, rank = 0;
    if (!r.get(dtype) || !r.get(rank)) return truncated(("tensor " + t.name).c_str());
    if (dtype != 1) return Error{name + ": tensor " + t.name + " has dtype " + std::to_string(dtype) + ", only 1 (float32) is read"};
    if (rank > 8) return Error{name + ": tensor " + t.name + " has rank " + std::to_string(rank) + ", over 8"};
    std::uint64_t elems = 1;
    for (int k = 0; k < rank; ++k) {
      std::uint32_t d = 0;
      if (!r.get(d)) return truncated(("tensor " + t.name).c_str());
      if (d == 0 || d > (1u << 28)) return Error{name + ": tensor " + t.name + " has dimension " + std::to_string(d)};
      t.shape.push_back(static_cast<int>(d));
      elems *= d;
      if (elems > (std::uint64_t{1} << 31)) return Error{name + ": tensor " + t.name + " is too large"};
    }
    Entry e{};
    if (!r.get(e.offset) || !r.get(e.bytes)) return truncated(("tensor " + t.name).c_str());
    if (e.bytes != elems * 4)
      return Error{name + ": tensor " + t.name + " " + t.shape_text() + " holds " + std::to_string(e.bytes) +
                   " bytes, its shape needs " + std::to_string(elems * 4)};
    entries.push_back(e);
    wf.tensors.push_back(std::move(t));
  }
  std::uint64_t data_len = 0;
  if (!r.get(data_len)) return truncated("the data length");
  if (data_len != r.n - r.at)
    return Error{name + ": truncated weight file (the data block should hold " + std::to_string(data_len) + " bytes, " +
                 std::to_string(r.n - r.at) + " remain)"};
  if (stored != actual) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "checksum mismatch (stored %016llx, computed %016llx)",
                  static_cast<unsigned long long>(stored), static_cast<unsigned long long>(actual));
    return Error{name + ": " + buf};
  }
  const std::uint8_t* block = data + r.at;
  for (std::size_t i = 0; i < wf.tensors.size(); ++i) {
    const Entry& e = entries[i];
    if (e.offset > data_len || e.bytes > data_len - e.offset)
      return Error{name + ": tensor " + wf.tensors[i].name + " runs past the data block"};
    auto& t = wf.tensors[i];
    t.data.resize(e.bytes / 4);
    for (std::size_t k = 0; k < t.data.size(); ++k) {
      const std::uint8_t* b = block + e.offset + 4 * k;
      const std::uint32_t u = std::uint32_t{b[0]} | std::uint32_t{b[1]} << 8 | std::uint32_t{b[2]} << 16 | std::uint32_t{b[3]} << 24;
      std::memcpy(&t.data[k], &u, 4);
    }
  }
  return wf;
}

Result<WeightFile> read_weights(const std::string& path, std::size_t max_bytes) {
  TERRALIGN_TRY_ASSIGN(const auto bytes, geo::read_file(path, max_bytes));
  return parse_weights(bytes.data(), bytes.size(), path);
}

}  // namespace terralign::nn
