#include <terralign/raster/terrain.hpp>

#include <algorithm>
#include <cmath>

namespace terralign::raster {
namespace {

// The height at (fx, fy) in [0, 1]^2 of a quad with corner heights h00 .. h11 split along its
// diagonal from corner 00 to 11, or with `anti` from 10 to 01 (as the renderer draws it).
template <class T>
T quad_height(T fx, T fy, T h00, T h10, T h01, T h11, bool anti) {
  if (anti)
    return fx + fy <= 1 ? h00 + fx * (h10 - h00) + fy * (h01 - h00) : h11 + (1 - fx) * (h01 - h11) + (1 - fy) * (h10 - h11);
  return fx >= fy ? h00 + fx * (h10 - h00) + fy * (h11 - h10) : h00 + fy * (h01 - h00) + fx * (h11 - h01);
}

}  // namespace

float chunk_screen_error_px(const TerrainChunk& c, float error, const Eigen::Matrix3f& R_C_W, const Eigen::Vector3f& t_local,
                            float f, float near_m, int cells) {
  // The box cut into cells x cells columns (each the box's full height), each bounded by its
  // own corners; the columns share their corners: (cells + 1)^2 x 2 points.
  constexpr int kMaxPts = kMaxErrorCells + 1;
  cells = std::min(std::max(cells, 1), kMaxErrorCells);
  const int pts = cells + 1;
  const Eigen::Vector3f up = R_C_W.col(2);
  float n2[2][kMaxPts][kMaxPts], z[2][kMaxPts][kMaxPts];
  for (int h = 0; h < 2; ++h)
    for (int b = 0; b < pts; ++b)
      for (int a = 0; a < pts; ++a) {
        // (the last column at the box's edge exactly, not at min + (max - min) rounded)
        const float x = a == cells ? c.max_x : c.min_x + (c.max_x - c.min_x) * static_cast<float>(a) / static_cast<float>(cells);
        const float y = b == cells ? c.max_y : c.min_y + (c.max_y - c.min_y) * static_cast<float>(b) / static_cast<float>(cells);
        const Eigen::Vector3f p = R_C_W * (Eigen::Vector3f(x, y, h ? c.max_z : c.min_z) - t_local);
        const float nx = up.x() * p.z() - p.x() * up.z(), ny = up.y() * p.z() - p.y() * up.z();
        n2[h][b][a] = nx * nx + ny * ny;
        z[h][b][a] = p.z();
      }
  float worst = 0.0f;
  for (int b = 0; b < cells; ++b)
    for (int a = 0; a < cells; ++a) {
      float n2_max = 0.0f, z_min = INFINITY;
      for (int h = 0; h < 2; ++h)
        for (int k = 0; k < 4; ++k) {
          n2_max = std::max(n2_max, n2[h][b + (k >> 1)][a + (k & 1)]);
          z_min = std::min(z_min, z[h][b + (k >> 1)][a + (k & 1)]);
        }
      // A point moved by +-error along up keeps its N and comes as near as z - error |u_z|.
      const float z_near = z_min - error * std::abs(up.z());
      if (!(z_near > near_m)) return INFINITY;
      worst = std::max(worst, std::sqrt(n2_max) / (z_min * z_near));
    }
  return error * f * worst;
}

Terrain Terrain::build(const geo::Map& map, double ox, double oy, double oz, ThreadPool* pool) {
  Terrain t;
  if (map.dem.constant) {
    // A flat grid over everything any layer covers (a little more, so texture edges are
    // reached by geometry). Its chunks are drawn as one quad each (kOneQuad); 65 x 65 posts,
    // so that those reaching behind the camera are refined and near-plane clipping stays local.
    geo::Extent e{INFINITY, INFINITY, -INFINITY, -INFINITY};
    for (const auto& L : map.layers) {
      e.min_x = std::min(e.min_x, L.extent.min_x);
      e.min_y = std::min(e.min_y, L.extent.min_y);
      e.max_x = std::max(e.max_x, L.extent.max_x);
      e.max_y = std::max(e.max_y, L.extent.max_y);
    }
    const int n = 4 * kChunkQuads + 1;
    t.nx_ = t.ny_ = n;
    t.px0_ = e.min_x - ox;
    t.pxi_ = e.width() / (n - 1);
    t.pxj_ = 0;
    t.py0_ = e.max_y - oy;
    t.pyi_ = 0;
    t.pyj_ = -e.height() / (n - 1);
    t.heights_.assign(static_cast<std::size_t>(n) * n, static_cast<float>(map.dem.constant_height - oz));
  } else {
    const auto& d = map.dem;
    t.nx_ = d.heights.width();
    t.ny_ = d.heights.height();
    // Post (i, j) is the DEM pixel centre (i, j).
    double x00, y00, x10, y10, x01, y01;
    d.transform.pixel_to_world(0, 0, x00, y00);
    d.transform.pixel_to_world(1, 0, x10, y10);
    d.transform.pixel_to_world(0, 1, x01, y01);
    t.px0_ = x00 - ox;
    t.py0_ = y00 - oy;
    t.pxi_ = x10 - x00;
    t.pyi_ = y10 - y00;
    t.pxj_ = x01 - x00;
    t.pyj_ = y01 - y00;
    t.heights_.resize(d.heights.size());
    for (std::size_t k = 0; k < d.heights.size(); ++k)
      t.heights_[k] = static_cast<float>(d.heights.data()[k] - oz);  // NaN stays NaN
  }
  float lo = INFINITY, hi = -INFINITY;
  for (float h : t.heights_)
    if (std::isfinite(h)) {
      lo = std::min(lo, h);
      hi = std::max(hi, h);
    }
  t.min_z_ = lo;
  t.max_z_ = hi;
  // The smallest level whose chunk covers every quad.
  const int quads = std::max(std::max(t.nx_, t.ny_) - 1, 1);
  int level = 0;
  while ((kChunkQuads << level) < quads) ++level;
  t.chunks_.reserve(static_cast<std::size_t>(4) << (2 * std::min(level, 10)));
  t.grid_.resize(static_cast<std::size_t>(level) + 1);
  for (int k = 0; k <= level; ++k) {
    const int span = kChunkQuads << k;
    Grid& g = t.grid_[static_cast<std::size_t>(k)];
    g.w = std::max((t.nx_ - 1 + span - 1) / span, 1);
    g.h = std::max((t.ny_ - 1 + span - 1) / span, 1);
    g.index.assign(static_cast<std::size_t>(g.w) * static_cast<std::size_t>(g.h), -1);
  }
  t.root_ = t.build_tree(level, 0, 0);
  // Each chunk measured on its own (the threads take every threads-th chunk: a chunk's
  // numbers do not depend on which thread measured it), then the Square errors made to
  // bound the children's, children before parents (a chunk's children follow it).
  struct Job {
    Terrain* t;
    int parts;
  } job{&t, pool ? pool->threads() : 1};
  auto measure = [](void* ctx, int part) {
    const Job& j = *static_cast<const Job*>(ctx);
    for (std::size_t i = static_cast<std::size_t>(part); i < j.t->chunks_.size(); i += static_cast<std::size_t>(j.parts))
      j.t->measure_chunk(j.t->chunks_[i]);
  };
  if (pool) pool->run(job.parts, measure, &job);
  else measure(&job, 0);
  for (std::size_t i = t.chunks_.size(); i-- > 0;) {
    TerrainChunk& c = t.chunks_[i];
    for (int k : c.child)
      if (k >= 0) c.error[kSquare] = std::max(c.error[kSquare], t.chunks_[static_cast<std::size_t>(k)].error[kSquare]);
  }
  return t;
}

// The quadtree from chunk (level, i0, j0) down, in pre-order (a chunk's children after it).
int Terrain::build_tree(int level, int i0, int j0) {
  TerrainChunk c{};
  c.level = level;
  c.i0 = i0;
  c.j0 = j0;
  c.span = kChunkQuads << level;
  for (int& ch : c.child) ch = -1;
  const int index = static_cast<int>(chunks_.size());
  chunks_.push_back(c);
  Grid& g = grid_[static_cast<std::size_t>(level)];
  g.index[static_cast<std::size_t>(j0 / c.span) * static_cast<std::size_t>(g.w) + static_cast<std::size_t>(i0 / c.span)] = index;
  if (level > 0) {
    const int half = c.span / 2;
    int k = 0;
    for (int dj = 0; dj < 2; ++dj)
      for (int di = 0; di < 2; ++di) {
        const int ci = i0 + di * half, cj = j0 + dj * half;
        if (ci >= nx_ - 1 || cj >= ny_ - 1) continue;
        const int child = build_tree(level - 1, ci, cj);
        chunks_[static_cast<std::size_t>(index)].child[k++] = child;
      }
  }
  return index;
}

// Chunk c's bounding box and its grids' errors (its own: build() adds the children's to the
// Square's).
void Terrain::measure_chunk(TerrainChunk& c) const {
  const int level = c.level, i0 = c.i0, j0 = c.j0, span = c.span;
  const int step = 1 << level;
  const int i1 = std::min(i0 + span, nx_ - 1), j1 = std::min(j0 + span, ny_ - 1);
  // Bounding box and the error of the coarse surface against every post inside.
  float bx0 = INFINITY, by0 = INFINITY, bz0 = INFINITY, bx1 = -INFINITY, by1 = -INFINITY, bz1 = -INFINITY;
  float err = 0;
  bool holes = false;
  for (int j = j0; j <= j1; ++j)
    for (int i = i0; i <= i1; ++i) {
      float x, y, z;
      post(i, j, x, y, z);
      bx0 = std::min(bx0, x); bx1 = std::max(bx1, x);
      by0 = std::min(by0, y); by1 = std::max(by1, y);
      if (!std::isfinite(z)) {
        holes = true;
        continue;
      }
      bz0 = std::min(bz0, z); bz1 = std::max(bz1, z);
      if (level == 0) continue;
      // The coarse surface the chunk draws: the two triangles (split along the diagonal
      // from (ci, cj) to (ci1, cj1)) of the coarse quad around (i, j).
      int ci = i0 + ((i - i0) / step) * step, cj = j0 + ((j - j0) / step) * step;
      if (ci >= i1 && ci > i0) ci -= step;
      if (cj >= j1 && cj > j0) cj -= step;
      const int ci1 = std::min(ci + step, i1), cj1 = std::min(cj + step, j1);
      const float fx = ci1 > ci ? static_cast<float>(i - ci) / static_cast<float>(ci1 - ci) : 0.0f;
      const float fy = cj1 > cj ? static_cast<float>(j - cj) / static_cast<float>(cj1 - cj) : 0.0f;
      float a, b, c00, c10, c01, c11;
      post(ci, cj, a, b, c00);
      post(ci1, cj, a, b, c10);
      post(ci, cj1, a, b, c01);
      post(ci1, cj1, a, b, c11);
      const float h = quad_height(fx, fy, c00, c10, c01, c11, false);
      if (std::isfinite(h)) err = std::max(err, std::abs(h - z));
      else err = std::max(err, bz1 - bz0 + 1.0f);  // a hole in the coarse surface
    }
  // The other diagonal, and the other grids with either, where the chunk's quads are whole
  // (not cut by the map's last post row or column) and every post has a height.
  c.error[kSquare] = err;
  c.error[kWide] = c.error[kTall] = c.error[kOneQuad] = INFINITY;
  const bool whole = !holes && i0 + span <= nx_ - 1 && j0 + span <= ny_ - 1;
  if (level > 0 && whole) {
    // (Wide and Tall serve only where they beat the Square; each second diagonal only where it
    // beats the first: measured only that far.)
    for (int g : {kSquare, kWide, kTall})
      for (bool other : {false, true}) {
        if (g == kSquare && !other) continue;  // measured above
        const float limit = std::min(c.error[g], c.error[kSquare]);
        const float e = grid_error(c, g, other, limit);
        if (e < limit) {
          c.error[g] = e;
          c.anti[g] = other;
        }
      }
  }
  // OneQuad, where the posts lie on it; on other ground the first post row or two exceed that.
  if (whole)
    for (bool other : {false, true}) {
      const float e = grid_error(c, kOneQuad, other, kOneQuadSlack);
      if (e <= kOneQuadSlack && !(e >= c.error[kOneQuad])) {
        c.error[kOneQuad] = e;
        c.anti[kOneQuad] = other;
      }
    }
  c.min_x = bx0; c.max_x = bx1; c.min_y = by0; c.max_y = by1;
  c.min_z = std::isfinite(bz0) ? bz0 : 0.0f;
  c.max_z = std::isfinite(bz1) ? bz1 : 0.0f;
}

double Terrain::surface(double u, double v) const {
  const int i = std::min(static_cast<int>(u), nx_ - 2), j = std::min(static_cast<int>(v), ny_ - 2);
  return quad_height<double>(u - i, v - j, height(i, j), height(i + 1, j), height(i, j + 1), height(i + 1, j + 1), false);
}

// The largest vertical distance between the full-resolution surface and chunk c drawn with
// `grid`, its quads split along the other diagonal where `anti` (c whole, without holes).
// Both surfaces are linear on the pieces their edges cut each other into, so the distance is
// largest at a post or where a coarse quad's diagonal crosses a full-resolution edge (a post
// column, a post row or a full-resolution diagonal: an integer u, v or u - v along it); the
// coarse quads' sides run along post rows and columns. So this is exact, in double; but it
// stops at a row of posts where it exceeds `limit` (returning more than that).
float Terrain::grid_error(const TerrainChunk& c, int grid, bool anti, float limit) const {
  const int si = c.step_i(grid), sj = c.step_j(grid);
  const int qi = c.quads_i(grid), qj = c.quads_j(grid);
  auto post = [this](int i, int j) { return static_cast<double>(height(i, j)); };
  double err = 0;
  for (int b = 0; b < qj && !(err > limit); ++b)
    for (int a = 0; a < qi && !(err > limit); ++a) {
      const int ci = c.i0 + a * si, cj = c.j0 + b * sj;
      const double c00 = post(ci, cj), c10 = post(ci + si, cj), c01 = post(ci, cj + sj), c11 = post(ci + si, cj + sj);
      // The posts of the quad (its sides included: either quad gives a side the same heights).
      for (int j = cj; j <= cj + sj && !(err > limit); ++j)
        for (int i = ci; i <= ci + si; ++i) {
          const double h = quad_height(static_cast<double>(i - ci) / si, static_cast<double>(j - cj) / sj, c00, c10, c01, c11, anti);
          err = std::max(err, std::abs(h - post(i, j)));
        }
      // The diagonal, from (u0, v0) by (du, dv) over t in (0, 1): crossings at t = k / m for
      // m = |du|, |dv| and |du - dv| (where u, v and u - v pass integers).
      const double u0 = anti ? ci + si : ci, v0 = cj, du = anti ? -si : si, dv = sj;
      const double h0 = anti ? c10 : c00, h1 = anti ? c01 : c11;
      for (const int m : {si, sj, std::abs(static_cast<int>(du) - sj)})
        for (int k = 1; k < m; ++k) {
          const double t = static_cast<double>(k) / m;
          err = std::max(err, std::abs(h0 + t * (h1 - h0) - surface(u0 + t * du, v0 + t * dv)));
        }
    }
  return static_cast<float>(err);
}

}  // namespace terralign::raster
