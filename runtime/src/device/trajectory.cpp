// Pose trajectories (hrt/trajectory.h, docs/trajectory-format.md).
#include "hrt/trajectory.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <sstream>

#include "hrt/files.h"

namespace hrt {
namespace {

// Below this norm a quaternion has no direction worth normalizing: it is a
// zero (or garbage) row, not a slightly denormalized rotation.
constexpr double kMinQuaternionNorm = 1e-6;

std::string trim(const std::string& s) {
  size_t b = 0, e = s.size();
  while (b < e && (s[b] == ' ' || s[b] == '\t' || s[b] == '\r')) ++b;
  while (e > b && (s[e - 1] == ' ' || s[e - 1] == '\t' || s[e - 1] == '\r')) --e;
  return s.substr(b, e - b);
}

std::vector<std::string> split_fields(const std::string& line) {
  std::vector<std::string> out;
  size_t start = 0;
  while (true) {
    size_t comma = line.find(',', start);
    out.push_back(trim(line.substr(start, comma == std::string::npos ? std::string::npos : comma - start)));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return out;
}

bool blank_or_comment(const std::string& line) {
  for (char c : line) {
    if (c == '#') return true;
    if (c != ' ' && c != '\t' && c != '\r') return false;
  }
  return true;
}

// Lines of a file descriptor, read in blocks: a line longer than
// kMaxTrajectoryLine is an error before it is held in memory whole.
class LineReader {
 public:
  explicit LineReader(int fd) : fd_(fd) {}
  ~LineReader() { ::close(fd_); }
  LineReader(const LineReader&) = delete;
  LineReader& operator=(const LineReader&) = delete;
  // 1: a line in `out` (without its newline); 0: end of file; -1: the line
  // is too long; 2: a read error.
  int next(std::string& out) {
    out.clear();
    for (;;) {
      if (pos_ == end_) {
        if (eof_) return out.empty() ? 0 : 1;
        ssize_t n;
        do n = ::read(fd_, buf_, sizeof buf_);
        while (n < 0 && errno == EINTR);
        if (n < 0) return 2;
        if (n == 0) {
          eof_ = true;
          continue;
        }
        pos_ = 0;
        end_ = static_cast<size_t>(n);
      }
      const char* start = buf_ + pos_;
      const void* nl = std::memchr(start, '\n', end_ - pos_);
      const size_t take = nl ? static_cast<size_t>(static_cast<const char*>(nl) - start) : end_ - pos_;
      if (out.size() + take > kMaxTrajectoryLine) return -1;
      out.append(start, take);
      pos_ += take;
      if (nl) {
        ++pos_;
        return 1;
      }
    }
  }

 private:
  int fd_;
  char buf_[1 << 16];
  size_t pos_ = 0, end_ = 0;
  bool eof_ = false;
};

std::string fmt(double v) {
  std::ostringstream s;
  s.precision(17);
  s << v;
  return s.str();
}

// The checks shared by load_csv and from_samples: `where(i)` names sample i
// ("FILE: line L" or "trajectory: sample i"). Normalizes the quaternions and
// flips each one onto the hemisphere of its predecessor, so that slerp between
// neighbours always takes the short way (q and -q are the same rotation).
template <class Where>
void check_and_align(const std::vector<double>& times, std::vector<Pose>& poses, Where where) {
  for (size_t i = 0; i < times.size(); ++i) {
    Pose& p = poses[i];
    if (!std::isfinite(times[i])) throw TrajectoryError(where(i) + ": time is not finite (" + fmt(times[i]) + ")");
    if (!p.position.allFinite()) throw TrajectoryError(where(i) + ": position is not finite");
    // As a scene's positions: parts of at most metres, in metres; past 1e4 m the
    // contact computations lose all precision and velocities overflow.
    if (!(p.position.cwiseAbs().maxCoeff() <= kMaxTrajectoryPosition))
      throw TrajectoryError(where(i) + ": position is more than " + fmt(kMaxTrajectoryPosition) +
                            " m from the origin along an axis (meters, not mm?)");
    if (!p.rotation.coeffs().allFinite()) throw TrajectoryError(where(i) + ": quaternion is not finite");
    // stableNorm: the plain norm of a finite quaternion of 1e300s is inf,
    // and dividing by it would make a zero quaternion out of it.
    const double norm = p.rotation.coeffs().stableNorm();
    if (!std::isfinite(norm)) throw TrajectoryError(where(i) + ": quaternion norm is not finite (" + fmt(norm) + ")");
    if (norm < kMinQuaternionNorm)
      throw TrajectoryError(where(i) + ": zero quaternion (norm " + fmt(norm) + "), no rotation");
    p.rotation.coeffs() /= norm;
    if (i > 0) {
      if (!(times[i] > times[i - 1]))
        throw TrajectoryError(where(i) + ": time " + fmt(times[i]) + " is not after the previous sample's " +
                              fmt(times[i - 1]) + " (times must increase strictly)");
      if (p.rotation.coeffs().dot(poses[i - 1].rotation.coeffs()) < 0) p.rotation.coeffs() *= -1.0;
    }
  }
}

}  // namespace

Trajectory Trajectory::load_csv(const std::string& path, const std::string& prefix) {
  // A regular file within the size limit (a FIFO would block, /dev/zero
  // never end), opened without blocking and checked again once open.
  const std::string name = printable(path, 240);
  try {
    check_input_file(path, kMaxTrajectoryBytes);
  } catch (const InputFileError& e) {
    throw TrajectoryError(e.what());
  }
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
  if (fd < 0) throw TrajectoryError(name + ": cannot read the file: " + std::strerror(errno));
  LineReader in(fd);
  struct stat st{};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode))
    throw TrajectoryError(name + ": cannot read the file: not a regular file");

