// One classical alignment of a 752x480 rendered pair (NAIP 2016, a known offset), with 20
// and 50 iterations per level and the time split into pyramids, Jacobians and iterations;
// beside OpenCV's findTransformECC (homography, 4-level pyramid, same pair) when OpenCV is
// installed (libopencv-dev). Medians of 15 runs, same process, same core count.
//   build/release/bench/bench_align
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <vector>

#include <terralign/geo/map.hpp>
#include <terralign/iclk/tracker.hpp>
#include <terralign/raster/renderer.hpp>

#if defined(TERRALIGN_BENCH_OPENCV)
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#endif

using namespace terralign;
using Clock = std::chrono::steady_clock;

namespace {
double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}
double ms_since(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }
}  // namespace

int main() {
  auto map = geo::load_map(TERRALIGN_SOURCE_DIR "/data/naip_west/map.json");
  if (!map.ok()) return 1;
  geo::CameraModel cam;
  cam.width = 752;
  cam.height = 480;
  cam.fx = cam.fy = 651.2;
  cam.cx = 375.5;
  cam.cy = 239.5;
  auto r = raster::Renderer::create(map.value(), cam);
  if (!r.ok()) return 1;
  auto ref = r.value()->make_output({"2016"}), live = r.value()->make_output({"2016"});
  const geo::Pose truth = geo::pose_from_ypr({487450, 5207437, 1370}, 30, 2, -3);
  const geo::Pose prior = geo::pose_from_ypr({487462, 5207428, 1376}, 31.5, 1, -2);
  if (!r.value()->render(prior, ref.value()).ok() || !r.value()->render(truth, live.value()).ok()) return 1;
  ImageF rg, lg, depth = ref->depth;
  iclk::rgb_to_grey(ref->rgb[0].view(), rg);
  iclk::rgb_to_grey(live->rgb[0].view(), lg);
  const iclk::Pinhole<float> K{651.2f, 651.2f, 375.5f, 239.5f};

  std::printf("| method | ms total (median of 15) | pyramids | Jacobians | iterations | iterations run | converged |\n");
  std::printf("|---|---|---|---|---|---|---|\n");
  double classic20 = 0;
  for (int iters : {20, 50})
    for (int dense = 0; dense < 2; ++dense)
      for (int threads = 1; threads <= 2; ++threads) {
      iclk::TrackerOptions opt;
      opt.iterations = iters;
      opt.step_tol = 0;  // run every iteration: the worst case the budget must hold
      opt.threads = threads;
      if (dense) opt.block = {1, 1, 1, 1, 1, 1};
      iclk::Tracker<float, iclk::SE3DepthWarp<float>, 1> t(cam.width, cam.height, opt);
      std::vector<double> total, pyr, jac, it;
      int n_it = 0;
      bool conv = false;
      for (int rep = 0; rep < 15; ++rep) {
        const auto t0 = Clock::now();
        const auto& res = t.align(rg.view(), depth.view(), lg.view(), K, iclk::SE3<float>::identity());
        total.push_back(ms_since(t0));
        pyr.push_back(res.ms_pyramid);
        jac.push_back(res.ms_jacobian);
        it.push_back(res.ms_iterations);
        n_it = res.iterations;
        conv = res.converged;
      }
      if (iters == 20 && !dense && threads == 2) classic20 = median(total);
      std::printf("| classic(%d)%s, %d thread%s | %.2f | %.2f | %.2f | %.2f | %d | %s |\n", iters, dense ? " dense" : "",
                  threads, threads > 1 ? "s" : "", median(total), median(pyr), median(jac), median(it), n_it, conv ? "yes" : "no");
    }
#if defined(TERRALIGN_BENCH_OPENCV)
  cv::setNumThreads(2);
  cv::Mat a(cam.height, cam.width, CV_32F, rg.data()), b(cam.height, cam.width, CV_32F, lg.data());
  std::vector<double> ecc;
  bool ecc_ok = true;
  for (int rep = 0; rep < 15; ++rep) {
    const auto t0 = Clock::now();
    std::vector<cv::Mat> pa{a}, pb{b};
    for (int l = 1; l < 4; ++l) {
      cv::Mat da, db;
      cv::pyrDown(pa.back(), da);
      cv::pyrDown(pb.back(), db);
      pa.push_back(da);
      pb.push_back(db);
    }
    cv::Mat H = cv::Mat::eye(3, 3, CV_32F);
    try {
      for (int l = 3; l >= 0; --l) {
        if (l < 3) {
          H.at<float>(0, 2) *= 2; H.at<float>(1, 2) *= 2;
          H.at<float>(2, 0) /= 2; H.at<float>(2, 1) /= 2;
        }
        cv::findTransformECC(pa[static_cast<std::size_t>(l)], pb[static_cast<std::size_t>(l)], H, cv::MOTION_HOMOGRAPHY,
                             cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-6), cv::noArray(), 5);
      }
    } catch (const cv::Exception&) {
      ecc_ok = false;
    }
    ecc.push_back(ms_since(t0));
  }
  std::printf("| OpenCV %s findTransformECC, homography, 4 levels, <= 50 iterations/level | %.2f | | | | | %s |\n",
              CV_VERSION, median(ecc), ecc_ok ? "yes" : "no");
  std::printf("\nclassic(20) takes %.2fx the time of OpenCV ECC on this pair.\n", classic20 / median(ecc));
#else
  std::printf("\nclassic(20), 2 threads: %.2f ms. (OpenCV not found at configure time: no ECC comparison;\n"
              "apt-get install libopencv-dev)\n", classic20);
#endif
  return 0;
}
