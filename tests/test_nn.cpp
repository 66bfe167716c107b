#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <tuple>

#include <doctest/doctest.h>

#include <terralign/geo/file.hpp>
#include <terralign/nn/network.hpp>

#include "alloc_counter.hpp"
#include "support.hpp"

using namespace terralign;
using namespace terralign::nn;

namespace {

WeightFile load(const char* rel) {
  auto w = read_weights(test::source_path(rel));
  REQUIRE(w.ok());
  return std::move(w.value());
}

// Same size and the same bits in every pixel's channels (halo and padding aside).
bool same_pixels(const Tensor& a, const Tensor& b) {
  if (a.h != b.h || a.w != b.w || a.c != b.c) return false;
  for (int y = 0; y < a.h; ++y)
    for (int x = 0; x < a.w; ++x)
      if (std::memcmp(a.at(y, x), b.at(y, x), sizeof(float) * static_cast<std::size_t>(a.c)) != 0) return false;
  return true;
}

// A kernel's rows [y0, y1) with scratch of their own.
void conv(ConvRowsFn fn, const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1) {
  std::vector<float> scratch(conv_scratch_floats(w));
  fn(in, w, out, y0, y1, scratch.data());
}

// Every convolution kernel this build and CPU have: name, function, weight block.
std::vector<std::tuple<const char*, ConvRowsFn, int>> conv_kernels() {
  std::vector<std::tuple<const char*, ConvRowsFn, int>> k{{"scalar", conv3x3_rows_scalar, 8}};
#if defined(TERRALIGN_NN_AVX2)
  if (nn_cpu_has_avx2()) k.emplace_back("avx2", conv3x3_rows_avx2, 8);
  if (nn_cpu_has_avx512()) k.emplace_back("avx512", conv3x3_rows_avx512, 16);
#endif
#if defined(TERRALIGN_NN_NEON)
  k.emplace_back("neon", conv3x3_rows_neon, 8);
#endif
  return k;
}

double worst_difference(const Tensor& a, const Tensor& b, double& scale) {
  double worst = 0;
  scale = 0;
  for (int y = 0; y < a.h; ++y)
    for (int x = 0; x < a.w; ++x)
      for (int k = 0; k < a.c; ++k) {
        worst = std::max(worst, double(std::abs(a.at(y, x)[k] - b.at(y, x)[k])));
        scale = std::max(scale, double(std::abs(a.at(y, x)[k])));
      }
  return worst;
}

// Copies channels [c0, c0 + c) of a C x H x W tensor into channels [at, at + c) of t.
void fill(Tensor& t, const TensorData& chw, int at) {
  const int c = chw.shape[0], h = chw.shape[1], w = chw.shape[2];
  REQUIRE((h == t.h && w == t.w));
  for (int k = 0; k < c; ++k)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) t.at(y, x)[at + k] = chw.data[(static_cast<std::size_t>(k) * h + y) * w + x];
}

// Normalised mean squared error of channels of t against a C x H x W reference.
double nmse(const Tensor& t, const TensorData& ref) {
  const int c = ref.shape[0], h = ref.shape[1], w = ref.shape[2];
  REQUIRE((h == t.h && w == t.w && c == t.c));
  double num = 0, den = 0;
  for (int k = 0; k < c; ++k)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const double r = ref.data[(static_cast<std::size_t>(k) * h + y) * w + x];
        const double d = t.at(y, x)[k] - r;
        num += d * d;
        den += r * r;
      }
  return num / den;
}

// Serialises a WeightFile as training/tlw.py does, for the bad-input cases.
std::vector<std::uint8_t> serialise(const WeightFile& wf, std::uint32_t version = 1) {
  std::vector<std::uint8_t> out;
  auto put = [&](const void* p, std::size_t n) { out.insert(out.end(), static_cast<const std::uint8_t*>(p), static_cast<const std::uint8_t*>(p) + n); };
  auto u = [&](std::uint64_t v, int bytes) { for (int i = 0; i < bytes; ++i) out.push_back(static_cast<std::uint8_t>(v >> (8 * i))); };
  put("TLNNWGT", 8);
  u(version, 4);
  u(wf.architecture.size(), 4);
  put(wf.architecture.data(), wf.architecture.size());
  u(wf.tensors.size(), 4);
  std::vector<std::uint8_t> blob;
  for (const auto& t : wf.tensors) {
    while (blob.size() % 16) blob.push_back(0);
    u(t.name.size(), 2);
    put(t.name.data(), t.name.size());
    u(1, 1);
    u(t.shape.size(), 1);
    for (int d : t.shape) u(static_cast<std::uint64_t>(d), 4);
    u(blob.size(), 8);
    u(t.data.size() * 4, 8);
    const auto* p = reinterpret_cast<const std::uint8_t*>(t.data.data());
    blob.insert(blob.end(), p, p + t.data.size() * 4);
  }
  u(blob.size(), 8);
  out.insert(out.end(), blob.begin(), blob.end());
  u(fnv1a64(out.data(), out.size()), 8);
  return out;
}

