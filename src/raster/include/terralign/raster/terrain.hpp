// The terrain as a quadtree of chunks for view-dependent level of detail.
//
// Posts: a regular grid of heights (the DEM's pixel centres, or a synthetic flat grid for a
// constant-height map) placed by an affine transform, in local coordinates (metres relative
// to the renderer's origin). A chunk at level k covers (kChunkQuads * 2^k) quads a side and
// is drawn as a kChunkQuads x kChunkQuads grid taking every 2^k-th post, or (ChunkGrid) twice
// as fine along one axis, or as one quad where its posts lie on it, each quad split into two
// triangles along one of its diagonals. Each grid's error, the largest vertical distance
// between its surface and the full-resolution one, is computed once at construction.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include <terralign/geo/map.hpp>
#include <terralign/geo/thread_pool.hpp>

namespace terralign::raster {

constexpr int kChunkQuads = 16;

// The grids a chunk of level k >= 1 can be drawn with: Square, kChunkQuads quads a side
// (every 2^k-th post); Wide, twice as many along i (every 2^(k-1)-th post column) and Tall,
// along j. Terrain whose relief runs one way (ridges, terraces, ripples) needs the finer
// spacing across it only: one of those, at twice the Square's triangles, instead of the four
// children's four times. And at any level, OneQuad: the chunk's four corner posts, where
// every post lies on those two triangles (within kOneQuadSlack): flat or evenly sloped
// ground, a lake, a constant-height map. Two triangles instead of 512, and large ones, so
// that most screen tiles see one triangle. The renderer draws it only where each side meets
// the same side of a neighbour (Renderer::Impl::seal_one_quads()).
enum ChunkGrid : int { kSquare = 0, kWide = 1, kTall = 2, kOneQuad = 3 };
constexpr int kChunkGrids = 4;
constexpr float kOneQuadSlack = 1e-3f;  // metres: a plane's posts, rounded to float heights
constexpr int kMaxGridQuads = 2 * kChunkQuads;  // quads along a Wide chunk's rows

struct TerrainChunk {
  int level;             // 0: full resolution
  int i0, j0;            // first post (column, row)
  int span;              // quads a side at full resolution: kChunkQuads << level
  // Per grid (ChunkGrid): the largest vertical distance in metres between the chunk's surface
  // drawn with it and the full-resolution one (the Square's also its children's; +inf where
  // the grid is not offered: Wide and Tall at level 0, OneQuad over kOneQuadSlack, any of
  // the three on a chunk cut by the map's last post row or column or with a post without
  // height), and the diagonal its quads are split along: false, post (i, j) to (i + di,
  // j + dj) for quads di x dj posts (every level-0 chunk's Square: the full-resolution
  // surface); true, (i + di, j) to (i, j + dj). A coarser chunk takes the one that fits the
  // posts better: a ridge or a ripple running along one diagonal is cut by the other at
  // every quad, and bends the surface there.
  float error[kChunkGrids];
  bool anti[kChunkGrids];
  float min_x, min_y, min_z, max_x, max_y, max_z;  // local bounding box
  int child[4];          // -1 where none
  // Quads along i and j, and posts between vertices along i and j, drawn with grid g.
  int quads_i(int g) const { return g == kOneQuad ? 1 : g == kWide ? 2 * kChunkQuads : kChunkQuads; }
  int quads_j(int g) const { return g == kOneQuad ? 1 : g == kTall ? 2 * kChunkQuads : kChunkQuads; }
  int step_i(int g) const { return span / quads_i(g); }
  int step_j(int g) const { return span / quads_j(g); }
};

// The most a point of chunk c's box moves on screen, in pixels of a pinhole camera with focal
// f, when moved up or down by `error` metres (chunk errors are vertical): f e |N| / (z z'),
// N = (u_x z - x u_z, u_y z - y u_z) for the point's camera-frame position (x, y, z) and the
// camera-frame up u = R_C_W (0, 0, 1), z' = z +- e u_z its moved depth (N does not change
// along u). |N| is convex in the point, so a box's corners bound it, and its least depth
// bounds 1 / (z z'). Seen straight down, N is the point's offset from the optical axis: a
// vertical error shows only off the axis. +inf where the box, moved, reaches nearer than
// near_m. t_local: the camera's position. `cells` > 1 cuts the box into cells x cells
// full-height columns and bounds each by its own corners (up to kMaxErrorCells): in an
// oblique view one box's far |N| over its near z^2 overstates the error by about the square
// of its depth ratio, which the columns mostly remove.
constexpr int kMaxErrorCells = 4;
float chunk_screen_error_px(const TerrainChunk& c, float error, const Eigen::Matrix3f& R_C_W, const Eigen::Vector3f& t_local,
                            float f, float near_m, int cells = 1);

class Terrain {
 public:
  // origin: the local frame's origin in map coordinates.
  // pool: the threads that measure the chunks' errors (the same result with any, or none).
  static Terrain build(const geo::Map& map, double ox, double oy, double oz, ThreadPool* pool = nullptr);

  int posts_x() const { return nx_; }
  int posts_y() const { return ny_; }
  // Local position of post (i, j); z is NaN for a no-data post.
  void post(int i, int j, float& x, float& y, float& z) const {
    x = static_cast<float>(px0_ + i * pxi_ + j * pxj_);
    y = static_cast<float>(py0_ + i * pyi_ + j * pyj_);
    z = height(i, j);
  }
  // Post (i, j)'s height (NaN: no data).
  float height(int i, int j) const {
    return heights_[static_cast<std::size_t>(j) * static_cast<std::size_t>(nx_) + static_cast<std::size_t>(i)];
  }
  const std::vector<TerrainChunk>& chunks() const { return chunks_; }
  // The chunk of `level` whose first post is (ci, cj) x its span; -1 where there is none
  // (off the map, or no posts there).
  int chunk_at(int level, int ci, int cj) const {
    if (level < 0 || level >= static_cast<int>(grid_.size())) return -1;
    const Grid& g = grid_[static_cast<std::size_t>(level)];
    if (ci < 0 || cj < 0 || ci >= g.w || cj >= g.h) return -1;
    return g.index[static_cast<std::size_t>(cj) * static_cast<std::size_t>(g.w) + static_cast<std::size_t>(ci)];
  }
  int root() const { return root_; }
  float min_z() const { return min_z_; }
  float max_z() const { return max_z_; }

 private:
  int build_tree(int level, int i0, int j0);
  void measure_chunk(TerrainChunk& c) const;
  float grid_error(const TerrainChunk& c, int grid, bool anti, float limit) const;
  double surface(double u, double v) const;
  int nx_ = 0, ny_ = 0;
  double px0_ = 0, pxi_ = 1, pxj_ = 0, py0_ = 0, pyi_ = 0, pyj_ = -1;
  std::vector<float> heights_;
  std::vector<TerrainChunk> chunks_;
  struct Grid {
    int w = 0, h = 0;
    std::vector<int> index;
  };
  std::vector<Grid> grid_;  // per level: chunk indices by chunk column and row
  int root_ = -1;
  float min_z_ = 0, max_z_ = 0;
};

}  // namespace terralign::raster
