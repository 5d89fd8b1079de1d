// A small, independent writer of spec'd bundle files for the loader tests
// (docs/bundle-format.md): PLY bytes written field by field, the atlas through
// OpenEXR's Imf::OutputFile, the manifest with nlohmann-json. It can also
// write *wrong* files on purpose (options below) so every rejection path of
// the loader is tested without depending on the Python side.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "hrt/model.h"

namespace hrt_test {

struct BundleContent {
  // coarse.ply
  std::vector<std::array<float, 3>> vertices;
  std::vector<hrt::Tri> faces;
  std::vector<std::array<float, 6>> uvs;                           // u0 v0 u1 v1 u2 v2 per face
  std::string coarse_comment = "comment hbundle coarse mesh 1.0";  // "" = no comment line
  // atlas.exr (row 0 = top), RGBA float
  int width = 0, height = 0;
  std::vector<float> rgba;
  // pieces.ply (local face indices per piece)
  std::vector<std::vector<std::array<float, 3>>> piece_vertices;
  std::vector<std::vector<hrt::Tri>> piece_faces;
  std::vector<std::vector<uint32_t>> piece_map;
  // manifest.json without "files" (write_bundle adds it)
  nlohmann::json manifest;
};

// How to write atlas.exr (defaults: what the spec requires).
struct ExrOptions {
  std::string compression = "zip";  // zip | piz | rle | none | ...
  std::string channels = "RGBA";    // which channels to write
  bool half = false;                // HALF instead of FLOAT pixels
  int data_offset_x = 0;            // shift of the data window
  bool tiled = false;
};

// The bytes of coarse.ply / pieces.ply exactly as the spec lays them out
// (pieces.ply in the layout of the manifest's format_version: 1.3 and later keep
// the map in fixed-size elements, 1.0-1.2 as one list per piece).
std::string coarse_ply_bytes(const BundleContent& b);
std::string pieces_ply_bytes(const BundleContent& b);
void write_atlas_exr(const std::string& path, int width, int height, const std::vector<float>& rgba,
                     const ExrOptions& opt = {});

// Writes the three files and manifest.json (with sizes and hashes) into dir,
// creating it. Returns the manifest written.
nlohmann::json write_bundle(const std::string& dir, const BundleContent& b, const ExrOptions& exr = {});
// Recomputes files.*.bytes/sha256 of dir's manifest after a file was altered.
void rehash(const std::string& dir);

// A textured cube (side 2 cm, centred off the origin), 12 triangles in 6 UV
// charts of a 96 x 64 atlas whose texels hold the exact affine position map
// (also in the gutters, by affine extrapolation), so a bilinear lookup
// anywhere inside a UV triangle returns the surface point exactly up to
// float32 rounding; two convex pieces (the two halves of the cube).
BundleContent make_cube();
hrt::Vec3 cube_center();
double cube_side();

// Atlas lookup checks. kEps32 = 2^-24, the float32 unit roundoff.
constexpr double kEps32 = 1.0 / (1 << 24);
// Float32 error bound of hrt::Atlas::sample4 against an exact evaluation with
// the same (float) u, v: x = u W - 0.5 is off by at most 2 W 2^-24 (two
// roundings) and y = (1 - v) H - 0.5 by at most 3 H 2^-24 (three), which
// moves the result by at most (|dx| + |dy|) * spread (spread = the largest
// difference between the four texels read); the weights and the 4-term sum
// add at most ~16 2^-24 max|texel|.
double sample_tolerance(int W, int H, double spread, double max_abs);
// The spec's bilinear lookup written independently, in double precision;
// also returns, per channel, the spread and the largest magnitude of the 4
// texels it reads.
Eigen::Vector4d reference_sample(const hrt::Atlas& a, float u, float v, Eigen::Vector4d* spread = nullptr,
                                 Eigen::Vector4d* max_abs = nullptr);

// The golden bundles' directory: HRT_GOLDEN_DIR (compile-time, the repo's
// tests/golden), overridden by the environment variable of the same name.
std::string golden_dir();

// The `hrt` binary next to the test binary ("" when it cannot be found).
std::string hrt_binary();
// Runs `hrt args...` as a child process (no shell): its exit code (128 +
// signal when killed), stdout (when asked; otherwise discarded), stderr and
// peak resident set (wait4; it includes the parent's peak, since the child
// shares the parent's memory until exec), so a crash or a memory blow-up of
// the command is an assertion failure, not a failure of the test binary.
struct HrtRun {
  int status = -1;
  std::string out, err;
  long max_rss_kb = 0;
};
HrtRun run_hrt(const std::vector<std::string>& args, bool capture_stdout = false);

// File helpers.
std::string read_bytes(const std::string& path);
void write_bytes(const std::string& path, const std::string& bytes);
nlohmann::json read_json(const std::string& path);
void write_json(const std::string& path, const nlohmann::json& j);
std::string fresh_dir(const std::string& name);  // empty temp directory named NAME.hbundle
void copy_dir(const std::string& from, const std::string& to);
void remove_tree(const std::string& path);

// A right prism over a regular k-gon of radius r about the cube's centre,
// z in [z0, z1] (2k vertices, 4k - 4 outward faces, convex in float32).
void prism(int k, double r, double z0, double z1, std::vector<std::array<float, 3>>& v, std::vector<hrt::Tri>& f);
// Writes bundle `b` with its pieces.ply replaced by `pieces` prisms over a
// `sides`-gon (512: 1024 vertices and 2044 faces each, the worst case of the
// convexity check per byte; 200 of them make a 10 MB pieces.ply).
void many_prism_bundle(const std::string& dir, BundleContent b, int pieces, int sides = 512);

}  // namespace hrt_test
