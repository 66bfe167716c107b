// Weight container (.tlw) reader, then the architecture text and the network plan and one
// forward pass at 16 x 16 for every network the file describes.
#include <cstdint>

#include <terralign/nn/network.hpp>
#include <terralign/nn/weights.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace terralign::nn;
  auto w = parse_weights(data, size, "fuzz.tlw");
  if (!w.ok()) return 0;
  auto nets = parse_architecture(w->architecture, w->name);
  if (!nets.ok()) return 0;
  for (const auto& d : nets.value()) {
    auto net = Network::plan(w.value(), d.name, 16, 16, 1, Simd::Scalar);
    if (net.ok()) net.value()->forward();
  }
  return 0;
}
