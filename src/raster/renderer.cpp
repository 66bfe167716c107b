#include <terralign/raster/renderer.hpp>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include <terralign/geo/float_environment.hpp>
#include <terralign/geo/number_text.hpp>
#include <terralign/geo/numeric.hpp>
#include <terralign/raster/geometry_kernels.hpp>
#include <terralign/raster/shade_kernels.hpp>
#include <terralign/raster/terrain.hpp>
#include <terralign/geo/thread_pool.hpp>

namespace terralign::raster {
namespace {

// A tile row is one call of the fused resolve-and-shade kernel: 128 pixels give the AVX-512
// kernel eight vectors to overlap (64 gave four: 7 % slower on the flat nadir frame). Tile
// rows are split between the threads whole (see render()): 24 pixels high, a 480-pixel
// frame has 20 of them, an even share for two threads (32 gave 15: 9 % slower oblique).
constexpr int kTileW = 128, kTileH = 24;
constexpr int kVisStride = kTileW + 8;   // a visibility buffer's row (see Impl::zbuf)
constexpr int kVisSlice = kTileH * kVisStride + 16;  // a tile's visibility buffer, and a cache line apart
constexpr double kGuardPx = 2048.0;      // guard band beyond the image, pixels
constexpr int kMaxClipVerts = 9;
constexpr int kMaxTileEntries = 1 << 16;  // triangles binned into one tile, at most
constexpr long kBoundMinPixels = 32;     // an entry covering fewer has no footprint bound

using Clock = std::chrono::steady_clock;

// The screen tiles a triangle's pixel box touches, inclusive (create() keeps tile indices
// below 2^16). Kept beside the triangles, 8 bytes each, so that binning reads these alone and
// not the triangles' cache lines.
struct TileSpan {
  std::uint16_t x0, y0, x1, y1;
};

// Plane k of t at (dx, dy) pixels from its box's corner, in double.
inline double plane_at(const Tri& t, int k, double dx, double dy) {
  return static_cast<double>(t.C[k]) + static_cast<double>(t.A[k]) * dx + static_cast<double>(t.B[k]) * dy;
}

constexpr int kChunkVerts = (kMaxGridQuads + 1) * (kChunkQuads + 1);  // a Wide or Tall chunk's posts

// One thread's share of a frame's geometry: the triangles of its run of chunks, in draw
// order, in its own region of the triangle array, and the scratch of the chunk being drawn.
// Each part, like each thread's RasterScratch and RowBand, starts a cache line of its own
// (kUnsharedAlign): a line that two threads write moves between their cores on every write,
// which costs far more than the write.
struct alignas(kUnsharedAlign) GeomPart {
  Tri* tris = nullptr;        // max_triangles entries
  TileSpan* spans = nullptr;  // likewise, one per triangle
  int n_tris = 0;
  bool overflow = false;
  int chunks_drawn = 0;
  std::vector<float> verts_f32;      // a chunk's posts in the camera frame (verts), kChunkVerts
  ClipGrid verts{};
  std::vector<double> proj_f64;      // their projections (proj), where out is 0
  std::vector<std::int32_t> proj_i32;
  ProjGrid proj{};
  std::vector<std::uint8_t> out;     // per post: bit p set when outside clip plane p
  bool no_height[kChunkVerts];       // per post: its height is NaN (no data)
  PixelBox row_boxes[2 * kMaxGridQuads];  // the boxes of a row of quads' triangles
  std::vector<int> tile_count;       // per screen tile: this part's triangles binned there (counted as drawn)
  std::vector<int> tile_fill;        // per screen tile: where this part's next entry goes
};

// A thread's band of units, tile rows or blocks of output rows (see Renderer::render()): the
// next unit to take from its top (low 16 bits) and the end of the units not yet taken (high
// 16 bits). 32 bits, which every target's atomics handle (a Cortex-M7 has none of 64); a view
// at most 2^20 pixels high has fewer than 2^16 tile rows or blocks of rows.
struct alignas(kUnsharedAlign) RowBand {
  std::atomic<std::uint32_t> rows{0};
};
constexpr int kRowsPerBlock = 24;  // output rows a unit of a distorted camera's resolve and shading
static_assert(((1 << 20) + std::min(kTileH, kRowsPerBlock) - 1) / std::min(kTileH, kRowsPerBlock) < (1 << 16),
              "units must fit a RowBand's 16-bit halves");

// What a thread writes as it rasterizes, beside its visibility buffer (see GeomPart).
struct alignas(kUnsharedAlign) RasterScratch {
  ShadeTarget targets[kMaxShadeTargets];  // the row being resolved, one per requested layer
  long fragments = 0;                     // pixels its tiles covered this frame
  int whole_tiles = 0;                    // its tiles wholly inside their only triangle
};

// Triangle t's three edge functions at pixel (x, y), in the fixed point of its corners, and
// their steps a pixel right and down. Edge k runs from corner k to corner k + 1; inside: E > 0,
// or E == 0 on a top or left edge (clockwise on screen with y down: top = horizontal going
// right, left = going up). The bias folds the rule into one test, E >= 0 for all three.
struct EdgeFunctions {
  std::int64_t E[3], dEx[3], dEy[3];
};
inline EdgeFunctions edge_functions(const Tri& t, int x, int y) {
  EdgeFunctions f;
  const std::int64_t px = static_cast<std::int64_t>(x) << kSubBits, py = static_cast<std::int64_t>(y) << kSubBits;
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3;
    const std::int64_t ex = std::int64_t{t.X[k1]} - t.X[k], ey = std::int64_t{t.Y[k1]} - t.Y[k];
    const bool top_left = (ey == 0 && ex > 0) || ey < 0;
    f.E[k] = ex * (py - t.Y[k]) - ey * (px - t.X[k]) - (top_left ? 0 : 1);
    f.dEx[k] = -ey * (std::int64_t{1} << kSubBits);
    f.dEy[k] = ex * (std::int64_t{1} << kSubBits);
  }
  return f;
}

// Whether triangle t covers every pixel of the box x0 .. x1, y0 .. y1 (`all`), or may cover
// one (not `all`: false only where the box lies wholly outside one of its edges). The edge
// functions are linear, so the box's four corners tell.
inline bool covers_box(const Tri& t, int x0, int y0, int x1, int y1, bool all) {
  const EdgeFunctions f = edge_functions(t, x0, y0);
  for (int k = 0; k < 3; ++k) {
    const std::int64_t right = f.dEx[k] * (x1 - x0), down = f.dEy[k] * (y1 - y0);
    const std::int64_t c[4] = {f.E[k], f.E[k] + right, f.E[k] + down, f.E[k] + right + down};
    if (all ? std::min({c[0], c[1], c[2], c[3]}) < 0 : std::max({c[0], c[1], c[2], c[3]}) < 0) return false;
  }
  return true;
}

// A row of a tile's entries where every pixel sees the tile's entry 0 (Impl::raster_tile()).
const std::array<int, kTileW> kEntryZeros{};

struct LayerTexture {
  std::string name;
  std::unique_ptr<std::uint32_t[]> texels;
  std::vector<MipLevel> levels;
  std::vector<LevelCoords> coords;  // local world -> each level's texel coordinates
  float lod_bias;
};

}  // namespace

struct Renderer::Impl {
  const geo::Map* map = nullptr;
  geo::CameraModel camera;        // the output camera
  geo::CameraModel pinhole;       // the G-buffer's camera (= camera without distortion)
  RenderOptions options;
  double ox = 0, oy = 0, oz = 0;  // local origin in map coordinates
  Terrain terrain;
  std::vector<LayerTexture> layers;
  ShadeRowFn shade = shade_row_scalar;
  ResolveShadeRowFn resolve_shade = resolve_shade_row_scalar;
  DepthBlockFn depth_block = depth_block_scalar;
  EdgeBlockFn edge_block = edge_block_scalar;
  EdgeBlock32Fn edge_block32 = nullptr;   // where built: blocks whose edge values fit 32 bits
  EmitQuadRowFn emit_quad_row = emit_quad_row_scalar;
  ProjectPostsFn project_posts = project_posts_scalar;
  SetupEntriesFn setup_entries = setup_entries_scalar;
  DrawSmallEntriesFn draw_small_entries = nullptr;  // where edge_block32 is built
  const char* simd = "scalar";
  std::unique_ptr<ThreadPool> own_pool;  // where the caller gave none
  ThreadPool* pool = nullptr;

  // Frame buffers, sized at construction.
  int vw = 0, vh = 0;                     // pinhole (G-buffer) size
  int tiles_x = 0, tiles_y = 0;
  // max_triangles per thread (thread j's triangles from j * max_triangles: a triangle's
  // index names it everywhere below), not zeroed (default-initialised): a view touches, and
  // so commits to memory, only the pages of the triangles it draws.
  std::unique_ptr<Tri[]> tris;
  std::unique_ptr<TileSpan[]> spans;      // likewise
  std::vector<GeomPart> parts;            // per thread
  std::vector<int> draw_list;             // the chunks a frame draws, in traversal order
  std::vector<std::uint8_t> drawn;        // per chunk: 1 + its grid (ChunkGrid) while in the draw list
  std::vector<int> tile_count, tile_start;  // per tile: bin entries, first entry
  std::vector<std::vector<float>> tile_coef;  // per thread: kPlaneFloats per bin entry of a tile
  int max_tile_entries = 0;                    // bin entries one tile may hold
  std::unique_ptr<int[]> bin_entries;     // likewise not zeroed
  std::size_t bin_capacity = 0;
  // Visibility: 1/z of the nearest triangle so far (0: none) and its bin entry (-1: none),
  // a tile's worth at a time (kTileH rows of kVisStride, kVisSlice apart). A pinhole camera
  // resolves each tile as soon as it is rasterized, so each thread keeps one (26 KB, in L1
  // from tile to tile); a distorted camera resolves after every tile is done and keeps one
  // per tile. Rows hold 8 pixels more than a tile's: the depth kernels read and write back
  // 8 columns from a block's first (shade_kernels.hpp), which stay inside the tile's own.
  std::vector<float> zbuf;
  std::vector<int> idbuf;
  std::vector<float> remap_u, remap_v;    // per output pixel, pinhole position (distortion)
  std::vector<float> gx, gy, gz;          // distorted camera, per output pixel: local world x, y; depth
  std::vector<float> log2fp;              // distorted camera, per output pixel
  std::vector<RasterScratch> raster_scratch;  // per thread
  std::unique_ptr<RowBand[]> row_bands;       // per thread
  std::vector<ShadeParams> layer_params;  // per layer
  std::vector<int> chunk_stack;

