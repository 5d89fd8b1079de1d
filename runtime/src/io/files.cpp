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

std::string read_file(const std::string& path, const std::string& label) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    const int err = errno;
    if (err == ENOENT || err == ENOTDIR) throw BundleError(BundleErrorClass::io, label + ": missing file");
    throw BundleError(BundleErrorClass::io, label + ": cannot read: " + std::strerror(err));
  }
  if (S_ISDIR(st.st_mode)) throw BundleError(BundleErrorClass::io, label + ": is a directory, not a file");
  if (!S_ISREG(st.st_mode)) throw BundleError(BundleErrorClass::io, label + ": not a regular file");
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) throw BundleError(BundleErrorClass::io, label + ": cannot read: " + std::strerror(errno));
  std::string bytes;
  bytes.resize(static_cast<size_t>(st.st_size));
  const size_t got = bytes.empty() ? 0 : std::fread(&bytes[0], 1, bytes.size(), f.get());
  if (got != bytes.size() || std::ferror(f.get())) {
    throw BundleError(BundleErrorClass::io, label + ": cannot read: short read");
  }
  return bytes;
}

}  // namespace hrt::io