std::string plan_error(const WeightFile& wf) {
  auto bytes = serialise(wf);
  auto parsed = parse_weights(bytes.data(), bytes.size(), "edited.tlw");
  if (!parsed.ok()) return parsed.error().message;
  auto n = Network::plan(parsed.value(), "encoder", 32, 32, 1);
  return n.ok() ? std::string("(planned)") : n.error().message;
}

}  // namespace

TEST_CASE("parity with PyTorch: Lv et al.'s encoder and M-estimator reproduce every level with NMSE <= 1e-7") {
  const WeightFile weights = load("weights/lv19_tum_abc.tlw");
  const WeightFile ref = load("tests/data/nn/lv19_tum_parity.tlw");
  for (Simd simd : {Simd::Scalar, Simd::Avx2, Simd::Avx512, Simd::Neon}) {
    if ((simd == Simd::Avx2 && !nn_cpu_has_avx2()) || (simd == Simd::Avx512 && !nn_cpu_has_avx512()) ||
        (simd == Simd::Neon && !nn_cpu_has_neon()))
      continue;
    auto enc = Network::plan(weights, "encoder", 160, 120, 2, simd);
    REQUIRE(enc.ok());
    MESSAGE("conv kernels: " << std::string(enc.value()->simd_name()));
    // Frame a: its own input, then the other frame's; frame b the other way round.
    std::vector<std::vector<float>> mean_out[2];
    Tensor f[2][4];
    for (int frame = 0; frame < 2; ++frame) {
      Tensor* x = enc.value()->input("x");
      REQUIRE(x);
      fill(*x, *ref.find(frame == 0 ? "in_a" : "in_b"), 0);
      fill(*x, *ref.find(frame == 0 ? "in_b" : "in_a"), 4);
      enc.value()->forward();
      const char* tag = frame == 0 ? "a" : "b";
      for (int l = 0; l < 4; ++l) {
        const Tensor* out = enc.value()->output("f" + std::to_string(l));
        REQUIRE(out);
        const double e = nmse(*out, *ref.find(std::string("f") + tag + std::to_string(l)));
        CAPTURE(l);
        CHECK(e <= 1e-7);
        f[frame][l] = *out;
      }
      const double e3 = nmse(*enc.value()->output("e3_2"), *ref.find(std::string("e") + tag + "3"));
      CHECK(e3 <= 1e-7);
      MESSAGE("frame " << std::string(tag) << ": level-3 features NMSE " << e3);
    }
    // The M-estimator, coarse to fine, on r = f_b - f_a with the previous weight upsampled.
    Tensor w_prev;
    for (int l = 3; l >= 0; --l) {
      const int h = f[0][l].h, w = f[0][l].w;
      auto mest = Network::plan(weights, "mestimator", w, h, 2, simd);
      REQUIRE(mest.ok());
      Tensor* x = mest.value()->input("x");
      Tensor up;
      up.allocate(h, w, 1);
      if (l == 3) {
        for (int y = 0; y < h; ++y)
          for (int xx = 0; xx < w; ++xx) up.at(y, xx)[0] = 1.0f;
      } else {
        upsample2_rows(w_prev, up, 0, h);
      }
      for (int y = 0; y < h; ++y)
        for (int xx = 0; xx < w; ++xx) {
          const float a = f[0][l].at(y, xx)[0], b = f[1][l].at(y, xx)[0];
          float* p = x->at(y, xx);
          p[0] = std::abs(b - a);
          p[1] = a;
          p[2] = b;
          p[3] = up.at(y, xx)[0];
        }
      mest.value()->forward();
      const double e = nmse(*mest.value()->output("w"), *ref.find("w" + std::to_string(l)));
      CAPTURE(l);
      CHECK(e <= 1e-7);
      w_prev = *mest.value()->output("w");
    }
  }
}