  // Per-frame state.
  RenderOutput* frame_out = nullptr;
  Eigen::Matrix3f R_C_W;
  Eigen::Vector3f t_local;     // camera centre, local
  PostFrame frame{};           // the vertex stage's constants (R_C_W, t_local, clip volume, pinhole)

  void emit_triangle(GeomPart& g, const ProjVert& a, const ProjVert& b, const ProjVert& c) const;
  void add_triangle(GeomPart& g, const PixelBox& p) const;
  void clip_and_emit(GeomPart& g, const ClipVert* v, int n) const;
  void draw_chunk(GeomPart& g, const TerrainChunk& c, int grid) const;
  float skirt_drop(const TerrainChunk& c, int grid, int side) const;
  void draw_chunks(int part);
  void bin_part(int part);
  PixelBox box(const Tri& t) const { return pixel_box(t.X, t.Y, vw, vh); }
  // Calls f(tile index) for every screen tile of triangle t's span s that t may cover: where
  // the span holds more than two tiles, not those wholly outside one of t's edges (a large
  // triangle's box holds many it misses; a tile inside one alone is drawn without a
  // visibility buffer, see raster_tile()).
  template <class F>
  void for_each_tile(const Tri& t, const TileSpan& s, F&& f) const {
    const bool test = (s.x1 - s.x0 + 1) * (s.y1 - s.y0 + 1) > 2;
    for (int b = s.y0; b <= s.y1; ++b)
      for (int a = s.x0; a <= s.x1; ++a)
        if (!test || covers_box(t, a * kTileW, b * kTileH, std::min(a * kTileW + kTileW, vw) - 1,
                                std::min(b * kTileH + kTileH, vh) - 1, false))
          f(static_cast<std::size_t>(b * tiles_x + a));
  }
  bool in_view(const TerrainChunk& c) const;
  bool chunk_visible_and_coarse_enough(const TerrainChunk& c, int& grid, bool one_quad = true) const;
  void choose_chunks();
  void seal_one_quads();
  bool drawn_along(int index, int side) const;
  struct Across {
    int same, drawn;
  };
  Across across(const TerrainChunk& c, int side) const;
  void raster_tile(int tile, int thread);
  void resolve_tile(int tile, int thread, const int* ids, std::ptrdiff_t id_stride, const float* coef);
  void deal_bands(int units);
  template <class F>
  void claim_units(int thread, F&& draw);
  void resolve_rows(int row0, int row1);
  void shade_span(int y, int x, int n, const float* wx, const float* wy, const float* log2fp);
};

namespace {

void build_mips(const geo::Layer& L, LayerTexture& T, ThreadPool& pool) {
  const int w0 = L.rgba.width(), h0 = L.rgba.height();
  T.levels = mip_chain(w0, h0, kMaxMipLevels);
  const std::size_t end = mip_chain_end(T.levels);
  // A guard texel (0) at each end: the vector kernels read a row's two taps as one pair,
  // which may start one texel before a level or end one after it (shade_kernels.hpp). Not
  // zero-filled here: every texel is written below, the rows split over the threads (a
  // 20000^2 layer is 2.1 GB with its mips; the first touch of its pages is most of the cost).
  T.texels.reset(new std::uint32_t[end + 1]);
  T.texels[0] = 0;
  T.texels[end] = 0;
  // Level 0, premultiplied (shade_kernels.hpp): a layer's alpha is 0 or 255, which makes this
  // exact; the rounding serves any other alpha.
  const std::uint8_t* src = L.rgba.data();
  for_rows(pool, h0, [&](int y) {
    for (std::size_t k = static_cast<std::size_t>(y) * static_cast<std::size_t>(w0); k < static_cast<std::size_t>(y + 1) * static_cast<std::size_t>(w0); ++k) {
      const std::uint32_t a = src[4 * k + 3];
      auto pre = [a](std::uint32_t c) { return (c * a + 127) / 255; };
      T.texels[1 + k] = pre(src[4 * k]) | pre(src[4 * k + 1]) << 8 | pre(src[4 * k + 2]) << 16 | a << 24;
    }
  });
  // Each coarser level: the rounded mean of the 2 x 2 premultiplied texels below (the last
  // row or column repeated where the level below is odd), channel by channel, alpha too.
  for (std::size_t l = 1; l < T.levels.size(); ++l) {
    const MipLevel prev = T.levels[l - 1], cur = T.levels[l];
    const int w = prev.width, h = prev.height;
    for_rows(pool, cur.height, [&](int y) {
      for (int x = 0; x < cur.width; ++x) {
        std::uint32_t sum[4] = {2, 2, 2, 2};
        for (int k = 0; k < 4; ++k) {
          const int sx = std::min(2 * x + (k & 1), w - 1), sy = std::min(2 * y + (k >> 1), h - 1);
          const std::uint32_t t = T.texels[static_cast<std::size_t>(prev.offset) + static_cast<std::size_t>(sy) * static_cast<std::size_t>(w) + static_cast<std::size_t>(sx)];
          for (int c = 0; c < 4; ++c) sum[c] += (t >> (8 * c)) & 255u;
        }
        T.texels[static_cast<std::size_t>(cur.offset) + static_cast<std::size_t>(y) * static_cast<std::size_t>(cur.width) + static_cast<std::size_t>(x)] =
            (sum[0] >> 2) | (sum[1] >> 2) << 8 | (sum[2] >> 2) << 16 | (sum[3] >> 2) << 24;
      }
    });
  }
}

}  // namespace

