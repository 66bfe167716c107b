#include "gl_peer.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <string>

#include <GL/gl.h>
#include <GL/osmesa.h>

#ifndef GL_GENERATE_MIPMAP
#define GL_GENERATE_MIPMAP 0x8191
#endif

using namespace terralign;

namespace bench {

GlFrame gl_render(const geo::Map& map, const std::string& layer, const geo::CameraModel& cam, const geo::Pose& T_W_C,
                  int threads, int frames) {
  GlFrame out;
  const geo::Layer* L = map.find_layer(layer);
  if (!L) {
    out.error = "no layer " + layer;
    return out;
  }
  // llvmpipe reads its thread count when the context is made.
  setenv("LP_NUM_THREADS", std::to_string(threads).c_str(), 1);
  OSMesaContext ctx = OSMesaCreateContextExt(OSMESA_RGBA, 24, 0, 0, nullptr);
  if (!ctx) {
    out.error = "OSMesaCreateContextExt failed";
    return out;
  }
  const int W = cam.width, H = cam.height;
  std::vector<std::uint8_t> buffer(static_cast<std::size_t>(W) * H * 4);
  if (!OSMesaMakeCurrent(ctx, buffer.data(), GL_UNSIGNED_BYTE, W, H)) {
    OSMesaDestroyContext(ctx);
    out.error = "OSMesaMakeCurrent failed";
    return out;
  }
  // The grid, in a local frame around the layer's centre (GL's floats would lose the
  // map's six-digit coordinates).
  const double ox = 0.5 * (L->extent.min_x + L->extent.max_x), oy = 0.5 * (L->extent.min_y + L->extent.max_y);
  int nx, ny;
  std::vector<float> xyz, st;
  auto texcoord = [&](double x, double y) {
    double u, v;
    L->transform.world_to_pixel(x, y, u, v);
    st.push_back(static_cast<float>((u + 0.5) / L->rgba.width()));
    st.push_back(static_cast<float>((v + 0.5) / L->rgba.height()));
  };
  if (map.dem.constant) {
    nx = ny = 257;
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        const double x = L->extent.min_x + L->extent.width() * i / (nx - 1);
        const double y = L->extent.max_y - L->extent.height() * j / (ny - 1);
        xyz.insert(xyz.end(), {static_cast<float>(x - ox), static_cast<float>(y - oy), static_cast<float>(map.dem.constant_height)});
        texcoord(x, y);
      }
  } else {
    nx = map.dem.heights.width();
    ny = map.dem.heights.height();
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        double x, y;
        map.dem.transform.pixel_to_world(i, j, x, y);
        xyz.insert(xyz.end(), {static_cast<float>(x - ox), static_cast<float>(y - oy), map.dem.heights.at(i, j)});
        texcoord(x, y);
      }
  }
  std::vector<GLuint> idx;
  for (int j = 0; j + 1 < ny; ++j)
    for (int i = 0; i + 1 < nx; ++i) {
      const GLuint a = static_cast<GLuint>(j * nx + i), b = a + 1, c = a + static_cast<GLuint>(nx), d = c + 1;
      idx.insert(idx.end(), {a, c, b, b, c, d});
    }
  out.triangles = static_cast<long>(idx.size() / 3);

  GLuint tex = 0;
  glGenTextures(1, &tex);
  glBindTexture(GL_TEXTURE_2D, tex);
  glTexParameteri(GL_TEXTURE_2D, GL_GENERATE_MIPMAP, GL_TRUE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA, L->rgba.width(), L->rgba.height(), 0, GL_RGBA, GL_UNSIGNED_BYTE, L->rgba.data());
  glEnable(GL_TEXTURE_2D);
  glTexEnvi(GL_TEXTURE_ENV, GL_TEXTURE_ENV_MODE, GL_REPLACE);
  glEnable(GL_DEPTH_TEST);
  glViewport(0, 0, W, H);

  // Projection from the pinhole: pixel (u, v), centres at integers, v down, onto GL's
  // window with centres at +0.5 and rows up; near / far around the scene.
  const double n = 1.0, f = 20000.0;
  const double P[16] = {2 * cam.fx / W, 0, 0, 0,
                        0, 2 * cam.fy / H, 0, 0,
                        1 - 2 * (cam.cx + 0.5) / W, 2 * (cam.cy + 0.5) / H - 1, -(f + n) / (f - n), -1,
                        0, 0, -2 * f * n / (f - n), 0};  // column-major
  glMatrixMode(GL_PROJECTION);
  glLoadMatrixd(P);
  // Model-view: eye = diag(1, -1, -1) R_C_W (p + o - t).
  const Eigen::Matrix3d R = Eigen::Vector3d(1, -1, -1).asDiagonal() * T_W_C.R().transpose();
  const Eigen::Vector3d tr = R * (Eigen::Vector3d(ox, oy, 0) - T_W_C.t_W_C);
  const double M[16] = {R(0, 0), R(1, 0), R(2, 0), 0, R(0, 1), R(1, 1), R(2, 1), 0,
                        R(0, 2), R(1, 2), R(2, 2), 0, tr.x(), tr.y(), tr.z(), 1};
  glMatrixMode(GL_MODELVIEW);
  glLoadMatrixd(M);
  glEnableClientState(GL_VERTEX_ARRAY);
  glEnableClientState(GL_TEXTURE_COORD_ARRAY);
  glVertexPointer(3, GL_FLOAT, 0, xyz.data());
  glTexCoordPointer(2, GL_FLOAT, 0, st.data());

  std::vector<std::uint8_t> rgba(static_cast<std::size_t>(W) * H * 4);
  std::vector<float> depth(static_cast<std::size_t>(W) * H);
  auto frame = [&] {
    glClearColor(0, 0, 0, 0);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    glDrawElements(GL_TRIANGLES, static_cast<GLsizei>(idx.size()), GL_UNSIGNED_INT, idx.data());
    glReadPixels(0, 0, W, H, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
    glReadPixels(0, 0, W, H, GL_DEPTH_COMPONENT, GL_FLOAT, depth.data());
  };
  frame();  // warm-up (texture upload, mip generation, shader compilation)
  std::vector<double> per;
  for (int b = 0; b < 3; ++b) {
    const auto t0 = std::chrono::steady_clock::now();
    for (int i = 0; i < frames; ++i) frame();
    per.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / frames);
  }
  std::sort(per.begin(), per.end());
  out.fps = 1.0 / per[1];
  if (glGetError() != GL_NO_ERROR) out.error = "an OpenGL call failed";
  out.rgb.resize(static_cast<std::size_t>(W) * H * 3);
  out.hit.resize(static_cast<std::size_t>(W) * H);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const std::size_t g = static_cast<std::size_t>(H - 1 - y) * W + x, o = static_cast<std::size_t>(y) * W + x;
      for (int c = 0; c < 3; ++c) out.rgb[3 * o + c] = rgba[4 * g + c];
      out.hit[o] = depth[g] < 1.0f;
    }
  glDeleteTextures(1, &tex);
  OSMesaDestroyContext(ctx);
  return out;
}

}  // namespace bench
