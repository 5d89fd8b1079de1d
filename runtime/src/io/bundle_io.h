// Private building blocks of the bundle loader (docs/bundle-format.md).
//
// Each reader takes the bytes of one file, already read into memory once (the
// same bytes are hashed and parsed, so what is verified is what is loaded),
// and throws hrt::BundleError with the file's label in the message. They check
// the *format* of their file; cross-file invariants (indices into the coarse
// mesh, UV coverage of the atlas, ...) are checked in bundle.cpp.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "hrt/model.h"

namespace hrt::io {

// Lower-case hex SHA-256 of a byte string (OpenSSL's libcrypto).
std::string sha256_hex(const std::string& bytes);

// Size of a regular file; BundleError(io) when it is missing, not a regular
// file, unreadable or larger than max_bytes. `label` names the file in messages.
uint64_t file_size(const std::string& path, const std::string& label, uint64_t max_bytes = UINT64_MAX);
// Reads a whole regular file of at most max_bytes bytes (errors as file_size).
std::string read_file(const std::string& path, const std::string& label, uint64_t max_bytes = UINT64_MAX);

// Size limits of the bundle's files (docs/input-contract.md), checked before
// a byte is read. A manifest written by hbake is a few KB; 1 MiB of JSON is
// at most ~30 MB as a DOM. The atlas limit (256 MiB of float32 RGBA) bounds
// an EXR, which is at most slightly larger than its raw texels; the PLYs'
// counts are bounded by their bytes, and 1 GiB holds 28M coarse triangles.
constexpr uint64_t kMaxManifestBytes = uint64_t{1} << 20;
constexpr uint64_t kMaxPlyBytes = uint64_t{1} << 30;
constexpr uint64_t kMaxExrBytes = uint64_t{512} << 20;
// Nesting of arrays and objects in manifest.json (the top-level object is
// level 1; hbake writes 4). Deeper input is refused while parsing.
constexpr int kMaxJsonDepth = 64;
// Vertices of one convex piece (shared with hbake), and so at most
// 2 * 1024 - 4 faces: a closed convex triangulated polyhedron with V
// vertices has 2 V - 4 faces (Euler). The convexity check costs
// vertices x faces per piece, at most 41 plane tests per byte of pieces.ply.
constexpr size_t kMaxPieceVertices = 1024;
constexpr size_t kMaxPieceFaces = 2 * kMaxPieceVertices - 4;

// coarse.ply: float32 positions, uint32 triangles, per-corner float32 UVs as
// stored (u0 v0 u1 v1 u2 v2 per face).
struct CoarsePly {
  std::vector<std::array<float, 3>> vertices;
  std::vector<Tri> faces;
  std::vector<std::array<float, 6>> uvs;
};
// Strict reader: exactly the header of the spec; record counts and file length
// must match. Errors are class `mesh`. (Index and value checks: bundle.cpp.)
CoarsePly parse_coarse_ply(const std::string& bytes, const std::string& label);

// pieces.ply: global vertex and face lists with their piece ids, and the
// piece -> coarse-triangle lists, exactly as stored (not yet validated).
struct PiecesPly {
  std::vector<std::array<float, 3>> vertices;
  std::vector<uint32_t> vertex_piece;
  std::vector<Tri> faces;  // global vertex indices
  std::vector<uint32_t> face_piece;
  std::vector<std::vector<uint32_t>> coarse_faces;  // one list per piece record
};
// Strict reader: exactly the header of the spec; counts, list lengths and file
// length must match. Errors are class `pieces`. `table_layout`: the layout of
// format 1.3 and later (the map as the fixed-size elements `piece` (counts) and
// `piece_coarse_face` (rows)); false: that of 1.0-1.2 (one variable-length list
// per piece). pieces_layout_is_table() says which a format_version uses.
PiecesPly parse_pieces_ply(const std::string& bytes, const std::string& label, bool table_layout = true);
// Whether a bundle of `format_version` ("1.x", already checked) keeps the map in
// the fixed-size elements of 1.3 (minor version 3 or more).
bool pieces_layout_is_table(const std::string& format_version);

// The atlas limit shared by hbake and the runtime (docs/input-contract.md):
// each side in [1, kMaxAtlasSide], at most kMaxAtlasTexels texels (256 MiB of
// float32 RGBA), checked on the manifest and on the EXR header before OpenEXR
// or the loader allocates anything of that size. A compressed EXR can expand
// a thousandfold, so the file size bounds nothing.
constexpr int64_t kMaxAtlasSide = 8192;
constexpr int64_t kMaxAtlasTexels = int64_t{1} << 24;
constexpr const char* kAtlasLimitText = " (each side at most 8192, at most 16777216 texels)";

// What the manifest says the atlas must be.
struct AtlasSpec {
  int width = 0;
  int height = 0;
  std::string compression;            // "zip" or "piz"
  std::vector<std::string> channels;  // files.atlas.channels: R, G, B, A and possibly more
};
// atlas.exr through OpenEXR (Imf::InputFile on an in-memory stream): single-part
// scanline, ZIP or PIZ matching the manifest, data and display window
// (0,0)-(W-1,H-1), exactly the manifest's channels (R, G, B, A looked up by
// name), all FLOAT and not subsampled. Errors are class `atlas`.
// Does not check the texel values (see bundle.cpp).
// `threads` as LoadOptions::decode_threads.
Atlas read_atlas_exr(const std::string& bytes, const std::string& label, const AtlasSpec& spec, int threads = 1);

// The manifest fields the loader uses, after check_manifest.
struct FileEntry {
  std::string path;    // file name inside the bundle directory
  std::string sha256;  // 64 lower-case hex digits
  uint64_t bytes = 0;
};
struct ManifestInfo {
  std::string format_version;  // "1.x"
  std::string source_name;
  FileEntry coarse_mesh, atlas, pieces;
  AtlasSpec atlas_spec;                        // files.atlas width, height, channels, compression
  uint64_t atlas_width = 0, atlas_height = 0;  // atlas.width / atlas.height (must equal files.atlas)
  uint64_t coarse_vertices = 0, coarse_triangles = 0;
  uint64_t piece_count = 0;
  double map_tolerance = 0.0;
  int gutter = 0;
  double coverage = 0.0;
  MassProperties mass;
  Quality quality;
};
// Checks the parsed manifest field by field (format and major version first,
// class `version`; then every required field and its type, class `schema`).
// Unknown fields are ignored (minor versions only add fields).
ManifestInfo check_manifest(const nlohmann::json& m, const std::string& label);

}  // namespace hrt::io