Result<std::unique_ptr<Renderer>> Renderer::create(const geo::Map& map, const geo::CameraModel& camera,
                                                   const RenderOptions& options, ThreadPool* pool) {
  const FloatEnvironmentScope float_environment;
  TERRALIGN_TRY(camera.validate("camera"));
  if (options.threads < 1 || options.threads > 64)
    return Error{"render threads " + std::to_string(options.threads) + " is outside 1..64"};
  if (pool && pool->threads() != options.threads)
    return Error{"render threads " + std::to_string(options.threads) + " but the pool given has " +
                 std::to_string(pool->threads())};
  if (!(options.lod_error_px > 0) || !(options.near_m > 0))
    return Error{"render options: lod_error_px and near_m must be > 0"};
  if (options.max_triangles < 1024 || options.max_triangles > (1 << 24))
    return Error{"render options: max_triangles " + std::to_string(options.max_triangles) + " is outside 1024..2^24"};
  // Each thread has max_triangles slots of its own (its share of the geometry may be all of
  // it), reserved but committed only where drawn; bound the reservation (4.3 GB at most).
  if (static_cast<long>(options.threads) * options.max_triangles > (1L << 25))
    return Error{"render options: threads x max_triangles (" + std::to_string(options.threads) + " x " +
                 std::to_string(options.max_triangles) + ") is over 2^25"};
  auto impl = std::make_unique<Impl>();
  Impl& m = *impl;
  m.map = &map;
  m.camera = camera;
  m.options = options;
  const geo::Extent common = map.common_extent();
  m.ox = 0.5 * (common.min_x + common.max_x);
  m.oy = 0.5 * (common.min_y + common.max_y);
  m.oz = map.dem.min_height;
  m.pool = given_or_own(pool, options.threads, m.own_pool);  // also builds the mip-maps below
  m.terrain = Terrain::build(map, m.ox, m.oy, m.oz, m.pool);

  for (const auto& L : map.layers) {
    LayerTexture T;
    T.name = L.name;
    build_mips(L, T, *m.pool);
    double u0, v0, u1, v1, u2, v2;
    L.transform.world_to_pixel(m.ox, m.oy, u0, v0);
    L.transform.world_to_pixel(m.ox + 1.0, m.oy, u1, v1);
    L.transform.world_to_pixel(m.ox, m.oy + 1.0, u2, v2);
    T.coords = level_coords(T.levels, u0, u1 - u0, u2 - u0, v0, v1 - v0, v2 - v0);
    const auto& g = L.transform.gdal();
    T.lod_bias = static_cast<float>(-0.5 * log_portable(std::abs(g[1] * g[5] - g[2] * g[4])) / 0.6931471805599453);  // log2
    m.layers.push_back(std::move(T));
  }

  // The G-buffer camera: the same pinhole, grown to hold every distorted output pixel.
  m.pinhole = camera;
  m.pinhole.model = geo::DistortionModel::None;
  m.pinhole.k = {};
  if (camera.model != geo::DistortionModel::None) {
    const std::size_t n = static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height);
    m.remap_u.assign(n, NAN);
    m.remap_v.assign(n, NAN);
    double umin = INFINITY, umax = -INFINITY, vmin = INFINITY, vmax = -INFINITY;
    for (int v = 0; v < camera.height; ++v)
      for (int u = 0; u < camera.width; ++u) {
        Eigen::Vector3d ray;
        if (!camera.unproject(Eigen::Vector2d(u, v), ray)) continue;
        const double pu = camera.fx * ray.x(), pv = camera.fy * ray.y();
        const std::size_t k = static_cast<std::size_t>(v) * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(u);
        m.remap_u[k] = static_cast<float>(pu);
        m.remap_v[k] = static_cast<float>(pv);
        umin = std::min(umin, pu); umax = std::max(umax, pu);
        vmin = std::min(vmin, pv); vmax = std::max(vmax, pv);
      }
    if (!(umin <= umax)) return Error{"camera: the distortion cannot be inverted anywhere in the image"};
    const double w = std::ceil(umax - umin) + 3, h = std::ceil(vmax - vmin) + 3;
    if (w * h > 4.0 * static_cast<double>(n))
      return Error{"camera: the undistorted view needs " + std::to_string(static_cast<long>(w)) + " x " +
                   std::to_string(static_cast<long>(h)) + " pixels, over 4x the image; distortion too strong"};
    m.pinhole.width = static_cast<int>(w);
    m.pinhole.height = static_cast<int>(h);
    m.pinhole.cx = 1.0 - umin;
    m.pinhole.cy = 1.0 - vmin;
    for (std::size_t k = 0; k < n; ++k) {
      m.remap_u[k] = static_cast<float>(m.remap_u[k] + m.pinhole.cx);
      m.remap_v[k] = static_cast<float>(m.remap_v[k] + m.pinhole.cy);
    }
  }
  m.vw = m.pinhole.width;
  m.vh = m.pinhole.height;
  if (m.vw > (1 << 20) || m.vh > (1 << 20))  // keeps fixed-point positions in 32 bits (Tri)
    return Error{"camera: the undistorted view is " + std::to_string(m.vw) + " x " + std::to_string(m.vh) +
                 " pixels, over 2^20 a side"};
  m.frame.guard[0] = static_cast<float>((-kGuardPx - m.pinhole.cx) / m.pinhole.fx);
  m.frame.guard[1] = static_cast<float>((m.vw + kGuardPx - m.pinhole.cx) / m.pinhole.fx);
  m.frame.guard[2] = static_cast<float>((-kGuardPx - m.pinhole.cy) / m.pinhole.fy);
  m.frame.guard[3] = static_cast<float>((m.vh + kGuardPx - m.pinhole.cy) / m.pinhole.fy);
  m.frame.near = static_cast<float>(options.near_m);
  m.frame.fx = m.pinhole.fx;
  m.frame.fy = m.pinhole.fy;
  m.frame.cx = m.pinhole.cx;
  m.frame.cy = m.pinhole.cy;
  m.tiles_x = (m.vw + kTileW - 1) / kTileW;
  m.tiles_y = (m.vh + kTileH - 1) / kTileH;
  if (m.tiles_x > 65535 || m.tiles_y > 65535)  // (TileSpan's 16 bits; the camera's 32768 px keep far below)
    return Error{"render: " + std::to_string(m.tiles_x) + " x " + std::to_string(m.tiles_y) + " screen tiles, over 65535 a side"};
  const std::size_t tiles = static_cast<std::size_t>(m.tiles_x) * static_cast<std::size_t>(m.tiles_y);
  m.tris.reset(new Tri[static_cast<std::size_t>(options.threads) * static_cast<std::size_t>(options.max_triangles)]);
  m.spans.reset(new TileSpan[static_cast<std::size_t>(options.threads) * static_cast<std::size_t>(options.max_triangles)]);
  m.parts.resize(static_cast<std::size_t>(options.threads));
  for (std::size_t j = 0; j < m.parts.size(); ++j) {
    GeomPart& g = m.parts[j];
    g.tris = m.tris.get() + j * static_cast<std::size_t>(options.max_triangles);
    g.spans = m.spans.get() + j * static_cast<std::size_t>(options.max_triangles);
    g.verts_f32.resize(5 * kChunkVerts);
    float* v = g.verts_f32.data();
    g.verts = {v, v + kChunkVerts, v + 2 * kChunkVerts, v + 3 * kChunkVerts, v + 4 * kChunkVerts};
    g.proj_f64.resize(5 * kChunkVerts);
    g.proj_i32.resize(2 * kChunkVerts);
    double* f = g.proj_f64.data();
    std::int32_t* i = g.proj_i32.data();
    g.proj = {f, f + kChunkVerts, f + 2 * kChunkVerts, f + 3 * kChunkVerts, f + 4 * kChunkVerts, i, i + kChunkVerts};
    g.out.resize(kChunkVerts);
    g.tile_count.resize(tiles);
    g.tile_fill.resize(tiles);
  }
  m.tile_count.resize(tiles);
  m.tile_start.resize(tiles + 1);
  // A tile holds each triangle at most once: no more entries than triangles (a small target's
  // renderer, with a small max_triangles, stays small).
  m.max_tile_entries = std::min(kMaxTileEntries, options.max_triangles);
  m.tile_coef.resize(static_cast<std::size_t>(options.threads));
  for (auto& coef : m.tile_coef) coef.resize(kPlaneFloats * static_cast<std::size_t>(m.max_tile_entries));
  m.bin_capacity = static_cast<std::size_t>(options.max_triangles) * 4 + tiles * 256;
  m.bin_entries.reset(new int[m.bin_capacity]);
  const std::size_t vpx = static_cast<std::size_t>(kVisSlice) *
                          (m.remap_u.empty() ? static_cast<std::size_t>(options.threads) : static_cast<std::size_t>(tiles));
  m.zbuf.resize(vpx);
  m.idbuf.resize(vpx);
  if (!m.remap_u.empty()) {
    const std::size_t opx = static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height);
    m.gx.resize(opx);
    m.gy.resize(opx);
    m.gz.resize(opx);
    m.log2fp.resize(opx);
  }
  m.raster_scratch.resize(static_cast<std::size_t>(options.threads));
  m.row_bands.reset(new RowBand[static_cast<std::size_t>(options.threads)]);
  for (const LayerTexture& T : m.layers)
    m.layer_params.push_back({T.texels.get(), T.levels.data(), T.coords.data(), static_cast<int>(T.levels.size()), T.lod_bias});
  m.chunk_stack.reserve(m.terrain.chunks().size() + 8);
  m.draw_list.reserve(m.terrain.chunks().size());
  m.drawn.assign(m.terrain.chunks().size(), 0);

  const bool avx2 = cpu_has_avx2();
  if (options.simd == RenderOptions::Simd::Avx2 && !avx2)
    return Error{"render options: AVX2 kernels requested but this CPU (or build) has none"};
#if defined(TERRALIGN_HAVE_AVX2)
  if (avx2 && options.simd != RenderOptions::Simd::Scalar) {
    m.shade = shade_row_avx2;
    m.resolve_shade = resolve_shade_row_avx2;
    m.depth_block = depth_block_avx2;
    m.edge_block = edge_block_avx2;
    m.edge_block32 = edge_block32_avx2;
    m.project_posts = project_posts_avx2;
    m.emit_quad_row = emit_quad_row_avx2;
    m.setup_entries = setup_entries_avx2;
    m.draw_small_entries = draw_small_entries_avx2;
    m.simd = "avx2";
  }
#endif
  if (options.simd == RenderOptions::Simd::Avx512 && !cpu_has_avx512())
    return Error{"render options: AVX-512 kernels requested but this CPU (or build) has none"};
#if defined(TERRALIGN_HAVE_AVX2)
  if (cpu_has_avx512() && (options.simd == RenderOptions::Simd::Auto || options.simd == RenderOptions::Simd::Avx512)) {
    m.shade = shade_row_avx512;  // the edge kernels stay AVX2
    m.resolve_shade = resolve_shade_row_avx512;
    m.depth_block = depth_block_avx512;
    m.emit_quad_row = emit_quad_row_avx512;
    m.project_posts = project_posts_avx512;
    m.setup_entries = setup_entries_avx512;
    m.simd = "avx512";
  }
#endif
#if defined(TERRALIGN_HAVE_NEON)
  if (options.simd == RenderOptions::Simd::Auto || options.simd == RenderOptions::Simd::Neon) {  // every aarch64 core has it
    m.shade = shade_row_neon;
    m.resolve_shade = resolve_shade_row_neon;
    m.depth_block = depth_block_neon;
    m.edge_block = edge_block_neon;
    m.edge_block32 = edge_block32_neon;
    m.draw_small_entries = draw_small_entries_neon;
    m.project_posts = project_posts_neon;
    m.emit_quad_row = emit_quad_row_neon;
    m.setup_entries = setup_entries_neon;
    m.simd = "neon";
  }
#else
  if (options.simd == RenderOptions::Simd::Neon)
    return Error{"render options: NEON kernels requested but this build (not aarch64) has none"};
#endif
  return std::unique_ptr<Renderer>(new Renderer(std::move(impl)));
}

Renderer::Renderer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Renderer::~Renderer() = default;
const geo::CameraModel& Renderer::camera() const { return impl_->camera; }
const char* Renderer::simd_name() const { return impl_->simd; }

