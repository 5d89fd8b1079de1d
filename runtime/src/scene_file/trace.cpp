// The trace of `hrt run` and the per-tick device log (docs/trace-format.md).
//
// Both are CSV with one header line, written to PATH.partial and renamed to
// PATH only when complete: a crashed or killed run leaves a .partial file,
// never a PATH that looks like a whole session. Numbers are written with
// std::to_chars (the shortest text that reads back to the same double), so a
// trace replays bit-exactly (its device_* columns are a trajectory, see
// hrt/trajectory.h).
#include <algorithm>
#include <cerrno>
#include <sys/stat.h>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>

#include "hrt/trace.h"

namespace hrt {

namespace {

// The column order of docs/trace-format.md (the tests compare this header
// with the spec's table, so the two cannot drift apart).
constexpr const char* kTraceHeader =
    "t,h,frame,"
    "device_t,clutched,"
    "device_x,device_y,device_z,device_qx,device_qy,device_qz,device_qw,"
    "target_x,target_y,target_z,target_qx,target_qy,target_qz,target_qw,"
    "probe_x,probe_y,probe_z,probe_qx,probe_qy,probe_qz,probe_qw,"
    "fx,fy,fz,tx,ty,tz,"
    "contact_fx,contact_fy,contact_fz,contact_tx,contact_ty,contact_tz,"
    "friction_fx,friction_fy,friction_fz,friction_tx,friction_ty,friction_tz,"
    "coupling_fx,coupling_fy,coupling_fz,coupling_tx,coupling_ty,coupling_tz,"
    "command_fx,command_fy,command_fz,command_tx,command_ty,command_tz,"
    "patches,sticking,slipping,refused,fading,"
    "kinetic_j,coupling_j,contact_j,gravity_j,friction_j,"
    "collision_us,clustering_us,force_us,frame_us,dynamics_us,total_us\n";

constexpr const char* kDeviceLogHeader =
    "t,target_x,target_y,target_z,target_qx,target_qy,target_qz,target_qw,fx,fy,fz,tx,ty,tz\n";

// Appends comma-separated numbers to a fixed buffer (a row is at most
// 71 columns x 25 characters; the buffer has room for well over that).
class Line {
 public:
  void num(double x) {
    sep();
    const auto r = std::to_chars(p_, end_, x);
    p_ = r.ptr;
  }
  void num(uint64_t x) {
    sep();
    const auto r = std::to_chars(p_, end_, x);
    p_ = r.ptr;
  }
  void num(int x) {
    sep();
    const auto r = std::to_chars(p_, end_, x);
    p_ = r.ptr;
  }
  void pose(const Pose& q) {
    for (int i = 0; i < 3; ++i) num(q.position[i]);
    num(q.rotation.x());
    num(q.rotation.y());
    num(q.rotation.z());
    num(q.rotation.w());
  }
  void wrench(const Vec6& w) {
    for (int i = 0; i < 6; ++i) num(w[i]);
  }
  const char* data() const { return buf_; }
  size_t size() const { return static_cast<size_t>(p_ - buf_); }
  void end_row() { *p_++ = '\n'; }

 private:
  void sep() {
    if (p_ != buf_) *p_++ = ',';
  }
  char buf_[4096];
  char* p_ = buf_;
  // Room kept for the separator and the newline of the last column.
  char* end_ = buf_ + sizeof(buf_) - 2;
};

[[noreturn]] void io_error(const std::string& path, const std::string& what, int err) {
  throw std::runtime_error(path + ": " + what + (err ? std::string(": ") + std::strerror(err) : std::string()));
}

std::FILE* open_partial(const std::string& path, const std::string& partial) {
  // The output replaces PATH by a rename: PATH must be absent or a regular
  // file. `--trace /dev/null` would otherwise replace the device node with a
  // regular file (found while benchmarking, as root).
  struct stat st;
  if (::lstat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode))
    throw std::runtime_error(path + ": exists and is not a regular file (the output is written to " + partial +
                             " and renamed over it); give a file path, or no trace");
  std::FILE* f = std::fopen(partial.c_str(), "wb");
  if (!f) io_error(path, "cannot open " + partial + " for writing", errno);
  return f;
}

void write_all(std::FILE* f, const std::string& path, const char* data, size_t n) {
  if (std::fwrite(data, 1, n, f) != n) io_error(path, "write failed", errno);
}

// Closes the partial file and renames it to path; on any failure the
// partial is removed, so nothing half-written stays behind under either name.
void finish(std::FILE* f, const std::string& path, const std::string& partial) {
  const bool flushed = std::fflush(f) == 0 && !std::ferror(f);
  const int flush_err = errno;
  const bool closed = std::fclose(f) == 0;
  const int close_err = errno;
  if (!flushed || !closed) {
    std::remove(partial.c_str());
    io_error(path, "write failed", !flushed ? flush_err : close_err);
  }
  if (std::rename(partial.c_str(), path.c_str()) != 0) {
    const int err = errno;
    std::remove(partial.c_str());
    io_error(path, "cannot rename " + partial + " to it", err);
  }
}

}  // namespace

