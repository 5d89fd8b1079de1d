// hrt_narrow_phase_compare A.hbundle B.hbundle [--poses N] [--repeat R] [--seed S]
//
// Speed and agreement of the runtime's piece-pair narrow phase
// (collision::piece_distance: FCL's GJK distance for separated pieces, the
// exact separating-axis depth for intersecting ones) against the previous
// one (fcl::distance with signed distance, GST_LIBCCD: GJK + FCL's
// libccd-extension EPA), on the piece pairs a frame would test: N random
// poses of A whose bounding sphere overlaps B's (rotations uniform, centre
// within half of B's radius of B's centre, so most candidate pairs are near
// or in contact), every piece pair whose boxes are within the contact
// tolerance.
//
// The previous narrow phase may abort the process (its EPA asserts), so it
// runs in a child process over the whole pair list; when it aborts, the
// child is restarted after the pair that killed it and the pair is counted.
// Prints per-call medians over R repeats of each list (ns), the largest
// |d_new - d_old| of intersecting and of separated pairs, and the largest
// angle between the normals, with the machine.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "collision/collision.h"
#include "hrt/model.h"
#include "hrt/scene.h"

namespace {

using hrt::Vec3;
using Clock = std::chrono::steady_clock;

struct Job {
  int pa, pb;
  Eigen::Isometry3d b_from_a;
};

struct Out {
  double d;
  double n[3];
  int ok;
};

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown CPU";
}

// The previous narrow phase: FCL's signed distance (GST_LIBCCD) of one job.
// May abort the process (its EPA asserts): call it in a child only.
fcl::DistanceResultd previous_distance(const hrt::collision::ModelGeometry& ga, const hrt::collision::ModelGeometry& gb,
                                       const Job& j, double tol) {
  fcl::DistanceRequestd req(true, true);
  req.distance_tolerance = tol;
  fcl::DistanceResultd res;
  fcl::Transform3d tf = fcl::Transform3d::Identity();
  tf.linear() = j.b_from_a.linear();
  tf.translation() = j.b_from_a.translation();
  fcl::distance(ga.convex[static_cast<size_t>(j.pa)].get(), tf, gb.convex[static_cast<size_t>(j.pb)].get(),
                fcl::Transform3d::Identity(), req, res);
  return res;
}

