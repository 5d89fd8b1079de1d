// The Scene (static: the models, their collision geometry, the options,
// checked once) and the State (every buffer a frame writes, allocated once
// for its scene): hrt/scene.h.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>

#include "collision/collision.h"
#include "contact/scratch.h"
#include "hrt/scene.h"
#include "parallel/task_pool.h"

namespace hrt {

Scene::Scene(std::vector<const Model*> objects, const SceneOptions& options)
    : objects_(std::move(objects)), options_(options) {
  if (objects_.size() < 2) throw std::invalid_argument("a scene needs the probe A and at least one other object");
  for (const Model* m : objects_)
    if (!m) throw std::invalid_argument("a scene object is null");
  const ForceOptions& f = options_.force;
  if (f.resolution < 8 || f.resolution > kMaxResolution)
    throw std::invalid_argument("resolution must be between 8 and " + std::to_string(kMaxResolution) + ", got " +
                                std::to_string(f.resolution));
  if (!(f.stiffness > 0) || !std::isfinite(f.stiffness))
    throw std::invalid_argument("stiffness must be a positive number of N/m");
  if (!(f.lin_step >= 0) || !std::isfinite(f.lin_step) || !(f.ang_step >= 0) || !std::isfinite(f.ang_step))
    throw std::invalid_argument("finite-difference steps must be >= 0 (0 = automatic)");
  {
    // Bounds of explicit finite-difference steps (Eq. 7). Below: the atlas
    // stores object-frame positions in float32, so a height carries a
    // rounding of up to 2^-24 x the largest coordinate c; a central
    // difference over 2 s then errs by up to 2^-24 c / s, which stays under
    // 1 % of a unit gradient only for s >= 100 x 2^-24 c. Above: a step of
    // more than 10 % of the smaller part (or 0.1 rad) is no derivative of the
    // local contact any more.
    double coord = 0.0, diag_min = std::numeric_limits<double>::infinity(), diag_a = 0.0;
    for (size_t i = 0; i < objects_.size(); ++i) {
      const Model& m = *objects_[i];
      for (const Vec3& x : m.vertices) coord = std::max(coord, x.cwiseAbs().maxCoeff());
      double diag = m.quality.bbox_diagonal;
      if (!(diag > 0)) {
        Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
        for (const Vec3& x : m.vertices) {
          lo = lo.cwiseMin(x);
          hi = hi.cwiseMax(x);
        }
        diag = m.vertices.empty() ? 0.0 : (hi - lo).norm();
      }
      diag_min = std::min(diag_min, diag);
      if (i == 0) diag_a = diag;
    }
    const double lin_min = 100.0 * std::ldexp(1.0, -24) * coord;
    const double lin_max = 0.1 * diag_min;
    const double ang_min = diag_a > 0 ? lin_min / diag_a : 0.0;
    const double ang_max = 0.1;
    char buf[256];
    if (f.lin_step != 0 && (f.lin_step < lin_min || f.lin_step > lin_max)) {
      std::snprintf(buf, sizeof buf,
                    "lin_step %.3g m is outside [%.3g, %.3g] m for these models (0 = one grid texel): below, the "
                    "float32 atlas positions make the finite differences noise; above, 10 %% of the smaller part",
                    f.lin_step, lin_min, lin_max);
      throw std::invalid_argument(buf);
    }
    if (f.ang_step != 0 && (f.ang_step < ang_min || f.ang_step > ang_max)) {
      std::snprintf(buf, sizeof buf,
                    "ang_step %.3g rad is outside [%.3g, %.3g] rad for these models (0 = matching angle): below, "
                    "the float32 atlas positions make the finite differences noise",
                    f.ang_step, ang_min, ang_max);
      throw std::invalid_argument(buf);
    }
  }
  const ClusterOptions& c = options_.cluster;
  if (c.max_patches < 1) throw std::invalid_argument("max_patches must be at least 1");
  if (!(c.max_normal_angle_deg > 0 && c.max_normal_angle_deg <= 180))
    throw std::invalid_argument("max_normal_angle_deg must be in (0, 180]");
  if (!(c.track_radius_factor >= 0)) throw std::invalid_argument("track_radius_factor must be >= 0");
  if (c.auto_resolution && (c.max_resolution < f.resolution || c.max_resolution > kMaxResolution))
    throw std::invalid_argument("max_resolution must be between the resolution (" + std::to_string(f.resolution) +
                                ") and " + std::to_string(kMaxResolution) + ", got " +
                                std::to_string(c.max_resolution));
  if (!(c.auto_cell_fraction > 0 && c.auto_cell_fraction <= 1))
    throw std::invalid_argument("auto_cell_fraction must be in (0, 1]");
  if (!std::isfinite(options_.collision.margin)) throw std::invalid_argument("margin must be finite");

  world_ = std::make_unique<collision::World>(objects_);
  const Model& A = *objects_[0];
  tolerance_.assign(objects_.size(), 0.0);
  for (size_t b = 1; b < objects_.size(); ++b) {
    const Model& B = *objects_[b];
    double margin = options_.collision.margin;
    if (margin < 0) {
      double da = A.quality.bbox_diagonal > 0 ? A.quality.bbox_diagonal : world_->geometry(0).scale;
      double db = B.quality.bbox_diagonal > 0 ? B.quality.bbox_diagonal : world_->geometry(static_cast<int>(b)).scale;
      margin = options_.collision.auto_margin_fraction * std::min(da, db);
    }
    tolerance_[b] = A.quality.displacement_outward + A.quality.hull_deviation + B.quality.displacement_outward +
                    B.quality.hull_deviation + margin;
  }
}

Scene::~Scene() = default;

void FrameScratch::resize_pair_scratch(size_t n) {
  pair_weight.resize(n);
  pair_overlap.resize(n);
  uf_parent.resize(n);
  pair_order.resize(n);
  pair_cluster.resize(n);
  cluster_weight.resize(n);
  cluster_patch.resize(n);
  cluster_order.resize(n);
}

State::State(const Scene& scene) : scratch(std::make_unique<FrameScratch>()) {
  FrameScratch& sc = *scratch;
  const int n = scene.size();
  poses.assign(static_cast<size_t>(n), Pose{});
  velocities.assign(static_cast<size_t>(n), Vec6::Zero());
  wrench_b.assign(static_cast<size_t>(n), Vec6::Zero());
  const Model& A = scene.model(0);
  size_t b_pieces = 0, b_faces = 0;
  for (int b = 1; b < n; ++b) {
    b_pieces += scene.model(b).pieces.size();
    b_faces = std::max(b_faces, scene.model(b).faces.size());
  }
  // Pairs: every A piece against a handful of B pieces is generous; the
  // buffer grows (counted in warnings.pairs_grown) if a scene needs more.
  size_t pair_cap = std::min<size_t>(A.pieces.size() * b_pieces, std::max<size_t>(1024, 8 * A.pieces.size()));
  pairs.resize(std::max<size_t>(pair_cap, 16));
  sc.resize_pair_scratch(pairs.size());
  sc.candidates.resize(static_cast<size_t>(std::max(1, scene.world().max_b_pieces())));

  const int maxp = scene.options().cluster.max_patches;
  patches.resize(static_cast<size_t>(maxp));
  for (ContactPatch& p : patches) {
    p.tris_a.reserve(A.faces.size());
    p.tris_b.reserve(b_faces);
    if (scene.options().force.heights == HeightMode::mesh) {
      p.reach_a.reserve(A.faces.size());
      p.reach_b.reserve(b_faces);
    }
  }
  patch_ids.assign(static_cast<size_t>(maxp), 0);
  sc.depth_jobs.resize(static_cast<size_t>(maxp));
  sc.depth_results.resize(static_cast<size_t>(maxp));
  sc.patch_first_pair.assign(static_cast<size_t>(maxp), 0);
  sc.patch_pair_count.assign(static_cast<size_t>(maxp), 0);
  sc.tracks.resize(static_cast<size_t>(maxp));
  sc.next_tracks.resize(static_cast<size_t>(maxp));
  sc.face_mark_a.assign(A.faces.size(), 0);
  sc.face_mark_b.assign(b_faces, 0);
  sc.piece_mark_a.assign(A.pieces.size(), 0);
  size_t maxbp = 0;
  for (int b = 1; b < n; ++b) maxbp = std::max(maxbp, scene.model(b).pieces.size());
  sc.piece_mark_b.assign(maxbp, 0);
  size_t b_vertices = 0;
  for (int b = 1; b < n; ++b) b_vertices = std::max(b_vertices, scene.model(b).vertices.size());
  sc.vertex_stamp_a.assign(A.vertices.size(), 0);
  sc.vertex_stamp_b.assign(b_vertices, 0);
  sc.vertex_proj_a.assign(3 * A.vertices.size(), 0.0);
  sc.vertex_proj_b.assign(3 * b_vertices, 0.0);
  sc.tri_box_a.assign(4 * A.faces.size(), 0.0);
  sc.tri_box_b.assign(4 * b_faces, 0.0);
  sc.piece_list_a.assign(A.pieces.size(), 0);
  sc.safety_mark_a.assign(A.pieces.size(), 0);
  sc.safety_mark_b.assign(maxbp, 0);
  sc.piece_list_b.assign(maxbp, 0);
  sc.track_taken.assign(static_cast<size_t>(maxp), 0);
  sc.target_cell.assign(static_cast<size_t>(n), 0.0);
  // The largest N any patch may use (ClusterOptions::auto_resolution).
  const ClusterOptions& copt = scene.options().cluster;
  const int reserve_n = copt.auto_resolution ? std::max(scene.options().force.resolution, copt.max_resolution)
                                             : scene.options().force.resolution;
  sc.depth.reserve(reserve_n);
  const int threads = resolve_threads(scene.options().threads);
  sc.narrow_b_from_a.assign(static_cast<size_t>(n), Eigen::Isometry3d::Identity());
  if (threads > 1) {
    sc.narrow_jobs.resize(pairs.size());
    sc.pool_order.assign(static_cast<size_t>(maxp), 0);
    sc.pool_cost.assign(static_cast<size_t>(maxp), 0.0);
    sc.pool = std::make_unique<TaskPool>(threads);
    sc.pool_depth.resize(static_cast<size_t>(threads - 1));
    for (DepthScratch& d : sc.pool_depth) d.reserve(reserve_n);
  }
}

State::~State() = default;

}  // namespace hrt