TraceWriter::~TraceWriter() {
  if (file_) {
    std::fclose(file_);
    std::remove(partial_.c_str());
  }
}

void TraceWriter::open(const std::string& path, const TraceConfig& config) {
  // The columns are the same for every scene (one reader reads every trace);
  // the configuration does not change them.
  if (file_) throw std::logic_error("TraceWriter::open(" + path + "): already open on " + path_);
  path_ = path;
  partial_ = path + ".partial";
  min_interval_ = config.rate > 0 ? 1.0 / config.rate : 0.0;
  max_bytes_ = config.max_bytes;
  bytes_ = rows_ = 0;
  truncated_ = false;
  file_ = open_partial(path_, partial_);
  write_all(file_, path_, kTraceHeader, std::strlen(kTraceHeader));
  bytes_ = std::strlen(kTraceHeader);
}

bool TraceWriter::row(const TraceRow& r) {
  if (!file_) throw std::logic_error("TraceWriter::row: not open");
  if (!r.frame || !r.device) throw std::invalid_argument(path_ + ": a trace row needs a frame and a device target");
  const SessionFrame& f = *r.frame;
  const DeviceTarget& d = *r.device;
  if (truncated_) return false;
  // The rate: a row when at least min_interval_ of session time has passed
  // since the last one written (less a relative 1e-9, so a frame exactly on
  // the grid is not dropped by rounding).
  if (rows_ > 0 && min_interval_ > 0 && f.t - last_t_ < min_interval_ * (1.0 - 1e-9)) return false;
  Line l;
  l.num(f.t);
  l.num(f.h);
  l.num(static_cast<uint64_t>(f.frame));
  l.num(d.time);
  l.num(d.clutched ? 1 : 0);
  l.pose(d.device);
  l.pose(f.target);
  l.pose(f.probe);
  l.wrench(d.output);
  l.wrench(f.contact);
  l.wrench(f.friction);
  l.wrench(f.coupling);
  l.wrench(f.device);
  l.num(f.patches);
  l.num(f.sticking);
  l.num(f.slipping);
  l.num(f.refused);
  l.num(f.fading);
  l.num(f.kinetic);
  l.num(f.coupling_energy);
  l.num(f.contact_energy);
  l.num(f.gravity_energy);
  l.num(f.friction_energy);
  l.num(f.timings.collision_us);
  l.num(f.timings.clustering_us);
  l.num(f.timings.force_us);
  l.num(f.timings.total_us);
  l.num(f.dynamics_us);
  l.num(f.timings.total_us + f.dynamics_us);
  l.end_row();
  if (bytes_ + l.size() > max_bytes_) {
    truncated_ = true;
    return false;
  }
  write_all(file_, path_, l.data(), l.size());
  bytes_ += l.size();
  ++rows_;
  last_t_ = f.t;
  return true;
}

void TraceWriter::close() {
  if (!file_) return;
  std::FILE* f = file_;
  file_ = nullptr;  // whatever finish() throws, the file is closed (and the partial gone)
  finish(f, path_, partial_);
}

void write_device_log(const std::string& path, const DeviceLoop& loop) {
  const std::string partial = path + ".partial";
  std::FILE* f = open_partial(path, partial);
  try {
    write_all(f, path, kDeviceLogHeader, std::strlen(kDeviceLogHeader));
    const size_t n = std::min(loop.log_size(), loop.log().size());
    for (size_t i = 0; i < n; ++i) {
      const DeviceLogRow& r = loop.log()[i];
      Line l;
      l.num(r.t);
      l.pose(r.target);
      l.wrench(r.output);
      l.end_row();
      write_all(f, path, l.data(), l.size());
    }
  } catch (...) {
    std::fclose(f);
    std::remove(partial.c_str());
    throw;
  }
  finish(f, path, partial);
}

}  // namespace hrt