  std::string line;
  size_t line_no = 0;
  std::vector<std::string> header;
  auto getline = [&](std::string& out) {
    const int r = in.next(out);
    if (r < 0)
      throw TrajectoryError(name + ": line " + std::to_string(line_no + 1) + ": longer than " +
                            std::to_string(kMaxTrajectoryLine) + " bytes");
    if (r == 2) throw TrajectoryError(name + ": line " + std::to_string(line_no + 1) + ": read error");
    return r == 1;
  };
  while (getline(line)) {
    ++line_no;
    if (blank_or_comment(line)) continue;
    header = split_fields(line);
    break;
  }
  const std::string at_header = name + ": line " + std::to_string(line_no);
  if (header.empty()) throw TrajectoryError(at_header + ": no header line (an empty file)");

  // Column indices of t, x, y, z, qx, qy, qz, qw.
  const std::string names[8] = {"t",           prefix + "x",  prefix + "y",  prefix + "z",
                                prefix + "qx", prefix + "qy", prefix + "qz", prefix + "qw"};
  int column[8];
  for (int k = 0; k < 8; ++k) {
    column[k] = -1;
    for (size_t c = 0; c < header.size(); ++c) {
      if (header[c] == names[k] || (k == 0 && header[c] == "time")) {
        if (column[k] >= 0)
          throw TrajectoryError(at_header + ": column '" + printable(header[c], 60) + "' appears twice in the header");
        column[k] = static_cast<int>(c);
      }
    }
    if (column[k] < 0)
      throw TrajectoryError(at_header + ": missing column '" + printable(names[k], 60) + "'" +
                            (k == 0 ? " (or 'time')" : "") + " in the header");
  }
  const int needed = *std::max_element(column, column + 8) + 1;

  std::vector<double> times;
  std::vector<Pose> poses;
  std::vector<size_t> lines;  // file line of each sample, for the shared checks' messages
  while (getline(line)) {
    ++line_no;
    if (blank_or_comment(line)) continue;
    const std::string at = name + ": line " + std::to_string(line_no);
    if (times.size() >= kMaxTrajectorySamples)
      throw TrajectoryError(at + ": more than " + std::to_string(kMaxTrajectorySamples) +
                            " samples, the limit of a trajectory (docs/trajectory-format.md)");
    const std::vector<std::string> fields = split_fields(line);
    if (static_cast<int>(fields.size()) < needed)
      throw TrajectoryError(at + ": " + std::to_string(fields.size()) + " fields, the header's columns need " +
                            std::to_string(needed));
    double v[8];
    for (int k = 0; k < 8; ++k) {
      const std::string& f = fields[column[k]];
      char* end = nullptr;
      errno = 0;
      v[k] = std::strtod(f.c_str(), &end);
      if (f.empty() || end != f.c_str() + f.size())
        throw TrajectoryError(at + ": column '" + printable(header[column[k]], 60) + "': '" + printable(f, 60) +
                              "' is not a number");
      if (!std::isfinite(v[k]))
        throw TrajectoryError(at + ": column '" + printable(header[column[k]], 60) + "': " + printable(f, 60) +
                              " is not finite");
    }
    Pose p;
    p.position = Vec3(v[1], v[2], v[3]);
    p.rotation = Eigen::Quaterniond(v[7], v[4], v[5], v[6]);  // Eigen's constructor is w, x, y, z
    times.push_back(v[0]);
    poses.push_back(p);
    lines.push_back(line_no);
  }
  if (times.empty())
    throw TrajectoryError(name + ": line " + std::to_string(line_no) + ": no data rows after the header");