Result<RenderOutput> Renderer::make_output(const std::vector<std::string>& names) const {
  RenderOutput out;
  const bool all = names.empty() || (names.size() == 1 && names[0] == "all");
  for (std::size_t i = 0; i < impl_->layers.size(); ++i)
    if (all) {
      out.layer_names.push_back(impl_->layers[i].name);
      out.layer_index.push_back(static_cast<int>(i));
    }
  if (!all) {
    for (const auto& n : names) {
      int index = -1;
      for (std::size_t i = 0; i < impl_->layers.size(); ++i)
        if (impl_->layers[i].name == n) index = static_cast<int>(i);
      if (index < 0)
        return Error{"no layer named '" + n + "' in " + impl_->map->path + " (layers: " + impl_->map->layer_names() + ")"};
      out.layer_names.push_back(n);
      out.layer_index.push_back(index);
    }
  }
  if (out.layer_names.size() > static_cast<std::size_t>(kMaxShadeTargets))
    return Error{"render: " + std::to_string(out.layer_names.size()) + " layers in one output, over " +
                 std::to_string(kMaxShadeTargets) + "; render them in several outputs"};
  const int w = impl_->camera.width, h = impl_->camera.height;
  for (std::size_t i = 0; i < out.layer_names.size(); ++i) {
    out.rgb.emplace_back(w, h, 3);
    out.valid.emplace_back(w, h, 1);
  }
  out.depth.resize(w, h, 1, NAN);
  return out;
}

// ---- geometry ----

void Renderer::Impl::emit_triangle(GeomPart& g, const ProjVert& a, const ProjVert& b, const ProjVert& c) const {
  if (g.n_tris >= options.max_triangles) {
    g.overflow = true;
    return;
  }
  PixelBox box;
  if (setup_triangle(a, b, c, vw, vh, g.tris[g.n_tris], box)) add_triangle(g, box);
}

// Counts the triangle just set up at g.tris[g.n_tris], whose pixel box is p, into its tiles.
void Renderer::Impl::add_triangle(GeomPart& g, const PixelBox& p) const {
  TileSpan& span = g.spans[g.n_tris];
  span = {static_cast<std::uint16_t>(p.x0 / kTileW), static_cast<std::uint16_t>(p.y0 / kTileH),
          static_cast<std::uint16_t>(p.x1 / kTileW), static_cast<std::uint16_t>(p.y1 / kTileH)};
  for_each_tile(g.tris[g.n_tris], span, [&](std::size_t tile) { ++g.tile_count[tile]; });
  ++g.n_tris;
}

void Renderer::Impl::clip_and_emit(GeomPart& g, const ClipVert* in, int n) const {
  const float near = frame.near;
  ClipVert buf[2][kMaxClipVerts];
  int count = n;
  std::copy(in, in + n, buf[0]);
  int cur = 0;
  for (int plane = 0; plane < 5; ++plane) {
    bool all_in = true, all_out = true;
    for (int i = 0; i < count; ++i) {
      const bool inside = clip_distance(frame, plane, buf[cur][i]) >= 0;
      all_in = all_in && inside;
      all_out = all_out && !inside;
    }
    if (all_out) return;
    if (all_in) continue;
    int m = 0;
    for (int i = 0; i < count && m < kMaxClipVerts - 1; ++i) {
      const ClipVert& a = buf[cur][i];
      const ClipVert& b = buf[cur][(i + 1) % count];
      const float da = clip_distance(frame, plane, a), db = clip_distance(frame, plane, b);
      if (da >= 0) buf[1 - cur][m++] = a;
      if ((da >= 0) != (db >= 0)) {
        const float s = da / (da - db);
        ClipVert c;
        c.x = a.x + s * (b.x - a.x);
        c.y = a.y + s * (b.y - a.y);
        c.z = a.z + s * (b.z - a.z);
        c.wx = a.wx + s * (b.wx - a.wx);
        c.wy = a.wy + s * (b.wy - a.wy);
        if (plane == 0) c.z = std::max(c.z, near);
        buf[1 - cur][m++] = c;
      }
    }
    cur = 1 - cur;
    count = m;
    if (count < 3) return;
  }
  ProjVert p[kMaxClipVerts];
  for (int i = 0; i < count; ++i) p[i] = project_vertex(frame, buf[cur][i]);
  for (int i = 1; i + 1 < count; ++i) emit_triangle(g, p[0], p[i], p[i + 1]);
}

// Whether chunk c's box may be in view: not all eight corners outside one side of the view
// frustum (the image, not the guard).
bool Renderer::Impl::in_view(const TerrainChunk& c) const {
  const float xs[2] = {c.min_x, c.max_x}, ys[2] = {c.min_y, c.max_y}, zs[2] = {c.min_z - 0.01f, c.max_z + 0.01f};
  const float l = static_cast<float>((-0.5 - pinhole.cx) / pinhole.fx), r = static_cast<float>((vw - 0.5 - pinhole.cx) / pinhole.fx);
  const float tp = static_cast<float>((-0.5 - pinhole.cy) / pinhole.fy), bt = static_cast<float>((vh - 0.5 - pinhole.cy) / pinhole.fy);
  int out[5] = {0, 0, 0, 0, 0};
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector3f p = R_C_W * (Eigen::Vector3f(xs[k & 1], ys[(k >> 1) & 1], zs[k >> 2]) - t_local);
    out[0] += p.z() < static_cast<float>(options.near_m);
    out[1] += p.x() < l * p.z();
    out[2] += p.x() > r * p.z();
    out[3] += p.y() < tp * p.z();
    out[4] += p.y() > bt * p.z();
  }
  for (int o : out)
    if (o == 8) return false;
  return true;
}

// Whether chunk c is in view, and then the grid to draw it with (ChunkGrid), or -1: refine it.
// `one_quad`: whether OneQuad may be taken.
bool Renderer::Impl::chunk_visible_and_coarse_enough(const TerrainChunk& c, int& grid, bool one_quad) const {
  if (!in_view(c)) return false;
  // One quad where it is offered (the posts lie on it) and its error allows. Else the Square:
  // the box's own bound first (8 points), the columns' tighter one (50 points) only where the
  // box's would refine. Then the grids twice as fine along one axis (twice the triangles; the
  // children take four times), the one with the smaller error where both would do.
  const float f = static_cast<float>(std::max(pinhole.fx, pinhole.fy)), near = static_cast<float>(options.near_m);
  const float lod = static_cast<float>(options.lod_error_px);
  grid = kOneQuad;
  if (one_quad && std::isfinite(c.error[kOneQuad]) && chunk_screen_error_px(c, c.error[kOneQuad], R_C_W, t_local, f, near) <= lod)
    return true;
  grid = kSquare;
  if (c.level == 0) return true;
  if (chunk_screen_error_px(c, c.error[kSquare], R_C_W, t_local, f, near) <= lod ||
      chunk_screen_error_px(c, c.error[kSquare], R_C_W, t_local, f, near, kMaxErrorCells) <= lod)
    return true;
  grid = -1;
  float best = lod;
  for (int g : {kWide, kTall}) {
    if (!(c.error[g] < c.error[kSquare])) continue;  // not offered (+inf), or no better
    const float e = chunk_screen_error_px(c, c.error[g], R_C_W, t_local, f, near, kMaxErrorCells);
    if (e <= best) {
      best = e;
      grid = g;
    }
  }
  return true;
}