// The previous narrow phase on jobs[first..): writes one Out per job to fd;
// returns when done.
void old_child(const hrt::collision::ModelGeometry& ga, const hrt::collision::ModelGeometry& gb,
               const std::vector<Job>& jobs, size_t first, double tol, int fd) {
  for (size_t k = first; k < jobs.size(); ++k) {
    Out o{};
    try {
      const fcl::DistanceResultd res = previous_distance(ga, gb, jobs[k], tol);
      o.d = res.min_distance;
      const Vec3 dir = o.d >= 0 ? Vec3(res.nearest_points[1] - res.nearest_points[0])
                                : Vec3(res.nearest_points[0] - res.nearest_points[1]);
      const Vec3 n = dir.norm() > 0 ? Vec3(dir.normalized()) : Vec3::Zero();
      o.n[0] = n.x(), o.n[1] = n.y(), o.n[2] = n.z();
      o.ok = 1;
    } catch (const std::exception&) {
      o.ok = 0;
    }
    if (write(fd, &o, sizeof o) != sizeof o) _exit(1);
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s A.hbundle B.hbundle [--poses N] [--repeat R] [--seed S]\n", argv[0]);
    return 2;
  }
  int poses = 200, repeat = 5;
  unsigned seed = 1;
  for (int i = 3; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--poses"))
      poses = std::atoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--repeat"))
      repeat = std::atoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--seed"))
      seed = static_cast<unsigned>(std::atoi(argv[i + 1]));
    else {
      std::fprintf(stderr, "unknown option %s\n", argv[i]);
      return 2;
    }
  }
  const hrt::Model A = hrt::load_bundle(argv[1]);
  const hrt::Model B = hrt::load_bundle(argv[2]);
  hrt::Scene scene({&A, &B});
  const auto& ga = scene.world().geometry(0);
  const auto& gb = scene.world().geometry(1);
  const double tol = scene.tolerance(1);
  const double gjk_tol = 1e-6 * std::max(ga.scale, gb.scale);

  // Candidate pairs of random poses.
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> uni(-1.0, 1.0);
  std::vector<Job> jobs;
  for (int k = 0; k < poses; ++k) {
    const Eigen::Quaterniond q = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized();
    Eigen::Isometry3d b_from_a = Eigen::Isometry3d::Identity();
    b_from_a.linear() = q.toRotationMatrix();
    const Vec3 target = gb.bounds.center + 0.5 * gb.bounds.radius * Vec3(uni(rng), uni(rng), uni(rng));
    b_from_a.translation() = target - q * ga.bounds.center;
    for (int pa = 0; pa < static_cast<int>(ga.piece_bounds.size()); ++pa) {
      const auto& bpa = ga.piece_bounds[static_cast<size_t>(pa)];
      const Vec3 c = b_from_a * bpa.center;
      for (int pb = 0; pb < static_cast<int>(gb.piece_bounds.size()); ++pb) {
        const auto& bpb = gb.piece_bounds[static_cast<size_t>(pb)];
        if ((c - bpb.center).norm() - bpa.radius - bpb.radius > tol) continue;
        jobs.push_back({pa, pb, b_from_a});
      }
    }
  }
  std::printf("machine     %s, %u hardware threads; one thread\n", cpu_model().c_str(),
              std::thread::hardware_concurrency());
  std::printf("bundles     A %s (%zu pieces), B %s (%zu pieces); %d poses, %zu candidate pairs\n", argv[1],
              ga.piece_bounds.size(), argv[2], gb.piece_bounds.size(), poses, jobs.size());

  // New narrow phase: results, then times per class (intersecting: d < 0).
  std::vector<Out> now(jobs.size());
  auto run_new = [&](size_t k) {
    const Job& j = jobs[k];
    double d = 0;
    Vec3 pa, pb, n;
    bool fb = false;
    const bool ok = hrt::collision::piece_distance(ga, j.pa, j.b_from_a, gb, j.pb, gjk_tol, d, pa, pb, n, fb);
    now[k] = Out{d, {n.x(), n.y(), n.z()}, ok ? 1 : 0};
  };
  for (size_t k = 0; k < jobs.size(); ++k) run_new(k);
  std::vector<char> intersecting(jobs.size());
  for (size_t k = 0; k < jobs.size(); ++k) intersecting[k] = now[k].ok == 1 && now[k].d < 0;
  // Median over repeats of the mean ns per call of one class.
  auto time_class = [&](auto&& call, bool cls) {
    std::vector<double> per;
    for (int r = 0; r < repeat; ++r) {
      size_t calls = 0;
      const auto t0 = Clock::now();
      for (size_t k = 0; k < jobs.size(); ++k)
        if (static_cast<bool>(intersecting[k]) == cls) {
          call(k);
          ++calls;
        }
      per.push_back(std::chrono::duration<double, std::nano>(Clock::now() - t0).count() /
                    static_cast<double>(std::max<size_t>(1, calls)));
    }
    return median(per);
  };
  const double new_in = time_class(run_new, true), new_sep = time_class(run_new, false);

  // Previous narrow phase, in children; restart after an abort.
  std::vector<Out> old(jobs.size(), Out{0, {0, 0, 0}, -1});
  size_t aborted = 0;
  size_t next = 0;
  while (next < jobs.size()) {
    int fd[2];
    if (pipe(fd) != 0) return 1;
    const pid_t pid = fork();
    if (pid == 0) {
      close(fd[0]);
      old_child(ga, gb, jobs, next, gjk_tol, fd[1]);
      _exit(0);
    }
    close(fd[1]);
    Out o;
    while (next < jobs.size() && read(fd[0], &o, sizeof o) == sizeof o) old[next++] = o;
    close(fd[0]);
    int status = 0;
    waitpid(pid, &status, 0);
    if (next < jobs.size()) {  // the child died on jobs[next]
      ++aborted;
      ++next;
    }
  }
  // Timing of the previous one on the pairs it survives (in a child too).
  double old_in = 0, old_sep = 0;
  {
    int fd[2];
    if (pipe(fd) != 0) return 1;
    const pid_t pid = fork();
    if (pid == 0) {
      close(fd[0]);
      auto run_old = [&](size_t k) {
        if (old[k].ok != 1) return;
        previous_distance(ga, gb, jobs[k], gjk_tol);
      };
      const double t[2] = {time_class(run_old, true), time_class(run_old, false)};
      if (write(fd[1], t, sizeof t) != sizeof t) _exit(1);
      _exit(0);
    }
    close(fd[1]);
    double t[2] = {0, 0};
    if (read(fd[0], t, sizeof t) == sizeof t) {
      old_in = t[0];
      old_sep = t[1];
    }
    close(fd[0]);
    int status = 0;
    waitpid(pid, &status, 0);
  }

  // Agreement.
  double worst_in = 0, worst_sep = 0, worst_angle = 0;
  size_t n_in = 0, n_sep = 0, new_fail = 0, old_fail = 0;
  for (size_t k = 0; k < jobs.size(); ++k) {
    if (now[k].ok != 1) ++new_fail;
    if (old[k].ok == 0) ++old_fail;
    if (now[k].ok != 1 || old[k].ok != 1) continue;
    const double diff = std::abs(now[k].d - old[k].d);
    if (old[k].d < 0 || now[k].d < 0) {
      ++n_in;
      worst_in = std::max(worst_in, diff);
    } else {
      ++n_sep;
      worst_sep = std::max(worst_sep, diff);
    }
    const Vec3 a = Eigen::Map<const Vec3>(now[k].n), b = Eigen::Map<const Vec3>(old[k].n);
    if (b.norm() > 0.5 && std::abs(old[k].d) > 10 * gjk_tol)
      worst_angle = std::max(worst_angle, std::acos(std::clamp(a.dot(b), -1.0, 1.0)));
  }
  std::printf(
      "per call    intersecting: new %.0f ns, previous %.0f ns (ratio %.2f); separated: new %.0f ns, "
      "previous %.0f ns (ratio %.2f); medians of %d repeats\n",
      new_in, old_in, new_in / std::max(1.0, old_in), new_sep, old_sep, new_sep / std::max(1.0, old_sep), repeat);
  std::printf(
      "agreement   %zu intersecting pairs: max |d_new - d_prev| %.3g m; %zu separated: %.3g m; "
      "normals (|d| > 10 tol) within %.3g rad\n",
      n_in, worst_in, n_sep, worst_sep, worst_angle);
  std::printf("failures    new %zu, previous %zu (FCL threw), previous aborted the process %zu time(s)\n", new_fail,
              old_fail, aborted);
  return 0;
}
