// The terrain as a quadtree of chunks for view-dependent level of detail.
//
// Posts: a regular grid of heights (the DEM's pixel centres, or a synthetic flat grid for a
// constant-height map) placed by an affine transform, in local coordinates (metres relative
// to the renderer's origin). A chunk at level k covers (kChunkQuads * 2^k) quads a side and
// is drawn as a kChunkQuads x kChunkQuads grid taking every 2^k-th post, each quad split into
// two triangles along one of its diagonals. Its error is the largest vertical distance between
// its coarse surface and the full-resolution one (and its children's errors), computed once at
// construction.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include <terralign/geo/map.hpp>

namespace terralign::raster {

constexpr int kChunkQuads = 16;

struct TerrainChunk {
  int level;             // 0: full resolution
  int i0, j0;            // first post (column, row)
  int span;              // quads a side at full resolution: kChunkQuads << level
  float error;           // metres
  // The diagonal its quads are split along: false, post (i, j) to (i + step, j + step) (every
  // level-0 chunk: the full-resolution surface); true, (i + step, j) to (i, j + step). A
  // coarser chunk takes the one that fits the posts better: a ridge or a ripple running along
  // one diagonal is cut by the other at every quad, and bends the surface there.
  bool anti;
  float min_x, min_y, min_z, max_x, max_y, max_z;  // local bounding box
  int child[4];          // -1 where none
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
  static Terrain build(const geo::Map& map, double ox, double oy, double oz);

  int posts_x() const { return nx_; }
  int posts_y() const { return ny_; }
  // Local position of post (i, j); z is NaN for a no-data post.
  void post(int i, int j, float& x, float& y, float& z) const {
    x = static_cast<float>(px0_ + i * pxi_ + j * pxj_);
    y = static_cast<float>(py0_ + i * pyi_ + j * pyj_);
    z = heights_[static_cast<std::size_t>(j) * static_cast<std::size_t>(nx_) + static_cast<std::size_t>(i)];
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
  int build_chunk(int level, int i0, int j0);
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
