// libFuzzer target: one input blob = one haptic bundle (docs/bundle-format.md)
// plus a few control bytes. The bundle is written to a per-process directory
// (the loader reads directories only: hrt::load_bundle has no in-memory entry),
// loaded with hrt::load_bundle, and when it loads, a Scene of the model with
// itself (or with the golden pebble bundle) runs one or two hrt::frame calls
// at a pose derived from the input.
//
// Accepted outcomes: a successful load (and frame), hrt::BundleError of one
// of the documented classes from load_bundle, std::invalid_argument from the
// Scene constructor. Anything else -- another exception, a crash, a sanitizer
// report, an abort, a timeout, running out of memory -- is a finding.
//
// Container format (little-endian; see runtime/fuzz/README.md):
//
//   offset  size  field
//   0       4     flags, uint32
//                   bit 0  verify hashes: LoadOptions::verify_hashes = true, and
//                          the harness first rewrites files.{coarse_mesh,atlas,
//                          pieces}.{sha256,bytes} in the manifest section to the
//                          sections' real SHA-256 and sizes (see patch_hashes)
//                   bit 1  LoadOptions::check_invariants = false; the model is
//                          then only loaded and looked up (Atlas::sample4 at its
//                          corner UVs), never put into a Scene
//                   bit 2  object B is the golden pebble bundle, not the model
//                   bit 3  ForceOptions::shortcut = true (Sec. 5.2)
//                   other bits are ignored
//   4       8     pose bytes p[0..7]:
//                   p0..p2  offset d = (p - 128) / 128 in [-1, 1) per axis; A's
//                           bbox centre is put at B's bbox centre + d (rA + rB)
//                           (rA, rB: half bbox diagonals), so d = 0 is a deep
//                           overlap and |d| ~ 1 a graze or a miss
//                   p3..p6  rotation of A, quaternion x, y, z, w = (p - 128) / 128,
//                           normalised (identity when its norm is below 1/64)
//                   p7      bit 0: a second frame with A moved by 1 % of rA (tracking)
//   12      ...   four sections, in this order: manifest.json, coarse.ply,
//                 atlas.exr, pieces.ply; each is a uint32 length L followed by
//                 L bytes. L = 0xFFFFFFFF: the file is absent (not written).
//                 An L beyond the end of the input is clamped to what is left;
//                 sections missing at the end are empty files; bytes after the
//                 fourth section are ignored.
//
// Files are always written under their default names; a manifest that names
// other paths makes the loader report a missing file (an accepted outcome).
//
// Environment:
//   HRT_FUZZ_TMPDIR   parent of the per-process bundle directory
//                     (default /dev/shm if writable, else $TMPDIR or /tmp)
//   HRT_FUZZ_GOLDEN   directory of the golden bundles (default: the repo's tests/golden)
//   HRT_FUZZ_STRICT=1 also treat as findings: a BundleError message that does not
//                     start with the bundle path or spans lines, and a non-finite
//                     net force or torque after a frame
//   HRT_FUZZ_VERBOSE=1 one line per input on stderr: how it ended (for
//                     reproducing a crash or checking what seeds reach)
#include <dirent.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <typeinfo>

#include <nlohmann/json.hpp>

#include "hrt/model.h"
#include "hrt/scene.h"
#include "io/bundle_io.h"  // hrt::io::sha256_hex (libcrypto), the loader's own

#ifndef HRT_GOLDEN_DIR
#define HRT_GOLDEN_DIR "tests/golden"
#endif

