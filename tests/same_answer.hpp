// Whether two alignments gave the same answer to the bit: pose, iterations, final cost and
// covariance (the same-bytes promise across thread counts, kernels and kept pyramids).
#pragma once

#include <cstring>

#include <doctest/doctest.h>

#include <terralign/iclk/tracker.hpp>

namespace terralign::test {

template <class Warp>
void check_same_answer(const iclk::TrackResult<Warp>& a, const iclk::TrackResult<Warp>& b) {
  CHECK(std::memcmp(a.params.R.data(), b.params.R.data(), sizeof(*a.params.R.data()) * 9) == 0);
  CHECK(std::memcmp(a.params.t.data(), b.params.t.data(), sizeof(*a.params.t.data()) * 3) == 0);
  CHECK(a.iterations == b.iterations);
  CHECK(a.cost_final == b.cost_final);
  CHECK(a.covariance == b.covariance);
}

}  // namespace terralign::test
