// The OpenGL peer of bench_render: the same map, camera and pose drawn by Mesa's llvmpipe
// (software OpenGL on the CPU, through OSMesa) as a textured triangle grid of the DEM, with
// trilinear mip-mapping, colour and depth read back every frame. Built only where Debian's
// libosmesa6-dev is installed; terralign never links it.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>

namespace bench {

struct GlFrame {
  std::string error;              // empty: it worked
  double fps = 0;                 // median of timed batches, read-back included
  long triangles = 0;             // drawn per frame (the whole grid)
  std::vector<std::uint8_t> rgb;  // top row first, 3 bytes a pixel
  std::vector<std::uint8_t> hit;  // 1 where a triangle covered the pixel
};

// Renders `layer` of `map` through `cam` (pinhole) at `T_W_C` with llvmpipe on `threads`
// threads (LP_NUM_THREADS). A constant DEM becomes a 257 x 257 grid over the layer; a DEM
// raster its own posts.
GlFrame gl_render(const terralign::geo::Map& map, const std::string& layer, const terralign::geo::CameraModel& cam,
                  const terralign::geo::Pose& T_W_C, int threads, int frames);

}  // namespace bench