namespace {

constexpr const char* kNames[4] = {"manifest.json", "coarse.ply", "atlas.exr", "pieces.ply"};
constexpr const char* kFileKeys[3] = {"coarse_mesh", "atlas", "pieces"};  // manifest files.* of sections 1..3
constexpr uint32_t kAbsent = 0xFFFFFFFFu;

constexpr uint32_t kFlagVerifyHashes = 1u << 0;
constexpr uint32_t kFlagNoInvariants = 1u << 1;
constexpr uint32_t kFlagGoldenB = 1u << 2;
constexpr uint32_t kFlagShortcut = 1u << 3;

std::string g_root;    // per-process directory, removed at exit
std::string g_bundle;  // g_root + "/b.hbundle"
bool g_strict = false;
bool g_verbose = false;
std::unique_ptr<hrt::Model> g_golden;  // pebble.hbundle, B when kFlagGoldenB

[[noreturn]] void finding(const char* what, const std::string& detail) {
  std::fprintf(stderr, "\nhrt_fuzz_bundle: FINDING: %s: %s\n", what, detail.c_str());
  std::fflush(stderr);
  std::abort();
}

uint32_t rd32(const uint8_t* p) {
  return static_cast<uint32_t>(p[0]) | static_cast<uint32_t>(p[1]) << 8 | static_cast<uint32_t>(p[2]) << 16 |
         static_cast<uint32_t>(p[3]) << 24;
}

void remove_tree(const std::string& dir) {
  if (DIR* d = ::opendir(dir.c_str())) {
    while (dirent* e = ::readdir(d)) {
      const std::string name = e->d_name;
      if (name == "." || name == "..") continue;
      const std::string p = dir + "/" + name;
      struct stat st{};
      if (::lstat(p.c_str(), &st) == 0 && S_ISDIR(st.st_mode)) {
        remove_tree(p);
      } else {
        ::unlink(p.c_str());
      }
    }
    ::closedir(d);
  }
  ::rmdir(dir.c_str());
}

void cleanup() {
  if (!g_root.empty()) remove_tree(g_root);
}

// Directories of earlier runs whose process is gone (a crash skips atexit).
void remove_stale(const std::string& parent) {
  DIR* d = ::opendir(parent.c_str());
  if (!d) return;
  const std::string prefix = "hrt_fuzz_";
  while (dirent* e = ::readdir(d)) {
    const std::string name = e->d_name;
    if (name.rfind(prefix, 0) != 0) continue;
    const long pid = std::strtol(name.c_str() + prefix.size(), nullptr, 10);
    if (pid > 0 && ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) remove_tree(parent + "/" + name);
  }
  ::closedir(d);
}

bool writable_dir(const char* p) { return p && *p && ::access(p, W_OK | X_OK) == 0; }

void write_file(const std::string& path, const uint8_t* data, size_t size) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) finding("harness", "cannot write " + path + ": " + std::strerror(errno));
  size_t done = 0;
  while (done < size) {
    const ssize_t n = ::write(fd, data + done, size - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) finding("harness", "short write to " + path + ": " + std::strerror(errno));
    done += static_cast<size_t>(n);
  }
  ::close(fd);
}

// Depth of [ and { outside strings, so that re-serialising the manifest (a
// recursive dump) stays shallow; the loader itself still sees deep inputs
// when hashes are off or the manifest is not patched.
size_t json_depth(const std::string& s) {
  size_t depth = 0, best = 0;
  bool in_str = false, esc = false;
  for (char c : s) {
    if (in_str) {
      if (esc)
        esc = false;
      else if (c == '\\')
        esc = true;
      else if (c == '"')
        in_str = false;
    } else if (c == '"') {
      in_str = true;
    } else if (c == '[' || c == '{') {
      best = std::max(best, ++depth);
    } else if ((c == ']' || c == '}') && depth > 0) {
      --depth;
    }
  }
  return best;
}

// With hash verification on, every mutation of a binary file would be caught
// by its SHA-256 before any parser runs. So the harness writes the sections'
// real SHA-256 and byte counts into files.<key>.{sha256,bytes} of the manifest
// (when it is a JSON object whose files.<key> is an object), and the parsers
// behind the hash check are fuzzed too. The manifest is re-serialised
// (nlohmann dump, 2-space indent): in this mode the manifest parser sees
// canonical JSON; the raw manifest bytes are fuzzed with hashes off (bit 0
// clear) and whenever the manifest does not parse (it is then kept as is).
std::string patch_hashes(const std::string& manifest, const std::string* sections[3]) {
  if (json_depth(manifest) > 64) return manifest;
  nlohmann::json j = nlohmann::json::parse(manifest, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) return manifest;
  auto files = j.find("files");
  if (files == j.end() || !files->is_object()) return manifest;
  for (int k = 0; k < 3; ++k) {
    if (!sections[k]) continue;  // absent file: nothing to hash
    auto f = files->find(kFileKeys[k]);
    if (f == files->end() || !f->is_object()) continue;
    (*f)["sha256"] = hrt::io::sha256_hex(*sections[k]);
    (*f)["bytes"] = static_cast<uint64_t>(sections[k]->size());
  }
  try {
    return j.dump(2) + "\n";
  } catch (const nlohmann::json::exception&) {
    return manifest;
  }
}

