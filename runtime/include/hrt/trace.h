// The trace a session writes (CSV; spec: docs/trace-format.md): one row per
// simulation frame (TraceWriter), and the per-tick device log (write_device_log).
// Scene files set them in [trace] (hrt/run_config.h); `hrt run`, hrt::Runner's
// callers and the Python module write them with these.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>

#include "hrt/device_loop.h"
#include "hrt/session.h"

namespace hrt {

struct TraceConfig {
  std::string path;        // "" = no trace
  std::string device_log;  // per-device-tick CSV ("" = none)
  // Where each path came from, for messages: the scene key or the flag.
  std::string path_key = "trace.path", device_log_key = "trace.device_log";
  // Most rows per second of session time (0: every simulation frame). Left
  // out: kDefaultRealtimeTraceRate in real time, every frame in lockstep.
  double rate = 0.0;
  bool rate_set = false;
  // The trace stops growing here (a warning; the session goes on).
  uint64_t max_bytes = uint64_t{1} << 30;
};

// Real-time trace rows per second of session time unless [trace] rate says.
constexpr double kDefaultRealtimeTraceRate = 1000.0;

// One trace row: a simulation frame and the device's state at it.
struct TraceRow {
  const SessionFrame* frame = nullptr;
  const DeviceTarget* device = nullptr;  // device pose and the wrench last written to it
};

// Trace writer: one row per simulation frame. Writes to PATH.partial and
// renames to PATH on close(), so a crash never leaves a trace that looks
// complete. Throws std::runtime_error("PATH: ...") on I/O errors.
//
// The rows follow `config`: at most `rate` rows per second of session
// time (a frame is written when its t is at least 1 / rate after the last
// written row's; 0 writes every frame), and none once the file would pass
// `max_bytes` (truncated() is then true: the caller warns; the trace stays
// a valid trace of the session's start).
class TraceWriter {
 public:
  TraceWriter() = default;
  ~TraceWriter();  // an unclosed writer removes its .partial file
  void open(const std::string& path, const TraceConfig& config);
  // True when the row was written (false: thinned out by the rate, or past max_bytes).
  bool row(const TraceRow& r);
  void close();
  bool is_open() const { return file_ != nullptr; }
  uint64_t rows() const { return rows_; }
  uint64_t bytes() const { return bytes_; }
  bool truncated() const { return truncated_; }

 private:
  std::string path_, partial_;
  std::FILE* file_ = nullptr;
  double min_interval_ = 0.0, last_t_ = 0.0;
  uint64_t max_bytes_ = UINT64_MAX, bytes_ = 0, rows_ = 0;
  bool truncated_ = false;
};

// Per-tick device log (DeviceLoop::log), same conventions; written at the end.
void write_device_log(const std::string& path, const DeviceLoop& loop);

}  // namespace hrt