void Renderer::Impl::draw_chunk(GeomPart& g, const TerrainChunk& c, int grid) const {
  std::vector<std::uint8_t>& chunk_out = g.out;
  const int qi = c.quads_i(grid), qj = c.quads_j(grid), si = c.step_i(grid), sj = c.step_j(grid);
  const bool anti = c.anti[grid];
  const int nx = terrain.posts_x(), ny = terrain.posts_y();
  const int n = qi + 1;  // posts a row
  int ii[kMaxGridQuads + 1], jj[kMaxGridQuads + 1];
  for (int k = 0; k <= qi; ++k) ii[k] = std::min(c.i0 + k * si, nx - 1);
  for (int k = 0; k <= qj; ++k) jj[k] = std::min(c.j0 + k * sj, ny - 1);
  const bool* nan_post = g.no_height;
  // Rows of posts all inside the clip volume and with heights, and whether every quad of a
  // row has four distinct posts (not so at the map's last column): there both triangles of
  // every quad of a row between two such rows go to emit_quad_row().
  bool row_inside[kMaxGridQuads + 1];
  bool columns_distinct = true;
  for (int a = 0; a < qi; ++a) columns_distinct = columns_distinct && ii[a + 1] != ii[a];
  for (int b = 0; b <= qj; ++b) {
    float x[kMaxGridQuads + 1], y[kMaxGridQuads + 1], z[kMaxGridQuads + 1];
    for (int a = 0; a < n; ++a) terrain.post(ii[a], jj[b], x[a], y[a], z[a]);
    row_inside[b] = project_posts(frame, x, y, z, n, b * n, g.verts, g.proj, chunk_out.data(), g.no_height);
  }
  // No back-face culling: render() refuses a camera below the terrain, and above it the
  // visible side of a heightfield faces the camera, so culling would only save time.
  for (int b = 0; b < qj; ++b) {
    if (jj[b + 1] == jj[b]) continue;
    if (columns_distinct && row_inside[b] && row_inside[b + 1] && g.n_tris + 2 * qi <= options.max_triangles) {
      const int kept = emit_quad_row(g.proj, b * n, (b + 1) * n, qi, anti, vw, vh, g.tris + g.n_tris, g.row_boxes);
      for (int i = 0; i < kept; ++i) add_triangle(g, g.row_boxes[i]);
      continue;
    }
    for (int a = 0; a < qi; ++a) {
      if (ii[a + 1] == ii[a]) continue;
      const int k00 = b * n + a, k10 = k00 + 1, k01 = k00 + n, k11 = k01 + 1;
      if (nan_post[k00] || nan_post[k10] || nan_post[k01] || nan_post[k11]) continue;
      // Wholly inside the clip volume (most triangles): each vertex was projected once. The
      // triangles as emit_quad_row() makes them.
      if ((chunk_out[static_cast<std::size_t>(k00)] | chunk_out[static_cast<std::size_t>(k10)] |
           chunk_out[static_cast<std::size_t>(k01)] | chunk_out[static_cast<std::size_t>(k11)]) == 0) {
        const ProjVert p00 = g.proj.at(k00), p10 = g.proj.at(k10), p01 = g.proj.at(k01), p11 = g.proj.at(k11);
        emit_triangle(g, p00, p10, anti ? p01 : p11);
        emit_triangle(g, anti ? p10 : p00, p11, p01);
        continue;
      }
      const ClipVert v00 = g.verts.at(k00), v10 = g.verts.at(k10), v01 = g.verts.at(k01), v11 = g.verts.at(k11);
      const ClipVert t1[3] = {v00, v10, anti ? v01 : v11}, t2[3] = {anti ? v10 : v00, v11, v01};
      clip_and_emit(g, t1, 3);
      clip_and_emit(g, t2, 3);
    }
  }
  // Skirts hang from the borders where the neighbour's posts along the side are not this
  // chunk's (see skirt_drop()), so the two surfaces leave no crack between them.
  const float drops[4] = {skirt_drop(c, grid, 0), skirt_drop(c, grid, 1), skirt_drop(c, grid, 2), skirt_drop(c, grid, 3)};
  if (drops[0] > 0 || drops[1] > 0 || drops[2] > 0 || drops[3] > 0) {
    auto skirt = [&](int ka, int kb, float drop) {
      if (nan_post[ka] || nan_post[kb]) return;
      const ClipVert a = g.verts.at(ka), b = g.verts.at(kb);
      // Dropping a vertex by `drop` along world -z is -drop times the world z axis in C.
      const Eigen::Vector3f down = R_C_W * Eigen::Vector3f(0, 0, -drop);
      ClipVert a2 = a, b2 = b;
      a2.x += down.x(); a2.y += down.y(); a2.z += down.z();
      b2.x += down.x(); b2.y += down.y(); b2.z += down.z();
      const ClipVert s1[3] = {a, b, b2}, s2[3] = {a, b2, a2};
      clip_and_emit(g, s1, 3);
      clip_and_emit(g, s2, 3);
    };
    for (int k = 0; k < qi; ++k) {
      if (drops[0] > 0) skirt(k, k + 1, drops[0]);                    // top row
      if (drops[1] > 0) skirt(qj * n + k, qj * n + k + 1, drops[1]);  // bottom row
    }
    for (int k = 0; k < qj; ++k) {
      if (drops[2] > 0) skirt(k * n, (k + 1) * n, drops[2]);            // left column
      if (drops[3] > 0) skirt(k * n + qi, (k + 1) * n + qi, drops[3]);  // right column
    }
  }
  ++g.chunks_drawn;
}

// How far the skirt on one side of a chunk drawn with `grid` hangs (metres; 0: none). Sides:
// 0 top (first post row), 1 bottom, 2 left (first post column), 3 right. Every grid's
// vertices are posts, every 2^m-th along a side from the side's first, and any two chunks
// meeting along a side take posts at spacings one of which divides the other. Where the two
// spacings are equal (chunks of one level, most), the two borders are the same: no crack,
// no skirt. Otherwise the coarser border's posts are some of the finer's, the two borders
// are linear between the finer's posts, so they are at most the coarser's error apart (its
// error bounds its surface against every post it covers, those of the border too). Where the
// finer border runs below the coarser, the coarser chunk's skirt covers the gap; where
// above, the finer's: so each side hangs by the larger of the two errors (and a centimetre).
// Where no chunk of this level or coarser is drawn across the side, the neighbour is of a
// finer level (its spacing along the side at most this one's: a chunk drawn as one quad has
// neighbours of its level alone, see seal_one_quads()) or not drawn: the chunk's own error.
// Off the map (no posts across the side): none.
float Renderer::Impl::skirt_drop(const TerrainChunk& c, int grid, int side) const {
  const bool along_i = side < 2;  // the top and bottom sides run along a post row
  const float own = c.error[grid];
  const Across a = across(c, side);
  if (a.same < 0) return 0.0f;  // no posts across the side
  if (a.drawn >= 0) {
    const TerrainChunk& o = terrain.chunks()[static_cast<std::size_t>(a.drawn)];
    const int g = drawn[static_cast<std::size_t>(a.drawn)] - 1;
    if (a.drawn == a.same && (along_i ? o.step_i(g) == c.step_i(grid) : o.step_j(g) == c.step_j(grid))) return 0.0f;
    return std::max(own, o.error[g]) + 0.01f;
  }
  return own > 0 ? own + 0.01f : 0.0f;
}

// Across side `side` of chunk c (sides as in skirt_drop()): the chunk of c's level (-1: the
// map's edge) and, up the levels from it (chunk_at() is -1 above the root), the first drawn
// this frame (-1: none of c's level or coarser is).
Renderer::Impl::Across Renderer::Impl::across(const TerrainChunk& c, int side) const {
  // The level-0 chunk cell just across the side, at the side's first post.
  const int cx = c.i0 / kChunkQuads, cy = c.j0 / kChunkQuads, cells = c.span / kChunkQuads;
  const int x = side == 2 ? cx - 1 : side == 3 ? cx + cells : cx;
  const int y = side == 0 ? cy - 1 : side == 1 ? cy + cells : cy;
  Across a{-1, -1};
  for (int k = c.level;; ++k) {
    const int id = terrain.chunk_at(k, x >= 0 ? x >> k : -1, y >= 0 ? y >> k : -1);
    if (id < 0) return a;
    if (k == c.level) a.same = id;
    if (drawn[static_cast<std::size_t>(id)] != 0) {
      a.drawn = id;
      return a;
    }
  }
}

// The level of detail from the chunks on chunk_stack down: each chunk in view is drawn
// (appended to draw_list, its grid + 1 in drawn[]) or refined into its children.
void Renderer::Impl::choose_chunks() {
  const auto& chunks = terrain.chunks();
  while (!chunk_stack.empty()) {
    const int index = chunk_stack.back();
    chunk_stack.pop_back();
    const TerrainChunk& c = chunks[static_cast<std::size_t>(index)];
    int grid = kSquare;
    if (!chunk_visible_and_coarse_enough(c, grid)) continue;
    if (grid < 0) {
      for (int k = 3; k >= 0; --k)
        if (c.child[k] >= 0) chunk_stack.push_back(c.child[k]);
    } else {
      draw_list.push_back(index);
      drawn[static_cast<std::size_t>(index)] = static_cast<std::uint8_t>(1 + grid);
    }
  }
}

// A chunk drawn as one quad has one straight edge a side. Against a neighbour whose vertices
// along that side are more (a chunk of another level, or drawn with another grid) the
// neighbour's vertices lie on that edge only before snapping: T-junctions, whose snapped
// corners can leave a sliver between the two no skirt closes where it is seen from above (a
// vertical skirt then covers no pixel). So a chunk keeps its one quad only where every side
// lies on the map's edge, against a chunk of its level drawn as one quad too (the same two
// corner posts: the same edge), or against one out of view; the others take the grid the
// level of detail gives them without it, or are refined (their children chosen anew), until
// no chunk changes.
void Renderer::Impl::seal_one_quads() {
  const auto& chunks = terrain.chunks();
  auto sealed = [&](const TerrainChunk& c) {
    for (int side = 0; side < 4; ++side) {
      // The first chunk drawn across, of c's level or coarser, must be of c's level, as one
      // quad; where none is, no finer one may be drawn along the side (side ^ 1 faces c).
      const Across a = across(c, side);
      if (a.same < 0) continue;  // the map's edge
      if (a.drawn >= 0) {
        if (a.drawn != a.same || drawn[static_cast<std::size_t>(a.same)] != 1 + kOneQuad) return false;
      } else if (drawn_along(a.same, side ^ 1)) {
        return false;
      }
    }
    return true;
  };
  for (bool changed = true; changed;) {
    changed = false;
    for (std::size_t n = 0; n < draw_list.size(); ++n) {
      const int index = draw_list[n];
      const TerrainChunk& c = chunks[static_cast<std::size_t>(index)];
      if (drawn[static_cast<std::size_t>(index)] != 1 + kOneQuad || sealed(c)) continue;
      changed = true;
      int grid = kSquare;
      (void)chunk_visible_and_coarse_enough(c, grid, false);  // in view: it was drawn
      if (grid >= 0) {
        drawn[static_cast<std::size_t>(index)] = static_cast<std::uint8_t>(1 + grid);
        continue;
      }
      drawn[static_cast<std::size_t>(index)] = 0;
      draw_list.erase(draw_list.begin() + static_cast<std::ptrdiff_t>(n--));
      for (int k = 3; k >= 0; --k)
        if (c.child[k] >= 0) chunk_stack.push_back(c.child[k]);
      choose_chunks();
    }
  }
}

