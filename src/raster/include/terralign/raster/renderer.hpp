// The reference-view renderer: what a camera at a pose sees of a map, as one RGB image per
// orthoimage layer and a metric depth image, on the CPU.
//
// Pipeline per frame (all buffers allocated at construction; a frame allocates nothing):
//  1. Level of detail: a quadtree of DEM chunks, each drawn at the coarsest level whose
//     vertical error projects to at most `lod_error_px` pixels (skirts hide the cracks
//     between levels). A constant-height map is one flat grid.
//  2. Geometry: chunk vertices to the camera frame (float, relative to a local origin of the
//     map), clipping at the near plane and a guard band, projection, triangle set-up (a row
//     of a chunk's quads at a time where no clipping is needed), triangles binned into
//     screen tiles (geometry_kernels.hpp).
//  3. Visibility: per tile, fixed-point edge functions (8 sub-pixel bits, top-left fill
//     rule) and a depth test on 1/z give each pixel its nearest triangle; entries are set up
//     16 at a time, and triangles within one 8 x 8 block of the tile (most over a detailed
//     DEM) drawn by 32-bit edge kernels.
//  4. Resolve: per pixel, depth along the optical axis and the world (x, y) of the surface
//     point, perspective-correct from the triangle's planes (fitted in double, evaluated in
//     float relative to the tile's corner).
//  5. Shading, per requested layer, fused with the resolve of each tile row: world (x, y) ->
//     that layer's texel coordinates through its own geotransform, bilinear within a mip
//     level chosen per 16 pixels of a row from the footprint (trilinear between two levels
//     when minifying), in integers over premultiplied texels (shade_kernels.hpp); pixels off
//     the layer or on its no-data are invalid. Geometry (1-4) is done once per frame however
//     many layers are shaded.
// Cameras with distortion are rendered as a pinhole G-buffer with a margin, resampled
// through a precomputed map per output pixel (the resolve in double), then shaded: colour
// and depth stay exact.
//
// Threads work on fixed screen tiles (and rows): 1 and 2 threads give the same bytes.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/image.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>
#include <terralign/geo/result.hpp>
#include <terralign/geo/thread_pool.hpp>

namespace terralign::raster {

struct RenderOptions {
  int threads = 2;               // 1 or more
  double lod_error_px = 0.5;     // screen-space geometric error bound of the terrain mesh
  double near_m = 0.5;           // near clipping distance, metres
  int max_triangles = 1 << 19;   // per frame, after clipping; more is a failed frame
  enum class Simd { Auto, Scalar, Avx2, Avx512, Neon } simd = Simd::Auto;
};

// What render() fills. Make one with Renderer::make_output() (it sizes everything once).
struct RenderOutput {
  std::vector<std::string> layer_names;   // the layers shaded, in this order
  std::vector<int> layer_index;           // their indices in the map (set by make_output)
  std::vector<ImageU8> rgb;               // per layer: 3 channels
  std::vector<ImageU8> valid;             // per layer: 255 where the colour is valid, else 0
  ImageF depth;                           // metres along the optical axis; NaN: no terrain
};

struct RenderStats {
  int triangles = 0;        // after LOD and clipping
  int chunks = 0;           // terrain chunks drawn
  int chunks_one_way = 0;   // of those, drawn with twice their grid along one axis (kWide, kTall)
  int chunks_one_quad = 0;  // of those, drawn as one quad (kOneQuad)
  long fragments = 0;       // pixels that passed a triangle's coverage test (overdraw included)
  int tiles_one_triangle = 0;  // pinhole screen tiles wholly inside their only triangle (no depth test)
  // Stage times: LOD, geometry and binning; visibility per tile (for a pinhole camera also
  // the resolve and the shading of every layer, done tile by tile); for a distorted camera,
  // the remap, resolve and shading afterwards (0 for a pinhole camera).
  double ms_geometry = 0, ms_raster = 0, ms_shade = 0;
};

class Renderer {
 public:
  // The map must outlive the renderer. Errors: bad camera, bad options. `pool`: the caller's
  // pool to run on, with options.threads threads, which must outlive the renderer and is not
  // used by two callers at once (a pipeline that renders and then aligns: nn::Network::plan);
  // else the renderer starts a pool of its own.
  static Result<std::unique_ptr<Renderer>> create(const geo::Map& map, const geo::CameraModel& camera,
                                                  const RenderOptions& options = {}, ThreadPool* pool = nullptr);
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  // Sizes an output for the given layers ("all" or names). Errors name an unknown layer.
  Result<RenderOutput> make_output(const std::vector<std::string>& layers) const;

  // Renders the view from T_W_C into `out`. A pose that is not finite, below the terrain or
  // whose view misses the map is an error (the output then holds an all-invalid frame).
  Status render(const geo::Pose& T_W_C, RenderOutput& out, RenderStats* stats = nullptr);

  const geo::CameraModel& camera() const;
  const char* simd_name() const;

  struct Impl;

 private:
  explicit Renderer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace terralign::raster
