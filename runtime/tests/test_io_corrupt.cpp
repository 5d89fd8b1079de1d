// Every rejection path of the loader, one corruption at a time, on bundles
// written by the test writer (independent of the Python side). Each case
// checks the error class and a fragment of the message; the fragments are the
// wording shared with hbake.bundle (see docs/bundle-format.md, error classes).
// Cases that alter a file after writing recompute the manifest's hashes
// ("rehash"), so the check behind the hash check is what fires.
#include <cmath>
#include <cstring>
#include <filesystem>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <limits>

#include <gtest/gtest.h>

#include "hrt/model.h"
#include "test_io_writer.h"

using hrt::BundleError;
using hrt::BundleErrorClass;
using namespace hrt_test;
using nlohmann::json;

namespace {

struct Case {
  std::string name;
  std::function<void(BundleContent&, ExrOptions&)> before;  // edit the content before writing
  std::function<void(const std::string& dir)> after;        // edit the files after writing
  bool rehash;                                              // recompute hashes after `after`
  BundleErrorClass cls;
  std::string fragment;
};

const float kNaN = std::numeric_limits<float>::quiet_NaN();

size_t body_offset(const std::string& bytes) { return bytes.find("end_header\n") + 11; }

void patch_u32(const std::string& path, size_t offset, uint32_t v) {
  std::string b = read_bytes(path);
  for (int k = 0; k < 4; ++k) b[offset + k] = static_cast<char>((v >> (8 * k)) & 0xff);
  write_bytes(path, b);
}
void patch_u8(const std::string& path, size_t offset, uint8_t v) {
  std::string b = read_bytes(path);
  b[offset] = static_cast<char>(v);
  write_bytes(path, b);
}
void replace_text(const std::string& path, const std::string& from, const std::string& to) {
  std::string b = read_bytes(path);
  const size_t at = b.find(from);
  ASSERT_NE(at, std::string::npos) << from;
  b.replace(at, from.size(), to);
  write_bytes(path, b);
}
void edit_manifest(const std::string& dir, const std::function<void(json&)>& f) {
  json m = read_json(dir + "/manifest.json");
  f(m);
  write_json(dir + "/manifest.json", m);
}
float* texel(BundleContent& b, int i, int j) { return &b.rgba[(static_cast<size_t>(j) * b.width + i) * 4]; }

// Pieces file layout (bytes after the header): vertices 16 B, faces 17 B, then
// the lists (1.0-1.2) or the per-piece counts and the rows (1.3).
size_t piece_vertex_offset(const std::string& dir, size_t i) {
  return body_offset(read_bytes(dir + "/pieces.ply")) + 16 * i;
}
size_t piece_list_offset(const std::string& dir) {
  return body_offset(read_bytes(dir + "/pieces.ply")) + 16 * 16 + 24 * 17;
}

std::vector<Case> cases() {
  using C = BundleErrorClass;
  auto none = [](BundleContent&, ExrOptions&) {};
  auto nofile = [](const std::string&) {};
  auto manifest = [](std::function<void(json&)> f) { return [f](const std::string& dir) { edit_manifest(dir, f); }; };
  auto content = [](std::function<void(BundleContent&)> f) { return [f](BundleContent& b, ExrOptions&) { f(b); }; };
  auto exr = [](std::function<void(ExrOptions&)> f) { return [f](BundleContent&, ExrOptions& e) { f(e); }; };
  auto v13 = [](BundleContent& b, ExrOptions&) { b.manifest["format_version"] = "1.3"; };
  std::vector<Case> v = {
      // ---- io
      {"manifest_missing", none, [](const std::string& d) { std::filesystem::remove(d + "/manifest.json"); }, false, C::io,
       "manifest.json: missing"},
      {"atlas_missing", none, [](const std::string& d) { std::filesystem::remove(d + "/atlas.exr"); }, false, C::io,
       "atlas.exr: missing (atlas file named by the manifest)"},
      {"pieces_is_directory", none,
       [](const std::string& d) {
         std::filesystem::remove(d + "/pieces.ply");
         std::filesystem::create_directory(d + "/pieces.ply");
       },
       false, C::io, "pieces.ply: is a directory, not a file"},
      // ---- schema
      {"manifest_not_json", none, [](const std::string& d) { write_bytes(d + "/manifest.json", "{\"format\": \"hbundle\",\n"); },
       false, C::schema, "not valid UTF-8 JSON"},
      {"manifest_nan", none,
       [](const std::string& d) { replace_text(d + "/manifest.json", "\"area\": ", "\"area\": NaN, \"x\": "); }, false, C::schema,
       "not valid UTF-8 JSON"},
      {"manifest_bad_utf8", none, [](const std::string& d) { replace_text(d + "/manifest.json", "cube.ply", "cube\xff.ply"); },
       false, C::schema, "not valid UTF-8 JSON"},
      {"manifest_array", none, [](const std::string& d) { write_bytes(d + "/manifest.json", "[1, 2]\n"); }, false, C::schema,
       "not an object"},
      {"missing_field", none, manifest([](json& m) { m["quality"].erase("bbox_diagonal"); }), false, C::schema,
       "quality: 'bbox_diagonal' is a required property"},
      {"missing_top_field", none, manifest([](json& m) { m.erase("mass"); }), false, C::schema,
       "(top level): 'mass' is a required property"},
      {"wrong_type", none, manifest([](json& m) { m["coarse"]["vertices"] = "8"; }), false, C::schema,
       "coarse/vertices: '8' is not of type 'integer'"},
      {"fractional_integer", none, manifest([](json& m) { m["coarse"]["triangles"] = 12.5; }), false, C::schema,
       "coarse/triangles: 12.5 is not of type 'integer'"},
      {"negative_bytes", none, manifest([](json& m) { m["files"]["pieces"]["bytes"] = -1; }), false, C::schema,
       "files/pieces/bytes: -1 is less than the minimum of 0"},
      {"zero_density", none, manifest([](json& m) { m["mass"]["density"] = 0; }), false, C::schema,
       "mass/density: 0 is less than or equal to the minimum of 0"},
      {"coverage_above_one", none, manifest([](json& m) { m["atlas"]["coverage"] = 1.5; }), false, C::schema,
       "atlas/coverage: 1.5 is greater than the maximum of 1"},
      {"path_escapes", none, manifest([](json& m) { m["files"]["atlas"]["path"] = "../atlas.exr"; }), false, C::schema,
       "files/atlas/path: '../atlas.exr' does not match"},
      {"path_dotdot", none, manifest([](json& m) { m["files"]["atlas"]["path"] = ".."; }), false, C::schema,
       "should not be valid under"},
      {"sha_uppercase", none,
       manifest([](json& m) {
         std::string s = m["files"]["coarse_mesh"]["sha256"];
         for (char& c : s) c = static_cast<char>(std::toupper(c));
         m["files"]["coarse_mesh"]["sha256"] = s;
       }),
       false, C::schema, "files/coarse_mesh/sha256"},
      {"compression_rle_in_manifest", none, manifest([](json& m) { m["files"]["atlas"]["compression"] = "rle"; }), false,
       C::schema, "files/atlas/compression: 'rle' is not one of ['zip', 'piz']"},
      {"channels_missing_A", none, manifest([](json& m) { m["files"]["atlas"]["channels"] = {"B", "G", "R"}; }), false,
       C::schema, "files/atlas/channels"},
      {"pixel_type_half", none, manifest([](json& m) { m["files"]["atlas"]["pixel_type"] = "half"; }), false, C::schema,
       "files/atlas/pixel_type: 'float' was expected"},
      {"generator_not_hbake", none, manifest([](json& m) { m["generator"]["name"] = "other"; }), false, C::schema,
       "generator/name: 'hbake' was expected"},
      {"vec3_short", none, manifest([](json& m) { m["mass"]["center_of_mass"] = {0.0, 1.0}; }), false, C::schema,
       "mass/center_of_mass: [0.0, 1.0] is too short"},
      {"warnings_not_strings", none, manifest([](json& m) { m["warnings"] = {1}; }), false, C::schema,
       "warnings/0: 1 is not of type 'string'"},
      {"bad_basis", none, manifest([](json& m) { m["mass"]["basis"] = "solid"; }), false, C::schema,
       "mass/basis: 'solid' is not one of"},
      // ---- version
      {"format_other", none, manifest([](json& m) { m["format"] = "gltf"; }), false, C::version, "not an hbundle"},
      {"format_missing", none, manifest([](json& m) { m.erase("format"); }), false, C::version, "not an hbundle"},
      {"major_2", none, manifest([](json& m) { m["format_version"] = "2.0"; }), false, C::version,
       "unsupported major version 2.0"},
      {"major_0", none, manifest([](json& m) { m["format_version"] = "0.9"; }), false, C::version, "unsupported major version"},
      {"version_not_major_minor", none, manifest([](json& m) { m["format_version"] = "1"; }), false, C::version,
       "is not MAJOR.MINOR"},
      {"version_number", none, manifest([](json& m) { m["format_version"] = 1.0; }), false, C::version, "is not MAJOR.MINOR"},
      // ---- hash
      {"coarse_flipped_byte", none, [](const std::string& d) { patch_u8(d + "/coarse.ply", read_bytes(d + "/coarse.ply").size() - 1, 0x7f); },
       false, C::hash, "coarse.ply: SHA-256"},
      {"pieces_appended", none, [](const std::string& d) { write_bytes(d + "/pieces.ply", read_bytes(d + "/pieces.ply") + "x"); },
       false, C::hash, "the manifest says"},
      {"atlas_sha_in_manifest", none, manifest([](json& m) { m["files"]["atlas"]["sha256"] = std::string(64, '0'); }), false,
       C::hash, "atlas.exr: SHA-256"},
      // ---- mesh
      {"ply_not_ply", none, [](const std::string& d) { replace_text(d + "/coarse.ply", "ply\n", "plx\n"); }, true, C::mesh,
       "not a PLY file"},
      {"ply_ascii", none,
       [](const std::string& d) { replace_text(d + "/coarse.ply", "binary_little_endian", "ascii"); }, true, C::mesh,
       "PLY header line 2 is 'format ascii 1.0'"},
      {"ply_big_endian", none,
       [](const std::string& d) { replace_text(d + "/coarse.ply", "binary_little_endian", "binary_big_endian"); }, true,
       C::mesh, "PLY header line 2 is 'format binary_big_endian 1.0'"},
      {"ply_double", none, [](const std::string& d) { replace_text(d + "/coarse.ply", "float x", "double x"); }, true, C::mesh,
       "PLY header line 5 is 'property double x'"},
      {"ply_extra_property", none,
       [](const std::string& d) { replace_text(d + "/coarse.ply", "property float z\n", "property float z\nproperty float w\n"); },
       true, C::mesh, "PLY header has 11 lines"},
      {"ply_comment_misplaced", none,
       [](const std::string& d) {
         replace_text(d + "/coarse.ply", "comment hbundle coarse mesh 1.0\n", "");
         replace_text(d + "/coarse.ply", "property float z\n", "property float z\ncomment late\n");
       },
       true, C::mesh, "PLY header"},
      {"ply_no_end_header", none, [](const std::string& d) { replace_text(d + "/coarse.ply", "end_header", "end_headex"); }, true,
       C::mesh, "no 'end_header' line"},
      {"ply_count_leading_zero", none,
       [](const std::string& d) { replace_text(d + "/coarse.ply", "element vertex 8", "element vertex 08"); }, true, C::mesh,
       "PLY header line 4 is 'element vertex 08', expected 'element vertex N'"},
      {"ply_truncated", none,
       [](const std::string& d) {
         std::string b = read_bytes(d + "/coarse.ply");
         write_bytes(d + "/coarse.ply", b.substr(0, b.size() - 5));
       },
       true, C::mesh, "faces need"},
      {"ply_trailing", none, [](const std::string& d) { write_bytes(d + "/coarse.ply", read_bytes(d + "/coarse.ply") + "xxxx"); },
       true, C::mesh, "faces need"},
      {"ply_count_vs_manifest", none, manifest([](json& m) { m["coarse"]["vertices"] = 9; }), false, C::mesh,
       "8 vertices and 12 faces, the manifest says 9 and 12"},
      {"face_4_indices", none,
       [](const std::string& d) { patch_u8(d + "/coarse.ply", body_offset(read_bytes(d + "/coarse.ply")) + 8 * 12 + 38 * 2, 4); },
       true, C::mesh, "face record not '3 indices, 6 texcoords' (first: face 2 has 4 indices"},
      {"index_out_of_range", content([](BundleContent& b) { b.faces[3][1] = 8; }), nofile, false, C::mesh,
       "1 face with a vertex index out of range (vertex count 8): face 3"},
      {"degenerate_repeated", content([](BundleContent& b) { b.faces[5][2] = b.faces[5][0]; }), nofile, false, C::mesh,
       "1 degenerate face (zero area): face 5"},
      {"degenerate_coincident_positions",
       // Vertex 1 moved onto vertex 3: faces using both collapse to a segment
       // (distinct indices, zero area), e.g. face 2 = (1, 3, 7) of the +x side.
       content([](BundleContent& b) { b.vertices[1] = b.vertices[3]; }), nofile, false, C::mesh,
       "degenerate faces (zero area): face 2"},
      {"vertex_nan", content([](BundleContent& b) { b.vertices[6][1] = kNaN; }), nofile, false, C::mesh,
       "1 vertex with non-finite positions: vertex 6"},
      {"vertex_inf", content([](BundleContent& b) { b.vertices[2][0] = std::numeric_limits<float>::infinity(); }), nofile, false,
       C::mesh, "with non-finite positions"},
      {"uv_outside", content([](BundleContent& b) { b.uvs[7][3] = 1.25f; }), nofile, false, C::mesh,
       "1 face with UVs outside [0, 1]: face 7"},
      {"uv_negative", content([](BundleContent& b) { b.uvs[0][0] = -0.01f; }), nofile, false, C::mesh, "outside [0, 1]"},
      {"uv_nan", content([](BundleContent& b) { b.uvs[4][1] = kNaN; }), nofile, false, C::mesh, "1 face with non-finite UVs: face 4"},
      // ---- atlas
      {"atlas_size_disagrees_in_manifest", none, manifest([](json& m) { m["atlas"]["width"] = 95; }), false, C::atlas,
       "atlas is 95x64 but files.atlas says 96x64"},
      {"exr_not_exr", none, [](const std::string& d) { write_bytes(d + "/atlas.exr", "this is not an EXR file"); }, true,
       C::atlas, "not an OpenEXR file (bad magic number)"},
      {"exr_truncated", none,
       [](const std::string& d) {
         std::string b = read_bytes(d + "/atlas.exr");
         write_bytes(d + "/atlas.exr", b.substr(0, b.size() / 2));
       },
       true, C::atlas, "atlas.exr: cannot"},
      {"exr_missing_channel", exr([](ExrOptions& e) { e.channels = "RGB"; }), nofile, false, C::atlas,
       "missing channel 'A' (channels present: B, G, R)"},
      {"exr_extra_channel", exr([](ExrOptions& e) { e.channels = "RGBAZ"; }), nofile, false, C::atlas,
       "channels Z are not declared in the manifest"},
      {"exr_half", exr([](ExrOptions& e) { e.half = true; }), nofile, false, C::atlas,
       "channel 'A' has pixel type HALF, the manifest says FLOAT"},
      {"exr_rle", exr([](ExrOptions& e) { e.compression = "rle"; }), nofile, false, C::atlas,
       "compression RLE is not allowed (ZIP or PIZ only)"},
      {"exr_uncompressed", exr([](ExrOptions& e) { e.compression = "none"; }), nofile, false, C::atlas,
       "compression NO is not allowed"},
      {"exr_piz_manifest_zip", exr([](ExrOptions& e) { e.compression = "piz"; }),
       manifest([](json& m) { m["files"]["atlas"]["compression"] = "zip"; }), false, C::atlas,
       "compression is PIZ, the manifest says ZIP"},
      {"exr_data_window_offset", exr([](ExrOptions& e) { e.data_offset_x = 1; }), nofile, false, C::atlas,
       "data window starts at (1, 0), not at (0, 0)"},
      {"exr_size_vs_manifest", none,
       manifest([](json& m) {
         m["atlas"]["height"] = 65;
         m["files"]["atlas"]["height"] = 65;
       }),
       false, C::atlas, "image is 96x64, the manifest says 96x65"},
      {"exr_tiled", exr([](ExrOptions& e) { e.tiled = true; }), nofile, false, C::atlas, "not a scanline image"},
      {"texel_nan_under_triangle", content([](BundleContent& b) { texel(b, 10, 10)[0] = kNaN; }), nofile, false, C::atlas,
       "read non-finite texels"},
      {"texel_inf_in_gutter", content([](BundleContent& b) { texel(b, 5, 5)[2] = std::numeric_limits<float>::infinity(); }),
       nofile, false, C::atlas, "read non-finite texels"},
      {"texel_nan_far_away", content([](BundleContent& b) { texel(b, 31, 0)[1] = kNaN; }), nofile, false, C::atlas,
       "1 non-finite texel outside every UV triangle's footprint (first: texel (31, 0))"},
      {"alpha_half", content([](BundleContent& b) { texel(b, 12, 12)[3] = 0.5f; }), nofile, false, C::atlas,
       "1 texel with coverage A other than 0 or 1 (first: texel (12, 12) has A = 0.5)"},
      {"chart_not_filled",
       content([](BundleContent& b) {
         for (int j = 2; j < 30; ++j)
           for (int i = 2; i < 30; ++i) texel(b, i, j)[3] = 0.0f;  // chart 0 loses its coverage
       }),
       nofile, false, C::atlas, "neither covered nor within the gutter (4) of a covered texel"},
      // The gutter distance (Chebyshev, manifest atlas.gutter): without coverage in
      // chart 0's first column (or row), the texels just outside it that lookups
      // read are 2 texels from the nearest covered one: unfilled for gutter 1,
      // filled for gutter 2 (then the coverage check catches the hole).
      {"gutter_1_column_gap",
       content([](BundleContent& b) {
         b.manifest["atlas"]["gutter"] = 1;
         for (int j = 6; j < 26; ++j) texel(b, 6, j)[3] = 0.0f;
       }),
       nofile, false, C::atlas, "neither covered nor within the gutter (1) of a covered texel"},
      {"gutter_1_row_gap",
       content([](BundleContent& b) {
         b.manifest["atlas"]["gutter"] = 1;
         for (int i = 6; i < 26; ++i) texel(b, i, 25)[3] = 0.0f;
       }),
       nofile, false, C::atlas, "neither covered nor within the gutter (1) of a covered texel"},
      {"gutter_2_column_gap",
       content([](BundleContent& b) {
         b.manifest["atlas"]["gutter"] = 2;
         for (int j = 6; j < 26; ++j) texel(b, 6, j)[3] = 0.0f;
       }),
       nofile, false, C::atlas, "texel (6, 6) has its centre inside the UV triangle"},
      {"alpha_hole_inside_triangle", content([](BundleContent& b) { texel(b, 15, 15)[3] = 0.0f; }), nofile, false, C::atlas,
       "texel (15, 15) has its centre inside the UV triangle"},
      {"alpha_outside_triangles", content([](BundleContent& b) { texel(b, 26, 15)[3] = 1.0f; }), nofile, false, C::atlas,
       "texel (26, 15) has coverage A = 1 but its centre lies in no UV triangle"},
      // ---- pieces
      {"pieces_count_vs_manifest", none, manifest([](json& m) { m["pieces"]["count"] = 3; }), false, C::pieces,
       "2 pieces, the manifest says 3"},
      {"pieces_header", none,
       [](const std::string& d) { replace_text(d + "/pieces.ply", "property uint piece\nelement face", "element face"); }, true,
       C::pieces, "PLY header has 12 lines, the spec's header has 13"},
      {"pieces_truncated", none,
       [](const std::string& d) {
         std::string b = read_bytes(d + "/pieces.ply");
         write_bytes(d + "/pieces.ply", b.substr(0, b.size() - 30));
       },
       true, C::pieces, "file is truncated in the coarse_faces list of piece 1"},
      {"pieces_truncated_fixed_part", none,
       [](const std::string& d) {
         std::string b = read_bytes(d + "/pieces.ply");
         write_bytes(d + "/pieces.ply", b.substr(0, body_offset(b) + 100));
       },
       true, C::pieces, "file is truncated ("},
      {"pieces_trailing", none, [](const std::string& d) { write_bytes(d + "/pieces.ply", read_bytes(d + "/pieces.ply") + "abc"); },
       true, C::pieces, "3 bytes after the last element"},
      {"pieces_huge_list", none, [](const std::string& d) { patch_u32(d + "/pieces.ply", piece_list_offset(d), 0xffffffffu); }, true,
       C::pieces, "file is truncated in the coarse_faces list of piece 0 (4294967295 entries)"},
      // ---- pieces.ply of format 1.3: the map in the fixed-size elements `piece`
      // (counts) and `piece_coarse_face` (rows); the layout follows the version
      {"v13_pieces_of_1_2_layout", none, manifest([](json& m) { m["format_version"] = "1.3"; }), false, C::pieces,
       "pieces.ply: the piece -> coarse-triangle map is in the layout of format 1.0-1.2 (one coarse_faces list per piece), "
       "but the manifest's format_version is 1.3 or later"},
      {"v12_pieces_of_1_3_layout", v13, manifest([](json& m) { m["format_version"] = "1.2"; }), false, C::pieces,
       "pieces.ply: the piece -> coarse-triangle map is in the layout of format 1.3 (elements piece and piece_coarse_face), "
       "but the manifest's format_version is below 1.3"},
      {"v13_pieces_header", v13,
       [](const std::string& d) { replace_text(d + "/pieces.ply", "element piece_coarse_face 20\n", "element piece_coarse_face x\n"); },
       true, C::pieces, "PLY header line 14 is 'element piece_coarse_face x', expected 'element piece_coarse_face K'"},
      {"v13_pieces_truncated", v13,
       [](const std::string& d) {
         std::string b = read_bytes(d + "/pieces.ply");
         write_bytes(d + "/pieces.ply", b.substr(0, b.size() - 4));
       },
       true, C::pieces, "the header's 16 vertices, 24 faces, 2 pieces and 20 coarse-face rows need 1"},
      {"v13_pieces_trailing", v13, [](const std::string& d) { write_bytes(d + "/pieces.ply", read_bytes(d + "/pieces.ply") + "abc"); },
       true, C::pieces, "(trailing bytes)"},
      {"v13_pieces_huge_row_count", v13,
       [](const std::string& d) {
         replace_text(d + "/pieces.ply", "element piece_coarse_face 20\n", "element piece_coarse_face 4294967295\n");
       },
       true, C::pieces, "2 pieces and 4294967295 coarse-face rows need"},
      {"v13_pieces_counts_disagree", v13, [](const std::string& d) { patch_u32(d + "/pieces.ply", piece_list_offset(d), 11); }, true,
       C::pieces, "the pieces' coarse_face_count add up to 21, the piece_coarse_face element has 20 rows"},
      {"v13_map_out_of_range", [](BundleContent& b, ExrOptions&) {
         b.manifest["format_version"] = "1.3";
         b.piece_map[1].push_back(12);
       }, nofile, false, C::pieces, "piece 1 maps to coarse triangle 12, out of range (coarse triangle count 12)"},
      {"v13_map_unsorted", [](BundleContent& b, ExrOptions&) {
         b.manifest["format_version"] = "1.3";
         std::swap(b.piece_map[0][2], b.piece_map[0][3]);
       }, nofile, false, C::pieces, "coarse_faces of piece 0 are not ascending and unique"},
      {"piece_id_out_of_range", none, [](const std::string& d) { patch_u32(d + "/pieces.ply", piece_vertex_offset(d, 15) + 12, 7); },
       true, C::pieces, "vertex 15 has piece id 7 (pieces are 0..1)"},
      {"pieces_out_of_order", none, [](const std::string& d) { patch_u32(d + "/pieces.ply", piece_vertex_offset(d, 0) + 12, 1); },
       true, C::pieces, "vertices are not stored piece by piece (vertex 1 has piece 0 after piece 1)"},
      {"piece_face_index_out_of_range", content([](BundleContent& b) { b.piece_faces[1][4][2] = 100; }), nofile, false, C::pieces,
       "1 face with a vertex index out of range (vertex count 16): face 16"},
      {"piece_face_uses_other_piece", content([](BundleContent& b) { b.piece_faces[0][0][0] = 9; }), nofile, false, C::pieces,
       "1 face using vertices of another piece: face 0 (piece 0) uses vertices of pieces [0, 1]"},
      {"piece_vertex_nan", content([](BundleContent& b) { b.piece_vertices[1][3][2] = kNaN; }), nofile, false, C::pieces,
       "1 vertex with non-finite positions (first: vertex 11)"},
      {"map_out_of_range", content([](BundleContent& b) { b.piece_map[1].push_back(12); }), nofile, false, C::pieces,
       "piece 1 maps to coarse triangle 12, out of range (coarse triangle count 12)"},
      {"map_unsorted", content([](BundleContent& b) { std::swap(b.piece_map[0][2], b.piece_map[0][3]); }), nofile, false, C::pieces,
       "coarse_faces of piece 0 are not ascending and unique"},
      {"map_duplicate", content([](BundleContent& b) { b.piece_map[1][1] = b.piece_map[1][0]; }), nofile, false, C::pieces,
       "coarse_faces of piece 1 are not ascending and unique"},
      {"piece_too_small",
       content([](BundleContent& b) {
         b.piece_vertices[0] = {{0, 0, 0}, {0.01f, 0, 0}, {0, 0.01f, 0}};
         b.piece_faces[0] = {{0, 1, 2}, {0, 2, 1}};
       }),
       nofile, false, C::pieces, "1 piece with fewer than 4 vertices or 4 faces: piece 0 has 3 vertices, 2 faces"},
      {"piece_open", content([](BundleContent& b) { b.piece_faces[0].pop_back(); }), nofile, false, C::pieces,
       "1 piece not a closed, consistently wound polyhedron: piece 0"},
      {"piece_one_face_flipped", content([](BundleContent& b) { std::swap(b.piece_faces[1][3][1], b.piece_faces[1][3][2]); }), nofile,
       false, C::pieces, "not a closed, consistently wound polyhedron: piece 1"},
      {"piece_inward",
       content([](BundleContent& b) {
         for (auto& f : b.piece_faces[1]) std::swap(f[1], f[2]);
       }),
       nofile, false, C::pieces, "1 piece wound inward (negative volume): piece 1"},
      {"piece_zero_area_face",
       content([](BundleContent& b) {
         // Collapse vertex 7 onto vertex 6 (both on the +z side): the faces using both become slivers.
         b.piece_vertices[0][7] = b.piece_vertices[0][6];
       }),
       nofile, false, C::pieces, "piece with a zero-area face: piece 0"},
      {"piece_not_convex",
       content([](BundleContent& b) {
         // Push corner 7 of piece 0 halfway towards the piece centre: a dent.
         auto& p = b.piece_vertices[0];
         float c[3] = {0, 0, 0};
         for (const auto& q : p)
           for (int k = 0; k < 3; ++k) c[k] += q[k] / 8;
         for (int k = 0; k < 3; ++k) p[7][k] = 0.5f * (p[7][k] + c[k]);
       }),
       nofile, false, C::pieces, "1 piece not convex (tolerance"},
  };
  return v;
}

// gtest prints parameters on failure: the case name, not its bytes.
void PrintTo(const Case& c, std::ostream* os) { *os << c.name; }

class Corruption : public ::testing::TestWithParam<Case> {};

TEST_P(Corruption, IsRejectedWithItsClassAndMessage) {
  const Case& c = GetParam();
  const std::string dir = fresh_dir("corrupt_" + c.name);
  BundleContent b = make_cube();
  ExrOptions e;
  c.before(b, e);
  write_bundle(dir, b, e);
  c.after(dir);
  if (c.rehash) rehash(dir);
  // Cross-check hook: HRT_IO_EXPORT_CASES=DIR keeps a copy of every variant and
  // a line {name, class, fragment} in DIR/index.jsonl, so `hbake validate` can
  // be run on the same bundles (see /work/notes/readme_runtime_io.md).
  if (const char* keep = std::getenv("HRT_IO_EXPORT_CASES")) {
    copy_dir(dir, std::string(keep) + "/" + c.name + ".hbundle");
    const json line = {{"name", c.name}, {"class", hrt::to_string(c.cls)}, {"fragment", c.fragment}};
    std::ofstream(std::string(keep) + "/index.jsonl", std::ios::app) << line.dump() << "\n";
  }
  try {
    hrt::load_bundle(dir);
    ADD_FAILURE() << c.name << ": loaded, expected a " << hrt::to_string(c.cls) << " error containing '" << c.fragment
                  << "'";
  } catch (const BundleError& err) {
    EXPECT_EQ(hrt::to_string(err.error_class()), std::string(hrt::to_string(c.cls))) << err.what();
    EXPECT_NE(std::string(err.what()).find(c.fragment), std::string::npos)
        << "message: " << err.what() << "\nexpected fragment: " << c.fragment;
    EXPECT_EQ(std::string(err.what()).find('\n'), std::string::npos) << "one line: " << err.what();
  }
  remove_tree(dir);
}

INSTANTIATE_TEST_SUITE_P(Io, Corruption, ::testing::ValuesIn(cases()),
                         [](const ::testing::TestParamInfo<Case>& info) { return info.param.name; });

TEST(IoCorruption, MissingOrNonDirectoryBundle) {
  const std::string dir = fresh_dir("missing_bundle");
  remove_tree(dir);
  try {
    hrt::load_bundle(dir);
    ADD_FAILURE() << "loaded a missing bundle";
  } catch (const BundleError& e) {
    EXPECT_EQ(e.error_class(), BundleErrorClass::io);
    EXPECT_NE(std::string(e.what()).find("bundle directory does not exist"), std::string::npos) << e.what();
  }
  write_bytes(dir, "a file");
  try {
    hrt::load_bundle(dir);
    ADD_FAILURE() << "loaded a file as a bundle";
  } catch (const BundleError& e) {
    EXPECT_EQ(e.error_class(), BundleErrorClass::io);
    EXPECT_NE(std::string(e.what()).find("not a directory"), std::string::npos) << e.what();
  }
  remove_tree(dir);
}

TEST(IoCorruption, InvariantChecksCanBeSkippedButIndexChecksCannot) {
  const std::string dir = fresh_dir("invariants_off");
  BundleContent b = make_cube();
  b.uvs[7][3] = 1.25f;         // a value check
  texel(b, 12, 12)[3] = 0.5f;  // a value check
  write_bundle(dir, b);
  hrt::LoadOptions off;
  off.check_invariants = false;
  EXPECT_NO_THROW(hrt::load_bundle(dir, off));
  EXPECT_THROW(hrt::load_bundle(dir), BundleError);
  b = make_cube();
  b.piece_map[0].push_back(40);  // an index check: always on
  write_bundle(dir, b);
  EXPECT_THROW(hrt::load_bundle(dir, off), BundleError);
  remove_tree(dir);
}

}  // namespace
