// PFM reader.
#include <cstdint>

#include <terralign/geo/image_io.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  (void)terralign::geo::decode_pfm(data, size, "fuzz.pfm");
  return 0;
}