double half_diagonal(const hrt::Model& m, hrt::Vec3& centre) {
  hrt::Vec3 lo = m.vertices.front(), hi = m.vertices.front();
  for (const hrt::Vec3& v : m.vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  centre = 0.5 * (lo + hi);
  return 0.5 * (hi - lo).norm();
}

// Cheap consistency checks of a loaded model: the shapes later stages index by.
void check_model(const hrt::Model& m, bool invariants) {
  const size_t nv = m.vertices.size(), nf = m.faces.size();
  if (m.uvs.size() != nf || m.face_normals.size() != nf || m.face_areas.size() != nf)
    finding("model", "per-face arrays differ in length from faces");
  for (const hrt::Tri& t : m.faces)
    for (uint32_t i : t)
      if (i >= nv) finding("model", "coarse face index " + std::to_string(i) + " >= " + std::to_string(nv));
  if (m.atlas.width <= 0 || m.atlas.height <= 0 ||
      m.atlas.rgba.size() != static_cast<size_t>(m.atlas.width) * static_cast<size_t>(m.atlas.height) * 4)
    finding("model", "atlas " + std::to_string(m.atlas.width) + "x" + std::to_string(m.atlas.height) + " with " +
                         std::to_string(m.atlas.rgba.size()) + " floats");
  for (const hrt::ConvexPiece& p : m.pieces) {
    for (const hrt::Tri& t : p.faces)
      for (uint32_t i : t)
        if (i >= p.vertices.size()) finding("model", "piece face index out of its piece");
    for (uint32_t f : p.coarse_faces)
      if (f >= nf) finding("model", "piece map index " + std::to_string(f) + " >= " + std::to_string(nf));
  }
  if (invariants) {
    if (nv < 3 || nf < 1) finding("model", "a mesh with fewer than 3 vertices or no face loaded");
    for (const hrt::Vec3& v : m.vertices)
      if (!v.allFinite()) finding("model", "non-finite vertex loaded with invariant checks on");
  }
  // Documented: NaN or far out-of-range UVs are clamped (no undefined behaviour).
  const size_t n = std::min<size_t>(nf, 64);
  float sink = 0;
  for (size_t f = 0; f < n; ++f)
    for (const hrt::Vec2f& uv : m.uvs[f]) sink += m.atlas.sample4(uv.x(), uv.y()).sum();
  const float odd[4] = {std::nanf(""), -1e30f, 1e30f, std::numeric_limits<float>::infinity()};
  for (float u : odd) sink += m.atlas.sample4(u, 0.5f).sum() + m.atlas.sample4(0.5f, u).sum();
  volatile float keep = sink;
  (void)keep;
}

void run_frames(const hrt::Model& a, const hrt::Model& b, uint32_t flags, const uint8_t pose[8]) {
  hrt::SceneOptions opts;
  opts.force.shortcut = (flags & kFlagShortcut) != 0;
  std::unique_ptr<hrt::Scene> scene;
  try {
    scene = std::make_unique<hrt::Scene>(std::vector<const hrt::Model*>{&a, &b}, opts);
  } catch (const std::invalid_argument& e) {
    if (g_verbose) std::fprintf(stderr, "hrt_fuzz_bundle: Scene refused: %s\n", e.what());
    return;  // documented: Scene validation
  }
  hrt::State st(*scene);
  hrt::Vec3 ca, cb;
  const double ra = half_diagonal(a, ca), rb = half_diagonal(b, cb);
  auto s = [&](int k) { return (static_cast<double>(pose[k]) - 128.0) / 128.0; };
  const hrt::Vec3 d(s(0), s(1), s(2));
  Eigen::Quaterniond q(s(6), s(3), s(4), s(5));  // Eigen's constructor order is w, x, y, z
  if (q.norm() < 1.0 / 64) q = Eigen::Quaterniond::Identity();
  q.normalize();
  st.poses[0].rotation = q;
  st.poses[0].position = cb + d * (ra + rb) - q.toRotationMatrix() * ca;
  st.poses[1] = hrt::Pose{};
  const int frames = 1 + (pose[7] & 1);
  for (int f = 0; f < frames; ++f) {
    if (f > 0) st.poses[0].position += 0.01 * ra * (d.norm() > 0 ? hrt::Vec3(d.normalized()) : hrt::Vec3::UnitX());
    hrt::frame(*scene, st);
    if (g_verbose)
      std::fprintf(stderr, "hrt_fuzz_bundle: frame %d: %d pairs, %d patches, |F| %.6g N, |T| %.6g N m\n", f,
                   st.num_pairs, st.num_patches, st.force.norm(), st.torque.norm());
    if (g_strict && !(st.force.allFinite() && st.torque.allFinite()))
      finding("frame", "non-finite net force or torque on A");
  }
}

int one_input(const uint8_t* data, size_t size) {
  if (size < 12) return -1;  // not even a header: reject (keeps it out of the corpus)
  const uint32_t flags = rd32(data);
  const uint8_t* pose = data + 4;
  size_t at = 12;
  std::string sec[4];
  bool present[4];
  for (int k = 0; k < 4; ++k) {
    uint32_t len = 0;
    if (at + 4 <= size) {
      len = rd32(data + at);
      at += 4;
    } else {
      at = size;
    }
    present[k] = len != kAbsent;
    if (!present[k]) continue;
    const size_t n = std::min<size_t>(len, size - at);
    sec[k].assign(reinterpret_cast<const char*>(data + at), n);
    at += n;
  }
  const bool verify = (flags & kFlagVerifyHashes) != 0;
  if (verify && present[0]) {
    const std::string* bins[3] = {present[1] ? &sec[1] : nullptr, present[2] ? &sec[2] : nullptr,
                                  present[3] ? &sec[3] : nullptr};
    sec[0] = patch_hashes(sec[0], bins);
  }
  for (int k = 0; k < 4; ++k) {
    const std::string p = g_bundle + "/" + kNames[k];
    if (present[k]) {
      write_file(p, reinterpret_cast<const uint8_t*>(sec[k].data()), sec[k].size());
    } else {
      ::unlink(p.c_str());
    }
  }

  hrt::LoadOptions lo;
  lo.verify_hashes = verify;
  lo.check_invariants = (flags & kFlagNoInvariants) == 0;
  lo.decode_threads = 1;  // deterministic, no OpenEXR thread pool
  hrt::Model model;
  try {
    model = hrt::load_bundle(g_bundle, lo);
  } catch (const hrt::BundleError& e) {
    const int cls = static_cast<int>(e.error_class());
    if (cls < static_cast<int>(hrt::BundleErrorClass::io) || cls > static_cast<int>(hrt::BundleErrorClass::pieces))
      finding("load", "BundleError with an undocumented class " + std::to_string(cls) + ": " + e.what());
    if (g_strict) {
      const std::string what = e.what();
      if (what.rfind(g_bundle, 0) != 0 || what.find('\n') != std::string::npos)
        finding("load", "BundleError message not one line naming the bundle: " + what);
    }
    if (g_verbose)
      std::fprintf(stderr, "hrt_fuzz_bundle: rejected (%s, hashes %s): %s\n", hrt::to_string(e.error_class()),
                   verify ? "on" : "off", e.what());
    return 0;
  }
  check_model(model, lo.check_invariants);
  if (g_verbose)
    std::fprintf(
        stderr,
        "hrt_fuzz_bundle: loaded (hashes %s, invariants %s): %zu vertices, %zu faces, %zu pieces, atlas %dx%d\n",
        verify ? "on" : "off", lo.check_invariants ? "on" : "off", model.vertices.size(), model.faces.size(),
        model.pieces.size(), model.atlas.width, model.atlas.height);
  if (!lo.check_invariants) return 0;  // values unchecked: not fit for a Scene
  const hrt::Model& b = (flags & kFlagGoldenB) && g_golden ? *g_golden : model;
  run_frames(model, b, flags, pose);
  return 0;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  const char* env = std::getenv("HRT_FUZZ_TMPDIR");
  std::string parent;
  if (writable_dir(env))
    parent = env;
  else if (writable_dir("/dev/shm"))
    parent = "/dev/shm";
  else if (writable_dir(std::getenv("TMPDIR")))
    parent = std::getenv("TMPDIR");
  else
    parent = "/tmp";
  remove_stale(parent);
  g_root = parent + "/hrt_fuzz_" + std::to_string(::getpid());
  remove_tree(g_root);
  g_bundle = g_root + "/b.hbundle";
  if (::mkdir(g_root.c_str(), 0700) != 0 || ::mkdir(g_bundle.c_str(), 0700) != 0) {
    std::fprintf(stderr, "hrt_fuzz_bundle: cannot create %s: %s\n", g_bundle.c_str(), std::strerror(errno));
    std::exit(1);
  }
  std::atexit(cleanup);
  const char* strict = std::getenv("HRT_FUZZ_STRICT");
  g_strict = strict && std::strcmp(strict, "0") != 0;
  const char* verbose = std::getenv("HRT_FUZZ_VERBOSE");
  g_verbose = verbose && std::strcmp(verbose, "0") != 0;

  const char* genv = std::getenv("HRT_FUZZ_GOLDEN");
  const std::string golden = std::string(genv && *genv ? genv : HRT_GOLDEN_DIR) + "/pebble.hbundle";
  try {
    hrt::LoadOptions lo;
    lo.decode_threads = 1;
    g_golden = std::make_unique<hrt::Model>(hrt::load_bundle(golden, lo));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hrt_fuzz_bundle: golden bundle %s not loaded (%s); flag bit 2 uses the model itself\n",
                 golden.c_str(), e.what());
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    return one_input(data, size);
  } catch (const std::exception& e) {
    finding("unexpected exception", std::string(typeid(e).name()) + ": " + e.what());
  } catch (...) {
    finding("unexpected exception", "not derived from std::exception");
  }
}