TEST_CASE("every build of the convolution gives the scalar build's bits: direct, Winograd F(2x2) and F(4x4), one output channel, every activation") {
  // The builds do the same operations in the same order (multiply-adds rounded once, ELU's exp
  // one polynomial, the one-channel kernel's eight lanes summed one way), so on any CPU each
  // gives the bytes of the scalar build, which is plain IEEE arithmetic and gives the same
  // bytes on every machine: x86-64's builds and aarch64's give the same bytes. Shapes: the
  // colour input (3), channel counts that fill no vector (5, 13, 37), one output channel with
  // and without a tail of channels past the last eight (13, 16, 24, 64), at dilations 1, 2, 4
  // on 13 x 29 (whole and partial register tiles, Winograd tiles past the edges).
  const auto kernels = conv_kernels();
  if (kernels.size() == 1) MESSAGE("only the scalar build on this CPU: nothing to compare");
  std::mt19937 rng(99);
  std::normal_distribution<float> n01(0, 1);
  int compared = 0;
  for (int dil : {1, 2, 4})
    for (const auto& shape : {std::pair<int, int>{3, 5}, {16, 32}, {37, 24}, {13, 1}, {16, 1}, {24, 1}, {64, 1}})
      for (Act act : {Act::Elu, Act::Relu, Act::None})
        for (int tile : {0, 2, 4}) {
          // Plain copies: CAPTURE's lambda may not capture a structured binding in C++17 (clang).
          const int cin = shape.first, cout = shape.second;
          const int wino = winograd_suits(cin, cout) ? tile : 0;
          if (tile != wino) continue;
          CAPTURE(dil);
          CAPTURE(cin);
          CAPTURE(cout);
          CAPTURE(static_cast<int>(act));
          CAPTURE(wino);
          Tensor in, a, b;
          in.allocate(13, 29, cin);
          a.allocate(13, 29, cout);
          b.allocate(13, 29, cout);
          for (int y = 0; y < 13; ++y)
            for (int x = 0; x < 29; ++x)
              for (int c = 0; c < cin; ++c) in.at(y, x)[c] = n01(rng);
          std::vector<float> wt(static_cast<std::size_t>(cout) * cin * 9), bias(static_cast<std::size_t>(cout));
          for (auto& v : wt) v = n01(rng) * 0.2f;
          for (auto& v : bias) v = n01(rng);
          conv(conv3x3_rows_scalar, in, pack_conv(wt.data(), bias.data(), cin, cout, dil, act, 8, wino), a, 0, 13);
          if (cout == 1) {  // the one-channel kernel (vectors along the input) against the block kernel
            ConvWeights blk = pack_conv(wt.data(), bias.data(), cin, cout, dil, act);
            blk.taps.clear();
            conv(conv3x3_rows_scalar, in, blk, b, 0, 13);
            double scale = 0;
            const double worst = worst_difference(a, b, scale);
            CHECK(worst <= 1e-5 * std::max(scale, 1.0));  // the same sum in another order
          }
          for (std::size_t k = 1; k < kernels.size(); ++k) {
            const auto& [kernel, fn, block] = kernels[k];
            const char* const name = kernel;
            CAPTURE(name);
            b.allocate(13, 29, cout);
            conv(fn, in, pack_conv(wt.data(), bias.data(), cin, cout, dil, act, block, wino), b, 0, 13);
            CHECK(same_pixels(a, b));
            ++compared;
          }
        }
  MESSAGE(compared << " layers compared bit for bit with the scalar build");
}

TEST_CASE("subnormal values: every build of the convolution keeps them as the scalar build does, but 32-bit ARM's NEON") {
  // Inputs of about 1e-38 and biases of zero, so that inputs, products, sums and outputs fall
  // on both sides of the smallest normal float, 2^-126 (about 1.2e-38). x86-64's vector units
  // and AArch64's NEON keep subnormals in the default floating-point environment (which every
  // onboard entry sets: FloatEnvironmentScope), as the scalar build does. 32-bit ARM's NEON
  // flushes them to zero whatever FPSCR says: there the kernels differ from the scalar build
  // in such values alone (simd_neon.hpp), which is printed, not checked.
  std::mt19937 rng(5);
  std::normal_distribution<float> n01(0, 1);
  int subnormal_outputs = 0;
  for (Act act : {Act::None, Act::Elu})
    for (int tile : {0, 4}) {
      const int cin = 16, cout = 16;
      CAPTURE(static_cast<int>(act));
      CAPTURE(tile);
      Tensor in, a, b;
      in.allocate(7, 11, cin);
      a.allocate(7, 11, cout);
      for (int y = 0; y < 7; ++y)
        for (int x = 0; x < 11; ++x)
          for (int c = 0; c < cin; ++c) in.at(y, x)[c] = n01(rng) * 1e-38f;
      std::vector<float> wt(static_cast<std::size_t>(cout) * cin * 9), bias(static_cast<std::size_t>(cout), 0.0f);
      for (auto& v : wt) v = n01(rng) * 0.2f;
      conv(conv3x3_rows_scalar, in, pack_conv(wt.data(), bias.data(), cin, cout, 1, act, 8, tile), a, 0, 7);
      for (int y = 0; y < 7; ++y)
        for (int x = 0; x < 11; ++x)
          for (int c = 0; c < cout; ++c)
            if (std::fpclassify(a.at(y, x)[c]) == FP_SUBNORMAL) ++subnormal_outputs;
      for (const auto& [kernel, fn, block] : conv_kernels()) {
        const char* const name = kernel;  // CAPTURE may not capture a structured binding (C++17)
        CAPTURE(name);
        b.allocate(7, 11, cout);
        conv(fn, in, pack_conv(wt.data(), bias.data(), cin, cout, 1, act, block, tile), b, 0, 7);
#if defined(__arm__)
        if (std::strcmp(name, "neon") == 0) {
          MESSAGE("32-bit ARM's NEON, act " << static_cast<int>(act) << ", Winograd tile " << tile << ": "
                                            << std::string(same_pixels(a, b) ? "the scalar bits" : "other bits (flushed)"));
          continue;
        }
#endif
        CHECK(same_pixels(a, b));
      }
    }
  CHECK(subnormal_outputs > 100);  // the case reaches what it is about
}

