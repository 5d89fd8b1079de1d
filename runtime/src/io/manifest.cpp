// Field-by-field check of manifest.json (docs/bundle-format.md, "manifest.json").
//
// The JSON Schema hbake/schema/manifest.schema.json (draft 2020-12) is the
// machine-readable form of these rules and `hbake validate` applies it with
// python-jsonschema. No JSON Schema validator is packaged for C++ in Debian 12,
// so the same rules are written out here, and the messages use jsonschema's
// wording ("<path>: 'x' is a required property", "... is not of type
// 'integer'", ...) so that one message fragment identifies a problem in both
// readers. Everything the schema requires is checked, plus: finite numbers
// (nlohmann-json refuses NaN/Infinity and overflowing numbers anyway), file
// names without "..", distinct file names, atlas sides <= 65536 (the atlas
// limit proper, 8192 and 2^24 texels, is class `atlas`: bundle.cpp), a
// format_version of at most 32 characters.
//
// Nothing here recurses on the input: the parser bounds the nesting depth
// (bundle.cpp) and py_repr stops at a fixed depth, so a hostile manifest
// cannot overflow the stack (once a 26.5k-digit format_version did, in
// std::regex_match, and a 35k-deep value of the wrong type in py_repr).
#include <cmath>
#include <functional>
#include <limits>

#include "io/bundle_io.h"

namespace hrt::io {
namespace {

using nlohmann::json;

constexpr uint64_t kMaxSchemaAtlasSide = 65536;  // keeps the sides within int

// format_version: "MAJOR.MINOR", each a run of decimal digits; longer strings
// are refused (Python's reader has no bound, but no real version needs more).
constexpr size_t kMaxVersionChars = 32;

// Nested values deeper than this are shown as [...] or {...} in messages.
constexpr int kReprDepth = 8;

// Python's repr() of a JSON value, as jsonschema's messages print it (short).
std::string py_repr(const json& v, int depth = 0) {
  std::string out;
  if (v.is_string()) {
    const std::string s = v.get<std::string>();
    const char q = (s.find('\'') != std::string::npos && s.find('"') == std::string::npos) ? '"' : '\'';
    out = q + s + q;
  } else if (v.is_boolean()) {
    out = v.get<bool>() ? "True" : "False";
  } else if (v.is_null()) {
    out = "None";
  } else if (v.is_array()) {
    if (depth >= kReprDepth) return "[...]";
    out = "[";
    for (size_t i = 0; i < v.size() && out.size() < 80; ++i) out += (i ? ", " : "") + py_repr(v[i], depth + 1);
    out += "]";
  } else if (v.is_object()) {
    if (depth >= kReprDepth) return "{...}";
    out = "{";
    bool first = true;
    for (auto it = v.begin(); it != v.end() && out.size() < 80; ++it) {
      out += (first ? "'" : ", '") + it.key() + "': " + py_repr(it.value(), depth + 1);
      first = false;
    }
    out += "}";
  } else {
    out = v.dump();
  }
  for (char& c : out)
    if (static_cast<unsigned char>(c) < 0x20) c = '?';
  if (out.size() > 80) out = out.substr(0, 77) + "...";
  return out;
}

// A schema bound as jsonschema prints it (the schema writes 0 and 1, not 0.0).
std::string num_str(double x) {
  if (std::floor(x) == x && std::fabs(x) < 1e15) return std::to_string(static_cast<long long>(x));
  return json(x).dump();
}

class Checker {
 public:
  explicit Checker(const std::string& label) : label_(label) {}

  [[noreturn]] void fail(BundleErrorClass cls, const std::string& what) const {
    throw BundleError(cls, label_ + ": " + what);
  }
  // "manifest.json: <path>: <message>", path as jsonschema's absolute_path.
  [[noreturn]] void bad(const std::string& path, const std::string& msg) const {
    fail(BundleErrorClass::schema, (path.empty() ? std::string("(top level)") : path) + ": " + msg);
  }
  static std::string join(const std::string& path, const std::string& key) {
    return path.empty() ? key : path + "/" + key;
  }