// Whether chunk `index` or a chunk under it touching its side `side` (as in skirt_drop()) is
// drawn this frame.
bool Renderer::Impl::drawn_along(int index, int side) const {
  if (drawn[static_cast<std::size_t>(index)] != 0) return true;
  const TerrainChunk& c = terrain.chunks()[static_cast<std::size_t>(index)];
  for (int k : c.child) {
    if (k < 0) continue;
    const TerrainChunk& h = terrain.chunks()[static_cast<std::size_t>(k)];
    const bool touches = side == 0 ? h.j0 == c.j0 : side == 1 ? h.j0 + h.span == c.j0 + c.span
                       : side == 2 ? h.i0 == c.i0 : h.i0 + h.span == c.i0 + c.span;
    if (touches && drawn_along(k, side)) return true;
  }
  return false;
}

// Part j of the frame's geometry: the j-th of `threads` equal runs of the draw list. The
// parts, taken in order, hold the triangles in draw-list order whatever the thread count.
void Renderer::Impl::draw_chunks(int part) {
  GeomPart& g = parts[static_cast<std::size_t>(part)];
  g.n_tris = 0;
  g.overflow = false;
  g.chunks_drawn = 0;
  std::fill(g.tile_count.begin(), g.tile_count.end(), 0);
  const std::size_t n = draw_list.size(), k = parts.size(), j = static_cast<std::size_t>(part);
  const auto& chunks = terrain.chunks();
  for (std::size_t i = j * n / k; i < (j + 1) * n / k; ++i) {
    const std::size_t index = static_cast<std::size_t>(draw_list[i]);
    draw_chunk(g, chunks[index], drawn[index] - 1);
  }
}

// Writes part j's triangles into the bins of the tiles they touch, from the offsets render()
// gave it: within a tile, part 0's entries come first, so a tile's entries are in draw order.
void Renderer::Impl::bin_part(int part) {
  GeomPart& g = parts[static_cast<std::size_t>(part)];
  const int first = part * options.max_triangles;
  for (int i = 0; i < g.n_tris; ++i)
    for_each_tile(g.tris[i], g.spans[i], [&](std::size_t tile) { bin_entries[static_cast<std::size_t>(g.tile_fill[tile]++)] = first + i; });
}

// ---- rasterization ----

namespace {

// log2 of a pixel's ground footprint (metres) on the triangle's plane: the larger of the
// lengths of d(world x, y)/du and d(world x, y)/dv, from the planes of 1/z, x/z and y/z.
template <class T>
inline float footprint_log2(T A0, T B0, T A1, T B1, T A2, T B2, T wx, T wy, T z) {
  const T du_x = (A1 - wx * A0) * z, du_y = (A2 - wy * A0) * z;
  const T dv_x = (B1 - wx * B0) * z, dv_y = (B2 - wy * B0) * z;
  const T d2 = std::max(du_x * du_x + du_y * du_y, dv_x * dv_x + dv_y * dv_y);
  return 0.5f * fast_log2(std::max(static_cast<float>(d2), 1e-12f));  // see shade_kernels.hpp
}

}  // namespace

void Renderer::Impl::raster_tile(int tile, int thread) {
  const int tx = tile % tiles_x, ty = tile / tiles_x;
  const int x0 = tx * kTileW, y0 = ty * kTileH;
  const int x1 = std::min(x0 + kTileW, vw) - 1, y1 = std::min(y0 + kTileH, vh) - 1;
  const bool resolve_here = remap_u.empty();
  // The tile's visibility buffers: pixel (x, y) at (y - y0) stride + x - x0.
  const std::ptrdiff_t stride = kVisStride;
  const std::ptrdiff_t origin = static_cast<std::ptrdiff_t>(resolve_here ? thread : tile) * kVisSlice;
  float* const tz = zbuf.data() + origin;
  int* const tid = idbuf.data() + origin;
  long frags = 0;
  const int first = tile_start[static_cast<std::size_t>(tile)];
  const int count = tile_count[static_cast<std::size_t>(tile)];
  // Each entry gets its planes in float relative to the tile's corner, for the resolve below
  // (a pinhole camera's; depth to about 3e-7 relative: the planes were fitted in double).
  float* coef = tile_coef[static_cast<std::size_t>(thread)].data();
  alignas(64) EntrySetup setup;
  // The footprint's bound over entry e's pixels in the tile (setup_entries() left +inf): where
  // it shows a layer magnified, its pixels skip their own footprints. It costs about what a few
  // pixels' footprints do, so entries covering fewer pixels (most of a view over a detailed DEM)
  // go without.
  auto footprint_bound = [&](int e, long pixels, int bx0, int bx1, int by0, int by1) {
    if (!resolve_here || pixels < kBoundMinPixels) return;
    float* c = coef + kPlaneFloats * e;
    c[9] = plane_footprint_bound_log2(c, static_cast<float>(bx0 - x0), static_cast<float>(bx1 - x0),
                                      static_cast<float>(by0 - y0), static_cast<float>(by1 - y0));
  };
  // A tile wholly inside its only triangle (most tiles of a view over flat ground, drawn as
  // one quad): every pixel sees that triangle, so it needs no visibility buffer, and the
  // resolve reads a row of entry 0s (the bytes are those the buffer would hold).
  if (resolve_here && count == 1 &&
      covers_box(tris[static_cast<std::size_t>(bin_entries[static_cast<std::size_t>(first)])], x0, y0, x1, y1, true)) {
    setup_entries(tris.get(), bin_entries.get() + first, 1, x0, y0, x1, y1, vw, vh, setup, coef);
    frags = static_cast<long>(x1 - x0 + 1) * (y1 - y0 + 1);
    footprint_bound(0, frags, x0, x1, y0, y1);
    RasterScratch& scratch = raster_scratch[static_cast<std::size_t>(thread)];
    scratch.fragments += frags;
    ++scratch.whole_tiles;
    resolve_tile(tile, thread, kEntryZeros.data(), 0, coef);
    return;
  }
  for (int r = 0; r <= y1 - y0; ++r) {
    std::fill(tz + r * stride, tz + r * stride + (x1 - x0 + 1), 0.0f);
    std::fill(tid + r * stride, tid + r * stride + (x1 - x0 + 1), -1);
  }
  // Entries are set up 16 at a time (setup_entries(): the small ones for the 32-bit edge kernel,
  // and every entry's planes), then drawn in bin order: runs of small entries by
  // draw_small_entries(), the others one by one.
  int covered[EntrySetup::kMax];
  for (int e0 = 0; e0 < count; e0 += EntrySetup::kMax) {
    const int batch = std::min(EntrySetup::kMax, count - e0);
    setup_entries(tris.get(), bin_entries.get() + first + e0, batch, x0, y0, x1, y1, vw, vh, setup, coef + kPlaneFloats * e0);
    // A view's triangles outgrow the caches: fetch the next batch's while drawing this one.
    for (int i = e0 + EntrySetup::kMax; i < std::min(count, e0 + 2 * EntrySetup::kMax); ++i)
      __builtin_prefetch(&tris[static_cast<std::size_t>(bin_entries[static_cast<std::size_t>(first + i)])]);
    const std::uint32_t small = draw_small_entries ? setup.small : 0u;
    for (int i = 0; i < batch; ++i) {
      const int e = e0 + i;
      if (small >> i & 1) {
        const int end = draw_small_entries(setup, i, batch, x0, y0, tz, tid, stride, e0, covered);
        for (int j = i; j < end; ++j) {
          frags += covered[j];
          footprint_bound(e0 + j, covered[j], setup.x0[j], setup.x0[j] + setup.w[j] - 1, setup.y0[j], setup.y0[j] + setup.h[j] - 1);
        }
        i = end - 1;
        continue;
      }
      const long frags_before = frags;
      const Tri& t = tris[static_cast<std::size_t>(bin_entries[static_cast<std::size_t>(first + e)])];
      const PixelBox tb = box(t);  // and the entry's pixels in this tile:
      const int bx0 = std::max(tb.x0, x0), bx1 = std::min(tb.x1, x1);
      const int by0 = std::max(tb.y0, y0), by1 = std::min(tb.y1, y1);
      if (bx0 > bx1 || by0 > by1) continue;
      const EdgeFunctions ef = edge_functions(t, bx0, by0);
      const std::int64_t *E = ef.E, *dEx = ef.dEx, *dEy = ef.dEy;
      // For the 32-bit kernel: narrowing is modular, so the slopes may wrap while every pixel's
      // value in a block whose corners fit is exact.
      std::int32_t dx32[3], dy32[3];
      for (int k = 0; k < 3; ++k) {
        dx32[k] = static_cast<std::int32_t>(dEx[k]);
        dy32[k] = static_cast<std::int32_t>(dEy[k]);
      }
      // 1/z relative to the box corner, in float (exact enough for the depth test only).
      const float A = t.A[0], B = t.B[0];
      const float base = static_cast<float>(plane_at(t, 0, bx0 - tb.x0, by0 - tb.y0));
      // A triangle within one block (most triangles over a detailed DEM cover a few pixels):
      // straight to the edge kernel, its values bounded by |E| + 7 |dEx| + 7 |dEy| per edge.
      bool one_block = edge_block32 && bx1 - bx0 < 8 && by1 - by0 < 8;
      if (one_block) {
        std::int64_t reach = 0;
        for (int k = 0; k < 3; ++k) reach = std::max(reach, std::abs(E[k]) + 7 * (std::abs(dEx[k]) + std::abs(dEy[k])));
        one_block = reach <= std::numeric_limits<std::int32_t>::max();
      }
      if (one_block) {
        const std::int32_t c32[3] = {static_cast<std::int32_t>(E[0]), static_cast<std::int32_t>(E[1]), static_cast<std::int32_t>(E[2])};
        const std::ptrdiff_t at = (by0 - y0) * stride + (bx0 - x0);
        frags += edge_block32(bx1 - bx0 + 1, by1 - by0 + 1, c32, dx32, dy32, base, A, B, 0, 0, tz + at, tid + at, stride, e);
      }
      // 8 x 8 blocks: the edge functions are linear, so their values at a block's corners say
      // whether the block is wholly inside (no per-pixel test), wholly outside one edge
      // (skipped), or crossed (tested per pixel, in the edge kernel). Blocks are taken 4 x 4 at
      // a time, and the group's corners first: a large triangle covers or misses most groups
      // wholly, whose blocks then need no test of their own.
      struct Corners {
        bool outside = false, inside = true, fits32 = true;
        std::int64_t c00[3] = {0, 0, 0};
      };
      auto classify = [&](int cx0, int cy0, int cx1, int cy1) {
        Corners q;
        for (int k = 0; k < 3 && !q.outside; ++k) {
          const std::int64_t c00 = E[k] + dEx[k] * (cx0 - bx0) + dEy[k] * (cy0 - by0);
          const std::int64_t c10 = c00 + dEx[k] * (cx1 - cx0), c01 = c00 + dEy[k] * (cy1 - cy0);
          const std::int64_t c11 = c10 + dEy[k] * (cy1 - cy0);
          const std::int64_t lo = std::min(std::min(c00, c10), std::min(c01, c11));
          const std::int64_t hi = std::max(std::max(c00, c10), std::max(c01, c11));
          q.c00[k] = c00;
          q.outside = hi < 0;
          q.inside = q.inside && lo >= 0;
          q.fits32 = q.fits32 && lo >= std::numeric_limits<std::int32_t>::min() && hi <= std::numeric_limits<std::int32_t>::max();
        }
        return q;
      };
      auto covered_block = [&](int bx, int by, int ex1, int ey1) {
        const std::ptrdiff_t at = static_cast<std::ptrdiff_t>(by - y0) * stride + (bx - x0);
        depth_block(ex1 - bx + 1, ey1 - by + 1, base, A, B, bx - bx0, by - by0, tz + at, tid + at, stride, e);
        frags += static_cast<long>(ex1 - bx + 1) * (ey1 - by + 1);
      };
      for (int qy0 = by0; qy0 <= by1 && !one_block; qy0 += 32) {
        const int qy1 = std::min(qy0 + 31, by1);
        for (int qx0 = bx0; qx0 <= bx1; qx0 += 32) {
          const int qx1 = std::min(qx0 + 31, bx1);
          const Corners group = classify(qx0, qy0, qx1, qy1);
          if (group.outside) continue;
          if (group.inside) {  // the whole group in one call (kDepthBlockMaxW: 32 columns)
            covered_block(qx0, qy0, qx1, qy1);
            continue;
          }
          for (int by = qy0; by <= qy1; by += 8) {
            const int ey1 = std::min(by + 7, qy1);
            for (int bx = qx0; bx <= qx1; bx += 8) {
              const int ex1 = std::min(bx + 7, qx1);
              const Corners q = classify(bx, by, ex1, ey1);
              if (q.outside) continue;
              const std::ptrdiff_t at = static_cast<std::ptrdiff_t>(by - y0) * stride + (bx - x0);
              if (q.inside) {
                covered_block(bx, by, ex1, ey1);
              } else if (q.fits32 && edge_block32) {
                const std::int32_t c32[3] = {static_cast<std::int32_t>(q.c00[0]), static_cast<std::int32_t>(q.c00[1]),
                                             static_cast<std::int32_t>(q.c00[2])};
                frags += edge_block32(ex1 - bx + 1, ey1 - by + 1, c32, dx32, dy32, base, A, B, bx - bx0, by - by0, tz + at,
                                      tid + at, stride, e);
              } else {
                frags += edge_block(ex1 - bx + 1, ey1 - by + 1, q.c00, dEx, dEy, base, A, B, bx - bx0, by - by0, tz + at,
                                    tid + at, stride, e);
              }
            }
          }
        }
      }
      footprint_bound(e, frags - frags_before, bx0, bx1, by0, by1);
    }
  }
  RasterScratch& scratch = raster_scratch[static_cast<std::size_t>(thread)];
  scratch.fragments += frags;
  if (!resolve_here) {
    // Distorted camera: resolve_rows() reads this tile later; it needs triangle indices.
    for (int r = 0; r <= y1 - y0; ++r) {
      int* irow = tid + r * stride;
      for (int x = 0; x <= x1 - x0; ++x)
        if (irow[x] >= 0) irow[x] = bin_entries[static_cast<std::size_t>(first + irow[x])];
    }
    return;
  }
  resolve_tile(tile, thread, tid, stride, coef);
}

