// hrt::Session on synthetic models (test_contact_models.h: the 40 x 20 x 10 mm
// probe box, its bottom at z = -5 mm, and the 200 x 200 x 10 mm plate, its top
// at z = 0), and the device log of a lockstep DeviceLoop:
//   - a patch the safety checks refuse fades out linearly over fade_time from
//     its last accepted wrench instead of stepping to zero (and steps at once
//     when fade_time is tiny, so the fade is what is tested);
//   - write_device_log writes the column table of docs/trace-format.md, one
//     row per tick, values that read back to the same doubles;
//   - a free probe settles on a still target as the coupling's
//     mass-spring-damper does, the device command is the reaction of the
//     coupling, and K_eff = K_c - K_c (K_c + K)^-1 K_c is symmetric positive
//     semi-definite, zero without contact and below K_c in contact.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Eigenvalues>

#include "hrt/device.h"
#include "hrt/device_loop.h"
#include "hrt/run_config.h"
#include "hrt/scene.h"
#include "hrt/session.h"
#include "hrt/trajectory.h"
#include "test_contact_models.h"
#include "trace_spec.h"

namespace fs = std::filesystem;

namespace {

using hrt::Mat6;
using hrt::Pose;
using hrt::Vec3;
using hrt::Vec6;
using hrt_test::pose_at;

constexpr double kDensity = 1000.0;  // kg/m^3: the probe box weighs 8 g

// The probe box with the inertia of a solid box (the synthetic model carries
// none, and a Session refuses a probe without it), at kDensity.
hrt::Model probe_with_inertia() {
  hrt::Model a = hrt_test::probe_box();
  const double lx = 0.04, ly = 0.02, lz = 0.01, m = kDensity * lx * ly * lz;
  a.mass.density = kDensity;
  a.mass.inertia = (m / 12) * Eigen::Vector3d(ly * ly + lz * lz, lx * lx + lz * lz, lx * lx + ly * ly).asDiagonal();
  return a;
}

hrt::SceneOptions scene_options() {
  hrt::SceneOptions o;
  o.collision.margin = 1e-3;  // as in test_patch_safety.cpp: the bound is 1 mm + the pieces' overlap
  return o;
}

// Corrupts A's bottom face (strip 0 of the atlas, test_contact_models.h) by
// lowering its heights: the patch then reports delta + `by`.
void lower_bottom_heights(hrt::Model& a, float by) {
  const int strip = 32;
  for (int j = 0; j < a.atlas.height; ++j)
    for (int i = 0; i < strip; ++i) a.atlas.rgba[(static_cast<size_t>(j) * a.atlas.width + i) * 4 + 2] -= by;
  hrt::prepare_surface_map(a);
}

std::vector<std::string> spec_table_columns(const std::string& heading) {
  return hrt_test::trace_spec_columns(heading);
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out(1);
  for (char c : s) {
    if (c == sep)
      out.emplace_back();
    else
      out.back() += c;
  }
  return out;
}

// x(t) of m x'' + b x' + k x = k X (underdamped, from rest at 0).
double step_response(double X, double k, double m, double zeta, double t) {
  const double w = std::sqrt(k / m), wd = w * std::sqrt(1 - zeta * zeta);
  return X * (1 - std::exp(-zeta * w * t) * (std::cos(wd * t) + zeta / std::sqrt(1 - zeta * zeta) * std::sin(wd * t)));
}

}  // namespace

// ---------------------------------------------------------------------------
// A refused patch fades out
// ---------------------------------------------------------------------------