TEST_CASE("Winograd's convolutions, F(2x2) and F(4x4), agree with the direct kernel in every build, at every dilation, with tiles past the edges, in bands split anywhere") {
  // 11 x 17 leaves tiles that reach past the bottom and right edges at every dilation (past
  // the halo, so read from gathered patches, at dilations 2 and 4), and the split at row 5
  // cuts a row group at every dilation (both bands compute that tile whole). Winograd sums
  // (m + 2)^2 transformed products instead of 9 taps, through transforms whose terms cancel:
  // the two differ by rounding, a few units in the last place of the largest partial sums.
  // Measured (session 69, scalar and AVX2): at most 8.0e-7 of the output's scale for F(2x2)
  // (8.6e-7 with AVX-512 before), 4.9e-6 for F(4x4) (its transforms scale terms by up to 200);
  // bounded by 5e-6 and 2e-5. A wrong tap, sign or offset would be of the order of the output.
  std::mt19937 rng(17);
  std::normal_distribution<float> n01(0, 1);
  const int h = 11, w = 17;
  double worst_of[5] = {0, 0, 0, 0, 0};
  for (const auto& [kernel, fn, block] : conv_kernels())
    for (int tile : {2, 4})
      for (int dil : {1, 2, 4})
        for (const auto& shape : {std::pair<int, int>{16, 5}, {16, 16}, {37, 24}, {32, 32}}) {
          // Plain copies: CAPTURE's lambda may not capture a structured binding in C++17 (clang).
          const char* const name = kernel;
          const int cin = shape.first, cout = shape.second;
          CAPTURE(name);
          CAPTURE(tile);
          CAPTURE(dil);
          CAPTURE(cin);
          CAPTURE(cout);
          Tensor in, direct, wino, split;
          in.allocate(h, w, cin);
          for (Tensor* t : {&direct, &wino, &split}) t->allocate(h, w, cout);
          for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
              for (int c = 0; c < cin; ++c) in.at(y, x)[c] = n01(rng);
          std::vector<float> wt(static_cast<std::size_t>(cout) * cin * 9), bias(static_cast<std::size_t>(cout));
          for (auto& v : wt) v = n01(rng) * 0.2f;
          for (auto& v : bias) v = n01(rng);
          const ConvWeights cw = pack_conv(wt.data(), bias.data(), cin, cout, dil, Act::Elu, block, tile);
          REQUIRE(!cw.winograd.empty());
          CHECK(cw.packed.empty());  // the direct kernel's copy is not kept
          CHECK(conv_row_align(cw) == tile * dil);
          const ConvWeights dw = pack_conv(wt.data(), bias.data(), cin, cout, dil, Act::Elu, block, 0);
          CHECK(dw.winograd.empty());
          CHECK(conv_row_align(dw) == 1);
          conv(fn, in, dw, direct, 0, h);
          conv(fn, in, cw, wino, 0, h);
          double scale = 0;
          const double worst = worst_difference(direct, wino, scale);
          worst_of[tile] = std::max(worst_of[tile], worst / std::max(scale, 1.0));
          CHECK(worst <= (tile == 2 ? 5e-6 : 2e-5) * std::max(scale, 1.0));
          CHECK(worst > 0);  // Winograd ran: its rounding differs from the direct sum's somewhere
          // Every split gives the same bytes as one band: on multiples of conv_row_align(),
          // and inside a row group (whose tile both bands compute whole).
          const int a = conv_row_align(cw);
          for (int cut : {a, 5}) {
            CAPTURE(cut);
            split.allocate(h, w, cout);  // zeros: both bands must write every row
            conv(fn, in, cw, split, 0, cut);
            conv(fn, in, cw, split, cut, h);
            CHECK(same_pixels(split, wino));
          }
        }
  MESSAGE("worst |Winograd - direct| / scale: F(2x2) " << worst_of[2] << ", F(4x4) " << worst_of[4]);
}

