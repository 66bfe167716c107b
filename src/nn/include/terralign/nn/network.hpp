// Networks described by data. The architecture text of a weight file holds one or more
// networks; each line is one node (names are unique within a network):
//
//   net NAME                          starts a network
//   input NAME C                      an input of C channels (the caller fills it)
//   conv NAME IN COUT DIL ACT PARAM   3x3 conv, stride 1, padding = dilation, weights
//                                     PARAM.weight (COUT x CIN x 3 x 3) and PARAM.bias (COUT),
//                                     batch norm folded in; ACT: none, elu, relu
//   pool NAME IN                      2x2 average pooling (floor)
//   upsample NAME IN                  2x bilinear (align_corners = False)
//   mean NAME IN [G]                  mean over channels -> 1 channel; G groups of
//                                     consecutive channels, each averaged -> G channels
//   sigmoid NAME IN
//   concat NAME IN1 IN2 ...           channels of the inputs, in order
//   output NAME ...                   the nodes the caller may read
//
// A Network is planned once for an input size: every tensor is allocated then, forward()
// allocates nothing. Work is split by output rows in fixed blocks, each row computed by one
// thread in one order (a Winograd convolution's rows in pairs, which no split divides), so 1
// and 2 threads give the same bytes.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <terralign/geo/result.hpp>
#include <terralign/geo/thread_pool.hpp>
#include <terralign/nn/kernels.hpp>
#include <terralign/nn/tensor.hpp>
#include <terralign/nn/weights.hpp>

namespace terralign::nn {

struct Node {
  std::string op, name;
  std::vector<std::string> inputs;
  int channels = 0;   // input: C; conv: COUT; mean: G (1 unless given)
  int dilation = 1;
  Act act = Act::None;
  std::string param;  // conv: tensor name prefix
  int line = 0;
};

struct NetDesc {
  std::string name;
  std::vector<Node> nodes;
  std::vector<std::string> outputs;
};

Result<std::vector<NetDesc>> parse_architecture(const std::string& text, const std::string& where);

enum class Simd { Auto, Scalar, Avx2, Avx512, Neon };
// Tensor memory: Shared places every tensor in one buffer, reusing the memory of tensors no
// later step reads (inputs and outputs keep theirs), so a network needs about its two
// largest live tensors instead of all of them; the halo a convolution reads is zeroed
// before it runs. External is Shared in memory the caller binds (bind()): networks that
// never run at the same time, and whose tensors the caller reads only right after their own
// forward(), can share one buffer. Separate gives each tensor its own.
enum class Memory { Shared, External, Separate };

class Network {
 public:
  // Checks the description against the weights (every conv's tensors present with the
  // right shapes; a tensor no network uses is an error), sizes every tensor for an input of
  // width x height, and packs the weights. `pool`: the caller's pool to run on (its thread
  // count replaces `threads`), which must outlive the network and is not used by two callers
  // at once; else the network starts a pool of its own. One pool for the networks and the
  // solver of a pipeline keeps one worker awake between them, where a pool each woke a
  // sleeping thread at every hand-over. `winograd_tile`: Winograd's output tile (kernels.hpp)
  // for the layers it suits, 4 (the product's) or 2; 0: every layer by the direct kernel (the
  // peers that bench_nn measures the product against, and tests compare it with).
  static Result<std::unique_ptr<Network>> plan(const WeightFile& weights, const std::string& net, int width, int height,
                                               int threads = 2, Simd simd = Simd::Auto,
                                               Memory memory = Memory::Shared, ThreadPool* pool = nullptr,
                                               int winograd_tile = 4);

  // The input tensor to fill (h x w x c, see tensor.hpp), or null for an unknown name.
  Tensor* input(const std::string& name);
  const Tensor* output(const std::string& name) const;
  void forward();
  // The steps run in the description's order; step_of(name) is the step that computes a
  // node (-1: no such node), and forward_until(k) runs steps 0..k alone (k < 0: none; past
  // the end: all): a caller that needs only the first outputs (an encoder's finest level)
  // skips the rest. With shared memory the outputs of the steps that did not run hold
  // nothing meaningful (the steps that ran may have used their memory). Set-up: step_of;
  // forward_until allocates nothing.
  int step_of(const std::string& name) const;
  void forward_until(int last_step);
  // The same steps on `on`, a pool of at most the planned pool's threads (each thread's band
  // has its scratch), in place of the planned one: a caller that runs two networks at once,
  // each on one thread of its own (a one-thread pool runs its tasks on the calling thread).
  // The bytes are forward_until(last_step)'s: rows do not depend on the split.
  void forward_until(int last_step, ThreadPool& on);
  const char* simd_name() const { return simd_name_; }
  // Bytes of tensor memory the network owns (activations and the convolutions' scratch; the
  // packed weights are not counted; 0 for Memory::External).
  std::size_t memory_bytes() const;
  // Memory::External: the floats the shared buffer needs (64-byte aligned; the tensors and
  // each thread's scratch for the convolutions), and binding it.
  // forward() before bind() is a programming error.
  std::size_t external_floats() const { return external_floats_; }
  void bind(float* memory);
  // Multiply-accumulates of one forward pass (3x3 convs, counted as the direct kernel's), for
  // benchmarks.
  double macs() const;
  // Per-node timing of forward() (no allocation; off by default), for benchmarks.
  void set_profiling(bool on) { profile_ = on; }
  struct StepTime {
    std::string name, op;
    double ms, macs;
    int winograd_tile;  // 2 or 4: a convolution by Winograd's kernel; 0: not
  };
  std::vector<StepTime> step_times() const;

  struct Step {
    const Node* node;
    std::vector<int> in;  // tensor indices
    int out;
    int conv = -1;        // index into convs_
  };

 private:
  Network() = default;
  NetDesc desc_;
  std::vector<Tensor> tensors_;
  std::vector<float> shared_;       // Memory::Shared: every tensor's pixels, then the scratch
  std::vector<float> own_scratch_;  // Memory::Separate: the convolutions' scratch
  std::size_t scratch_floats_ = 0;  // a band's (conv_scratch_floats(), the largest layer's)
  std::size_t tensor_floats_ = 0;   // Shared, External: the tensors' part of the buffer
  float* scratch_ = nullptr;        // one band's scratch after another
  std::vector<std::size_t> offsets_;  // Shared, External: each tensor's place, in floats
  std::size_t external_floats_ = 0;
  bool bound_ = true;
  void share_memory(Memory memory);
  std::vector<std::string> names_;  // tensor names, by index
  std::vector<ConvWeights> convs_;
  std::vector<Step> steps_;
  std::unique_ptr<ThreadPool> own_pool_;  // without a caller's pool
  ThreadPool* pool_ = nullptr;
  ConvRowsFn conv_ = conv3x3_rows_scalar;
  const char* simd_name_ = "scalar";
  bool profile_ = false;
  std::vector<double> step_ms_;
  int index_of(const std::string& name) const;
};

}  // namespace terralign::nn