  check_and_align(times, poses, [&](size_t i) { return name + ": line " + std::to_string(lines[i]); });
  Trajectory out;
  out.times_ = std::move(times);
  out.poses_ = std::move(poses);
  return out;
}

Trajectory Trajectory::from_samples(std::vector<double> times, std::vector<Pose> poses) {
  if (times.size() != poses.size())
    throw TrajectoryError("trajectory: " + std::to_string(times.size()) + " times but " + std::to_string(poses.size()) +
                          " poses");
  if (times.empty()) throw TrajectoryError("trajectory: no samples");
  check_and_align(times, poses, [](size_t i) { return "trajectory: sample " + std::to_string(i); });
  Trajectory out;
  out.times_ = std::move(times);
  out.poses_ = std::move(poses);
  return out;
}

namespace {

// Index i of the segment [times[i], times[i + 1]] holding t, for
// times.front() < t < times.back() (n >= 2). Tries the cached segment and its
// successor first: a device thread advancing t by one period stays in the
// same segment or moves to the next one, so this is O(1) then.
size_t find_segment(const std::vector<double>& times, double t, size_t& hint) {
  const size_t last = times.size() - 2;
  size_t i = std::min(hint, last);
  if (times[i] <= t && t <= times[i + 1]) return hint = i;
  if (i + 1 <= last && times[i + 1] <= t && t <= times[i + 2]) return hint = i + 1;
  // upper_bound: first time > t; t lies strictly inside, so 1 <= it <= last + 1.
  const size_t j = static_cast<size_t>(std::upper_bound(times.begin(), times.end(), t) - times.begin());
  return hint = std::min(j - 1, last);
}

}  // namespace

Pose Trajectory::sample(double t) const {
  if (times_.empty()) return Pose{};
  // !(t > front): also catches a NaN t, which then holds the first pose.
  if (!(t > times_.front())) return poses_.front();
  if (t >= times_.back()) return poses_.back();
  const size_t i = find_segment(times_, t, hint_);
  const double s = (t - times_[i]) / (times_[i + 1] - times_[i]);
  const Pose& a = poses_[i];
  const Pose& b = poses_[i + 1];
  Pose out;
  out.position = a.position + s * (b.position - a.position);
  // Neighbours are on one hemisphere (check_and_align), so this is the short arc.
  out.rotation = a.rotation.slerp(s, b.rotation).normalized();
  return out;
}

Vec6 Trajectory::velocity(double t) const {
  Vec6 v = Vec6::Zero();
  if (times_.size() < 2 || !(t >= times_.front()) || t > times_.back()) return v;
  const size_t i = find_segment(times_, t, hint_);
  const double dt = times_[i + 1] - times_[i];
  const Pose& a = poses_[i];
  const Pose& b = poses_[i + 1];
  v.head<3>() = (b.position - a.position) / dt;
  // World angular velocity w with b = exp(w dt) a: the rotation b a^-1 as an
  // axis-angle over dt (slerp turns at this constant rate over the segment).
  const Eigen::AngleAxisd d(b.rotation * a.rotation.conjugate());
  double angle = d.angle();
  Vec3 axis = d.axis();
  if (angle > M_PI) {  // AngleAxis gives [0, 2 pi); the short way round
    angle = 2 * M_PI - angle;
    axis = -axis;
  }
  v.tail<3>() = axis * (angle / dt);
  return v;
}

}  // namespace hrt