TEST_CASE("the layers Winograd suits (16 input channels or more, more than one output) and the scratch they need") {
  CHECK(!winograd_suits(3, 16));  // the colour input: its transforms would cost more than they save
  CHECK(!winograd_suits(8, 16));
  CHECK(winograd_suits(16, 16));
  CHECK(winograd_suits(512, 2));
  CHECK(!winograd_suits(16, 1));  // the one-channel kernel's layer
  std::vector<float> wt(9 * 32 * 16, 0.1f), bias(16, 0.0f);
  const ConvWeights direct = pack_conv(wt.data(), bias.data(), 3, 16, 1, Act::Elu);
  CHECK(direct.winograd.empty());
  CHECK(!direct.packed.empty());
  CHECK(conv_scratch_floats(direct) == 0);
  // The transformed inputs of 6 tiles ((m + 2)^2 x 6 x 32), the products of a register tile's
  // output channels (16 blocks: 64, 8 blocks: 16; (m + 2)^2 x 6 x channels) and 6 tiles'
  // gathered patches ((m + 2)^2 x 6 x 32).
  CHECK(conv_scratch_floats(pack_conv(wt.data(), bias.data(), 32, 16, 2, Act::Elu, 16, 2)) == 16 * 6 * (32 + 64 + 32));
  CHECK(conv_scratch_floats(pack_conv(wt.data(), bias.data(), 32, 16, 2, Act::Elu, 16)) == 36 * 6 * (32 + 64 + 32));
  CHECK(conv_scratch_floats(pack_conv(wt.data(), bias.data(), 32, 16, 2, Act::Elu, 8)) == 36 * 6 * (32 + 16 + 32));
}

TEST_CASE("a forward pass gives the same bytes on 1 and 2 threads and on a pool shared with another network, and allocates nothing") {
  const WeightFile weights = load("weights/lv19_tum_abc.tlw");
  auto one = Network::plan(weights, "encoder", 97, 61, 1);
  auto two = Network::plan(weights, "encoder", 97, 61, 2);
  // Three threads (other bands) of a pool the M-estimator also runs on, in turn.
  ThreadPool pool(3);
  auto shared = Network::plan(weights, "encoder", 97, 61, 2, Simd::Auto, Memory::Shared, &pool);
  auto other = Network::plan(weights, "mestimator", 97, 61, 2, Simd::Auto, Memory::Shared, &pool);
  REQUIRE((one.ok() && two.ok() && shared.ok() && other.ok()));
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-2, 2);
  Tensor* a = one.value()->input("x");
  Tensor* b = two.value()->input("x");
  Tensor* d = shared.value()->input("x");
  for (int y = 0; y < 61; ++y)
    for (int x = 0; x < 97; ++x)
      for (int c = 0; c < 8; ++c) a->at(y, x)[c] = b->at(y, x)[c] = d->at(y, x)[c] = u(rng);
  one.value()->forward();
  test::AllocationCounter count;
  two.value()->forward();
  other.value()->forward();
  shared.value()->forward();
  other.value()->forward();
  CHECK(count.allocations() == 0);
  for (const char* o : {"f0", "f3", "e3_2"}) {
    CHECK(same_pixels(*one.value()->output(o), *two.value()->output(o)));
    CHECK(same_pixels(*one.value()->output(o), *shared.value()->output(o)));
  }
}

TEST_CASE("two networks at once, each on one thread of a pool, give the bytes of a pass on the whole pool, and allocate nothing") {
  // The learned tracker's first encoding of a pair (iclk::DeepAligner::encode_pair): the
  // reference and the live image, each network on a one-thread pool of its own inside a task of
  // the two-thread pool the networks were planned on. Unpaired rows and columns (97 x 61) and
  // dilated layers: a band of the whole image on one thread, where two bands split it before.
  const WeightFile weights = load("weights/lv19_tum_abc.tlw");
  ThreadPool pool(2);
  ThreadPool solo[2] = {ThreadPool(1), ThreadPool(1)};
  std::unique_ptr<Network> at_once[2], split[2];
  for (int k = 0; k < 2; ++k) {
    auto a = Network::plan(weights, "encoder", 97, 61, 2, Simd::Auto, Memory::Shared, &pool);
    auto b = Network::plan(weights, "encoder", 97, 61, 2, Simd::Auto, Memory::Shared, &pool);
    REQUIRE((a.ok() && b.ok()));
    at_once[k] = std::move(a.value());
    split[k] = std::move(b.value());
  }
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> u(-2, 2);
  for (int k = 0; k < 2; ++k) {  // two different images
    Tensor* a = at_once[k]->input("x");
    Tensor* b = split[k]->input("x");
    for (int y = 0; y < 61; ++y)
      for (int x = 0; x < 97; ++x)
        for (int c = 0; c < 8; ++c) a->at(y, x)[c] = b->at(y, x)[c] = u(rng);
  }
  for (auto& n : split) n->forward();
  struct Ctx {
    std::unique_ptr<Network>* nets;
    ThreadPool* solo;
  } ctx{at_once, solo};
  test::AllocationCounter count;
  pool.run(2, [](void* c, int i) {
    auto* x = static_cast<Ctx*>(c);
    x->nets[i]->forward_until(1 << 30, x->solo[i]);
  }, &ctx);
  CHECK(count.allocations() == 0);
  for (int k = 0; k < 2; ++k)
    for (const char* o : {"f0", "f3", "e3_2"}) CHECK(same_pixels(*at_once[k]->output(o), *split[k]->output(o)));
  // Not one image twice: the two networks' outputs differ.
  CHECK_FALSE(same_pixels(*at_once[0]->output("f0"), *at_once[1]->output("f0")));
}