// Pinhole camera: resolves and shades tile `tile` now, row by row (the fused kernel keeps each
// pixel's world position in registers), its entries' planes in `coef`, pixel (x, y)'s entry
// at ids[(y - y0) id_stride + x - x0].
void Renderer::Impl::resolve_tile(int tile, int thread, const int* ids, std::ptrdiff_t id_stride, const float* coef) {
  const int tx = tile % tiles_x, ty = tile / tiles_x;
  const int x0 = tx * kTileW, y0 = ty * kTileH;
  const int x1 = std::min(x0 + kTileW, vw) - 1, y1 = std::min(y0 + kTileH, vh) - 1;
  const std::size_t w = static_cast<std::size_t>(camera.width);
  const std::size_t n_layers = frame_out->layer_names.size();
  ShadeTarget* targets = raster_scratch[static_cast<std::size_t>(thread)].targets;
  for (int y = y0; y <= y1; ++y) {
    const std::size_t k = static_cast<std::size_t>(y) * w + static_cast<std::size_t>(x0);
    for (std::size_t l = 0; l < n_layers; ++l)
      targets[l] = {&layer_params[static_cast<std::size_t>(frame_out->layer_index[l])], frame_out->rgb[l].data() + 3 * k,
                    frame_out->valid[l].data() + k};
    resolve_shade(x1 - x0 + 1, ids + static_cast<std::ptrdiff_t>(y - y0) * id_stride, coef, 0.0f, static_cast<float>(y - y0),
                  frame_out->depth.data() + k, static_cast<int>(n_layers), targets);
  }
}

// Deals `units` (tile rows, or blocks of output rows) to the threads as bands: unit runs
// [j units / threads, (j + 1) units / threads) for thread j. claim_units() then takes them.
void Renderer::Impl::deal_bands(int units) {
  const int threads = pool->threads();
  for (int j = 0; j < threads; ++j) {
    const std::uint32_t top = static_cast<std::uint32_t>(j * units / threads);
    const std::uint32_t end = static_cast<std::uint32_t>((j + 1) * units / threads);
    row_bands[static_cast<std::size_t>(j)].rows.store(end << 16 | top, std::memory_order_relaxed);
  }
}

// Thread j's share of the dealt units (see render()): draw(unit) for each unit of its own band
// from the top, then for units from the bottom of the band with the most left, until none is.
template <class F>
void Renderer::Impl::claim_units(int thread, F&& draw) {
  auto rows_of = [](std::uint32_t r, std::uint32_t& top, std::uint32_t& end) {
    top = r & 0xFFFFu;
    end = r >> 16;
  };
  // Takes one unit of band b, from its top or its bottom; -1 when the band has none left.
  auto take = [&](int b, bool from_top) {
    std::atomic<std::uint32_t>& w = row_bands[static_cast<std::size_t>(b)].rows;
    std::uint32_t r = w.load(std::memory_order_relaxed), top, end;
    for (;;) {
      rows_of(r, top, end);
      if (top >= end) return -1;
      const std::uint32_t next = from_top ? (end << 16 | (top + 1)) : ((end - 1) << 16 | top);
      if (w.compare_exchange_weak(r, next, std::memory_order_relaxed)) return static_cast<int>(from_top ? top : end - 1);
    }
  };
  for (int unit = take(thread, true); unit >= 0; unit = take(thread, true)) draw(unit);
  for (;;) {
    int band = -1;
    std::uint32_t most = 0, top, end;
    for (int b = 0; b < pool->threads(); ++b) {
      rows_of(row_bands[static_cast<std::size_t>(b)].rows.load(std::memory_order_relaxed), top, end);
      if (end > top && end - top > most) {
        most = end - top;
        band = b;
      }
    }
    if (band < 0) return;
    const int unit = take(band, false);
    if (unit >= 0) draw(unit);
  }
}

// Shades pixels [x, x + n) of output row y in every requested layer.
void Renderer::Impl::shade_span(int y, int x, int n, const float* wx, const float* wy, const float* l2) {
  const std::size_t k = static_cast<std::size_t>(y) * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(x);
  for (std::size_t l = 0; l < frame_out->layer_names.size(); ++l)
    shade(n, wx, wy, l2, frame_out->rgb[l].data() + 3 * k, frame_out->valid[l].data() + k,
          layer_params[static_cast<std::size_t>(frame_out->layer_index[l])]);
}