// The probe box held 0.2 mm into the plate (its body state is reset to that
// pose at rest before every step, so every accepted frame sees the same
// contact: 0.2 N up). After three accepted frames A's bottom heights are
// lowered by 5 mm (test_patch_safety.cpp's HeightsBeyondThePiecesAreClampedOrRefused:
// delta 5.2 mm, beyond twice the pieces' bound of 1.2 mm): frame() refuses the
// patch from then on. The session must then apply fade x W_last with fade
// decreasing by h / fade_time per frame: with h = 1 ms and fade_time = 20 ms,
// frame j after the refusal carries (1 - j / 20) W_last, zero from j = 20 on.
// Tolerance 1e-12 |W_last|: fade is a running sum of twenty h / fade_time
// steps (rounding ~1e-16 each), times a wrench of order 1.
namespace {

struct FadeRun {
  Vec6 last_accepted = Vec6::Zero();
  std::vector<Vec6> refused;  // contact wrench of each frame after the corruption
  std::vector<int> refused_count, fading_count;
};

FadeRun run_fade(double fade_time, int refused_frames) {
  hrt::Model a = probe_with_inertia();
  hrt::Model b = hrt_test::plate_box();
  hrt::Scene scene({&a, &b}, scene_options());
  hrt::SessionOptions so;
  so.density = kDensity;
  so.coupling = hrt::Coupling{200.0, 1.0, 0.2, 0.001};
  so.fade_time = fade_time;
  const Pose pressed = pose_at(Vec3(0.003, 0.002, 0.005 - 0.2e-3));
  hrt::Session session(scene, so, {pressed, pose_at(Vec3::Zero())});
  const double h = 1e-3;
  FadeRun out;
  int frame = 0;
  auto step = [&]() -> const hrt::SessionFrame& {
    session.body_state() = hrt::BodyState::at_pose(pressed, session.body().center_of_mass);
    ++frame;
    return session.step(frame * h, h, pressed);
  };
  for (int i = 0; i < 3; ++i) {
    const hrt::SessionFrame& f = step();
    EXPECT_EQ(f.patches, 1);
    EXPECT_EQ(f.refused, 0);
    out.last_accepted = f.contact;
  }
  lower_bottom_heights(a, 5e-3f);
  for (int j = 1; j <= refused_frames; ++j) {
    const hrt::SessionFrame& f = step();
    out.refused.push_back(f.contact);
    out.refused_count.push_back(f.refused);
    out.fading_count.push_back(f.fading);
  }
  return out;
}

}  // namespace

TEST(Session, RefusedPatchFadesOutLinearlyOverFadeTime) {
  const double fade_time = 0.02, h = 1e-3;
  const int n = 25;
  const FadeRun r = run_fade(fade_time, n);
  const Vec6 W = r.last_accepted;
  // The accepted contact: 0.2 N up (k = 1000 N/m times 0.2 mm), within the
  // float32 atlas's 1e-8 m (test_patch_safety.cpp's kPosTol) times k.
  ASSERT_NEAR(W[2], 0.2, 1000 * 2e-8);
  const double tol = 1e-12 * W.norm();
  for (int j = 1; j <= n; ++j) {
    const Vec6& w = r.refused[static_cast<size_t>(j - 1)];
    EXPECT_EQ(r.refused_count[static_cast<size_t>(j - 1)], 1) << "frame " << j << " after the corruption";
    const double fade = std::max(0.0, 1.0 - j * h / fade_time);
    EXPECT_LE((w - fade * W).cwiseAbs().maxCoeff(), tol)
        << "frame " << j << ": contact " << w.transpose() << ", want " << (fade * W).transpose();
    // Still fading while something is left (the frames 1..19; the 20th is ~0).
    if (j < 20) EXPECT_EQ(r.fading_count[static_cast<size_t>(j - 1)], 1) << "frame " << j;
    if (j > 20) {
      EXPECT_EQ(r.fading_count[static_cast<size_t>(j - 1)], 0) << "frame " << j;
      EXPECT_EQ(w.norm(), 0.0) << "frame " << j;
    }
  }
  // No step: the first refused frame keeps 95 % of the wrench, and no frame
  // drops by more than h / fade_time of it.
  EXPECT_GT(r.refused[0].norm(), 0.9 * W.norm());
  Vec6 prev = W;
  for (const Vec6& w : r.refused) {
    EXPECT_LE((prev - w).norm(), (h / fade_time) * W.norm() + tol);
    prev = w;
  }
}