TEST_CASE("forward_until runs the first steps alone, and a pass again on the same input gives the same bytes") {
  // The learned tracker's refinement encodes only the finest level this way (docs/history.md,
  // "Session 30"). Shared memory: the input must outlive every step (until session 30 the
  // first convolution's output took the input's memory, and a second pass read garbage).
  const WeightFile weights = load("weights/lv19_tum_abc.tlw");
  auto part = Network::plan(weights, "encoder", 97, 61, 2);
  auto whole = Network::plan(weights, "encoder", 97, 61, 2, Simd::Auto, Memory::Separate);
  REQUIRE((part.ok() && whole.ok()));
  Network& P = *part.value();
  Network& W = *whole.value();
  CHECK(P.step_of("x") == 0);
  CHECK(P.step_of("f0") == 4);  // x, e0_0, e0_1, e0_2, f0
  CHECK(P.step_of("no such node") == -1);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-2, 2);
  for (int y = 0; y < 61; ++y)
    for (int x = 0; x < 97; ++x)
      for (int c = 0; c < 8; ++c) P.input("x")->at(y, x)[c] = W.input("x")->at(y, x)[c] = u(rng);
  W.forward();
  for (int pass = 0; pass < 2; ++pass) {  // the same input twice: the input is not written over
    CAPTURE(pass);
    test::AllocationCounter count;
    P.forward_until(P.step_of("f0"));
    CHECK(count.allocations() == 0);
    CHECK(same_pixels(*P.output("f0"), *W.output("f0")));
    CHECK(same_pixels(*P.output("e0_2"), *W.output("e0_2")));
    P.forward_until(-1);  // nothing
    CHECK(same_pixels(*P.output("f0"), *W.output("f0")));
    P.forward_until(1000);  // past the end: all of it
    for (const char* o : {"f0", "f1", "f2", "f3", "e3_2"}) {
      CAPTURE(o);
      CHECK(same_pixels(*P.output(o), *W.output(o)));
    }
  }
}

TEST_CASE("shared tensor memory gives the same bytes as separate tensors, frame after frame, in far less memory") {
  // Shared memory reuses what earlier layers wrote, halo included: a second frame through the
  // same buffers must still match separate tensors bit for bit.
  const WeightFile weights = load("weights/lv19_tum_abc.tlw");
  auto shared = Network::plan(weights, "encoder", 97, 61, 2, Simd::Auto, Memory::Shared);
  auto separate = Network::plan(weights, "encoder", 97, 61, 2, Simd::Auto, Memory::Separate);
  REQUIRE((shared.ok() && separate.ok()));
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-2, 2);
  for (int frame = 0; frame < 2; ++frame) {
    Tensor* a = shared.value()->input("x");
    Tensor* b = separate.value()->input("x");
    for (int y = 0; y < 61; ++y)
      for (int x = 0; x < 97; ++x)
        for (int c = 0; c < 8; ++c) a->at(y, x)[c] = b->at(y, x)[c] = u(rng);
    shared.value()->forward();
    separate.value()->forward();
    CAPTURE(frame);
    for (const char* o : {"f0", "f1", "f2", "f3", "e0_2", "e3_2"})
      CHECK(same_pixels(*shared.value()->output(o), *separate.value()->output(o)));
  }
  const double ratio = static_cast<double>(shared.value()->memory_bytes()) / static_cast<double>(separate.value()->memory_bytes());
  MESSAGE("tensor memory: shared " << shared.value()->memory_bytes() << " bytes, separate "
                                   << separate.value()->memory_bytes() << " (" << ratio << ")");
  // Lv et al.'s encoder keeps every level's last features as outputs, so it saves less than
  // a network with one output would; measured 0.45.
  CHECK(ratio < 0.6);
}

