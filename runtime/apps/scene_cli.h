// Command-line pieces shared by `hrt query` and `hrt bench`: the scene
// options as flags, pose parsing, bundle loading. Header-only, used by
// cmd_query.cpp and cmd_bench.cpp.
#pragma once

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "commands.h"
#include "hrt/model.h"
#include "hrt/scene.h"

namespace hrt_cli {

// Flags that set hrt::SceneOptions; defaults are SceneOptions' own.
struct SceneFlags {
  int resolution = hrt::kDefaultResolution;
  double stiffness = hrt::kDefaultStiffness;
  double lin_step = 0.0;
  double ang_step = 0.0;
  double margin = -1.0;
  bool shortcut = false;
  int max_patches = hrt::ClusterOptions{}.max_patches;
  bool verify_hashes = true;

  void add_to(CLI::App* cmd, bool with_resolution = true) {
    if (with_resolution)
      cmd->add_option("--resolution", resolution, "grid resolution N of each patch window (N x N texels)")
          ->capture_default_str();
    cmd->add_option("--stiffness", stiffness, "stiffness k of Eq. 3, N/m")->capture_default_str();
    cmd->add_option("--lin-step", lin_step, "translation step of Eq. 7, m (0: one grid texel)")->capture_default_str();
    cmd->add_option("--ang-step", ang_step, "rotation step of Eq. 7, rad (0: the matching angle, one texel)")
        ->capture_default_str();
    cmd->add_option("--margin", margin,
                    "m added to the contact tolerance (negative: 0.1% of the smaller bbox diagonal)")
        ->capture_default_str();
    cmd->add_flag("--shortcut", shortcut, "resample h_A(0) for the translated and n-rotated configurations (Sec. 5.2)");
    cmd->add_option("--max-patches", max_patches, "most contact patches per frame")->capture_default_str();
    cmd->add_flag("!--no-verify-hashes", verify_hashes, "skip the SHA-256 checks of the bundles' files");
  }

  hrt::SceneOptions scene_options() const {
    hrt::SceneOptions o;
    o.force.resolution = resolution;
    o.force.stiffness = stiffness;
    o.force.lin_step = lin_step;
    o.force.ang_step = ang_step;
    o.force.shortcut = shortcut;
    o.collision.margin = margin;
    o.cluster.max_patches = max_patches;
    return o;
  }
};

// A pose from 7 numbers x y z qx qy qz qw (m, unit quaternion in glTF order).
// The quaternion is normalised; one whose norm is far from 1 is refused
// (it is most likely in w x y z order or not a rotation).
inline hrt::Pose parse_pose(const std::vector<double>& v, const std::string& flag) {
  if (v.size() != 7)
    throw Exit(kUsage, flag + ": expected 7 numbers x y z qx qy qz qw, got " + std::to_string(v.size()));
  for (double x : v)
    if (!std::isfinite(x)) throw Exit(kUsage, flag + ": every number must be finite");
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);  // Eigen's constructor takes w first
  const double norm = q.norm();
  if (std::abs(norm - 1.0) > 1e-3)
    throw Exit(kUsage, flag + ": the quaternion (qx qy qz qw) has norm " + std::to_string(norm) +
                           ", expected a unit quaternion (x, y, z, w order)");
  hrt::Pose p;
  p.position = hrt::Vec3(v[0], v[1], v[2]);
  p.rotation = q.normalized();
  return p;
}

// Loads every bundle (BundleError propagates to main: exit code 3).
inline std::vector<std::unique_ptr<hrt::Model>> load_models(const std::vector<std::string>& paths, bool verify) {
  hrt::LoadOptions lo;
  lo.verify_hashes = verify;
  std::vector<std::unique_ptr<hrt::Model>> out;
  for (const std::string& p : paths) out.push_back(std::make_unique<hrt::Model>(hrt::load_bundle(p, lo)));
  return out;
}

// Builds the scene; bad options become a usage error.
inline std::unique_ptr<hrt::Scene> make_scene(const std::vector<const hrt::Model*>& objects,
                                              const hrt::SceneOptions& o) {
  try {
    return std::make_unique<hrt::Scene>(objects, o);
  } catch (const std::invalid_argument& e) {
    throw Exit(kUsage, e.what());
  }
}

}  // namespace hrt_cli
