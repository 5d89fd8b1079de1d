// Trajectories (hrt/trajectory.h, docs/trajectory-format.md) and the scripted
// device that plays them: CSV parsing and each of its errors (the message
// names the file and the line), interpolation against closed forms, and the
// segment cache agreeing with a plain search.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <limits>
#include <thread>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <unistd.h>

#include "hrt/device.h"
#include "hrt/trajectory.h"

namespace {

using Eigen::AngleAxisd;
using Eigen::Quaterniond;
using hrt::Pose;
using hrt::Trajectory;
using hrt::TrajectoryError;
using hrt::Vec3;

std::string write_file(const std::string& name, const std::string& text) {
  const auto dir = std::filesystem::temp_directory_path() / ("hrt_traj_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const std::string path = (dir / name).string();
  std::ofstream(path) << text;
  return path;
}

std::string load_error(const std::string& path, const std::string& prefix = "") {
  try {
    Trajectory::load_csv(path, prefix);
  } catch (const TrajectoryError& e) {
    return e.what();
  }
  return "(no error)";
}

Pose pose(Vec3 p, Quaterniond q) {
  Pose out;
  out.position = p;
  out.rotation = q;
  return out;
}

}  // namespace

// Columns in any order, extra columns ignored, quaternions normalized, and
// the second quaternion (written as -q) flipped onto the first's hemisphere.
TEST(Trajectory, LoadsColumnsInAnyOrderNormalizesAndAlignsSigns) {
  const std::string path = write_file("order.csv",
                                      "# comment line\n"
                                      "qw, note ,qz,t,z,y,x,qy,qx\n"
                                      "2,a,0,0,3,2,1,0,0\n"
                                      "\n"
                                      "-0.8,b,-0.6,0.5,6,5,4,0,0\n");
  const Trajectory tr = Trajectory::load_csv(path);
  ASSERT_EQ(tr.size(), 2u);
  EXPECT_DOUBLE_EQ(tr.start_time(), 0.0);
  EXPECT_DOUBLE_EQ(tr.end_time(), 0.5);
  EXPECT_TRUE(tr.poses()[0].position.isApprox(Vec3(1, 2, 3)));
  EXPECT_TRUE(tr.poses()[1].position.isApprox(Vec3(4, 5, 6)));
  EXPECT_NEAR(tr.poses()[0].rotation.w(), 1.0, 1e-15);  // 2 normalized
  EXPECT_NEAR(tr.poses()[1].rotation.w(), 0.8, 1e-15);  // sign flipped
  EXPECT_NEAR(tr.poses()[1].rotation.z(), 0.6, 1e-15);
}

// A trace of `hrt run` holds several poses; the prefix picks the device's, and
// the time column may be called `time`.
TEST(Trajectory, PrefixSelectsTheDeviceColumnsOfATrace) {
  const std::string path = write_file("trace.csv",
                                      "time,probe_x,probe_y,probe_z,probe_qx,probe_qy,probe_qz,probe_qw,"
                                      "device_x,device_y,device_z,device_qx,device_qy,device_qz,device_qw\n"
                                      "0,9,9,9,0,0,0,1,0.1,0.2,0.3,0,0,0,1\n"
                                      "1,9,9,9,0,0,0,1,0.2,0.4,0.6,0,0,0,1\n");
  const Trajectory tr = Trajectory::load_csv(path, "device_");
  EXPECT_TRUE(tr.sample(0.5).position.isApprox(Vec3(0.15, 0.3, 0.45)));
  EXPECT_NE(load_error(path).find("missing column 'x'"), std::string::npos) << load_error(path);
}

// Each error names the file, the line and what is wrong.
TEST(Trajectory, EachErrorNamesTheFileAndTheLine) {
  const std::string h = "t,x,y,z,qx,qy,qz,qw\n";
  const std::string ok = "0,0,0,0,0,0,0,1\n";
  struct Case {
    std::string name, text, line, what;
  };
  const Case cases[] = {
      {"missing.csv", "t,x,y,z,qx,qy,qw\n" + ok, "line 1", "missing column 'qz'"},
      {"notime.csv", "s,x,y,z,qx,qy,qz,qw\n" + ok, "line 1", "missing column 't' (or 'time')"},
      {"twice.csv", "t,x,y,z,qx,qy,qz,qw,x\n" + ok, "line 1", "column 'x' appears twice"},
      {"empty.csv", "\n\n", "line 2", "no header line"},
      {"norows.csv", h + "\n", "line 2", "no data rows"},
      {"text.csv", h + ok + "1,0,abc,0,0,0,0,1\n", "line 3", "column 'y': 'abc' is not a number"},
      {"partial.csv", h + ok + "1,0,0.5x,0,0,0,0,1\n", "line 3", "'0.5x' is not a number"},
      {"blankfield.csv", h + "0,0,,0,0,0,0,1\n", "line 2", "column 'y': '' is not a number"},
      {"nan.csv", h + ok + "1,0,0,nan,0,0,0,1\n", "line 3", "column 'z': nan is not finite"},
      {"inf.csv", h + ok + "1,0,0,0,0,0,0,inf\n", "line 3", "column 'qw': inf is not finite"},
      {"overflow.csv", h + "1e999,0,0,0,0,0,0,1\n", "line 2", "column 't': 1e999 is not finite"},
      {"short.csv", h + ok + "1,0,0\n", "line 3", "3 fields, the header's columns need 8"},
      {"zeroq.csv", h + ok + "\n1,0,0,0,0,0,0,0\n", "line 4", "zero quaternion"},
      {"back.csv", h + ok + "1,0,0,0,0,0,0,1\n1,0,0,0,0,0,0,1\n", "line 4", "time 1 is not after"},
      {"down.csv", h + "2,0,0,0,0,0,0,1\n1,0,0,0,0,0,0,1\n", "line 3", "not after the previous sample's 2"},
      {"far.csv", h + ok + "1,-1e308,0,0,0,0,0,1\n", "line 3", "more than 10000 m from the origin"},
      {"nul.csv", h + std::string("0,0,0,0\0,0,0,0,1\n", 19), "line 2", "'0\\x00' is not a number"},
  };
  for (const Case& c : cases) {
    const std::string path = write_file(c.name, c.text);
    const std::string msg = load_error(path);
    EXPECT_EQ(msg.rfind(path + ": " + c.line + ": ", 0), 0u) << c.name << ": " << msg;
    EXPECT_NE(msg.find(c.what), std::string::npos) << c.name << ": " << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << c.name << ": one line: " << msg;
  }
  // A quaternion whose plain norm overflows (the fuzzer's find: dividing by an infinite
  // norm made it a zero quaternion) is a rotation like any other, normalized.
  const hrt::Trajectory big = hrt::Trajectory::load_csv(write_file("bigq.csv", h + "0,0,0,0,0,0,1e300,1\n"));
  EXPECT_NEAR(big.poses()[0].rotation.norm(), 1.0, 1e-15);
  EXPECT_NEAR(std::abs(big.poses()[0].rotation.z()), 1.0, 1e-15);
  const std::string nofile = "/nonexistent/hrt/none.csv";
  const std::string msg = load_error(nofile);
  EXPECT_EQ(msg, nofile + ": no such file");
  const std::string dir = std::filesystem::temp_directory_path().string();
  EXPECT_EQ(load_error(dir), dir + ": is a directory, not a regular file");
  // A FIFO and a device are named, never opened for reading (which would block or never end).
  EXPECT_EQ(load_error("/dev/zero"), "/dev/zero: is a character device, not a regular file");
}

TEST(Trajectory, FromSamplesChecksTheSamples) {
  auto err = [](std::vector<double> t, std::vector<Pose> p) -> std::string {
    try {
      Trajectory::from_samples(std::move(t), std::move(p));
    } catch (const TrajectoryError& e) {
      return e.what();
    }
    return "(no error)";
  };
  const Pose id;
  EXPECT_EQ(err({0, 1}, {id}), "trajectory: 2 times but 1 poses");
  EXPECT_EQ(err({}, {}), "trajectory: no samples");
  EXPECT_NE(err({0, 0}, {id, id}).find("trajectory: sample 1: time 0 is not after"), std::string::npos);
  Pose zero;
  zero.rotation.coeffs().setZero();
  EXPECT_NE(err({0, 1}, {id, zero}).find("trajectory: sample 1: zero quaternion"), std::string::npos);
  Pose nan;
  nan.position.x() = NAN;
  EXPECT_NE(err({0}, {nan}).find("trajectory: sample 0: position is not finite"), std::string::npos);
  EXPECT_NE(err({0, INFINITY}, {id, id}).find("sample 1: time is not finite"), std::string::npos);
}

// Linear position and slerp against closed forms: identity to a 100-degree
// turn about a tilted axis (not 45 or 90 degrees, where the chord and the arc
// could agree by symmetry), sampled at s = 0.5 and 0.3 -- the rotation is
// s * 100 degrees about the same axis. The end quaternion is given as -q: the
// stored one is flipped, and the motion still takes the short way.
TEST(Trajectory, SampleIsLinearAndSlerpsAgainstClosedForms) {
  const Vec3 axis = Vec3(1, 2, 2).normalized();
  const double angle = 100.0 * M_PI / 180.0;
  Quaterniond q1(AngleAxisd(angle, axis));
  q1.coeffs() *= -1.0;
  const Trajectory tr =
      Trajectory::from_samples({1.0, 3.0}, {pose(Vec3(0, 0, 0), Quaterniond::Identity()), pose(Vec3(2, -4, 6), q1)});
  EXPECT_GT(tr.poses()[1].rotation.w(), 0.0);
  for (double s : {0.5, 0.3}) {
    const Pose p = tr.sample(1.0 + 2.0 * s);
    EXPECT_TRUE(p.position.isApprox(s * Vec3(2, -4, 6), 1e-14)) << s;
    const Quaterniond expect(AngleAxisd(s * angle, axis));
    EXPECT_NEAR(p.rotation.angularDistance(expect), 0.0, 1e-12) << s;
    EXPECT_NEAR(p.rotation.norm(), 1.0, 1e-14);
  }
  // A normalized lerp instead would be 1.1 degrees short at s = 0.3 (28.9
  // instead of 30), far above the 1e-12 tolerance above.
  // End poses held outside [start, end], and for a NaN time.
  EXPECT_TRUE(tr.sample(-5.0).position.isZero());
  EXPECT_TRUE(tr.sample(1.0).position.isZero());
  EXPECT_TRUE(tr.sample(100.0).position.isApprox(Vec3(2, -4, 6)));
  EXPECT_NEAR(tr.sample(100.0).rotation.angularDistance(q1), 0.0, 1e-12);
  EXPECT_TRUE(tr.sample(NAN).position.isZero());
  EXPECT_TRUE(Trajectory().sample(1.0).position.isZero());
}

TEST(Trajectory, VelocityIsTheSegmentsFiniteDifference) {
  const Vec3 axis = Vec3(0, 0.6, 0.8);
  const double angle = 1.2;  // rad over the 2 s segment
  const Trajectory tr =
      Trajectory::from_samples({0.0, 2.0, 3.0}, {pose(Vec3(0, 0, 0), Quaterniond::Identity()),
                                                 pose(Vec3(1, 2, 3), Quaterniond(AngleAxisd(angle, axis))),
                                                 pose(Vec3(1, 2, 3), Quaterniond(AngleAxisd(angle, axis)))});
  const hrt::Vec6 v = tr.velocity(0.7);
  EXPECT_TRUE(v.head<3>().isApprox(Vec3(0.5, 1.0, 1.5), 1e-14));
  EXPECT_TRUE(v.tail<3>().isApprox(axis * angle / 2.0, 1e-12)) << v.transpose();
  EXPECT_TRUE(tr.velocity(2.5).isZero(1e-12));
  EXPECT_TRUE(tr.velocity(-0.1).isZero());
  EXPECT_TRUE(tr.velocity(3.1).isZero());
  // A turn of more than pi between two samples is the short way round (the
  // stored quaternions are sign-aligned): 200 degrees one way = 160 the other.
  const Trajectory big = Trajectory::from_samples(
      {0.0, 1.0}, {pose(Vec3::Zero(), Quaterniond::Identity()),
                   pose(Vec3::Zero(), Quaterniond(AngleAxisd(200.0 * M_PI / 180.0, Vec3::UnitZ())))});
  EXPECT_TRUE(big.velocity(0.5).tail<3>().isApprox(Vec3(0, 0, -160.0 * M_PI / 180.0), 1e-12))
      << big.velocity(0.5).transpose();
}

// The cached segment (forward steps, backward jumps, random access) gives
// the same poses as a fresh trajectory that has to search.
TEST(Trajectory, CachedSegmentAgreesWithSearch) {
  std::vector<double> times;
  std::vector<Pose> poses;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  double t = 0;
  for (int i = 0; i < 200; ++i) {
    t += 0.001 + 0.01 * (u(rng) + 1.0);
    times.push_back(t);
    poses.push_back(pose(Vec3(u(rng), u(rng), u(rng)), Quaterniond(u(rng), u(rng), u(rng), u(rng)).normalized()));
  }
  const Trajectory tr = Trajectory::from_samples(times, poses);
  auto check = [&](double s) {
    const Trajectory cold = Trajectory::from_samples(times, poses);
    const Pose a = tr.sample(s), b = cold.sample(s);
    ASSERT_TRUE(a.position.isApprox(b.position, 1e-15)) << s;
    ASSERT_NEAR(a.rotation.angularDistance(b.rotation), 0.0, 1e-12) << s;
    ASSERT_TRUE(tr.velocity(s).isApprox(cold.velocity(s), 1e-12)) << s;
  };
  for (double s = times.front() - 0.01; s < times.back() + 0.01; s += 0.001) check(s);  // advancing
  for (double s = times.back(); s > times.front(); s -= 0.037) check(s);                // backwards
  for (int i = 0; i < 300; ++i) check(times.front() + (u(rng) + 1.0) / 2.0 * (times.back() - times.front()));
  // At a sample time the pose is the sample's own.
  for (size_t i = 0; i < times.size(); ++i)
    ASSERT_TRUE(tr.sample(times[i]).position.isApprox(tr.poses()[i].position, 1e-12)) << i;
}

TEST(ScriptedDevice, PlaysTheTrajectoryAndKeepsTheLastWrench) {
  const Trajectory tr =
      Trajectory::from_samples({0.0, 1.0}, {pose(Vec3(0, 0, 0), Quaterniond::Identity()),
                                            pose(Vec3(0.1, 0, 0), Quaterniond(AngleAxisd(0.5, Vec3::UnitX())))});
  hrt::DeviceInfo info;
  info.name = "scripted";
  hrt::ScriptedDevice dev(tr, info);
  EXPECT_EQ(dev.info().name, "scripted");
  hrt::DeviceSample s;
  s.clutch = true;
  s.buttons = 7;
  for (double t : {0.0, 0.25, 0.5, 2.0}) {
    ASSERT_TRUE(dev.read(t, s));
    EXPECT_TRUE(s.pose.position.isApprox(tr.sample(t).position)) << t;
    EXPECT_NEAR(s.pose.rotation.angularDistance(tr.sample(t).rotation), 0.0, 1e-14) << t;
    EXPECT_FALSE(s.clutch);
    EXPECT_EQ(s.buttons, 0u);
  }
  EXPECT_NEAR(s.pose.rotation.angularDistance(Quaterniond(AngleAxisd(0.5, Vec3::UnitX()))), 0.0, 1e-14);
  hrt::Vec6 w;
  w << 1, 2, 3, 4, 5, 6;
  dev.write(0.1, w);
  EXPECT_EQ(dev.last_wrench(), w);

  info.dof_sensed = 3;  // position only: orientation reads identity
  hrt::ScriptedDevice dev3(tr, info);
  ASSERT_TRUE(dev3.read(0.5, s));
  EXPECT_TRUE(s.pose.position.isApprox(Vec3(0.05, 0, 0)));
  EXPECT_EQ(s.pose.rotation.coeffs(), Quaterniond::Identity().coeffs());

  hrt::ScriptedDevice none(Trajectory(), info);
  EXPECT_FALSE(none.read(0.0, s));
}

TEST(VirtualDevice, ReadsThePoseLastSetAndRefusesNonFiniteOnes) {
  hrt::DeviceInfo info;
  const Pose start = pose(Vec3(0.01, 0.02, 0.03), Quaterniond(AngleAxisd(0.3, Vec3::UnitY())));
  hrt::VirtualDevice dev(start, info);
  hrt::DeviceSample s;
  ASSERT_TRUE(dev.read(0.0, s));
  EXPECT_EQ(s.pose.position, start.position);
  EXPECT_NEAR(s.pose.rotation.angularDistance(start.rotation), 0.0, 1e-15);
  EXPECT_FALSE(s.clutch);
  // A quaternion of any non-zero norm is normalized; the clutch is passed on.
  Pose p = pose(Vec3(-0.04, 0.0, 0.5), Quaterniond(2.0, 0.0, 0.0, 2.0));
  ASSERT_TRUE(dev.set_pose(p, true));
  ASSERT_TRUE(dev.read(0.1, s));
  EXPECT_EQ(s.pose.position, p.position);
  EXPECT_NEAR(s.pose.rotation.norm(), 1.0, 1e-15);
  EXPECT_NEAR(s.pose.rotation.angularDistance(Quaterniond(AngleAxisd(M_PI / 2, Vec3::UnitZ()))), 0.0, 1e-12);
  EXPECT_TRUE(s.clutch);
  // Refused, and the previous pose kept: a NaN, an infinity, a zero quaternion.
  Pose bad = p;
  bad.position.x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(dev.set_pose(bad));
  bad = p;
  bad.rotation = Quaterniond(0, 0, 0, 0);
  EXPECT_FALSE(dev.set_pose(bad));
  bad = p;
  bad.position.z() = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(dev.set_pose(bad));
  ASSERT_TRUE(dev.read(0.2, s));
  EXPECT_EQ(s.pose.position, p.position);
  hrt::Vec6 w;
  w << 1, 2, 3, 4, 5, 6;
  dev.write(0.2, w);
  EXPECT_EQ(dev.last_wrench(), w);
  info.dof_sensed = 3;  // position only: orientation reads identity
  hrt::VirtualDevice dev3(p, info);
  ASSERT_TRUE(dev3.read(0.0, s));
  EXPECT_EQ(s.pose.rotation.coeffs(), Quaterniond::Identity().coeffs());
  // A start pose that is not one is replaced by the origin.
  hrt::VirtualDevice dev0(bad, hrt::DeviceInfo{});
  ASSERT_TRUE(dev0.read(0.0, s));
  EXPECT_EQ(s.pose.position, Vec3::Zero());
}

// set_pose on one thread while read() runs on another: every pose read is one
// that was set, never half of one (the sequence lock).
TEST(VirtualDevice, ReadsWholePosesWhileAnotherThreadSetsThem) {
  hrt::VirtualDevice dev(pose(Vec3(0, 0, 0), Quaterniond::Identity()), hrt::DeviceInfo{});
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    for (int i = 1; !stop.load(); ++i) {
      const double a = 1e-3 * (i % 1000);
      dev.set_pose(pose(Vec3(a, 2 * a, 3 * a), Quaterniond(AngleAxisd(a, Vec3::UnitZ()))));
    }
  });
  hrt::DeviceSample s;
  int torn = 0;
  for (int k = 0; k < 200000; ++k) {
    ASSERT_TRUE(dev.read(0.0, s));
    const double a = s.pose.position.x();
    if (s.pose.position.y() != 2 * a || s.pose.position.z() != 3 * a ||
        s.pose.rotation.angularDistance(Quaterniond(AngleAxisd(a, Vec3::UnitZ()))) > 1e-12)
      ++torn;
  }
  stop = true;
  writer.join();
  EXPECT_EQ(torn, 0);
}
