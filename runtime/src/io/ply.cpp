// Strict readers of the two PLY files of a bundle (docs/bundle-format.md).
//
// Why hand-written: the spec fixes the header of each file exactly (binary
// little-endian, fixed element and property order), so a reader of exactly
// those headers is a few dozen lines and rejects anything else with a precise
// message; Debian 12 packages no C++ PLY library, and a general PLY reader
// would accept (and silently reorder or convert) files the spec forbids.
//
// Every count read from the file is checked against the bytes that are left
// before anything is allocated, so a corrupted count cannot trigger a huge
// allocation or a read past the end; the file length must match exactly.
#include <algorithm>
#include <cstring>
#include <limits>
#include <string_view>

#include "io/bundle_io.h"

namespace hrt::io {
namespace {

// Header lines longer than this, or a header without end_header in this many
// bytes, are rejected (the spec's headers are about 300 bytes).
constexpr size_t kMaxHeaderBytes = 4096;

[[noreturn]] void fail(BundleErrorClass cls, const std::string& label, const std::string& what) {
  throw BundleError(cls, label + ": " + what);
}

// Parses a decimal count: digits only, no sign, no leading zeros, fits uint32.
bool parse_count(const std::string& s, uint64_t& out) {
  if (s.empty() || s.size() > 10) return false;
  if (s.size() > 1 && s[0] == '0') return false;
  uint64_t v = 0;
  for (char c : s) {
    if (c < '0' || c > '9') return false;
    v = v * 10 + static_cast<uint64_t>(c - '0');
  }
  if (v > std::numeric_limits<uint32_t>::max()) return false;
  out = v;
  return true;
}

// Matches the header against `lines`, in which the token "#" stands for a
// count (returned in order in `counts`). A single "comment ..." line is allowed
// directly after the format line (the spec's optional comment). Returns the
// offset of the first body byte. Messages and line numbers (as in the file)
// are those of hbake.bundle's reader.
size_t read_header(const std::string& bytes, const std::vector<std::string>& lines, BundleErrorClass cls,
                   const std::string& label, std::vector<uint64_t>& counts) {
  if (bytes.compare(0, 4, "ply\n") != 0) fail(cls, label, "not a PLY file (the first line must be 'ply')");
  static const std::string kEnd = "end_header\n";
  const size_t end = std::string_view(bytes.data(), std::min(bytes.size(), kMaxHeaderBytes)).find(kEnd);
  if (end == std::string::npos || end + kEnd.size() > kMaxHeaderBytes) {
    fail(cls, label, "PLY header has no 'end_header' line within " + std::to_string(kMaxHeaderBytes) + " bytes");
  }
  const size_t body = end + kEnd.size();
  std::vector<std::string> got;
  for (size_t pos = 0; pos < body;) {
    const size_t nl = bytes.find('\n', pos);
    got.push_back(bytes.substr(pos, nl - pos));
    pos = nl + 1;
  }
  for (const std::string& line : got) {
    for (char c : line)
      if (static_cast<unsigned char>(c) >= 0x80) fail(cls, label, "PLY header is not ASCII");
  }
  const bool had_comment = got.size() >= 3 && got[2].rfind("comment ", 0) == 0;
  if (had_comment) got.erase(got.begin() + 2);
  if (got.size() != lines.size()) {
    fail(cls, label,
         "PLY header has " + std::to_string(got.size()) + " lines, the spec's header has " +
             std::to_string(lines.size()) + " (not counting the optional comment)");
  }
  auto printable = [](const std::string& s) {
    std::string out;
    for (char c : s) out += (c >= 0x20 && c < 0x7f) ? c : '?';
    return out.size() > 60 ? out.substr(0, 60) + "..." : out;
  };
  static const char* kCountNames[] = {"N", "M", "P", "K"};
  size_t nth = 0;
  for (size_t k = 0; k < lines.size(); ++k) {
    const std::string& want = lines[k];
    const std::string& line = got[k];
    const size_t hash = want.find('#');
    bool ok;
    if (hash == std::string::npos) {
      ok = line == want;
    } else {
      const std::string prefix = want.substr(0, hash);
      uint64_t n = 0;
      ok = line.size() > prefix.size() && line.compare(0, prefix.size(), prefix) == 0 &&
           parse_count(line.substr(prefix.size()), n);
      if (ok) counts.push_back(n);
    }
    if (!ok) {
      std::string shown = want;
      if (hash != std::string::npos) shown.replace(hash, 1, kCountNames[std::min<size_t>(nth, 3)]);
      const size_t line_no = k + 1 + (had_comment && k >= 2 ? 1 : 0);  // as in the file
      fail(cls, label,
           "PLY header line " + std::to_string(line_no) + " is '" + printable(line) + "', expected '" + shown + "'");
    }
    if (hash != std::string::npos) ++nth;
  }
  return body;
}

// Little-endian cursor over the body (portable: bytes assembled by shifts).
// Reads are not checked here: the callers check the bytes left first.
class Cursor {
 public:
  Cursor(const std::string& bytes, size_t pos)
      : p_(reinterpret_cast<const unsigned char*>(bytes.data())), pos_(pos), size_(bytes.size()) {}
  size_t left() const { return size_ - pos_; }
  uint8_t u8() { return p_[pos_++]; }
  uint32_t u32() {
    const uint32_t v = static_cast<uint32_t>(p_[pos_]) | static_cast<uint32_t>(p_[pos_ + 1]) << 8 |
                       static_cast<uint32_t>(p_[pos_ + 2]) << 16 | static_cast<uint32_t>(p_[pos_ + 3]) << 24;
    pos_ += 4;
    return v;
  }
  float f32() {
    const uint32_t bits = u32();
    float f;
    std::memcpy(&f, &bits, 4);
    return f;
  }

