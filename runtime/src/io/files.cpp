// Whole-file reads and SHA-256 for the bundle loader.
#include <sys/stat.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>

#include <openssl/evp.h>

#include "io/bundle_io.h"

namespace hrt::io {

std::string sha256_hex(const std::string& bytes) {
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  // One-shot EVP digest: libcrypto's SHA-256 (never hand-written).
  if (EVP_Digest(bytes.data(), bytes.size(), digest, &len, EVP_sha256(), nullptr) != 1 || len != 32) {
    throw std::runtime_error("OpenSSL EVP_Digest(SHA-256) failed");
  }
  static const char* hex = "0123456789abcdef";
  std::string out(64, '0');
  for (unsigned int i = 0; i < 32; ++i) {
    out[2 * i] = hex[digest[i] >> 4];
    out[2 * i + 1] = hex[digest[i] & 15];
  }
  return out;
}

namespace {

void check_limit(uint64_t size, uint64_t max_bytes, const std::string& label) {
  if (size > max_bytes) {
    throw BundleError(BundleErrorClass::io, label + ": " + std::to_string(size) + " bytes, more than the limit of " +
                                                std::to_string(max_bytes) + " bytes for this file");
  }
}

}  // namespace

uint64_t file_size(const std::string& path, const std::string& label, uint64_t max_bytes) {
  struct stat st{};
  if (::stat(path.c_str(), &st) != 0) {
    const int err = errno;
    if (err == ENOENT || err == ENOTDIR) throw BundleError(BundleErrorClass::io, label + ": missing file");
    throw BundleError(BundleErrorClass::io, label + ": cannot read: " + std::strerror(err));
  }
  if (S_ISDIR(st.st_mode)) throw BundleError(BundleErrorClass::io, label + ": is a directory, not a file");
  // Regular files only: a FIFO, device or socket has no size to bound.
  if (!S_ISREG(st.st_mode)) throw BundleError(BundleErrorClass::io, label + ": not a regular file");
  const uint64_t size = static_cast<uint64_t>(st.st_size);
  check_limit(size, max_bytes, label);
  return size;
}

std::string read_file(const std::string& path, const std::string& label, uint64_t max_bytes) {
  file_size(path, label, max_bytes);
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) throw BundleError(BundleErrorClass::io, label + ": cannot read: " + std::strerror(errno));
  // The size of the file opened (it may have been replaced since the stat).
  struct stat st{};
  if (::fstat(::fileno(f.get()), &st) != 0 || !S_ISREG(st.st_mode)) {
    throw BundleError(BundleErrorClass::io, label + ": cannot read: not a regular file");
  }
  check_limit(static_cast<uint64_t>(st.st_size), max_bytes, label);
  std::string bytes;
  bytes.resize(static_cast<size_t>(st.st_size));
  const size_t got = bytes.empty() ? 0 : std::fread(&bytes[0], 1, bytes.size(), f.get());
  if (got != bytes.size() || std::ferror(f.get())) {
    throw BundleError(BundleErrorClass::io, label + ": cannot read: short read");
  }
  return bytes;
}

}  // namespace hrt::io