  const json& field(const json& obj, const std::string& path, const char* key) const {
    auto it = obj.find(key);
    if (it == obj.end()) bad(path, std::string("'") + key + "' is a required property");
    return *it;
  }
  void type(const json& v, const std::string& path, const char* name) const {
    const std::string t = name;
    bool ok = false;
    if (t == "object")
      ok = v.is_object();
    else if (t == "string")
      ok = v.is_string();
    else if (t == "boolean")
      ok = v.is_boolean();
    else if (t == "array")
      ok = v.is_array();
    else if (t == "number")
      ok = v.is_number();
    else if (t == "integer")
      ok = v.is_number_integer() || (v.is_number_float() && std::floor(v.get<double>()) == v.get<double>());
    if (!ok) bad(path, py_repr(v) + " is not of type '" + t + "'");
  }
  const json& object(const json& obj, const std::string& path, const char* key) const {
    const json& v = field(obj, path, key);
    type(v, join(path, key), "object");
    return v;
  }
  std::string string(const json& obj, const std::string& path, const char* key, bool non_empty = false) const {
    const json& v = field(obj, path, key);
    type(v, join(path, key), "string");
    if (non_empty && v.get<std::string>().empty()) bad(join(path, key), "'' should be non-empty");
    return v.get<std::string>();
  }
  void constant(const json& obj, const std::string& path, const char* key, const char* want) const {
    const json& v = field(obj, path, key);
    if (!(v.is_string() && v.get<std::string>() == want))
      bad(join(path, key), std::string("'") + want + "' was expected");
  }
  std::string one_of(const json& obj, const std::string& path, const char* key,
                     const std::vector<std::string>& allowed) const {
    const json& v = field(obj, path, key);
    if (v.is_string()) {
      for (const auto& a : allowed)
        if (v.get<std::string>() == a) return a;
    }
    std::string list;
    for (const auto& a : allowed) list += (list.empty() ? "'" : ", '") + a + "'";
    bad(join(path, key), py_repr(v) + " is not one of [" + list + "]");
  }
  bool boolean(const json& obj, const std::string& path, const char* key) const {
    const json& v = field(obj, path, key);
    type(v, join(path, key), "boolean");
    return v.get<bool>();
  }
  // A finite number >= lo (> lo when exclusive).
  double number_value(const json& v, const std::string& path, double lo = -HUGE_VAL, bool exclusive = false,
                      double hi = HUGE_VAL) const {
    type(v, path, "number");
    const double d = v.get<double>();
    if (!std::isfinite(d)) bad(path, py_repr(v) + " is not a finite number");
    if (exclusive && d <= lo) bad(path, py_repr(v) + " is less than or equal to the minimum of " + num_str(lo));
    if (!exclusive && d < lo) bad(path, py_repr(v) + " is less than the minimum of " + num_str(lo));
    if (d > hi) bad(path, py_repr(v) + " is greater than the maximum of " + num_str(hi));
    return d;
  }
  double number(const json& obj, const std::string& path, const char* key, double lo = -HUGE_VAL,
                bool exclusive = false, double hi = HUGE_VAL) const {
    return number_value(field(obj, path, key), join(path, key), lo, exclusive, hi);
  }
  // An integer in [lo, hi] (JSON Schema's "integer" admits 2.0).
  int64_t integer(const json& obj, const std::string& path, const char* key, int64_t lo = INT64_MIN,
                  int64_t hi = INT64_MAX) const {
    const json& v = field(obj, path, key);
    const std::string p = join(path, key);
    type(v, p, "integer");
    int64_t n;
    if (v.is_number_unsigned()) {
      const uint64_t u = v.get<uint64_t>();
      if (u > static_cast<uint64_t>(INT64_MAX))
        bad(p, py_repr(v) + " is greater than the maximum of " + std::to_string(hi));
      n = static_cast<int64_t>(u);
    } else if (v.is_number_integer()) {
      n = v.get<int64_t>();
    } else {
      const double d = v.get<double>();
      if (!(std::fabs(d) < 9.0e18)) bad(p, py_repr(v) + " is out of range");
      n = static_cast<int64_t>(d);
    }
    if (n < lo) bad(p, py_repr(v) + " is less than the minimum of " + std::to_string(lo));
    if (n > hi) bad(p, py_repr(v) + " is greater than the maximum of " + std::to_string(hi));
    return n;
  }
  uint64_t count(const json& obj, const std::string& path, const char* key, int64_t lo = 0,
                 int64_t hi = INT64_MAX) const {
    return static_cast<uint64_t>(integer(obj, path, key, lo, hi));
  }
  Vec3 vec3_value(const json& v, const std::string& p) const {
    type(v, p, "array");
    if (v.size() < 3) bad(p, py_repr(v) + " is too short");
    if (v.size() > 3) bad(p, py_repr(v) + " is too long");
    Vec3 out;
    for (int i = 0; i < 3; ++i) out[i] = number_value(v[i], p + "/" + std::to_string(i));
    return out;
  }
  Vec3 vec3(const json& obj, const std::string& path, const char* key) const {
    return vec3_value(field(obj, path, key), join(path, key));
  }
  Mat3 mat3(const json& obj, const std::string& path, const char* key) const {
    const json& v = field(obj, path, key);
    const std::string p = join(path, key);
    type(v, p, "array");
    if (v.size() < 3) bad(p, py_repr(v) + " is too short");
    if (v.size() > 3) bad(p, py_repr(v) + " is too long");
    Mat3 out;
    for (int i = 0; i < 3; ++i) out.row(i) = vec3_value(v[i], p + "/" + std::to_string(i)).transpose();
    return out;
  }
  std::string sha256(const json& obj, const std::string& path, const char* key) const {
    const json& v = field(obj, path, key);
    const std::string p = join(path, key);
    type(v, p, "string");
    const std::string s = v.get<std::string>();
    bool ok = s.size() == 64;
    for (char c : s) ok = ok && ((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'));
    if (!ok) bad(p, py_repr(v) + " does not match '^[0-9a-f]{64}$'");
    return s;
  }
  // A file name: no '/' or '\' (the schema's pattern), not "." or "..", and
  // (stricter than the schema) no ".." anywhere.
  std::string file_name(const json& obj, const std::string& path, const char* key) const {
    const std::string s = string(obj, path, key, true);
    const std::string p = join(path, key);
    if (s.find('/') != std::string::npos || s.find('\\') != std::string::npos) {
      bad(p, py_repr(obj.at(key)) + " does not match '^[^/\\\\\\\\]+$'");
    }
    if (s == "." || s == "..") bad(p, py_repr(obj.at(key)) + " should not be valid under {'enum': ['.', '..']}");
    if (s.find("..") != std::string::npos || s.find('\0') != std::string::npos) {
      bad(p, py_repr(obj.at(key)) + " contains '..' (a file name inside the bundle is required)");
    }
    return s;
  }

 private:
  const std::string& label_;
};

}  // namespace

namespace {

// Identity and version first (class `version`): a bundle of another major
// version may have another schema, whose errors would hide the real problem.
// Returns the version (MAJOR.MINOR, major 1).
std::string check_version(const Checker& c, const json& m) {
  auto fmt = m.find("format");
  if (fmt == m.end() || !fmt->is_string() || fmt->get<std::string>() != "hbundle") {
    c.fail(BundleErrorClass::version,
           "format is " + (fmt == m.end() ? std::string("None") : py_repr(*fmt)) + ", not 'hbundle' (not an hbundle)");
  }
  auto fv = m.find("format_version");
  const std::string version = (fv != m.end() && fv->is_string()) ? fv->get<std::string>() : std::string();
  // MAJOR.MINOR by hand (linear, bounded; std::regex recursed per character).
  const size_t dot = version.find('.');
  bool well_formed = fv != m.end() && fv->is_string() && version.size() <= kMaxVersionChars &&
                     dot != std::string::npos && dot > 0 && dot + 1 < version.size();
  for (size_t i = 0; well_formed && i < version.size(); ++i)
    well_formed = i == dot || (version[i] >= '0' && version[i] <= '9');
  if (!well_formed) {
    c.fail(BundleErrorClass::version,
           "format_version " + (fv == m.end() ? std::string("None") : py_repr(*fv)) + " is not MAJOR.MINOR" +
               (version.size() > kMaxVersionChars ? " (at most " + std::to_string(kMaxVersionChars) + " characters)"
                                                  : std::string()));
  }
  // Compare the major number as a number ("01.0" is major 1, as in Python's int()).
  std::string major = version.substr(0, dot);
  major.erase(0, std::min(major.find_first_not_of('0'), major.size() - 1));
  if (major != "1") {
    c.fail(BundleErrorClass::version, "unsupported major version " + version + " (this reader supports 1.x)");
  }
  return version;
}

// files: the three files, and the atlas's EXR header.
void check_files(const Checker& c, const json& m, ManifestInfo& info) {
  const json& files = c.object(m, "", "files");
  auto file_entry = [&](const char* key, FileEntry& out) -> const json& {
    const std::string p = std::string("files/") + key;
    const json& f = c.object(files, "files", key);
    out.path = c.file_name(f, p, "path");
    out.sha256 = c.sha256(f, p, "sha256");
    out.bytes = c.count(f, p, "bytes");
    return f;
  };
  file_entry("coarse_mesh", info.coarse_mesh);
  const json& fatlas = file_entry("atlas", info.atlas);
  file_entry("pieces", info.pieces);
  if (info.atlas.path == info.coarse_mesh.path || info.pieces.path == info.coarse_mesh.path ||
      info.pieces.path == info.atlas.path || info.coarse_mesh.path == "manifest.json" ||
      info.atlas.path == "manifest.json" || info.pieces.path == "manifest.json") {
    c.bad("files", "two files have the same path (or one is manifest.json)");
  }
  info.atlas_spec.width = static_cast<int>(c.integer(fatlas, "files/atlas", "width", 1, kMaxSchemaAtlasSide));
  info.atlas_spec.height = static_cast<int>(c.integer(fatlas, "files/atlas", "height", 1, kMaxSchemaAtlasSide));
  {
    const json& ch = c.field(fatlas, "files/atlas", "channels");
    c.type(ch, "files/atlas/channels", "array");
    for (size_t i = 0; i < ch.size(); ++i) {
      c.type(ch[i], "files/atlas/channels/" + std::to_string(i), "string");
      if (ch[i].get<std::string>().empty())
        c.bad("files/atlas/channels/" + std::to_string(i), "'' should be non-empty");
      info.atlas_spec.channels.push_back(ch[i].get<std::string>());
    }
    std::vector<std::string> sorted = info.atlas_spec.channels;
    std::sort(sorted.begin(), sorted.end());
    if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end()) {
      c.bad("files/atlas/channels", py_repr(ch) + " has non-unique elements");
    }
    for (const char* need : {"R", "G", "B", "A"}) {
      if (!std::binary_search(sorted.begin(), sorted.end(), std::string(need))) {
        c.bad("files/atlas/channels",
              py_repr(ch) + " does not contain items matching the given schema (channel '" + need + "')");
      }
    }
  }
  c.constant(fatlas, "files/atlas", "pixel_type", "float");
  info.atlas_spec.compression = c.one_of(fatlas, "files/atlas", "compression", {"zip", "piz"});
}

// coarse, pieces, atlas, mass, quality.
void check_summaries(const Checker& c, const json& m, ManifestInfo& info) {
  const json& coarse = c.object(m, "", "coarse");
  info.coarse_vertices = c.count(coarse, "coarse", "vertices", 3);
  info.coarse_triangles = c.count(coarse, "coarse", "triangles", 1);
  c.vec3(coarse, "coarse", "bbox_min");
  c.vec3(coarse, "coarse", "bbox_max");
  c.number(coarse, "coarse", "area", 0.0);

  const json& pieces = c.object(m, "", "pieces");
  info.piece_count = c.count(pieces, "pieces", "count", 1);
  info.map_tolerance = c.number(pieces, "pieces", "map_tolerance", 0.0);

  const json& atlas = c.object(m, "", "atlas");
  info.atlas_width = c.count(atlas, "atlas", "width", 1, kMaxSchemaAtlasSide);
  info.atlas_height = c.count(atlas, "atlas", "height", 1, kMaxSchemaAtlasSide);
  info.gutter = static_cast<int>(c.count(atlas, "atlas", "gutter", 1, 1 << 20));
  info.quality.texel_size = c.number(atlas, "atlas", "texel_size", 0.0, true);
  info.coverage = c.number(atlas, "atlas", "coverage", 0.0, false, 1.0);

  const json& mass = c.object(m, "", "mass");
  info.mass.basis = c.one_of(mass, "mass", "basis", {"full", "coarse", "hull"});
  info.mass.density = c.number(mass, "mass", "density", 0.0, true);
  info.mass.volume = c.number(mass, "mass", "volume", 0.0);
  info.mass.center_of_mass = c.vec3(mass, "mass", "center_of_mass");
  info.mass.inertia = c.mat3(mass, "mass", "inertia");
  info.mass.closed = c.boolean(mass, "mass", "closed");

  const json& q = c.object(m, "", "quality");
  info.quality.displacement_outward = c.number(q, "quality", "displacement_outward", 0.0);
  info.quality.displacement_inward = c.number(q, "quality", "displacement_inward", 0.0);
  info.quality.hull_deviation = c.number(q, "quality", "hull_deviation", 0.0);
  c.number(q, "quality", "hull_volume_excess");
  info.quality.min_wavelength = c.number(q, "quality", "min_wavelength", 0.0);
  const json& rec = c.object(q, "quality", "reconstruction");
  for (const char* dir : {"coarse_to_full", "full_to_coarse"}) {
    const std::string p = std::string("quality/reconstruction/") + dir;
    const json& r = c.object(rec, "quality/reconstruction", dir);
    c.integer(r, p, "samples", 1);
    for (const char* k : {"mean", "p95", "max", "mean_rel", "p95_rel", "max_rel"}) c.number(r, p, k, 0.0);
  }
  info.quality.bbox_diagonal = c.number(q, "quality", "bbox_diagonal", 0.0, true);
}

}  // namespace

ManifestInfo check_manifest(const json& m, const std::string& label) {
  Checker c(label);
  ManifestInfo info;
  if (!m.is_object()) {
    c.fail(BundleErrorClass::schema, std::string("top level is ") +
                                         (m.is_array() ? "an array" : std::string("a ") + m.type_name()) +
                                         ", not an object");
  }

  info.format_version = check_version(c, m);

  // Every required field of the schema with its type (class `schema`), in the
  // schema's order.
  for (const char* key : {"format", "format_version", "generator", "units", "source", "method", "settings", "seeds",
                          "libraries", "files", "coarse", "pieces", "atlas", "mass", "quality", "warnings"}) {
    c.field(m, "", key);
  }
  const json& gen = c.object(m, "", "generator");
  c.constant(gen, "generator", "name", "hbake");
  c.string(gen, "generator", "version", true);

  const json& units = c.object(m, "", "units");
  c.constant(units, "units", "length", "m");
  c.one_of(units, "units", "source_unit", {"mm", "cm", "m", "in", "unknown"});
  c.number(units, "units", "scale_to_meters", 0.0, true);

  const json& source = c.object(m, "", "source");
  info.source_name = c.file_name(source, "source", "name");
  c.sha256(source, "source", "sha256");
  c.count(source, "source", "vertices");
  c.count(source, "source", "triangles");
  c.count(source, "source", "bodies");
  c.boolean(source, "source", "closed");

  c.one_of(m, "", "method", {"cage", "pp"});
  c.object(m, "", "settings");
  const json& seeds = c.object(m, "", "seeds");
  c.integer(seeds, "seeds", "coacd");
  c.integer(seeds, "seeds", "quality");
  const json& libs = c.object(m, "", "libraries");
  for (auto it = libs.begin(); it != libs.end(); ++it) c.type(it.value(), "libraries/" + it.key(), "string");

  check_files(c, m, info);
  check_summaries(c, m, info);

  const json& warnings = c.field(m, "", "warnings");
  c.type(warnings, "warnings", "array");
  for (size_t i = 0; i < warnings.size(); ++i) c.type(warnings[i], "warnings/" + std::to_string(i), "string");
  return info;
}

}  // namespace hrt::io