 private:
  const unsigned char* p_;
  size_t pos_;
  size_t size_;
};

}  // namespace

CoarsePly parse_coarse_ply(const std::string& bytes, const std::string& label) {
  const BundleErrorClass cls = BundleErrorClass::mesh;
  static const std::vector<std::string> kHeader = {
      "ply",
      "format binary_little_endian 1.0",
      "element vertex #",
      "property float x",
      "property float y",
      "property float z",
      "element face #",
      "property list uchar uint vertex_indices",
      "property list uchar float texcoord",
      "end_header",
  };
  std::vector<uint64_t> counts;
  const size_t body = read_header(bytes, kHeader, cls, label, counts);
  const uint64_t n = counts[0], m = counts[1];
  constexpr uint64_t kVertexBytes = 12, kFaceBytes = 1 + 12 + 1 + 24;
  const uint64_t want = n * kVertexBytes + m * kFaceBytes;
  const uint64_t have = bytes.size() - body;
  if (have != want) {
    fail(cls, label,
         std::to_string(bytes.size()) + " bytes, the header's " + std::to_string(n) + " vertices and " +
             std::to_string(m) + " faces need " + std::to_string(body + want) +
             (have < want ? " (file is truncated)" : " (trailing bytes)"));
  }
  Cursor c(bytes, body);
  CoarsePly out;
  out.vertices.resize(n);
  for (auto& v : out.vertices) {
    v[0] = c.f32();
    v[1] = c.f32();
    v[2] = c.f32();
  }
  out.faces.resize(m);
  out.uvs.resize(m);
  uint64_t bad = 0, first = 0;
  unsigned first_k = 0, first_t = 0;
  for (uint64_t f = 0; f < m; ++f) {
    const unsigned k = c.u8();
    for (int i = 0; i < 3; ++i) out.faces[f][i] = c.u32();
    const unsigned t = c.u8();
    for (int i = 0; i < 6; ++i) out.uvs[f][i] = c.f32();
    if ((k != 3 || t != 6) && bad++ == 0) first = f, first_k = k, first_t = t;
  }
  if (bad) {
    fail(cls, label,
         std::to_string(bad) + (bad == 1 ? " face record" : " face records") +
             " not '3 indices, 6 texcoords' (first: face " + std::to_string(first) + " has " + std::to_string(first_k) +
             " indices, " + std::to_string(first_t) + " texcoords)");
  }
  return out;
}

bool pieces_layout_is_table(const std::string& format_version) {
  const size_t dot = format_version.find('.');
  if (dot == std::string::npos) return true;
  const std::string minor = format_version.substr(dot + 1);
  if (minor.empty() || minor.find_first_not_of("0123456789") != std::string::npos) return true;
  const size_t first = minor.find_first_not_of('0');
  if (first == std::string::npos) return false;  // minor 0
  const std::string digits = minor.substr(first);
  return digits.size() > 1 || digits[0] >= '3';  // compared as digits (a 30-digit minor is >= 3)
}

namespace {

// The vertex and face records shared by both layouts; `c` is at the first vertex.
void read_piece_records(Cursor& c, uint64_t n, uint64_t m, PiecesPly& out, const std::string& label) {
  out.vertices.resize(n);
  out.vertex_piece.resize(n);
  for (uint64_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) out.vertices[i][k] = c.f32();
    out.vertex_piece[i] = c.u32();
  }
  out.faces.resize(m);
  out.face_piece.resize(m);
  uint64_t bad = 0, first = 0;
  for (uint64_t f = 0; f < m; ++f) {
    const unsigned k = c.u8();
    for (int i = 0; i < 3; ++i) out.faces[f][i] = c.u32();
    out.face_piece[f] = c.u32();
    if (k != 3 && bad++ == 0) first = f;
  }
  if (bad) {
    fail(BundleErrorClass::pieces, label,
         std::to_string(bad) + (bad == 1 ? " face record" : " face records") + " without 3 indices (first: face " +
             std::to_string(first) + ")");
  }
}

// Format 1.3: per piece a uint32 count, then all map rows (uint32 coarse
// triangle ids), piece by piece. Every element has fixed-size records, so the
// file length is known from the header.
PiecesPly parse_pieces_table(const std::string& bytes, const std::string& label) {
  const BundleErrorClass cls = BundleErrorClass::pieces;
  static const std::vector<std::string> kHeader = {
      "ply",
      "format binary_little_endian 1.0",
      "element vertex #",
      "property float x",
      "property float y",
      "property float z",
      "property uint piece",
      "element face #",
      "property list uchar uint vertex_indices",
      "property uint piece",
      "element piece #",
      "property uint coarse_face_count",
      "element piece_coarse_face #",
      "property uint coarse_face",
      "end_header",
  };
  std::vector<uint64_t> counts;
  const size_t body = read_header(bytes, kHeader, cls, label, counts);
  const uint64_t n = counts[0], m = counts[1], p = counts[2], k = counts[3];
  constexpr uint64_t kVertexBytes = 16, kFaceBytes = 1 + 12 + 4;
  const uint64_t want = n * kVertexBytes + m * kFaceBytes + 4 * p + 4 * k;
  const uint64_t have = bytes.size() - body;
  if (have != want) {
    fail(cls, label,
         std::to_string(bytes.size()) + " bytes, the header's " + std::to_string(n) + " vertices, " +
             std::to_string(m) + " faces, " + std::to_string(p) + " pieces and " + std::to_string(k) +
             " coarse-face rows need " + std::to_string(body + want) +
             (have < want ? " (file is truncated)" : " (trailing bytes)"));
  }
  Cursor c(bytes, body);
  PiecesPly out;
  read_piece_records(c, n, m, out, label);
  std::vector<uint32_t> lens(p);
  uint64_t total = 0;
  for (auto& len : lens) total += (len = c.u32());
  if (total != k) {
    fail(cls, label,
         "the pieces' coarse_face_count add up to " + std::to_string(total) + ", the piece_coarse_face element has " +
             std::to_string(k) + " rows");
  }
  out.coarse_faces.resize(p);
  for (uint64_t q = 0; q < p; ++q) {
    auto& list = out.coarse_faces[q];
    list.resize(lens[q]);
    for (auto& x : list) x = c.u32();
  }
  return out;
}

}  // namespace

