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

#include "hrt/model.h"

namespace hrt::io {

// Lower-case hex SHA-256 of a byte string (OpenSSL's libcrypto).
std::string sha256_hex(const std::string& bytes);

// Reads a whole regular file; BundleError(io) when it is missing, not a
// regular file or unreadable. `label` names the file in messages.
std::string read_file(const std::string& path, const std::string& label);

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
// length must match. Errors are class `pieces`.
PiecesPly parse_pieces_ply(const std::string& bytes, const std::string& label);

// What the manifest says the atlas must be.
struct AtlasSpec {
  int width = 0;
  int height = 0;
  std::string compression;  // "zip" or "piz"
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
  AtlasSpec atlas_spec;       // files.atlas width, height, channels, compression
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