TEST(Session, RefusedPatchWithATinyFadeTimeStopsAtOnce) {
  const FadeRun r = run_fade(1e-6, 3);
  ASSERT_GT(r.last_accepted.norm(), 0.1);
  for (size_t j = 0; j < r.refused.size(); ++j) {
    EXPECT_EQ(r.refused_count[j], 1);
    EXPECT_EQ(r.refused[j].norm(), 0.0) << "frame " << j + 1 << " after the corruption";
    EXPECT_EQ(r.fading_count[j], 0);
  }
}

// ---------------------------------------------------------------------------
// write_device_log
// ---------------------------------------------------------------------------

// A lockstep DeviceLoop on a ScriptedDevice moving along a turning segment
// (so every target column varies), a command published every tick, 12 ticks
// logged: the file's header is the spec's "Device log columns" table, one
// row per tick, and every value reads back (strtod) to the very double of
// DeviceLoop::log() (the writer prints shortest round-trip text): EXPECT_EQ.
TEST(Session, DeviceLogHasTheSpecsColumnsAndOneExactRowPerTick) {
  const std::vector<std::string> spec = spec_table_columns("## Device log columns");
  ASSERT_EQ(spec.size(), 14u);
  const hrt::Trajectory tr = hrt::Trajectory::from_samples(
      {0.0, 0.1},
      {pose_at(Vec3(0.01, -0.02, 0.03)),
       pose_at(Vec3(0.02, 0.01, 0.025), Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Vec3(1, 2, 3).normalized())))});
  hrt::ScriptedDevice device(tr, hrt::DeviceInfo{});
  hrt::DeviceLoopOptions o;
  o.soft_start = 0.005;
  o.log_capacity = 64;
  hrt::ManualClock clock;
  hrt::DeviceLoop loop(device, o, clock, 0);
  const int ticks = 12;
  std::vector<Vec6> written;
  for (int i = 0; i < ticks; ++i) {
    clock.set(i * 1e-3);
    loop.tick();
    written.push_back(device.last_wrench());
    hrt::DeviceTarget tgt;
    ASSERT_TRUE(loop.target(tgt));
    hrt::DeviceCommand c;
    c.valid = true;
    c.time = i * 1e-3;
    c.frame = static_cast<uint64_t>(i + 1);
    c.target_ref = tgt.target;
    c.wrench << 0.1 * (i + 1) / 3.0, -0.05, 1.0 / 7.0, 1e-3 / 3.0, 0.0, -2e-3 / 9.0;
    loop.publish(c);
  }
  ASSERT_EQ(loop.log_size(), static_cast<size_t>(ticks));

  const fs::path dir = fs::path(::testing::TempDir()) / ("hrt_session_log_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string path = (dir / "device.csv").string();
  hrt::write_device_log(path, loop);
  EXPECT_FALSE(fs::exists(path + ".partial"));
  std::ifstream in(path);
  ASSERT_TRUE(in.good());
  std::string line;
  ASSERT_TRUE(std::getline(in, line));
  EXPECT_EQ(split(line, ','), spec);
  std::vector<std::vector<double>> rows;
  while (std::getline(in, line)) {
    std::vector<double> r;
    for (const std::string& s : split(line, ',')) {
      char* end = nullptr;
      r.push_back(std::strtod(s.c_str(), &end));
      EXPECT_TRUE(!s.empty() && *end == '\0') << "'" << s << "' in " << line;
    }
    ASSERT_EQ(r.size(), spec.size()) << line;
    rows.push_back(r);
  }
  fs::remove_all(dir);
  ASSERT_EQ(rows.size(), static_cast<size_t>(ticks));
  bool some_force = false;
  for (int i = 0; i < ticks; ++i) {
    const hrt::DeviceLogRow& l = loop.log()[static_cast<size_t>(i)];
    const std::vector<double>& r = rows[static_cast<size_t>(i)];
    EXPECT_EQ(r[0], l.t);
    EXPECT_EQ(r[0], i * 1e-3);
    const double want[13] = {l.target.position.x(),
                             l.target.position.y(),
                             l.target.position.z(),
                             l.target.rotation.x(),
                             l.target.rotation.y(),
                             l.target.rotation.z(),
                             l.target.rotation.w(),
                             l.output[0],
                             l.output[1],
                             l.output[2],
                             l.output[3],
                             l.output[4],
                             l.output[5]};
    for (int c = 0; c < 13; ++c)
      EXPECT_EQ(r[static_cast<size_t>(c + 1)], want[c]) << spec[static_cast<size_t>(c + 1)] << ", tick " << i;
    // The log is what the device was given, and the target is the trajectory's.
    for (int c = 0; c < 6; ++c) EXPECT_EQ(r[static_cast<size_t>(8 + c)], written[static_cast<size_t>(i)][c]);
    const Pose p = tr.sample(i * 1e-3);
    EXPECT_NEAR((l.target.position - p.position).norm(), 0.0, 1e-15);
    some_force = some_force || l.output.norm() > 0;
  }
  EXPECT_TRUE(some_force) << "every logged output is zero: the round trip would prove little";
  EXPECT_NE(rows.front()[1], rows.back()[1]);  // the target moved
}