TEST_CASE("bad weight files are refused with the tensor and the numbers") {
  const WeightFile good = load("weights/lv19_tum_abc.tlw");
  auto bytes = geo::read_file(test::source_path("weights/lv19_tum_abc.tlw"));
  REQUIRE(bytes.ok());
  auto err = [&](std::vector<std::uint8_t> b) {
    auto r = parse_weights(b.data(), b.size(), "w.tlw");
    return r.ok() ? std::string("(loaded)") : r.error().message;
  };
  SUBCASE("truncated, at many lengths") {
    for (std::size_t len : {std::size_t{0}, std::size_t{7}, std::size_t{20}, std::size_t{300}, bytes->size() / 2, bytes->size() - 9}) {
      CAPTURE(len);
      std::vector<std::uint8_t> cut(bytes->begin(), bytes->begin() + static_cast<std::ptrdiff_t>(len));
      CHECK(err(cut) != "(loaded)");
    }
    CHECK(err(std::vector<std::uint8_t>(bytes->begin(), bytes->end() - 100)).find("truncated") != std::string::npos);
  }
  SUBCASE("wrong magic") {
    auto b = bytes.value();
    b[0] = 'X';
    CHECK(err(b).find("magic") != std::string::npos);
  }
  SUBCASE("another format version") {
    auto b = serialise(good, 2);
    CHECK(err(b).find("version 2") != std::string::npos);
  }
  SUBCASE("checksum mismatch") {
    auto b = bytes.value();
    b[b.size() / 2] ^= 0x40;
    CHECK(err(b).find("checksum mismatch") != std::string::npos);
  }
  SUBCASE("missing tensor") {
    WeightFile w = good;
    w.tensors.erase(w.tensors.begin() + 2);
    CHECK(plan_error(w).find("missing tensor encoder.net0.1.weight") != std::string::npos);
  }
  SUBCASE("extra tensor") {
    WeightFile w = good;
    w.tensors.push_back({"encoder.net9.0.weight", {2, 2}, {1, 2, 3, 4}});
    CHECK(plan_error(w).find("extra tensor encoder.net9.0.weight [2, 2]") != std::string::npos);
  }
  SUBCASE("shape mismatch") {
    WeightFile w = good;
    for (auto& t : w.tensors)
      if (t.name == "encoder.net0.1.weight") {
        t.shape = {32, 16, 9, 1};
      }
    const std::string e = plan_error(w);
    CHECK(e.find("encoder.net0.1.weight is [32, 16, 9, 1], the layer needs [32, 16, 3, 3]") != std::string::npos);
  }
  SUBCASE("a missing file") {
    auto r = read_weights("/nonexistent/w.tlw");
    REQUIRE(!r.ok());
    CHECK(r.error().message.find("/nonexistent/w.tlw") != std::string::npos);
  }
  SUBCASE("a broken architecture line") {
    WeightFile w = good;
    w.architecture += "conv bad e3_2 8 9 elu x\n";  // dilation 9 exceeds the halo
    CHECK(plan_error(w).find("must be an integer in [1, 4]") != std::string::npos);
  }
}

TEST_CASE("mean over channels: in equal groups of consecutive channels, and refused where they do not divide") {
  WeightFile w;
  w.name = "groups.tlw";
  w.version = kWeightFormatVersion;
  w.architecture = "terralign-net 1\nnet encoder\ninput x 12\nmean one x\nmean four x 4\noutput one four\n";
  auto n = Network::plan(w, "encoder", 11, 3, 2);  // 11: one pixel group of eight and a tail of three
  REQUIRE_MESSAGE(n.ok(), (n.ok() ? "" : n.error().message));
  Tensor* x = n.value()->input("x");
  for (int y = 0; y < 3; ++y)
    for (int i = 0; i < 11; ++i)
      for (int c = 0; c < 12; ++c) x->at(y, i)[c] = static_cast<float>(100 * y + 10 * i + c * c);
  n.value()->forward();
  const Tensor& one = *n.value()->output("one");
  const Tensor& four = *n.value()->output("four");
  REQUIRE((one.c == 1 && four.c == 4));
  // The group sums of c^2: 506 over all twelve, 5, 50, 149, 302 over each three (the kernel
  // multiplies by 1/3 in float: a rounding, hence 1e-6).
  for (int y = 0; y < 3; ++y)
    for (int i = 0; i < 11; ++i) {
      const float base = static_cast<float>(100 * y + 10 * i);
      CHECK(one.at(y, i)[0] == doctest::Approx(base + 506.0f / 12.0f).epsilon(1e-6));
      CHECK(four.at(y, i)[0] == doctest::Approx(base + 5.0f / 3.0f).epsilon(1e-6));
      CHECK(four.at(y, i)[1] == doctest::Approx(base + 50.0f / 3.0f).epsilon(1e-6));
      CHECK(four.at(y, i)[2] == doctest::Approx(base + 149.0f / 3.0f).epsilon(1e-6));
      CHECK(four.at(y, i)[3] == doctest::Approx(base + 302.0f / 3.0f).epsilon(1e-6));
    }
  w.architecture = "terralign-net 1\nnet encoder\ninput x 12\nmean five x 5\noutput five\n";
  auto refused = Network::plan(w, "encoder", 11, 3, 1);
  REQUIRE_FALSE(refused.ok());
  CHECK(refused.error().message.find("5 groups do not divide 12 channels") != std::string::npos);
}