// The wording shared with hbake.bundle for a pieces.ply in the other layout.
const char* const kPiecesLayout13 =
    "the piece -> coarse-triangle map is in the layout of format 1.3 (elements piece and piece_coarse_face), "
    "but the manifest's format_version is below 1.3 (one coarse_faces list per piece)";
const char* const kPiecesLayout12 =
    "the piece -> coarse-triangle map is in the layout of format 1.0-1.2 (one coarse_faces list per piece), "
    "but the manifest's format_version is 1.3 or later (elements piece and piece_coarse_face)";

PiecesPly parse_pieces_ply(const std::string& bytes, const std::string& label, bool table_layout) {
  const std::string_view head(bytes.data(), std::min(bytes.size(), kMaxHeaderBytes));
  const size_t end = head.find("end_header\n");
  const std::string_view header = head.substr(0, end == std::string_view::npos ? head.size() : end);
  if (table_layout && header.find("\nproperty list uint uint coarse_faces\n") != std::string_view::npos)
    fail(BundleErrorClass::pieces, label, kPiecesLayout12);
  if (!table_layout && header.find("\nelement piece_coarse_face ") != std::string_view::npos)
    fail(BundleErrorClass::pieces, label, kPiecesLayout13);
  if (table_layout) return parse_pieces_table(bytes, label);
  // Format 1.0-1.2: the map as one variable-length list per piece.
  const BundleErrorClass cls = BundleErrorClass::pieces;
  static const std::vector<std::string> kHeader = {
      "ply",
      "format binary_little_endian 1.0",
      "element vertex #",
      "property float x",
      "property float y",
      "property float z",
      "property uint piece",
      "element face #",
      "property list uchar uint vertex_indices",
      "property uint piece",
      "element piece #",
      "property list uint uint coarse_faces",
      "end_header",
  };
  std::vector<uint64_t> counts;
  const size_t body = read_header(bytes, kHeader, cls, label, counts);
  const uint64_t n = counts[0], m = counts[1], p = counts[2];
  constexpr uint64_t kVertexBytes = 16, kFaceBytes = 1 + 12 + 4, kPieceMinBytes = 4;
  Cursor c(bytes, body);
  // Fixed-size part first, so the counts are bounded by the file before allocating.
  const uint64_t fixed = n * kVertexBytes + m * kFaceBytes + p * kPieceMinBytes;
  if (fixed > c.left()) {
    fail(cls, label,
         "file is truncated (" + std::to_string(bytes.size()) + " bytes; the header's " + std::to_string(n) +
             " vertices, " + std::to_string(m) + " faces and " + std::to_string(p) + " pieces need at least " +
             std::to_string(body + fixed) + ")");
  }
  PiecesPly out;
  read_piece_records(c, n, m, out, label);
  out.coarse_faces.resize(p);
  for (uint64_t q = 0; q < p; ++q) {
    if (c.left() < 4) fail(cls, label, "file is truncated in the coarse_faces list of piece " + std::to_string(q));
    const uint32_t len = c.u32();
    if (static_cast<uint64_t>(len) * 4 > c.left()) {
      fail(cls, label,
           "file is truncated in the coarse_faces list of piece " + std::to_string(q) + " (" + std::to_string(len) +
               " entries)");
    }
    auto& list = out.coarse_faces[q];
    list.resize(len);
    for (auto& x : list) x = c.u32();
  }
  if (c.left() != 0) fail(cls, label, std::to_string(c.left()) + " bytes after the last element");
  return out;
}

}  // namespace hrt::io
