// Command-line pieces shared by `hrt query` and `hrt bench`: the scene
// options as flags, pose parsing, bundle loading. Header-only, used by
// cmd_query.cpp and cmd_bench.cpp.
#pragma once

#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "commands.h"
#include "hrt/model.h"
#include "hrt/scene.h"

namespace hrt_cli {

// Strict number syntax for every numeric option. CLI11 2.1's own conversion
// reads "" as 0 and accepts hex, "nan", "inf" and out-of-range values, so
// each value's text is checked first: a decimal number, fully consumed,
// finite, nothing before or after it.
inline std::string real_number_error(const std::string& s) {
  if (s.empty()) return "empty value, expected a number";
  if (s.find_first_not_of("0123456789+-.eE") != std::string::npos) return "'" + s + "' is not a decimal number";
  errno = 0;
  char* end = nullptr;
  const double x = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size()) return "'" + s + "' is not a number";
  // ERANGE on underflow (1e-400 -> 0) is harmless; overflow is refused.
  if ((errno == ERANGE && std::fabs(x) >= 1.0) || !std::isfinite(x)) return "'" + s + "' is out of the range of a double";
  return "";
}
inline std::string integer_error(const std::string& s) {
  if (s.empty()) return "empty value, expected an integer";
  const size_t digits = s[0] == '-' || s[0] == '+' ? 1 : 0;
  if (s.size() == digits || s.find_first_not_of("0123456789", digits) != std::string::npos)
    return "'" + s + "' is not a decimal integer";
  errno = 0;
  const long long v = std::strtoll(s.c_str(), nullptr, 10);
  if (errno == ERANGE || v < INT_MIN || v > INT_MAX) return "'" + s + "' is out of the range of an int";
  return "";
}
inline CLI::Validator RealNumber() {
  return CLI::Validator([](std::string& s) { return real_number_error(s); }, "NUMBER", "RealNumber");
}
inline CLI::Validator Integer() {
  return CLI::Validator([](std::string& s) { return integer_error(s); }, "INT", "Integer");
}

// Flags that set hrt::SceneOptions; defaults are SceneOptions' own.
struct SceneFlags {
  int resolution = hrt::kDefaultResolution;
  double stiffness = hrt::kDefaultStiffness;
  double lin_step = 0.0;
  double ang_step = 0.0;
  double margin = -1.0;
  bool shortcut = false;
  std::string heights = "surface";
  int max_patches = hrt::ClusterOptions{}.max_patches;
  bool auto_resolution = hrt::ClusterOptions{}.auto_resolution;
  int max_resolution = hrt::ClusterOptions{}.max_resolution;
  bool verify_hashes = true;

  void add_to(CLI::App* cmd, bool with_resolution = true) {
    if (with_resolution)
      cmd->add_option("--resolution", resolution, "grid resolution N of each patch window (N x N texels)")
          ->check(Integer())
          ->capture_default_str();
    cmd->add_option("--stiffness", stiffness, "stiffness k of Eq. 3, N/m")->check(RealNumber())->capture_default_str();
    cmd->add_option("--lin-step", lin_step, "translation step of Eq. 7, m (0: one grid texel)")
        ->check(RealNumber())
        ->capture_default_str();
    cmd->add_option("--ang-step", ang_step, "rotation step of Eq. 7, rad (0: the matching angle, one texel)")
        ->check(RealNumber())
        ->capture_default_str();
    cmd->add_option("--margin", margin,
                    "m added to the contact tolerance (negative: 0.1% of the smaller bbox diagonal)")
        ->check(RealNumber())
        ->capture_default_str();
    cmd->add_flag("--shortcut", shortcut, "resample h_A(0) for the translated and n-rotated configurations (Sec. 5.2)");
    cmd->add_option("--heights", heights,
                    "surface: the reconstructed full surface on each texel column (parallax corrected); coarse: the "
                    "literal Eq. 8 of format 1.0 (n . f(q) at the coarse point q's column)")
        ->check(CLI::IsMember({"surface", "coarse"}))
        ->capture_default_str();
    cmd->add_option("--max-patches", max_patches, "most contact patches per frame")->check(Integer())->capture_default_str();
    cmd->add_flag("--auto-resolution", auto_resolution,
                  "per patch, raise N (up to --max-resolution) until the grid texel is <= 1/4 of the bundles' "
                  "min_wavelength");
    cmd->add_option("--max-resolution", max_resolution, "budget of --auto-resolution: largest N of a patch")
        ->check(Integer())
        ->capture_default_str();
    cmd->add_flag("!--no-verify-hashes", verify_hashes, "skip the SHA-256 checks of the bundles' files");
  }

  hrt::SceneOptions scene_options() const {
    hrt::SceneOptions o;
    o.force.resolution = resolution;
    o.force.stiffness = stiffness;
    o.force.lin_step = lin_step;
    o.force.ang_step = ang_step;
    o.force.shortcut = shortcut;
    o.force.heights = heights == "coarse" ? hrt::HeightMode::coarse : hrt::HeightMode::surface;
    o.collision.margin = margin;
    o.cluster.max_patches = max_patches;
    o.cluster.auto_resolution = auto_resolution;
    o.cluster.max_resolution = max_resolution;
    return o;
  }
};

// The supported range of positions (poses, bench paths): |p| <= 1e4 m. The
// models are parts of at most metres; far beyond this the contact
// computations lose all precision in double and overflow near 1e308 (a
// position of 5e307 printed null for the contact points in --json).
constexpr double kMaxPosition = 1e4;
// Tolerance on the norm of a pose's quaternion before it is normalised.
constexpr double kQuaternionTolerance = 1e-3;

inline std::string fmt_g(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", x);
  return buf;
}

// A pose from 7 numbers x y z qx qy qz qw (m, unit quaternion in glTF order).
// The quaternion is normalised; one whose norm is far from 1 is refused
// (it is most likely in w x y z order or not a rotation).
inline hrt::Pose parse_pose(const std::vector<double>& v, const std::string& flag) {
  if (v.size() != 7)
    throw Exit(kUsage, flag + ": expected 7 numbers x y z qx qy qz qw, got " + std::to_string(v.size()));
  for (double x : v)
    if (!std::isfinite(x)) throw Exit(kUsage, flag + ": every number must be finite");
  const hrt::Vec3 position(v[0], v[1], v[2]);
  if (!(position.stableNorm() <= kMaxPosition))
    throw Exit(kUsage, flag + ": the position (" + fmt_g(v[0]) + ", " + fmt_g(v[1]) + ", " + fmt_g(v[2]) + ") is " + fmt_g(position.stableNorm()) +
                           " m from the origin; |position| must be at most " + fmt_g(kMaxPosition) + " m");
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);  // Eigen's constructor takes w first
  const double norm = q.coeffs().stableNorm();  // no overflow to inf for 1e308
  if (!(std::abs(norm - 1.0) <= kQuaternionTolerance))
    throw Exit(kUsage, flag + ": the quaternion (qx qy qz qw) has norm " + fmt_g(norm) +
                           ", expected a unit quaternion (x, y, z, w order; norm within " + fmt_g(kQuaternionTolerance) + " of 1)");
  hrt::Pose p;
  p.position = position;
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
