#include <terralign/geo/assert.hpp>
#include <terralign/geo/float_environment.hpp>
#include <terralign/nn/network.hpp>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <set>
#include <sstream>

namespace terralign::nn {

Result<std::vector<NetDesc>> parse_architecture(const std::string& text, const std::string& where) {
  std::vector<NetDesc> nets;
  std::istringstream in(text);
  std::string line;
  int n = 0;
  bool header = false;
  while (std::getline(in, line)) {
    ++n;
    std::istringstream ls(line);
    std::vector<std::string> t;
    std::string tok;
    while (ls >> tok) t.push_back(tok);
    if (t.empty() || t[0][0] == '#') continue;
    const std::string at = where + ": architecture line " + std::to_string(n);
    if (!header) {
      if (t.size() != 2 || t[0] != "terralign-net" || t[1] != "1")
        return Error{at + ": expected 'terralign-net 1', found '" + line + "'"};
      header = true;
      continue;
    }
    if (t[0] == "net") {
      if (t.size() != 2) return Error{at + ": 'net NAME'"};
      nets.push_back({t[1], {}, {}});
      continue;
    }
    if (nets.empty()) return Error{at + ": a node before any 'net'"};
    NetDesc& net = nets.back();
    if (t[0] == "output") {
      if (t.size() < 2) return Error{at + ": 'output NAME ...'"};
      net.outputs.insert(net.outputs.end(), t.begin() + 1, t.end());
      continue;
    }
    Node node;
    node.op = t[0];
    node.line = n;
    auto integer = [&](const std::string& s, int lo, int hi, int& out) -> Status {
      char* end = nullptr;
      const long v = std::strtol(s.c_str(), &end, 10);
      if (s.empty() || *end || v < lo || v > hi)
        return Error{at + ": '" + s + "' must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]"};
      out = static_cast<int>(v);
      return Ok{};
    };
    if (node.op == "input") {
      if (t.size() != 3) return Error{at + ": 'input NAME C'"};
      node.name = t[1];
      TERRALIGN_TRY(integer(t[2], 1, 4096, node.channels));
    } else if (node.op == "conv") {
      if (t.size() != 7) return Error{at + ": 'conv NAME IN COUT DIL ACT PARAM'"};
      node.name = t[1];
      node.inputs = {t[2]};
      TERRALIGN_TRY(integer(t[3], 1, 4096, node.channels));
      TERRALIGN_TRY(integer(t[4], 1, kHalo, node.dilation));
      if (t[5] == "elu") node.act = Act::Elu;
      else if (t[5] == "relu") node.act = Act::Relu;
      else if (t[5] == "none") node.act = Act::None;
      else return Error{at + ": activation '" + t[5] + "' (none, elu, relu)"};
      node.param = t[6];
    } else if (node.op == "mean") {
      if (t.size() != 3 && t.size() != 4) return Error{at + ": 'mean NAME IN [GROUPS]'"};
      node.name = t[1];
      node.inputs = {t[2]};
      node.channels = 1;
      if (t.size() == 4) TERRALIGN_TRY(integer(t[3], 1, 4096, node.channels));
    } else if (node.op == "pool" || node.op == "upsample" || node.op == "sigmoid") {
      if (t.size() != 3) return Error{at + ": '" + node.op + " NAME IN'"};
      node.name = t[1];
      node.inputs = {t[2]};
    } else if (node.op == "concat") {
      if (t.size() < 4) return Error{at + ": 'concat NAME IN1 IN2 ...'"};
      node.name = t[1];
      node.inputs.assign(t.begin() + 2, t.end());
    } else {
      return Error{at + ": unknown operation '" + node.op + "'"};
    }
    for (const auto& other : net.nodes)
      if (other.name == node.name) return Error{at + ": node '" + node.name + "' defined twice"};
    net.nodes.push_back(node);
  }
  if (!header) return Error{where + ": empty architecture"};
  return nets;
}

int Network::index_of(const std::string& name) const {
  for (std::size_t i = 0; i < names_.size(); ++i)
    if (names_[i] == name) return static_cast<int>(i);
  return -1;
}

Result<std::unique_ptr<Network>> Network::plan(const WeightFile& weights, const std::string& net, int width, int height,
                                               int threads, Simd simd, Memory memory, ThreadPool* pool,
                                               int winograd_tile) {
  const FloatEnvironmentScope float_environment;
  if (winograd_tile != 0 && winograd_tile != 2 && winograd_tile != 4)
    return Error{"network " + net + ": Winograd's tile " + std::to_string(winograd_tile) + " is not 0 (direct), 2 or 4"};
  TERRALIGN_TRY_ASSIGN(const auto nets, parse_architecture(weights.architecture, weights.name));
  // Every tensor must belong to a conv of some network.
  std::set<std::string> used;
  for (const auto& d : nets)
    for (const auto& nd : d.nodes)
      if (nd.op == "conv") {
        used.insert(nd.param + ".weight");
        used.insert(nd.param + ".bias");
      }
  for (const auto& t : weights.tensors)
    if (!used.count(t.name)) return Error{weights.name + ": extra tensor " + t.name + " " + t.shape_text() + " is used by no layer"};
  const NetDesc* desc = nullptr;
  for (const auto& d : nets)
    if (d.name == net) desc = &d;
  if (!desc) return Error{weights.name + ": no network named '" + net + "'"};
  if (width < 1 || height < 1 || width > 16384 || height > 16384)
    return Error{"network " + net + ": input size " + std::to_string(width) + " x " + std::to_string(height) + " is outside 1..16384"};

  std::unique_ptr<Network> N(new Network);
  N->desc_ = *desc;
  // The kernel, picked once: its block width decides how the weights are packed.
  const bool avx2 = nn_cpu_has_avx2(), avx512 = nn_cpu_has_avx512(), neon = nn_cpu_has_neon();
  if ((simd == Simd::Avx2 && !avx2) || (simd == Simd::Avx512 && !avx512) || (simd == Simd::Neon && !neon))
    return Error{"network " + net + ": the requested SIMD kernels are not available on this CPU or build"};
  int block = 8;
#if defined(TERRALIGN_NN_AVX2)
  if (avx512 && (simd == Simd::Auto || simd == Simd::Avx512)) {
    N->conv_ = conv3x3_rows_avx512;
    N->simd_name_ = "avx512";
    block = 16;
  } else if (avx2 && (simd == Simd::Auto || simd == Simd::Avx2)) {
    N->conv_ = conv3x3_rows_avx2;
    N->simd_name_ = "avx2";
  }
#endif
#if defined(TERRALIGN_NN_NEON)
  if (neon && (simd == Simd::Auto || simd == Simd::Neon)) {
    N->conv_ = conv3x3_rows_neon;
    N->simd_name_ = "neon";
  }
#endif
  N->tensors_.reserve(N->desc_.nodes.size());
  for (const auto& node : N->desc_.nodes) {
    const std::string at = weights.name + ": " + net + " line " + std::to_string(node.line) + " (" + node.name + ")";
    Step step{&node, {}, -1, -1};
    for (const auto& in : node.inputs) {
      const int i = N->index_of(in);
      if (i < 0) return Error{at + ": input '" + in + "' is not defined above"};
      step.in.push_back(i);
    }
    int h = height, w = width, c = node.channels;
    if (!step.in.empty()) {
      const Tensor& a = N->tensors_[static_cast<std::size_t>(step.in[0])];
      h = a.h;
      w = a.w;
      c = a.c;
    }
    if (node.op == "pool") {
      if (h < 2 || w < 2) return Error{at + ": cannot pool a " + std::to_string(w) + " x " + std::to_string(h) + " map"};
      h /= 2;
      w /= 2;
    } else if (node.op == "upsample") {
      h *= 2;
      w *= 2;
    } else if (node.op == "mean") {
      if (c % node.channels)
        return Error{at + ": " + std::to_string(node.channels) + " groups do not divide " + std::to_string(c) +
                     " channels"};
      c = node.channels;
    } else if (node.op == "concat") {
      c = 0;
      for (int i : step.in) {
        const Tensor& a = N->tensors_[static_cast<std::size_t>(i)];
        if (a.h != h || a.w != w) return Error{at + ": concatenated inputs differ in size"};
        c += a.c;
      }
    } else if (node.op == "conv") {
      const int cin = c;
      c = node.channels;
      const TensorData* wt = weights.find(node.param + ".weight");
      const TensorData* bt = weights.find(node.param + ".bias");
      if (!wt) return Error{at + ": missing tensor " + node.param + ".weight"};
      if (!bt) return Error{at + ": missing tensor " + node.param + ".bias"};
      const std::vector<int> ws{c, cin, 3, 3}, bs{c};
      auto text = [](const std::vector<int>& s) {
        std::string r = "[";
        for (std::size_t k = 0; k < s.size(); ++k) r += (k ? ", " : "") + std::to_string(s[k]);
        return r + "]";
      };
      if (wt->shape != ws)
        return Error{at + ": tensor " + wt->name + " is " + wt->shape_text() + ", the layer needs " + text(ws)};
      if (bt->shape != bs)
        return Error{at + ": tensor " + bt->name + " is " + bt->shape_text() + ", the layer needs " + text(bs)};
      step.conv = static_cast<int>(N->convs_.size());
      N->convs_.push_back(pack_conv(wt->data.data(), bt->data.data(), cin, c, node.dilation, node.act, block, winograd_tile));
    }
    Tensor t;
    const bool padded = node.op == "conv";
    if (memory == Memory::Separate) t.allocate(h, w, c, padded);
    else t.place(h, w, c, padded, nullptr);  // placed in the shared buffer below
    step.out = static_cast<int>(N->tensors_.size());
    N->tensors_.push_back(std::move(t));
    N->names_.push_back(node.name);
    N->steps_.push_back(step);
  }
  for (auto& s : N->steps_) s.node = &N->desc_.nodes[static_cast<std::size_t>(&s - N->steps_.data())];
  for (const auto& o : N->desc_.outputs)
    if (N->index_of(o) < 0) return Error{weights.name + ": " + net + ": output '" + o + "' is not a node"};
  N->pool_ = given_or_own(pool, threads, N->own_pool_);
  // Each band (one a thread) has scratch of its own for the convolutions (Winograd's tiles).
  for (const auto& c : N->convs_) N->scratch_floats_ = std::max(N->scratch_floats_, (conv_scratch_floats(c) + 15) / 16 * 16);
  if (memory != Memory::Separate) {
    N->share_memory(memory);
  } else if (N->scratch_floats_ > 0) {
    // On a 64-byte boundary, as in the shared buffer: Winograd's vectors unsplit by cache lines
    // (a 16 -> 16 layer takes 8 % longer on scratch 16-byte aligned).
    N->own_scratch_.assign(N->scratch_floats_ * static_cast<std::size_t>(N->pool_->threads()) + 16, 0.0f);
    N->scratch_ = N->own_scratch_.data();
    while (reinterpret_cast<std::uintptr_t>(N->scratch_) % 64 != 0) ++N->scratch_;
  }
  N->step_ms_.assign(N->steps_.size(), 0.0);
  return N;
}

void Network::share_memory(Memory memory) {
  // Tensor i is needed from its step until its last reader; inputs and outputs always.
  const std::size_t n = tensors_.size();
  std::vector<std::size_t> last(n, 0);
  for (std::size_t k = 0; k < n; ++k) {
    last[k] = k;
    // max: an input's n must survive its readers (a plain assignment let the first
    // convolution's output reuse the input's memory, so a second forward() on the same input
    // read the first pass's activations; every caller refilled the input, which hid it).
    for (int i : steps_[k].in) last[static_cast<std::size_t>(i)] = std::max(last[static_cast<std::size_t>(i)], k);
    if (steps_[k].node->op == "input") last[k] = n;
  }
  for (const auto& o : desc_.outputs) last[static_cast<std::size_t>(index_of(o))] = n;
  // First fit over the free blocks, lowest offset first; blocks 64-byte aligned. Tensor k
  // is placed after every tensor whose last reader came before step k is released (never
  // its own inputs: their last reader is k or later).
  struct Block {
    std::size_t at, size;
  };
  constexpr std::size_t kAlign = 16;  // floats
  std::vector<Block> free_blocks;
  std::vector<std::size_t> offset(n, 0);
  std::size_t end = 0;
  auto release = [&](std::size_t at, std::size_t size) {
    free_blocks.push_back({at, size});
    std::sort(free_blocks.begin(), free_blocks.end(), [](const Block& a, const Block& b) { return a.at < b.at; });
    std::vector<Block> merged;
    for (const Block& b : free_blocks)
      if (!merged.empty() && merged.back().at + merged.back().size == b.at) merged.back().size += b.size;
      else merged.push_back(b);
    free_blocks = merged;
  };
  for (std::size_t k = 0; k < n; ++k) {
    for (std::size_t i = 0; i < k; ++i)
      if (last[i] + 1 == k) release(offset[i], (tensors_[i].floats() + kAlign - 1) / kAlign * kAlign);
    const std::size_t size = (tensors_[k].floats() + kAlign - 1) / kAlign * kAlign;
    auto fit = std::find_if(free_blocks.begin(), free_blocks.end(), [&](const Block& b) { return b.size >= size; });
    if (fit != free_blocks.end()) {
      offset[k] = fit->at;
      fit->at += size;
      fit->size -= size;
      if (fit->size == 0) free_blocks.erase(fit);
    } else {
      offset[k] = end;
      end += size;
    }
  }
  offsets_ = offset;
  tensor_floats_ = end;
  end += scratch_floats_ * static_cast<std::size_t>(pool_->threads());
  if (memory == Memory::External) {
    external_floats_ = end;
    bound_ = false;
    return;
  }
  // 64 extra bytes so that the first tensor can start on a 64-byte boundary.
  shared_.assign(end + kAlign, 0.0f);
  float* base = shared_.data();
  while (reinterpret_cast<std::uintptr_t>(base) % (kAlign * sizeof(float)) != 0) ++base;
  bind(base);
}

void Network::bind(float* memory) {
  TERRALIGN_ASSERT(memory && reinterpret_cast<std::uintptr_t>(memory) % 64 == 0 && offsets_.size() == tensors_.size(),
                   "Network::bind: a 64-byte aligned buffer, for a network planned with shared memory");
  for (std::size_t k = 0; k < tensors_.size(); ++k) {
    Tensor& t = tensors_[k];
    t.place(t.h, t.w, t.c, steps_[k].node->op == "conv", memory + offsets_[k]);
  }
  scratch_ = scratch_floats_ > 0 ? memory + tensor_floats_ : nullptr;
  bound_ = true;
}

std::size_t Network::memory_bytes() const {
  std::size_t b = (shared_.size() + own_scratch_.size()) * sizeof(float);
  for (const auto& t : tensors_) b += t.storage.size() * sizeof(float);
  return b;
}

Tensor* Network::input(const std::string& name) {
  for (std::size_t i = 0; i < steps_.size(); ++i)
    if (steps_[i].node->op == "input" && names_[i] == name) return &tensors_[i];
  return nullptr;
}

const Tensor* Network::output(const std::string& name) const {
  for (const auto& o : desc_.outputs)
    if (o == name) return &tensors_[static_cast<std::size_t>(index_of(name))];
  return nullptr;
}

double Network::macs() const {
  double m = 0;
  for (const auto& s : steps_)
    if (s.conv >= 0) {
      const Tensor& o = tensors_[static_cast<std::size_t>(s.out)];
      m += 9.0 * o.h * o.w * o.c * convs_[static_cast<std::size_t>(s.conv)].cin;
    }
  return m;
}

namespace {
struct StepCtx {
  Network::Step const* step;
  std::vector<Tensor>* tensors;
  const ConvWeights* conv;
  ConvRowsFn conv_fn;
  float* scratch;        // band i's: scratch + i * scratch_floats
  std::size_t scratch_floats;
  int bands;
  int align;  // band edges on multiples of this (a Winograd convolution's row groups: no tile computed twice)
};
constexpr int kMaxConcat = 16;
}  // namespace

std::vector<Network::StepTime> Network::step_times() const {
  std::vector<StepTime> out;
  for (std::size_t i = 0; i < steps_.size(); ++i) {
    const Step& s = steps_[i];
    if (s.node->op == "input") continue;
    const Tensor& o = tensors_[static_cast<std::size_t>(s.out)];
    const ConvWeights* c = s.conv >= 0 ? &convs_[static_cast<std::size_t>(s.conv)] : nullptr;
    const double m = c ? 9.0 * o.h * o.w * o.c * c->cin : 0.0;
    out.push_back({names_[i], s.node->op, step_ms_[i], m, c && !c->winograd.empty() ? c->winograd_tile : 0});
  }
  return out;
}

int Network::step_of(const std::string& name) const {
  for (std::size_t k = 0; k < steps_.size(); ++k)
    if (steps_[k].node->name == name) return static_cast<int>(k);
  return -1;
}

void Network::forward() { forward_until(static_cast<int>(steps_.size()) - 1); }

void Network::forward_until(int last_step) { forward_until(last_step, *pool_); }

void Network::forward_until(int last_step, ThreadPool& on) {
  const FloatEnvironmentScope float_environment;
  TERRALIGN_ASSERT(bound_, "Network::forward: a Memory::External network before bind()");
  TERRALIGN_ASSERT(on.threads() <= pool_->threads(), "Network::forward_until: a pool of more threads than planned");
  const std::size_t end = last_step < 0 ? 0 : std::min(steps_.size(), static_cast<std::size_t>(last_step) + 1);
  for (std::size_t step = 0; step < end; ++step) {
    const Step& s = steps_[step];
    if (s.node->op == "input") continue;
    const auto t0 = profile_ ? std::chrono::steady_clock::now() : std::chrono::steady_clock::time_point{};
    // Shared memory: a convolution's input gets its zero padding back (another tensor may
    // have written there since).
    if (s.conv >= 0 && !offsets_.empty()) tensors_[static_cast<std::size_t>(s.in[0])].zero_halo();
    // One band of neighbouring output rows a thread (every row costs the same): the threads
    // then share cache lines of the output only where two bands meet. Two-row tasks dealt in
    // turn made the two cores pass lines back and forth every two rows, 7 % of a pair's
    // deep alignment (bench_localize, interleaved). Rows are independent (a Winograd
    // convolution's in pairs, which the band edges keep whole), so the bytes are the same
    // however they are split.
    const ConvWeights* cw = s.conv >= 0 ? &convs_[static_cast<std::size_t>(s.conv)] : nullptr;
    StepCtx ctx{&s, &tensors_, cw, conv_, scratch_, scratch_floats_, on.threads(), cw ? conv_row_align(*cw) : 1};
    on.run(ctx.bands, [](void* p, int i) {
      auto* c = static_cast<StepCtx*>(p);
      const Network::Step& st = *c->step;
      std::vector<Tensor>& T = *c->tensors;
      Tensor& o = T[static_cast<std::size_t>(st.out)];
      auto edge = [c, &o](int k) { return k >= c->bands ? o.h : k * o.h / c->bands / c->align * c->align; };
      const int y0 = edge(i), y1 = edge(i + 1);
      const Tensor& a = T[static_cast<std::size_t>(st.in[0])];
      const std::string& op = st.node->op;
      if (op == "conv") c->conv_fn(a, *c->conv, o, y0, y1, c->scratch ? c->scratch + static_cast<std::size_t>(i) * c->scratch_floats : nullptr);
      else if (op == "pool") avgpool2_rows(a, o, y0, y1);
      else if (op == "mean") mean_channels_rows(a, o, y0, y1);
      else if (op == "sigmoid") sigmoid_rows(a, o, y0, y1);
      else if (op == "upsample") upsample2_rows(a, o, y0, y1);
      else if (op == "concat") {
        const Tensor* ins[kMaxConcat];
        const int n = std::min(static_cast<int>(st.in.size()), kMaxConcat);
        for (int k = 0; k < n; ++k) ins[k] = &T[static_cast<std::size_t>(st.in[static_cast<std::size_t>(k)])];
        concat_rows(ins, n, o, y0, y1);
      }
    }, &ctx);
    if (profile_)
      step_ms_[static_cast<std::size_t>(&s - steps_.data())] =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
}

}  // namespace terralign::nn