void Renderer::Impl::resolve_rows(int row0, int row1) {
  const int w = camera.width;
  for (int y = row0; y < row1; ++y)
    for (int x = 0; x < w; ++x) {
      const std::size_t k = static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
      const double px = remap_u[k], py = remap_v[k];
      gx[k] = gy[k] = gz[k] = NAN;
      log2fp[k] = 0.0f;
      if (!(px > -0.5 && py > -0.5 && px < vw - 0.5 && py < vh - 0.5)) continue;
      const int ix = static_cast<int>(std::lround(px)), iy = static_cast<int>(std::lround(py));
      const int id = idbuf[static_cast<std::size_t>((iy / kTileH) * tiles_x + ix / kTileW) * kVisSlice +
                           static_cast<std::size_t>(iy % kTileH) * kVisStride +
                           static_cast<std::size_t>(ix % kTileW)];
      if (id < 0) continue;
      // The pinhole pixel nearest to this output pixel's ray names the triangle; its planes
      // are evaluated at the ray's exact pinhole position.
      const Tri& t = tris[static_cast<std::size_t>(id)];
      const PixelBox tb = box(t);
      const double iz = plane_at(t, 0, px - tb.x0, py - tb.y0);
      if (!(iz > 0)) continue;
      const double z = 1.0 / iz;
      const double wx = plane_at(t, 1, px - tb.x0, py - tb.y0) * z;
      const double wy = plane_at(t, 2, px - tb.x0, py - tb.y0) * z;
      gz[k] = static_cast<float>(z);
      gx[k] = static_cast<float>(wx);
      gy[k] = static_cast<float>(wy);
      log2fp[k] = footprint_log2<double>(t.A[0], t.B[0], t.A[1], t.B[1], t.A[2], t.B[2], wx, wy, z);
    }
}


Status Renderer::render(const geo::Pose& T_W_C, RenderOutput& out, RenderStats* stats) {
  const FloatEnvironmentScope float_environment;
  Impl& m = *impl_;
  const auto t0 = Clock::now();
  auto invalidate = [&] {
    for (auto& v : out.valid) std::fill(v.pixels().begin(), v.pixels().end(), std::uint8_t{0});
    for (auto& c : out.rgb) std::fill(c.pixels().begin(), c.pixels().end(), std::uint8_t{0});
    std::fill(out.depth.pixels().begin(), out.depth.pixels().end(), NAN);
  };
  if (out.depth.width() != m.camera.width || out.depth.height() != m.camera.height ||
      out.rgb.size() != out.layer_names.size() || out.valid.size() != out.layer_names.size() ||
      out.layer_index.size() != out.layer_names.size())
    return Error{"render: the output was not made by this renderer's make_output()"};
  const Eigen::Vector3d& t = T_W_C.t_W_C;
  if (!t.allFinite() || !T_W_C.q_W_C.coeffs().allFinite() || std::abs(T_W_C.q_W_C.norm() - 1.0) > 1e-3) {
    invalidate();
    return Error{"render: pose " + geo::format_pose(T_W_C) + " is not finite or its quaternion is not unit"};
  }
  const double ground = m.map->dem.height_at(t.x(), t.y());
  if (std::isfinite(ground) && t.z() < ground) {
    invalidate();
    return Error{"render: camera at z " + geo::format_double(t.z()) + " m is below the terrain (" +
                 geo::format_double(ground) + " m) at (" + geo::format_double(t.x()) + ", " + geo::format_double(t.y()) + ")"};
  }
  m.frame_out = &out;
  m.R_C_W = T_W_C.q_W_C.conjugate().toRotationMatrix().cast<float>();
  m.t_local = Eigen::Vector3f(static_cast<float>(t.x() - m.ox), static_cast<float>(t.y() - m.oy),
                              static_cast<float>(t.z() - m.oz));
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m.frame.R[3 * i + j] = m.R_C_W(i, j);
    m.frame.t[i] = m.t_local[i];
  }

  // 1-2. Level of detail and geometry.
  m.chunk_stack.clear();
  m.chunk_stack.push_back(m.terrain.root());
  m.draw_list.clear();
  m.choose_chunks();
  m.seal_one_quads();
  m.pool->run(m.pool->threads(), [](void* c, int j) { static_cast<Impl*>(c)->draw_chunks(j); }, &m);
  int n_tris = 0, chunks_drawn = 0, chunks_one_way = 0, chunks_one_quad = 0;
  for (int index : m.draw_list) {
    const int grid = m.drawn[static_cast<std::size_t>(index)] - 1;
    chunks_one_way += grid == kWide || grid == kTall;
    chunks_one_quad += grid == kOneQuad;
    m.drawn[static_cast<std::size_t>(index)] = 0;
  }
  bool overflow = false;
  for (const GeomPart& g : m.parts) {
    n_tris += g.n_tris;
    chunks_drawn += g.chunks_drawn;
    overflow = overflow || g.overflow;
  }
  if (overflow || n_tris > m.options.max_triangles) {
    invalidate();
    return Error{"render: the view needs more than " + std::to_string(m.options.max_triangles) +
                 " triangles (raise max_triangles or lod_error_px)"};
  }
  // Binning: each part counted its triangles per tile; prefix sums over tiles and, within a
  // tile, over parts; then each part fills its share (triangle order kept within each tile).
  long total = 0;
  for (std::size_t k = 0; k < m.tile_count.size(); ++k) {
    m.tile_start[k] = static_cast<int>(std::min<long>(total, std::numeric_limits<int>::max()));
    int count = 0;
    for (GeomPart& g : m.parts) {
      g.tile_fill[k] = m.tile_start[k] + count;
      count += g.tile_count[k];
    }
    m.tile_count[k] = count;
    total += count;
  }
  if (total > static_cast<long>(m.bin_capacity)) {
    invalidate();
    return Error{"render: tile bins overflow (" + std::to_string(total) + " entries)"};
  }
  m.tile_start.back() = static_cast<int>(total);
  m.pool->run(m.pool->threads(), [](void* c, int j) { static_cast<Impl*>(c)->bin_part(j); }, &m);
  const auto t1 = Clock::now();

  // 3-5. Visibility per tile; for a pinhole camera the tile is resolved and shaded there,
  // for a distorted one each output row block is resolved and shaded afterwards.
  for (int c : m.tile_count)
    if (c > m.max_tile_entries) {
      invalidate();
      return Error{"render: a screen tile holds " + std::to_string(c) + " triangles, over " + std::to_string(m.max_tile_entries)};
    }
  for (RasterScratch& s : m.raster_scratch) {
    s.fragments = 0;
    s.whole_tiles = 0;
  }
  // Tile rows are claimed, not dealt: thread j starts at the top of band j of the rows and
  // works down it, then takes the band with the most rows left from its bottom up
  // (raster_rows()). Each thread's rows stay together, so two threads share cache lines of the
  // output only where their rows meet: a line written by two cores moves between them on
  // every write, and with rows dealt alternately two threads were only 1.2x one in this VM's
  // slow periods. Taking rows as they come keeps the two busy to the end however the view's
  // cost is spread, and which thread draws a tile changes none of its bytes (its pixels come
  // from its own bins, through the thread's own buffers), so the output is the same for any
  // thread count and any timing.
  const int threads = m.pool->threads();
  m.deal_bands(m.tiles_y);
  m.pool->run(threads, [](void* c, int j) {
    Impl& im = *static_cast<Impl*>(c);
    im.claim_units(j, [&im, j](int row) {
      for (int a = 0; a < im.tiles_x; ++a) im.raster_tile(row * im.tiles_x + a, j);
    });
  }, &m);
  const auto t2 = Clock::now();
  if (!m.remap_u.empty()) {
    // A distorted camera: blocks of output rows, claimed in bands as the tile rows were.
    m.deal_bands((m.camera.height + kRowsPerBlock - 1) / kRowsPerBlock);
    m.pool->run(threads, [](void* c, int j) {
      Impl& im = *static_cast<Impl*>(c);
      im.claim_units(j, [&im](int block) {
        const int r0 = block * kRowsPerBlock, r1 = std::min(r0 + kRowsPerBlock, im.camera.height);
        im.resolve_rows(r0, r1);
        for (int y = r0; y < r1; ++y) {
          const std::size_t k = static_cast<std::size_t>(y) * static_cast<std::size_t>(im.camera.width);
          im.shade_span(y, 0, im.camera.width, im.gx.data() + k, im.gy.data() + k, im.log2fp.data() + k);
        }
      });
    }, &m);
    std::copy(m.gz.begin(), m.gz.end(), out.depth.pixels().begin());
  }
  const auto t3 = Clock::now();
  // Terrain seen: for a pinhole camera every covered pixel has a depth (clipping keeps 1/z
  // positive), so the tiles' fragment counts tell without a pass over the depth image.
  long fragments = 0;
  int whole_tiles = 0;
  for (const RasterScratch& s : m.raster_scratch) {
    fragments += s.fragments;
    whole_tiles += s.whole_tiles;
  }
  if (stats) {
    stats->triangles = n_tris;
    stats->chunks = chunks_drawn;
    stats->chunks_one_way = chunks_one_way;
    stats->chunks_one_quad = chunks_one_quad;
    stats->fragments = fragments;
    stats->tiles_one_triangle = whole_tiles;
    stats->ms_geometry = std::chrono::duration<double, std::milli>(t1 - t0).count();
    stats->ms_raster = std::chrono::duration<double, std::milli>(t2 - t1).count();
    stats->ms_shade = std::chrono::duration<double, std::milli>(t3 - t2).count();
  }
  bool any = fragments > 0;
  if (any && !m.remap_u.empty()) {
    any = false;
    for (float z : out.depth.pixels())
      if (z == z) {
        any = true;
        break;
      }
  }
  if (!any) return Error{"render: the view from " + geo::format_pose(T_W_C) +
                         " sees no terrain (off the map, or looking at the sky)"};
  return Ok{};
}

}  // namespace terralign::raster
