// Test-side writer of bundle files (see test_io_writer.h).
#include "test_io_writer.h"

#include <fcntl.h>
#include <poll.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfOutputFile.h>
#include <ImfTiledOutputFile.h>
#include <half.h>
#include <gtest/gtest.h>

#include "io/bundle_io.h"

namespace fs = std::filesystem;

extern char** environ;

namespace hrt_test {
namespace {

void put_u8(std::string& s, unsigned v) { s.push_back(static_cast<char>(v & 0xff)); }
void put_u32(std::string& s, uint32_t v) {
  for (int k = 0; k < 4; ++k) s.push_back(static_cast<char>((v >> (8 * k)) & 0xff));
}
void put_f32(std::string& s, float f) {
  uint32_t bits;
  std::memcpy(&bits, &f, 4);
  put_u32(s, bits);
}

Imf::Compression compression_of(const std::string& name) {
  if (name == "zip") return Imf::ZIP_COMPRESSION;
  if (name == "piz") return Imf::PIZ_COMPRESSION;
  if (name == "rle") return Imf::RLE_COMPRESSION;
  if (name == "zips") return Imf::ZIPS_COMPRESSION;
  if (name == "none") return Imf::NO_COMPRESSION;
  if (name == "pxr24") return Imf::PXR24_COMPRESSION;
  throw std::invalid_argument("unknown compression " + name);
}

// Cube geometry: corner index = x + 2 y + 4 z (bits), faces as CCW loops seen from outside.
constexpr int kLoops[6][4] = {
    {0, 4, 6, 2},  // -x
    {1, 3, 7, 5},  // +x
    {0, 1, 5, 4},  // -y
    {2, 6, 7, 3},  // +y
    {0, 2, 3, 1},  // -z
    {4, 5, 7, 6},  // +z
};
constexpr int kW = 96, kH = 64, kCell = 32, kInset = 6, kChart = 20, kGutter = 4;
constexpr double kSide = 0.02;

std::array<float, 3> corner(const hrt::Vec3& lo, const hrt::Vec3& hi, int bits) {
  return {static_cast<float>(bits & 1 ? hi.x() : lo.x()), static_cast<float>(bits & 2 ? hi.y() : lo.y()),
          static_cast<float>(bits & 4 ? hi.z() : lo.z())};
}

void box(const hrt::Vec3& lo, const hrt::Vec3& hi, std::vector<std::array<float, 3>>& verts,
         std::vector<hrt::Tri>& faces) {
  verts.clear();
  faces.clear();
  for (int b = 0; b < 8; ++b) verts.push_back(corner(lo, hi, b));
  for (const auto& l : kLoops) {
    faces.push_back({static_cast<uint32_t>(l[0]), static_cast<uint32_t>(l[1]), static_cast<uint32_t>(l[2])});
    faces.push_back({static_cast<uint32_t>(l[0]), static_cast<uint32_t>(l[2]), static_cast<uint32_t>(l[3])});
  }
}

}  // namespace

hrt::Vec3 cube_center() { return hrt::Vec3(0.1, -0.05, 0.03); }
double cube_side() { return kSide; }

std::string coarse_ply_bytes(const BundleContent& b) {
  std::ostringstream h;
  h << "ply\nformat binary_little_endian 1.0\n";
  if (!b.coarse_comment.empty()) h << b.coarse_comment << "\n";
  h << "element vertex " << b.vertices.size() << "\nproperty float x\nproperty float y\nproperty float z\n"
    << "element face " << b.faces.size() << "\nproperty list uchar uint vertex_indices\n"
    << "property list uchar float texcoord\nend_header\n";
  std::string s = h.str();
  for (const auto& v : b.vertices)
    for (float x : v) put_f32(s, x);
  for (size_t f = 0; f < b.faces.size(); ++f) {
    put_u8(s, 3);
    for (uint32_t i : b.faces[f]) put_u32(s, i);
    put_u8(s, 6);
    for (float x : b.uvs[f]) put_f32(s, x);
  }
  return s;
}

bool pieces_table_layout(const BundleContent& b) {
  const auto it = b.manifest.find("format_version");
  if (it == b.manifest.end() || !it->is_string()) return false;
  const std::string v = it->get<std::string>();
  const size_t dot = v.find('.');
  if (dot == std::string::npos) return false;
  const std::string minor = v.substr(dot + 1);
  if (minor.empty() || minor.find_first_not_of("0123456789") != std::string::npos) return false;
  const std::string d = minor.substr(std::min(minor.find_first_not_of('0'), minor.size()));
  return d.size() > 1 || (d.size() == 1 && d[0] >= '3');  // minor >= 3: the layout of format 1.3
}

std::string pieces_ply_bytes(const BundleContent& b) {
  size_t nv = 0, nf = 0, nmap = 0;
  for (size_t p = 0; p < b.piece_vertices.size(); ++p) {
    nv += b.piece_vertices[p].size();
    nf += b.piece_faces[p].size();
  }
  for (const auto& list : b.piece_map) nmap += list.size();
  const bool table = pieces_table_layout(b);
  std::ostringstream h;
  h << "ply\nformat binary_little_endian 1.0\ncomment hbundle pieces " << (table ? "1.3" : "1.0") << "\n"
    << "element vertex " << nv << "\nproperty float x\nproperty float y\nproperty float z\nproperty uint piece\n"
    << "element face " << nf << "\nproperty list uchar uint vertex_indices\nproperty uint piece\n";
  if (table) {
    h << "element piece " << b.piece_map.size() << "\nproperty uint coarse_face_count\n"
      << "element piece_coarse_face " << nmap << "\nproperty uint coarse_face\nend_header\n";
  } else {
    h << "element piece " << b.piece_map.size() << "\nproperty list uint uint coarse_faces\nend_header\n";
  }
  std::string s = h.str();
  for (size_t p = 0; p < b.piece_vertices.size(); ++p) {
    for (const auto& v : b.piece_vertices[p]) {
      for (float x : v) put_f32(s, x);
      put_u32(s, static_cast<uint32_t>(p));
    }
  }
  uint32_t base = 0;
  for (size_t p = 0; p < b.piece_faces.size(); ++p) {
    for (const auto& f : b.piece_faces[p]) {
      put_u8(s, 3);
      for (uint32_t i : f) put_u32(s, base + i);
      put_u32(s, static_cast<uint32_t>(p));
    }
    base += static_cast<uint32_t>(b.piece_vertices[p].size());
  }
  if (table) {
    for (const auto& list : b.piece_map) put_u32(s, static_cast<uint32_t>(list.size()));
    for (const auto& list : b.piece_map)
      for (uint32_t t : list) put_u32(s, t);
  } else {
    for (const auto& list : b.piece_map) {
      put_u32(s, static_cast<uint32_t>(list.size()));
      for (uint32_t t : list) put_u32(s, t);
    }
  }
  return s;
}

void write_atlas_exr(const std::string& path, int width, int height, const std::vector<float>& rgba,
                     const ExrOptions& opt) {
  Imf::Header header(width, height);
  header.compression() = compression_of(opt.compression);
  header.dataWindow() =
      Imath::Box2i(Imath::V2i(opt.data_offset_x, 0), Imath::V2i(width - 1 + opt.data_offset_x, height - 1));
  const Imf::PixelType type = opt.half ? Imf::HALF : Imf::FLOAT;
  for (char c : opt.channels) header.channels().insert(std::string(1, c), Imf::Channel(type));
  Imf::FrameBuffer fb;
  // OpenEXR writes HALF channels only from HALF slices: convert first.
  std::vector<half> halves(opt.half ? rgba.size() : 0);
  for (size_t k = 0; k < halves.size(); ++k) halves[k] = half(rgba[k]);
  const size_t elem = opt.half ? sizeof(half) : sizeof(float);
  const size_t xs = 4 * elem, ys = xs * static_cast<size_t>(width);
  // Slice base so that pixel (dx, 0) of the data window is element 0.
  char* data =
      opt.half ? reinterpret_cast<char*>(halves.data()) : reinterpret_cast<char*>(const_cast<float*>(rgba.data()));
  char* base = data - static_cast<ptrdiff_t>(opt.data_offset_x) * xs;
  for (char c : opt.channels) {
    const int k = c == 'R' ? 0 : c == 'G' ? 1 : c == 'B' ? 2 : 3;
    fb.insert(std::string(1, c), Imf::Slice(type, base + k * elem, xs, ys));
  }
  if (opt.tiled) {
    header.setTileDescription(Imf::TileDescription(16, 16, Imf::ONE_LEVEL));
    Imf::TiledOutputFile out(path.c_str(), header);
    out.setFrameBuffer(fb);
    out.writeTiles(0, out.numXTiles() - 1, 0, out.numYTiles() - 1);
  } else {
    Imf::OutputFile out(path.c_str(), header);
    out.setFrameBuffer(fb);
    out.writePixels(height);
  }
}

nlohmann::json write_bundle(const std::string& dir, const BundleContent& b, const ExrOptions& exr) {
  fs::create_directories(dir);
  write_bytes(dir + "/coarse.ply", coarse_ply_bytes(b));
  write_bytes(dir + "/pieces.ply", pieces_ply_bytes(b));
  write_atlas_exr(dir + "/atlas.exr", b.width, b.height, b.rgba, exr);
  nlohmann::json m = b.manifest;
  m["files"] = {
      {"coarse_mesh", {{"path", "coarse.ply"}}},
      {"atlas",
       {{"path", "atlas.exr"},
        {"width", b.width},
        {"height", b.height},
        {"channels", {"A", "B", "G", "R"}},
        {"pixel_type", "float"},
        {"compression", exr.compression == "piz" ? "piz" : "zip"}}},
      {"pieces", {{"path", "pieces.ply"}}},
  };
  write_json(dir + "/manifest.json", m);
  rehash(dir);
  return read_json(dir + "/manifest.json");
}

void rehash(const std::string& dir) {
  nlohmann::json m = read_json(dir + "/manifest.json");
  for (const char* key : {"coarse_mesh", "atlas", "pieces"}) {
    auto& f = m["files"][key];
    const std::string bytes = read_bytes(dir + "/" + f["path"].get<std::string>());
    f["bytes"] = bytes.size();
    f["sha256"] = hrt::io::sha256_hex(bytes);
  }
  write_json(dir + "/manifest.json", m);
}

BundleContent make_cube() {
  BundleContent b;
  const hrt::Vec3 c = cube_center(), half = hrt::Vec3::Constant(kSide / 2);
  const hrt::Vec3 lo = c - half, hi = c + half;
  for (int bits = 0; bits < 8; ++bits) b.vertices.push_back(corner(lo, hi, bits));
  b.width = kW;
  b.height = kH;
  b.rgba.assign(static_cast<size_t>(kW) * kH * 4, 0.0f);
  size_t covered = 0;
  for (int k = 0; k < 6; ++k) {
    const int* l = kLoops[k];
    const int X0 = (k % 3) * kCell + kInset, Y0 = (k / 3) * kCell + kInset;
    // Corner (s, t) of the face -> texel coordinates (y down) -> UV (v up).
    auto uv = [&](double s, double t) {
      return std::array<float, 2>{static_cast<float>((X0 + kChart * s) / kW),
                                  static_cast<float>(1.0 - (Y0 + kChart * (1.0 - t)) / kH)};
    };
    const std::array<float, 2> st[4] = {uv(0, 0), uv(1, 0), uv(1, 1), uv(0, 1)};
    const int tris[2][3] = {{0, 1, 2}, {0, 2, 3}};
    for (const auto& t : tris) {
      b.faces.push_back(
          {static_cast<uint32_t>(l[t[0]]), static_cast<uint32_t>(l[t[1]]), static_cast<uint32_t>(l[t[2]])});
      b.uvs.push_back({st[t[0]][0], st[t[0]][1], st[t[1]][0], st[t[1]][1], st[t[2]][0], st[t[2]][1]});
    }
    // Affine position map of the chart, written into the covered texels and
    // extrapolated into the gutter.
    const hrt::Vec3 a(b.vertices[l[0]][0], b.vertices[l[0]][1], b.vertices[l[0]][2]);
    const hrt::Vec3 eb = hrt::Vec3(b.vertices[l[1]][0], b.vertices[l[1]][1], b.vertices[l[1]][2]) - a;
    const hrt::Vec3 ed = hrt::Vec3(b.vertices[l[3]][0], b.vertices[l[3]][1], b.vertices[l[3]][2]) - a;
    for (int j = Y0 - kGutter; j < Y0 + kChart + kGutter; ++j) {
      for (int i = X0 - kGutter; i < X0 + kChart + kGutter; ++i) {
        const double s = (i + 0.5 - X0) / kChart, t = 1.0 - (j + 0.5 - Y0) / kChart;
        const hrt::Vec3 p = a + s * eb + t * ed;
        float* px = &b.rgba[(static_cast<size_t>(j) * kW + i) * 4];
        px[0] = static_cast<float>(p.x());
        px[1] = static_cast<float>(p.y());
        px[2] = static_cast<float>(p.z());
        const bool in = i >= X0 && i < X0 + kChart && j >= Y0 && j < Y0 + kChart;
        px[3] = in ? 1.0f : 0.0f;
        covered += in;
      }
    }
  }
  // Pieces: the two halves of the cube along x; each maps to every coarse
  // triangle except those of the opposite x face.
  const hrt::Vec3 mid_hi(c.x(), hi.y(), hi.z()), mid_lo(c.x(), lo.y(), lo.z());
  b.piece_vertices.resize(2);
  b.piece_faces.resize(2);
  box(lo, mid_hi, b.piece_vertices[0], b.piece_faces[0]);
  box(mid_lo, hi, b.piece_vertices[1], b.piece_faces[1]);
  b.piece_map = {{0, 1, 4, 5, 6, 7, 8, 9, 10, 11}, {2, 3, 4, 5, 6, 7, 8, 9, 10, 11}};

  const double volume = kSide * kSide * kSide, density = 1.0, mass = density * volume;
  const double I = mass * kSide * kSide / 6.0;
  const double diag = std::sqrt(3.0) * kSide;
  const nlohmann::json rec = {{"samples", 1000}, {"mean", 0.0},    {"p95", 0.0},    {"max", 0.0},
                              {"mean_rel", 0.0}, {"p95_rel", 0.0}, {"max_rel", 0.0}};
  b.manifest = {
      {"format", "hbundle"},
      {"format_version", "1.0"},
      {"generator", {{"name", "hbake"}, {"version", "0.0.0+hrt-test-writer"}}},
      {"units", {{"length", "m"}, {"source_unit", "m"}, {"scale_to_meters", 1.0}}},
      {"source",
       {{"name", "cube.ply"},
        {"sha256", std::string(64, '0')},
        {"vertices", 8},
        {"triangles", 12},
        {"bodies", 1},
        {"closed", true}}},
      {"method", "cage"},
      {"settings", nlohmann::json::object()},
      {"seeds", {{"coacd", 0}, {"quality", 0}}},
      {"libraries", {{"OpenEXR", "3.1"}}},
      {"coarse",
       {{"vertices", 8},
        {"triangles", 12},
        {"bbox_min", {lo.x(), lo.y(), lo.z()}},
        {"bbox_max", {hi.x(), hi.y(), hi.z()}},
        {"area", 6 * kSide * kSide}}},
      {"pieces", {{"count", 2}, {"map_tolerance", 1e-6}}},
      {"atlas",
       {{"width", kW},
        {"height", kH},
        {"gutter", kGutter},
        {"texel_size", kSide / kChart},
        {"coverage", static_cast<double>(covered) / (kW * kH)}}},
      {"mass",
       {{"basis", "full"},
        {"density", density},
        {"volume", volume},
        {"center_of_mass", {c.x(), c.y(), c.z()}},
        {"inertia", {{I, 0.0, 0.0}, {0.0, I, 0.0}, {0.0, 0.0, I}}},
        {"closed", true}}},
      {"quality",
       {{"displacement_outward", 0.0},
        {"displacement_inward", 0.0},
        {"hull_deviation", 0.0},
        {"hull_volume_excess", 0.0},
        {"min_wavelength", 2 * kSide / kChart},
        {"reconstruction", {{"coarse_to_full", rec}, {"full_to_coarse", rec}}},
        {"bbox_diagonal", diag}}},
      {"warnings", nlohmann::json::array()},
  };
  return b;
}

double sample_tolerance(int W, int H, double spread, double max_abs) {
  return (2.0 * W + 3.0 * H) * kEps32 * spread + 16.0 * kEps32 * max_abs;
}

Eigen::Vector4d reference_sample(const hrt::Atlas& a, float u, float v, Eigen::Vector4d* spread,
                                 Eigen::Vector4d* max_abs) {
  const double x = static_cast<double>(u) * a.width - 0.5, y = (1.0 - static_cast<double>(v)) * a.height - 0.5;
  const double x0 = std::floor(x), y0 = std::floor(y), fx = x - x0, fy = y - y0;
  auto cl = [](double i, int n) { return static_cast<int>(std::min(std::max(i, 0.0), n - 1.0)); };
  const int i0 = cl(x0, a.width), i1 = cl(x0 + 1, a.width), j0 = cl(y0, a.height), j1 = cl(y0 + 1, a.height);
  Eigen::Vector4d out = Eigen::Vector4d::Zero(), sp = Eigen::Vector4d::Zero(), mx = Eigen::Vector4d::Zero();
  const int ii[4] = {i0, i1, i0, i1}, jj[4] = {j0, j0, j1, j1};
  const double w[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
  for (int k = 0; k < 4; ++k) {
    const float* t = a.texel(ii[k], jj[k]);
    for (int c = 0; c < 4; ++c) {
      out[c] += w[k] * t[c];
      mx[c] = std::max(mx[c], std::fabs(static_cast<double>(t[c])));
      for (int q = 0; q < 4; ++q)
        sp[c] = std::max(sp[c], std::fabs(static_cast<double>(t[c]) - a.texel(ii[q], jj[q])[c]));
    }
  }
  if (spread) *spread = sp;
  if (max_abs) *max_abs = mx;
  return out;
}

std::string golden_dir() {
  const char* env = std::getenv("HRT_GOLDEN_DIR");
  return env && *env ? env : HRT_GOLDEN_DIR;
}

std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void write_bytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error("cannot write " + path);
}

nlohmann::json read_json(const std::string& path) { return nlohmann::json::parse(read_bytes(path)); }

void write_json(const std::string& path, const nlohmann::json& j) { write_bytes(path, j.dump(2) + "\n"); }

std::string fresh_dir(const std::string& name) {
  // The pid keeps concurrent runs of the suite (other build dirs) apart.
  const std::string dir = ::testing::TempDir() + "hrt_io_" + std::to_string(::getpid()) + "_" + name + ".hbundle";
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

void copy_dir(const std::string& from, const std::string& to) {
  fs::remove_all(to);
  fs::copy(from, to, fs::copy_options::recursive);
}

void remove_tree(const std::string& path) { fs::remove_all(path); }

std::string hrt_binary() {
  char buf[4096];
  const ssize_t n = ::readlink("/proc/self/exe", buf, sizeof buf - 1);
  if (n <= 0) return "";
  const std::string self(buf, static_cast<size_t>(n));
  return self.substr(0, self.rfind('/') + 1) + "hrt";
}

HrtRun run_hrt(const std::vector<std::string>& args, bool capture_stdout) {
  HrtRun r;
  const std::string bin = hrt_binary();
  int out_fd[2], err_fd[2];
  if (::pipe(out_fd) != 0) return r;
  if (::pipe(err_fd) != 0) {
    ::close(out_fd[0]);
    ::close(out_fd[1]);
    return r;
  }
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  if (capture_stdout)
    posix_spawn_file_actions_adddup2(&fa, out_fd[1], 1);
  else
    posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_adddup2(&fa, err_fd[1], 2);
  for (int fd : {out_fd[0], out_fd[1], err_fd[0], err_fd[1]}) posix_spawn_file_actions_addclose(&fa, fd);
  std::vector<char*> argv{const_cast<char*>(bin.c_str())};
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, bin.c_str(), &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  ::close(out_fd[1]);
  ::close(err_fd[1]);
  if (rc == 0) {
    // Both pipes drained together, so a child filling one cannot block.
    pollfd fds[2] = {{out_fd[0], POLLIN, 0}, {err_fd[0], POLLIN, 0}};
    std::string* sinks[2] = {&r.out, &r.err};
    int open_fds = 2;
    while (open_fds > 0) {
      if (::poll(fds, 2, -1) < 0) break;
      for (int k = 0; k < 2; ++k) {
        if (fds[k].fd < 0 || !(fds[k].revents & (POLLIN | POLLHUP | POLLERR))) continue;
        char buf[65536];
        const ssize_t n = ::read(fds[k].fd, buf, sizeof buf);
        if (n > 0) {
          sinks[k]->append(buf, static_cast<size_t>(n));
        } else {
          ::close(fds[k].fd);
          fds[k].fd = -1;
          --open_fds;
        }
      }
    }
    int status = 0;
    struct rusage ru{};
    ::wait4(pid, &status, 0, &ru);
    r.status = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    r.max_rss_kb = ru.ru_maxrss;
  } else {
    ::close(out_fd[0]);
    ::close(err_fd[0]);
  }
  return r;
}

// A right prism over a regular k-gon (2k vertices, 4k - 4 faces, outward):
// convex in float32 with a wide margin (the caps are exactly planar, the
// sides exactly vertical), so only the limits can refuse it.
void prism(int k, double r, double z0, double z1, std::vector<std::array<float, 3>>& v, std::vector<hrt::Tri>& f) {
  const hrt::Vec3 c = cube_center();
  v.clear();
  f.clear();
  for (int side = 0; side < 2; ++side)
    for (int i = 0; i < k; ++i) {
      const double a = 2 * M_PI * i / k;
      v.push_back({static_cast<float>(c.x() + r * std::cos(a)), static_cast<float>(c.y() + r * std::sin(a)),
                   static_cast<float>(c.z() + (side ? z1 : z0))});
    }
  const uint32_t K = static_cast<uint32_t>(k);
  for (uint32_t i = 1; i + 1 < K; ++i) {
    f.push_back({0, i + 1, i});          // bottom, seen from below
    f.push_back({K, K + i, K + i + 1});  // top
  }
  for (uint32_t i = 0; i < K; ++i) {
    const uint32_t j = (i + 1) % K;
    f.push_back({i, j, K + j});
    f.push_back({i, K + j, K + i});
  }
}

// Writes a bundle whose pieces.ply holds `pieces` prisms of 1024 vertices
// and 2044 faces each (the worst case of the convexity check per byte).
void many_prism_bundle(const std::string& dir, BundleContent b, int pieces, int sides) {
  b.piece_vertices.assign(static_cast<size_t>(pieces), {});
  b.piece_faces.assign(static_cast<size_t>(pieces), {});
  b.piece_map.assign(static_cast<size_t>(pieces), {});
  for (int p = 0; p < pieces; ++p) prism(sides, 0.005, -0.005, 0.005, b.piece_vertices[p], b.piece_faces[p]);
  b.manifest["pieces"]["count"] = pieces;
  write_bundle(dir, b);
}

}  // namespace hrt_test
