// Uses each installed library once; exits 0 when the pieces link and agree.
#include <cstdio>

#include <terralign/geo/pose.hpp>
#include <terralign/iclk/se3.hpp>
#include <terralign/geo/thread_pool.hpp>

int main() {
  auto p = terralign::geo::parse_pose("1 2 3 1 0 0 0");
  terralign::ThreadPool pool(2);
  const auto T = terralign::iclk::SE3<double>::exp(terralign::iclk::Vec6<double>::Zero());
  const bool ok = p.ok() && pool.threads() == 2 && T.R.isIdentity();
  std::printf("find_package(terralign): %s\n", ok ? "ok" : "FAILED");
  return ok ? 0 : 1;
}
