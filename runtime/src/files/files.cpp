// Input and output file rules of hrt (hrt/files.h).
#include "hrt/files.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <memory>

namespace hrt {
namespace {

std::string type_of(mode_t m) {
  if (S_ISREG(m)) return "a regular file";
  if (S_ISDIR(m)) return "a directory";
  if (S_ISFIFO(m)) return "a FIFO";
  if (S_ISCHR(m)) return "a character device";
  if (S_ISBLK(m)) return "a block device";
  if (S_ISSOCK(m)) return "a socket";
  return "not a regular file";
}

std::string name_of(const std::string& path, const std::string& label) {
  return printable(label.empty() ? path : label, 240);
}

void check_stat(const struct stat& st, uint64_t max_bytes, const std::string& name) {
  if (!S_ISREG(st.st_mode))
    throw InputFileError(InputFileError::Kind::not_regular, name, "is " + type_of(st.st_mode) + ", not a regular file");
  const uint64_t size = static_cast<uint64_t>(st.st_size);
  if (size > max_bytes)
    throw InputFileError(
        InputFileError::Kind::too_large, name,
        std::to_string(size) + " bytes, more than the limit of " + std::to_string(max_bytes) + " bytes for this file");
}

// realpath of the folder plus the name (the file itself may not exist yet).
std::string resolve(const std::string& path) {
  char buf[PATH_MAX];
  if (::realpath(path.c_str(), buf)) return buf;
  const size_t slash = path.find_last_of('/');
  const std::string dir = slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash));
  const std::string base = slash == std::string::npos ? path : path.substr(slash + 1);
  if (::realpath(dir.c_str(), buf)) return std::string(buf) + (std::string(buf) == "/" ? "" : "/") + base;
  return path;
}

}  // namespace

std::string describe_file_type(const std::string& path) {
  struct stat st{};
  if (::stat(path.c_str(), &st) != 0) return "missing";
  return type_of(st.st_mode);
}

uint64_t check_input_file(const std::string& path, uint64_t max_bytes, const std::string& label) {
  const std::string name = name_of(path, label);
  struct stat st{};
  if (::stat(path.c_str(), &st) != 0) {
    const int err = errno;
    if (err == ENOENT || err == ENOTDIR) throw InputFileError(InputFileError::Kind::missing, name, "no such file");
    throw InputFileError(InputFileError::Kind::unreadable, name, std::string("cannot read: ") + std::strerror(err));
  }
  check_stat(st, max_bytes, name);
  return static_cast<uint64_t>(st.st_size);
}

std::string read_input_file(const std::string& path, uint64_t max_bytes, const std::string& label) {
  const std::string name = name_of(path, label);
  check_input_file(path, max_bytes, label);
  // O_NONBLOCK: if the path was replaced by a FIFO since the stat, the open
  // returns at once instead of waiting for a writer; fstat then refuses it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
  if (fd < 0)
    throw InputFileError(InputFileError::Kind::unreadable, name, std::string("cannot read: ") + std::strerror(errno));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st{};
  if (::fstat(fd, &st) != 0)
    throw InputFileError(InputFileError::Kind::unreadable, name, std::string("cannot read: ") + std::strerror(errno));
  check_stat(st, max_bytes, name);
  std::string bytes(static_cast<size_t>(st.st_size), '\0');
  size_t got = 0;
  while (got < bytes.size()) {
    const ssize_t n = ::read(fd, &bytes[got], bytes.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0)
      throw InputFileError(InputFileError::Kind::unreadable, name, std::string("cannot read: ") + std::strerror(errno));
    if (n == 0) break;  // the file shrank since the fstat
    got += static_cast<size_t>(n);
  }
  bytes.resize(got);
  return bytes;
}

std::string printable(std::string_view text, size_t max_chars) {
  static const char* hex = "0123456789abcdef";
  std::string out;
  out.reserve(std::min(text.size(), max_chars) + 16);
  size_t i = 0;
  for (; i < text.size(); ++i) {
    const unsigned char c = static_cast<unsigned char>(text[i]);
    std::string piece;
    if (c == '\n')
      piece = "\\n";
    else if (c == '\t')
      piece = "\\t";
    else if (c == '\r')
      piece = "\\r";
    else if (c < 0x20 || c == 0x7f)
      piece = std::string("\\x") + hex[c >> 4] + hex[c & 15];
    else
      piece = std::string(1, static_cast<char>(c));  // UTF-8 bytes pass through
    if (out.size() + piece.size() > max_chars) break;
    out += piece;
  }
  if (i < text.size()) out += "... (" + std::to_string(text.size()) + " bytes)";
  return out;
}

void InputFiles::add_one(const std::string& path, const std::string& what) {
  struct stat st{};
  if (::stat(path.c_str(), &st) != 0) return;
  Entry e;
  e.dev = static_cast<uint64_t>(st.st_dev);
  e.ino = static_cast<uint64_t>(st.st_ino);
  e.resolved = resolve(path);
  e.what = what;
  entries_.push_back(std::move(e));
}

void InputFiles::add_path(const std::string& path, const std::string& what) {
  Entry e;
  e.resolved = resolve(path);
  e.what = what;
  entries_.push_back(std::move(e));
}

void InputFiles::add(const std::string& path, const std::string& what) {
  struct stat st{};
  if (::stat(path.c_str(), &st) != 0) return;
  add_one(path, what);
  if (!S_ISDIR(st.st_mode)) return;
  std::unique_ptr<DIR, int (*)(DIR*)> d(::opendir(path.c_str()), &::closedir);
  if (!d) return;
  while (const dirent* e = ::readdir(d.get())) {
    const std::string name = e->d_name;
    if (name == "." || name == "..") continue;
    add_one(path + "/" + name, what + " (" + name + ")");
  }
}

void InputFiles::check_output(const std::string& output, const std::string& key) const {
  for (const std::string& p : {output, output + ".partial"}) {
    struct stat st{};
    const bool exists = ::stat(p.c_str(), &st) == 0;
    const std::string resolved = resolve(p);
    for (const Entry& e : entries_) {
      // By identity where both exist (hard links, symbolic links, "a/../b"),
      // else by the resolved path.
      const bool both = exists && e.ino != 0;
      const bool same = both ? (static_cast<uint64_t>(st.st_dev) == e.dev && static_cast<uint64_t>(st.st_ino) == e.ino)
                             : resolved == e.resolved;
      if (same)
        throw OutputOverwritesInput(printable(output, 240) + " (" + key + "): is " + e.what +
                                    (p == output ? "" : " (its .partial file)") +
                                    ": writing it would destroy an input; choose another path");
    }
  }
}

}  // namespace hrt