// ---------------------------------------------------------------------------
// Session basics
// ---------------------------------------------------------------------------

// A free probe (the plate 1 m below: no contact) and a still target 1 mm away
// along (0.6, 0.8, 0): the session's coupling alone pulls it there, as the
// closed-form step response of m x'' + b x' + k x = k X, within 5 % of the
// step (the tolerance; k = 20 N/m on 8 g: w = 50 rad/s, w h = 0.05,
// and backward Euler's first-order error is an extra decay of the transient
// of w^2 h t / 2, 2.5 % at t = 1 / w); settled to 1e-6 of the step after 1 s
// (25 decay times 1 / (zeta w): e^-25 ~ 1e-11).
// Every frame: no patch, the device command is the reaction of the coupling
// (-coupling wrench on A, bit for bit), the coupling wrench is k (x_t - x) - b v
// of the state after the step, and K_eff is zero (no contact: pushing the
// handle moves a free probe, the device feels no stiffness at rest).
TEST(Session, FreeProbeSettlesOnAStillTargetThroughTheCoupling) {
  hrt::Model a = probe_with_inertia();
  hrt::Model b = hrt_test::plate_box();
  hrt::Scene scene({&a, &b}, scene_options());
  hrt::SessionOptions so;
  so.density = kDensity;
  const double m = kDensity * 0.04 * 0.02 * 0.01, k = 20.0, zeta = 0.5;
  so.coupling = hrt::Coupling{k, 2 * zeta * std::sqrt(k * m), 0.2, 2 * 0.7 * std::sqrt(0.2 * 1e-6)};
  hrt::Session session(scene, so, {pose_at(Vec3::Zero()), pose_at(Vec3(0, 0, -1.0))});
  ASSERT_NEAR(session.body().mass, m, 1e-15);
  const Vec3 dir(0.6, 0.8, 0.0);
  const double X = 1e-3, h = 1e-3;
  const Pose target = pose_at(X * dir);
  double worst = 0;
  for (int i = 1; i <= 1000; ++i) {
    const hrt::SessionFrame& f = session.step(i * h, h, target);
    ASSERT_EQ(f.patches, 0);
    ASSERT_EQ(f.contact.norm(), 0.0);
    const double x = f.probe.position.dot(dir);
    worst = std::max(worst, std::abs(x - step_response(X, k, m, zeta, i * h)));
    const hrt::DeviceCommand& c = session.command();
    ASSERT_TRUE(c.valid);
    for (int e = 0; e < 6; ++e) ASSERT_EQ(c.wrench[e], -f.coupling[e]) << "frame " << i;
    const hrt::BodyState& s = session.body_state();
    const Vec3 spring =
        k * (target.position + target.rotation * session.body().center_of_mass - s.x) - so.coupling.b_lin * s.v;
    ASSERT_NEAR((f.coupling.head<3>() - spring).norm(), 0.0, 1e-12) << "frame " << i;
    ASSERT_LE(c.stiffness.cwiseAbs().maxCoeff(), 1e-9 * k) << "frame " << i;
    ASSERT_TRUE(c.target_ref.position == target.position);
  }
  std::printf("free probe: worst error %.3g of the step\n", worst / X);
  EXPECT_LT(worst, 0.05 * X);
  EXPECT_NEAR((session.last().probe.position - target.position).norm(), 0.0, 1e-6 * X);
  EXPECT_NEAR(session.last().probe.rotation.angularDistance(target.rotation), 0.0, 1e-9);
}