TEST_CASE("sigmoid matches 1 / (1 + exp(-x)) to 5e-7 of itself from -87 to 87, and stays in [0, 1] beyond") {
  // The M-estimator's last step. Its exp is ELU's polynomial (3.5e-7), not libm's expf, whose
  // last bit may differ between machines: e / (1 + e) below 0 keeps the relative precision
  // where the sigmoid is tiny (1 / (1 + 1/e) would round 1/e's error into it).
  const int n = 4001;
  Tensor in, out;
  in.allocate(1, n + 3, 1);
  out.allocate(1, n + 3, 1);
  for (int i = 0; i < n; ++i) in.at(0, i)[0] = -87.0f + 174.0f * static_cast<float>(i) / (n - 1);
  in.at(0, n)[0] = -200.0f;
  in.at(0, n + 1)[0] = 200.0f;
  in.at(0, n + 2)[0] = std::numeric_limits<float>::quiet_NaN();
  sigmoid_rows(in, out, 0, 1);
  double worst = 0;
  for (int i = 0; i < n; ++i) {
    const double x = in.at(0, i)[0];
    const double want = 1.0 / (1.0 + std::exp(-x));
    worst = std::max(worst, std::abs(out.at(0, i)[0] - want) / want);
  }
  MESSAGE("worst relative error of sigmoid on [-87, 87]: " << worst);
  CHECK(worst < 5e-7);
  CHECK(out.at(0, n)[0] >= 0.0f);
  CHECK(out.at(0, n)[0] < 2e-38f);  // exp(-87)'s 1.6e-38: the clamp
  CHECK(out.at(0, n + 1)[0] == 1.0f);
  CHECK(std::isnan(out.at(0, n + 2)[0]));
}

TEST_CASE("every conv kernel's ELU matches expm1 to 5e-7 (one polynomial in every build)") {
  // A 1 -> 1 channel conv whose only non-zero weight is the centre tap: out = ELU(in). The
  // inputs run from -100 (past the clamp at -87, where 2^n would leave the normal range) to 100
  // (past 88, where the vector kernels' discarded exp overflows), densest across the
  // polynomial's range near 0; then 0, 0 and NaN (the 3 x 3 footprint multiplies the NaN's
  // neighbour by zero, and 0 x NaN is NaN: the middle one is not checked).
  std::vector<float> w(9, 0.0f);
  w[4] = 1.0f;
  const float bias = 0.0f;
  Tensor in, out;
  const int n = 4003;
  in.allocate(1, n, 1);
  out.allocate(1, n, 1);
  for (int i = 0; i < n - 3; ++i) {
    const float u = -1.0f + 2.0f * static_cast<float>(i) / (n - 4);  // -1 .. 1
    in.at(0, i)[0] = 100.0f * u * u * u;
  }
  in.at(0, n - 3)[0] = 0.0f;
  in.at(0, n - 2)[0] = 0.0f;
  in.at(0, n - 1)[0] = std::numeric_limits<float>::quiet_NaN();
  for (const auto& [kernel, fn, block] : conv_kernels()) {
    const char* const name = kernel;  // CAPTURE may not capture a structured binding (C++17)
    CAPTURE(name);
    conv(fn, in, pack_conv(w.data(), &bias, 1, 1, 1, Act::Elu, block), out, 0, 1);
    double worst = 0;
    for (int i = 0; i < n - 3; ++i) {
      const double x = in.at(0, i)[0];
      const double want = x > 0 ? x : std::expm1(x);
      worst = std::max(worst, std::abs(out.at(0, i)[0] - want) / std::max(std::abs(want), 1e-3));
    }
    CHECK(worst < 5e-7);
    CHECK(out.at(0, n - 3)[0] == 0.0f);
    CHECK(std::isnan(out.at(0, n - 1)[0]));
  }
}
