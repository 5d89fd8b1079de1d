// Synthetic Models for the collision and contact tests: objects made of
// axis-aligned boxes, each box one convex piece (8 vertices, 12 outward CCW
// triangles) whose 12 coarse triangles are its coarse_faces.
//
// The atlas is an identity haptic texture for the top (+z) and bottom (-z)
// faces: each of those faces has its own vertical strip of the atlas, its
// rectangle maps affinely onto the strip (inset by kInset texels), and every
// texel of the strip holds the affine extension of that map, so a bilinear
// lookup anywhere inside the UV rectangle returns exactly the coarse surface
// point (bilinear interpolation reproduces affine functions). Side faces map
// to a small triangle of a last strip; their texels hold the box centre
// (they never face +-z, so the tests never rasterize them).
#pragma once

#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "hrt/model.h"

namespace hrt_test {

using hrt::Vec3;

struct Box {
  Vec3 lo, hi;
};

inline hrt::Model make_boxes(const std::vector<Box>& boxes, const std::string& name = "boxes",
                             int texels_per_strip = 32, int height = 32) {
  hrt::Model m;
  m.path = name + ".hbundle";
  m.name = name + ".ply";
  m.format_version = "1.0";
  const int nb = static_cast<int>(boxes.size());
  const int strips = 2 * nb + 1;
  const int W = strips * texels_per_strip, H = height;
  const double kInset = 3.0;  // texels between a UV rectangle and its strip's border
  m.atlas.width = W;
  m.atlas.height = H;
  m.atlas.rgba.assign(static_cast<size_t>(W) * H * 4, 0.0f);

  // UV rectangle of strip s: [u0, u1] x [v0, v1].
  auto strip_rect = [&](int s, double& u0, double& u1, double& v0, double& v1) {
    u0 = (s * texels_per_strip + kInset) / W;
    u1 = ((s + 1) * texels_per_strip - kInset) / W;
    v0 = kInset / H;
    v1 = 1.0 - kInset / H;
  };

  Vec3 com = Vec3::Zero();
  double volume = 0;
  Vec3 lo_all = boxes[0].lo, hi_all = boxes[0].hi;
  for (int b = 0; b < nb; ++b) {
    const Box& bx = boxes[static_cast<size_t>(b)];
    lo_all = lo_all.cwiseMin(bx.lo);
    hi_all = hi_all.cwiseMax(bx.hi);
    const uint32_t base = static_cast<uint32_t>(m.vertices.size());
    for (int k = 0; k < 8; ++k)
      m.vertices.emplace_back((k & 1) ? bx.hi.x() : bx.lo.x(), (k & 2) ? bx.hi.y() : bx.lo.y(),
                              (k & 4) ? bx.hi.z() : bx.lo.z());
    // Outward CCW triangles: (-x) (+x) (-y) (+y) (-z) (+z).
    const std::array<std::array<uint32_t, 3>, 12> tris = {{{0, 4, 6},
                                                           {0, 6, 2},
                                                           {1, 3, 7},
                                                           {1, 7, 5},
                                                           {0, 1, 5},
                                                           {0, 5, 4},
                                                           {2, 6, 7},
                                                           {2, 7, 3},
                                                           {0, 2, 3},
                                                           {0, 3, 1},
                                                           {4, 5, 7},
                                                           {4, 7, 6}}};
    hrt::ConvexPiece piece;
    for (int k = 0; k < 8; ++k) piece.vertices.push_back(m.vertices[base + static_cast<uint32_t>(k)]);
    for (int t = 0; t < 12; ++t) {
      const auto& tr = tris[static_cast<size_t>(t)];
      hrt::Tri f{base + tr[0], base + tr[1], base + tr[2]};
      const uint32_t fid = static_cast<uint32_t>(m.faces.size());
      m.faces.push_back(f);
      piece.faces.push_back(hrt::Tri{tr[0], tr[1], tr[2]});
      piece.coarse_faces.push_back(fid);
      const Vec3 &a = m.vertices[f[0]], &bq = m.vertices[f[1]], &c = m.vertices[f[2]];
      Vec3 nrm = (bq - a).cross(c - a);
      m.face_areas.push_back(0.5 * nrm.norm());
      m.face_normals.push_back(nrm.normalized());
      std::array<hrt::Vec2f, 3> uv;
      const int face_group = t / 2;  // 4 = bottom (-z), 5 = top (+z)
      if (face_group >= 4) {
        const int s = 2 * b + (face_group - 4);
        double u0, u1, v0, v1;
        strip_rect(s, u0, u1, v0, v1);
        for (int c3 = 0; c3 < 3; ++c3) {
          const Vec3& p = m.vertices[f[static_cast<size_t>(c3)]];
          const double fx = (p.x() - bx.lo.x()) / (bx.hi.x() - bx.lo.x());
          const double fy = (p.y() - bx.lo.y()) / (bx.hi.y() - bx.lo.y());
          uv[static_cast<size_t>(c3)] =
              hrt::Vec2f(static_cast<float>(u0 + fx * (u1 - u0)), static_cast<float>(v0 + fy * (v1 - v0)));
        }
      } else {
        double u0, u1, v0, v1;
        strip_rect(strips - 1, u0, u1, v0, v1);
        uv = {hrt::Vec2f(float(u0), float(v0)), hrt::Vec2f(float(u1), float(v0)), hrt::Vec2f(float(u0), float(v1))};
      }
      m.uvs.push_back(uv);
    }
    m.pieces.push_back(piece);

    // Atlas strips of the bottom (s = 2b) and top (s = 2b + 1) faces.
    for (int side = 0; side < 2; ++side) {
      const int s = 2 * b + side;
      const double z = side ? bx.hi.z() : bx.lo.z();
      double u0, u1, v0, v1;
      strip_rect(s, u0, u1, v0, v1);
      for (int j = 0; j < H; ++j)
        for (int i = s * texels_per_strip; i < (s + 1) * texels_per_strip; ++i) {
          const double u = (i + 0.5) / W, v = 1.0 - (j + 0.5) / H;
          const double fx = (u - u0) / (u1 - u0), fy = (v - v0) / (v1 - v0);
          float* t = &m.atlas.rgba[(static_cast<size_t>(j) * W + i) * 4];
          t[0] = static_cast<float>(bx.lo.x() + fx * (bx.hi.x() - bx.lo.x()));
          t[1] = static_cast<float>(bx.lo.y() + fy * (bx.hi.y() - bx.lo.y()));
          t[2] = static_cast<float>(z);
          t[3] = (fx >= 0 && fx <= 1 && fy >= 0 && fy <= 1) ? 1.0f : 0.0f;
        }
    }
    const Vec3 size = bx.hi - bx.lo;
    const double vol = size.x() * size.y() * size.z();
    com += vol * 0.5 * (bx.lo + bx.hi);
    volume += vol;
  }
  // Side strip: the centre of the first box.
  const Vec3 c0 = 0.5 * (boxes[0].lo + boxes[0].hi);
  for (int j = 0; j < H; ++j)
    for (int i = (strips - 1) * texels_per_strip; i < W; ++i) {
      float* t = &m.atlas.rgba[(static_cast<size_t>(j) * W + i) * 4];
      t[0] = float(c0.x());
      t[1] = float(c0.y());
      t[2] = float(c0.z());
      t[3] = 1.0f;
    }
  m.mass.basis = "coarse";
  m.mass.volume = volume;
  m.mass.center_of_mass = com / volume;
  m.mass.closed = true;
  m.quality.bbox_diagonal = (hi_all - lo_all).norm();
  // A relief-free texture: nothing lies outside the coarse surface.
  m.quality.displacement_outward = 0.0;
  m.quality.hull_deviation = 0.0;
  m.quality.texel_size = (hi_all - lo_all).maxCoeff() / texels_per_strip;
  m.quality.min_wavelength = 0.0;  // no relief: never undersampled
  hrt::prepare_surface_map(m);     // as load_bundle does
  return m;
}

inline hrt::Model make_box(const Vec3& lo, const Vec3& hi, const std::string& name = "box") {
  return make_boxes({Box{lo, hi}}, name);
}

// The flat pair of the frame, safety and dynamics tests: a 40 x 20 x 10 mm
// probe box centred on its origin (its bottom at z = -5 mm) and a
// 200 x 200 x 10 mm plate whose top face is z = 0.
inline hrt::Model probe_box() { return make_box(Vec3(-0.02, -0.01, -0.005), Vec3(0.02, 0.01, 0.005), "a"); }
inline hrt::Model plate_box() { return make_box(Vec3(-0.1, -0.1, -0.01), Vec3(0.1, 0.1, 0.0), "b"); }

inline hrt::Pose pose_at(const Vec3& t, const Eigen::Quaterniond& q = Eigen::Quaterniond::Identity()) {
  hrt::Pose p;
  p.position = t;
  p.rotation = q.normalized();
  return p;
}

// pose composed with a global rigid motion g: world' = g * world.
inline hrt::Pose moved(const Eigen::Isometry3d& g, const hrt::Pose& p) {
  const Eigen::Isometry3d m = g * p.iso();
  hrt::Pose out;
  out.position = m.translation();
  out.rotation = Eigen::Quaterniond(m.linear()).normalized();
  return out;
}

}  // namespace hrt_test