// In contact: the probe box 0.5 mm into the plate (k = 1000 N/m) on a 200 N/m
// coupling. K_eff is symmetric (exactly: the session symmetrizes it),
// positive semi-definite, and below K_c (K_c - K_eff positive semi-definite):
// eigenvalues >= -1e-9 x k_c (rounding of a 6 x 6 solve on gains of order
// 1e2). Along the normal the flat contact's K is k (its gradient is pure n
// up to the float32 atlas, ~1e-6 relative), so K_eff_zz is the series
// stiffness k_c k / (k_c + k) = 166.7 N/m, to 1 %.
// With k_lin above the device's max_stiffness K_eff is capped there.
TEST(Session, EffectiveStiffnessIsSymmetricPsdAndBelowTheCouplingInContact) {
  hrt::Model a = probe_with_inertia();
  hrt::Model b = hrt_test::plate_box();
  hrt::Scene scene({&a, &b}, scene_options());
  const double kc = 200.0, k = scene.options().force.stiffness;
  for (const double k_lin : {kc, 5000.0}) {
    hrt::SessionOptions so;
    so.density = kDensity;
    so.coupling = hrt::Coupling{k_lin, 1.0, 0.2, 0.001};
    so.max_device_stiffness = 2000.0;
    const Pose pressed = pose_at(Vec3(0.0, 0.0, 0.005 - 0.5e-3));
    hrt::Session session(scene, so, {pressed, pose_at(Vec3::Zero())});
    const hrt::SessionFrame& f = session.step(1e-3, 1e-3, pressed);
    ASSERT_EQ(f.patches, 1);
    ASSERT_EQ(f.refused, 0);
    ASSERT_GT(f.contact[2], 0.4);  // 0.5 N up
    const Mat6 K = session.command().stiffness;
    ASSERT_TRUE(K.allFinite());
    EXPECT_EQ(K, K.transpose());
    Mat6 Kc = Mat6::Zero();
    Kc.topLeftCorner<3, 3>() = k_lin * hrt::Mat3::Identity();
    Kc.bottomRightCorner<3, 3>() = 0.2 * hrt::Mat3::Identity();
    const Eigen::SelfAdjointEigenSolver<Mat6> eig(K);
    const Eigen::SelfAdjointEigenSolver<Mat6> gap(Kc - K);
    std::ostringstream ev;
    ev << eig.eigenvalues().transpose();
    std::printf("k_lin %.0f: K_eff eigenvalues %s; K_eff_zz %.4f N/m\n", k_lin, ev.str().c_str(), K(2, 2));
    EXPECT_GE(eig.eigenvalues().minCoeff(), -1e-9 * k_lin);
    EXPECT_GE(gap.eigenvalues().minCoeff(), -1e-9 * k_lin);
    const double series = k_lin * k / (k_lin + k);
    // The cap: a congruence by sqrt(max / k_lin) on the linear block.
    const double cap = k_lin > so.max_device_stiffness ? so.max_device_stiffness / k_lin : 1.0;
    EXPECT_NEAR(K(2, 2), cap * series, 0.01 * cap * series);
    EXPECT_LE(K(2, 2), so.max_device_stiffness);
    // Free directions in the plane (frictionless, flat): no stiffness.
    EXPECT_NEAR(K(0, 0), 0.0, 1e-6 * k_lin);
    EXPECT_NEAR(K(1, 1), 0.0, 1e-6 * k_lin);
  }
}
