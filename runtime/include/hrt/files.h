// The rules for every file `hrt run` and `hrt query` read or write besides
// the bundles' own (which follow the same rules in src/io): scene files,
// trajectories, device plugins, traces and device logs.
//
// Inputs: a regular file (a FIFO would block the open, /dev/zero would be
// read forever), within a size limit checked before a byte is read; the
// message names the path and what the path is ("is a FIFO", "is a
// directory", "no such file").
//
// Outputs: never an input. InputFiles collects the identity (device and
// inode, and the resolved path) of every file a session reads; an output
// path that is one of them, or whose PATH.partial would be, is refused
// before anything is opened for writing.
//
// Messages: printable() cuts a value to a readable length and escapes
// control bytes, so a 10 MB value or a NUL byte from a file never reaches a
// terminal raw.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace hrt {

// "PATH: what is wrong" (one line). `kind` says which rule broke.
struct InputFileError : std::runtime_error {
  enum class Kind { missing, not_regular, too_large, unreadable };
  Kind kind;
  std::string problem;  // the message without "LABEL: "
  InputFileError(Kind k, const std::string& label, const std::string& what)
      : std::runtime_error(label + ": " + what), kind(k), problem(what) {}
};

// An output path that resolves to a file the session reads.
struct OutputOverwritesInput : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Size limits of the inputs (docs/input-contract.md).
constexpr uint64_t kMaxSceneFileBytes = uint64_t{1} << 20;   // 1 MiB of TOML
constexpr uint64_t kMaxTrajectoryBytes = uint64_t{1} << 30;  // 1 GiB of CSV (rows are capped too)
constexpr uint64_t kMaxPluginBytes = uint64_t{256} << 20;    // 256 MiB shared library

// What the file at `path` is, for messages: "a FIFO", "a directory",
// "a character device", "a block device", "a socket", "a regular file",
// "missing" (lstat is not used: a symbolic link is judged by its target).
std::string describe_file_type(const std::string& path);

// Checks that `path` is a regular file of at most max_bytes bytes and
// returns its size; throws InputFileError("LABEL: ...") otherwise. `label`
// names the file in the message (usually the path itself).
uint64_t check_input_file(const std::string& path, uint64_t max_bytes, const std::string& label = "");

// Reads the whole file under the same rules (opened with O_NONBLOCK and
// checked again after the open, so a file swapped for a FIFO in between
// neither blocks nor passes).
std::string read_input_file(const std::string& path, uint64_t max_bytes, const std::string& label = "");

// `text` for a one-line message: control bytes and bytes >= 0x7f escaped as
// \xHH (\n, \t, \r as such), cut to at most max_chars characters of output
// with "... (N bytes)" when longer.
std::string printable(std::string_view text, size_t max_chars = 120);

// The files a session reads, by identity.
class InputFiles {
 public:
  // Records `path` (a file or a folder: a folder's regular files are added
  // one level deep, for a bundle). `what` names it in messages ("the scene
  // file", "the device's trajectory", "bundle object[1]"). Missing paths are
  // ignored (the readers report them).
  void add(const std::string& path, const std::string& what);
  // Records a path that may not exist yet (an output of the same session),
  // matched by its resolved path.
  void add_path(const std::string& path, const std::string& what);
  // Throws OutputOverwritesInput("OUTPUT (KEY): is WHAT: writing it would
  // destroy an input") when `output` or `output + ".partial"` is one of the
  // inputs: the same device and inode when it exists, else the same
  // resolved path (realpath of its folder plus its name). `key` names where
  // the path came from ("--trace", "trace.path").
  void check_output(const std::string& output, const std::string& key) const;

 private:
  struct Entry {
    uint64_t dev = 0, ino = 0;
    std::string resolved;
    std::string what;
  };
  void add_one(const std::string& path, const std::string& what);
  std::vector<Entry> entries_;
};

}  // namespace hrt
