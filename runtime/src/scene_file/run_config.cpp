// Scene files of `hrt run` (docs/scene-format.md): TOML read with toml++ and
// checked key by key into a RunConfig.
//
// The whole file is checked before anything runs, and the first problem is
// reported as "FILE: KEY: what is wrong (line L)": a session that starts
// with a typo silently defaulted (a stiffness, a device limit) would push a
// wrong force into someone's hand, so every key must be known, typed, finite
// and in range. toml++ is included in this file only (it is slow to compile).
#include <arpa/inet.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <toml++/toml.h>

#include "hrt/files.h"
#include "hrt/run_config.h"

namespace hrt {

// The message is one line of printable text whatever the file held: the
// values quoted in `what` are cut where they are inserted (quote_value()); this
// escapes what is left (a control byte in a key name, a parser's message).
SceneFileError::SceneFileError(const std::string& f, const std::string& k, const std::string& what)
    : std::runtime_error(printable(f, 240) + ": " + (k.empty() ? std::string() : printable(k, 120) + ": ") +
                         printable(what, 600)),
      file(f),
      key(k) {}

namespace {

namespace fs = std::filesystem;

// The positions a pose may have (as `hrt query --pose`): parts of at most
// metres; far beyond, the contact computations lose all precision.
constexpr double kMaxPosition = 1e4;
// A quaternion's norm must be within this of 1 before it is normalised, as
// for `hrt query --pose`: one far from 1 is most likely in w x y z order or
// not a rotation at all.
constexpr double kQuaternionTolerance = 1e-3;
// A string value of the file, quoted for a message: cut to 80 characters,
// control bytes escaped.
std::string quote_value(const std::string& v) { return "\"" + printable(v, 80) + "\""; }

// A key's accepted values, with the unit and the reason for the message.
struct Range {
  double lo, hi;
  const char* unit;
  const char* why;
};

// The ranges of docs/scene-format.md, grounded in what devices and the
// physics can use: a value outside is a mistake (a unit slip, a typo of the
// exponent), never a setting that does something useful. A stiffness of
// 1 N/m gives 1 mN at 1 mm; one of 1e308 makes the coupling and the
// contact meaningless.
const Range kDuration{1e-3, 86400.0, "s", "a session of at most a day"};
const Range kMaxStep{1e-4, 1.0, "s", ""};
const Range kContactStiffness{1.0, 1e7, "N/m", "1 N/m gives 1 mN at 1 mm; 1e7 N/m gives 10 N at 1 um"};
const Range kLinStep{0.0, 0.1, "m", "0: one grid texel"};
const Range kAngStep{0.0, 0.5, "rad", "0: the matching angle"};
const Range kMargin{0.0, 0.1, "m", ""};
const Range kFadeTime{1e-3, 10.0, "s", ""};
const Range kDensity{1.0, 1e5, "kg/m^3", "aerogel to well past osmium"};
const Range kGravity{0.0, 1000.0, "m/s^2", "the norm of the vector"};
const Range kCouplingK{1.0, 1e6, "N/m", ""};
const Range kCouplingB{0.0, 1e4, "N s/m", ""};
const Range kCouplingKAng{1e-3, 1e4, "N m/rad", ""};
const Range kCouplingBAng{0.0, 1e3, "N m s/rad", ""};
const Range kFriction{0.0, 10.0, "", "a coefficient of friction"};
const Range kScale{1e-3, 1e3, "", "scene displacement per device displacement"};
const Range kWorkspace{1e-3, 10.0, "m", "half extents of the handle's workspace"};
const Range kMaxForce{1e-3, 1000.0, "N", "haptic devices display mN to hundreds of N"};
const Range kMaxTorque{1e-4, 100.0, "N m", ""};
const Range kMaxStiffness{1.0, 1e6, "N/m", "1 mm must give at least 1 mN"};
const Range kMaxAngularStiffness{1e-3, 1e4, "N m/rad", "1 rad must give at least 1 mN m"};
const Range kDisplayRate{1.0, 1000.0, "Hz", ""};
const Range kPeriod{1e-4, 0.1, "s", "a device loop runs at 10 Hz to 10 kHz"};
const Range kWatchdog{1e-3, 10.0, "s", ""};
const Range kWatchdogRamp{1e-4, 1.0, "s", ""};
const Range kSoftStart{0.0, 60.0, "s", ""};
const Range kForceRate{1e-3, 1e7, "N/s", ""};
const Range kTorqueRate{1e-4, 1e6, "N m/s", ""};
const Range kTraceRate{0.0, 1e6, "Hz", "0: a row for every simulation frame"};
const Range kTraceMaxBytes{1e6, 1e12, "bytes", ""};

// Every table and its keys: the single list the unknown-key check and its
// suggestions use (docs/scene-format.md documents the same keys).
const std::map<std::string, std::vector<std::string>>& known_keys() {
  static const std::map<std::string, std::vector<std::string>> k = {
      {"run", {"duration", "lockstep", "sim_every", "max_step", "backend", "gl_search", "occlusion_steps", "threads"}},
      {"object", {"name", "bundle", "position", "orientation", "trajectory"}},
      {"force",
       {"stiffness", "resolution", "lin_step", "ang_step", "shortcut", "heights", "margin", "max_patches",
        "auto_resolution", "max_resolution", "fade_time"}},
      {"probe", {"density", "gravity"}},
      {"coupling", {"enabled", "k_lin", "b_lin", "k_ang", "b_ang"}},
      {"friction", {"enabled", "mu_static", "mu_dynamic"}},
      {"material", {"object", "stiffness", "mu_static", "mu_dynamic"}},
      {"workspace", {"scale", "offset_position", "offset_orientation", "grasp_position", "grasp_orientation"}},
      {"device",
       {"type",
        "trajectory",
        "trajectory_prefix",
        "name",
        "dof_actuated",
        "dof_sensed",
        "workspace",
        "max_force",
        "max_torque",
        "max_stiffness",
        "max_angular_stiffness",
        "bind",
        "port",
        "reply_address",
        "reply_port",
        "display_address",
        "display_port",
        "display_rate",
        "plugin",
        "config",
        "start_position",
        "start_orientation"}},
      {"loop",
       {"period", "watchdog", "watchdog_ramp", "soft_start", "max_force_rate", "max_torque_rate", "multirate",
        "realtime", "priority", "log_capacity"}},
      {"trace", {"path", "device_log", "rate", "max_bytes"}},
  };
  return k;
}

// Tables written [[name]] (arrays of tables); the others are [name].
bool is_array_table(const std::string& t) { return t == "object" || t == "material"; }

size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<size_t> prev(b.size() + 1), cur(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) prev[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    cur[0] = i;
    for (size_t j = 1; j <= b.size(); ++j)
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
    std::swap(prev, cur);
  }
  return prev[b.size()];
}

// The closest of `candidates` to `word` when it is close enough to be a typo
// (at most 2 edits, and fewer than half the word's letters), else "".
std::string closest(const std::string& word, const std::vector<std::string>& candidates) {
  std::string best;
  size_t best_d = std::numeric_limits<size_t>::max();
  for (const std::string& c : candidates) {
    const size_t d = edit_distance(word, c);
    if (d < best_d) best_d = d, best = c;
  }
  if (best_d <= 2 && 2 * best_d < std::max(word.size(), best.size())) return best;
  // A key with a unit or a word added or left out ("display_rate_hz" for
  // "display_rate", "max_force_n"): one is the other plus "_..." .
  for (const std::string& c : candidates) {
    const std::string& shorter = c.size() < word.size() ? c : word;
    const std::string& longer = c.size() < word.size() ? word : c;
    if (shorter.size() >= 4 && longer.compare(0, shorter.size(), shorter) == 0 && longer[shorter.size()] == '_')
      return c;
  }
  return "";
}

const char* type_name(const toml::node& n) {
  switch (n.type()) {
    case toml::node_type::table: return "a table";
    case toml::node_type::array: return "an array";
    case toml::node_type::string: return "a string";
    case toml::node_type::integer: return "an integer";
    case toml::node_type::floating_point: return "a float";
    case toml::node_type::boolean: return "a boolean";
    case toml::node_type::date: return "a date";
    case toml::node_type::time: return "a time";
    case toml::node_type::date_time: return "a date-time";
    default: return "nothing";
  }
}

std::string fmt(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", x);
  return buf;
}

std::string one_line(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  std::replace(s.begin(), s.end(), '\r', ' ');
  return s;
}

// Shared by every section of one file: its name, folder, and the failure path.
struct FileContext {
  std::string file;
  fs::path dir;

  [[noreturn]] void fail(const std::string& key, const std::string& what, const toml::node* at = nullptr) const {
    std::string w = what;
    if (at && at->source().begin.line > 0) w += " (line " + std::to_string(at->source().begin.line) + ")";
    throw SceneFileError(file, key, w);
  }

  // A path as written in the file, relative ones against the file's folder
  // (so a scene runs the same from any working directory).
  std::string resolve(const std::string& p) const {
    const fs::path q(p);
    if (q.is_absolute() || dir.empty()) return q.lexically_normal().string();
    return (dir / q).lexically_normal().string();
  }
};

// One table of the file ([run], [[object]] number i, ...): typed getters
// that name the key in every error. `table` may be null (the table is
// absent): every getter then returns its default.
class Section {
 public:
  Section(const FileContext& ctx, const toml::table* table, std::string name, std::string label)
      : ctx_(ctx), table_(table), name_(std::move(name)), label_(std::move(label)) {
    check_keys();
  }

  std::string key(const std::string& k) const { return label_ + "." + k; }
  const toml::node* node(const std::string& k) const { return table_ ? table_->get(k) : nullptr; }
  bool has(const std::string& k) const { return node(k) != nullptr; }

  [[noreturn]] void fail(const std::string& k, const std::string& what) const {
    const toml::node* n = node(k);
    ctx_.fail(key(k), what, n ? n : table_);
  }
  // A required key that is absent (reported at the table's line).
  [[noreturn]] void missing(const std::string& k, const std::string& what) const {
    ctx_.fail(key(k), "missing: " + what, table_);
  }

  std::optional<double> number(const std::string& k) const {
    const toml::node* n = node(k);
    if (!n) return std::nullopt;
    double v = 0.0;
    if (const auto* i = n->as_integer())
      v = static_cast<double>(i->get());
    else if (const auto* f = n->as_floating_point())
      v = f->get();
    else
      fail(k, std::string("expected a number, got ") + type_name(*n));
    if (!std::isfinite(v)) fail(k, "must be finite, got " + fmt(v));
    return v;
  }
  double number(const std::string& k, double def) const { return number(k).value_or(def); }
  // Finite and > 0, or finite and >= 0.
  double positive(const std::string& k, double def) const {
    const auto v = number(k);
    if (v && !(*v > 0)) fail(k, "must be > 0, got " + fmt(*v));
    return v.value_or(def);
  }
  double nonnegative(const std::string& k, double def) const {
    const auto v = number(k);
    if (v && !(*v >= 0)) fail(k, "must be >= 0, got " + fmt(*v));
    return v.value_or(def);
  }
  // Within [lo, hi] (docs/scene-format.md gives each key's range and why).
  double range(const std::string& k, double def, const Range& r) const {
    const auto v = number(k);
    if (v && !(*v >= r.lo && *v <= r.hi))
      fail(k, "must be between " + fmt(r.lo) + " and " + fmt(r.hi) + (r.unit[0] ? std::string(" ") + r.unit : "") +
                  ", got " + fmt(*v) + (r.why[0] ? std::string(" (") + r.why + ")" : ""));
    return v.value_or(def);
  }

  std::optional<int64_t> integer(const std::string& k, int64_t lo, int64_t hi) const {
    const toml::node* n = node(k);
    if (!n) return std::nullopt;
    const auto* i = n->as_integer();
    if (!i) fail(k, std::string("expected an integer, got ") + type_name(*n));
    const int64_t v = i->get();
    if (v < lo || v > hi)
      fail(k, "must be between " + std::to_string(lo) + " and " + std::to_string(hi) + ", got " + std::to_string(v));
    return v;
  }
  int integer(const std::string& k, int def, int64_t lo, int64_t hi) const {
    const auto v = integer(k, lo, hi);
    return v ? static_cast<int>(*v) : def;
  }

  bool boolean(const std::string& k, bool def) const {
    const toml::node* n = node(k);
    if (!n) return def;
    const auto* b = n->as_boolean();
    if (!b) fail(k, std::string("expected true or false, got ") + type_name(*n));
    return b->get();
  }

  std::optional<std::string> string(const std::string& k) const {
    const toml::node* n = node(k);
    if (!n) return std::nullopt;
    const auto* s = n->as_string();
    if (!s) fail(k, std::string("expected a string, got ") + type_name(*n));
    return s->get();
  }
  std::string string(const std::string& k, const std::string& def) const { return string(k).value_or(def); }
  std::string choice(const std::string& k, const std::string& def, const std::vector<std::string>& allowed) const {
    const std::string v = string(k, def);
    if (std::find(allowed.begin(), allowed.end(), v) == allowed.end()) {
      std::string list;
      for (const std::string& a : allowed) list += (list.empty() ? "\"" : ", \"") + a + "\"";
      fail(k, "must be one of " + list + ", got " + quote_value(v));
    }
    return v;
  }
  // A non-empty path, resolved against the scene file's folder.
  std::optional<std::string> path(const std::string& k) const {
    const auto s = string(k);
    if (!s) return std::nullopt;
    if (s->empty()) fail(k, "empty path (leave the key out instead)");
    // TOML allows "\u0000"; the operating system would cut the path there and
    // open another file than the one the message names.
    if (s->find('\0') != std::string::npos) fail(k, "a path must not contain a NUL character");
    return ctx_.resolve(*s);
  }
  // A path to a regular file of at most max_bytes (hrt/files.h: a FIFO or
  // a device is named as such, not read).
  std::optional<std::string> existing_file(const std::string& k, uint64_t max_bytes) const {
    const auto p = path(k);
    if (!p) return p;
    try {
      check_input_file(*p, max_bytes);
    } catch (const InputFileError& e) {
      fail(k, e.what());
    }
    return p;
  }

  std::vector<double> numbers(const std::string& k, size_t count, const char* layout) const {
    const toml::node* n = node(k);
    const auto* a = n->as_array();
    const std::string expected = "expected an array of " + std::to_string(count) + " numbers " + layout;
    if (!a) fail(k, expected + ", got " + type_name(*n));
    if (a->size() != count) fail(k, expected + ", got " + std::to_string(a->size()) + " elements");
    std::vector<double> v;
    for (const toml::node& e : *a) {
      if (const auto* i = e.as_integer())
        v.push_back(static_cast<double>(i->get()));
      else if (const auto* f = e.as_floating_point())
        v.push_back(f->get());
      else
        fail(k, expected + ", element " + std::to_string(v.size()) + " is " + type_name(e));
      if (!std::isfinite(v.back()))
        fail(k, "element " + std::to_string(v.size() - 1) + " must be finite, got " + fmt(v.back()));
    }
    return v;
  }
  Vec3 vec3(const std::string& k, const Vec3& def) const {
    if (!has(k)) return def;
    const std::vector<double> v = numbers(k, 3, "[x, y, z]");
    return Vec3(v[0], v[1], v[2]);
  }
  Vec3 position(const std::string& k) const {
    const Vec3 p = vec3(k, Vec3::Zero());
    if (!(p.stableNorm() <= kMaxPosition))
      fail(k,
           "is " + fmt(p.stableNorm()) + " m from the origin; at most " + fmt(kMaxPosition) + " m (meters, not mm?)");
    return p;
  }
  Eigen::Quaterniond quaternion(const std::string& k) const {
    if (!has(k)) return Eigen::Quaterniond::Identity();
    const std::vector<double> v = numbers(k, 4, "[x, y, z, w]");
    const Eigen::Quaterniond q(v[3], v[0], v[1], v[2]);  // Eigen's constructor takes w first
    const double norm = q.coeffs().stableNorm();
    if (!(std::abs(norm - 1.0) <= kQuaternionTolerance))
      fail(k, "the quaternion has norm " + fmt(norm) + ", expected a unit quaternion [x, y, z, w] (norm within " +
                  fmt(kQuaternionTolerance) + " of 1)");
    return q.normalized();
  }

 private:
  void check_keys() const {
    if (!table_) return;
    const auto& all = known_keys();
    const std::vector<std::string>& mine = all.at(name_);
    for (auto&& [k, v] : *table_) {
      const std::string key_str(k.str());
      if (std::find(mine.begin(), mine.end(), key_str) != mine.end()) continue;
      std::string what = "unknown key";
      const std::string near = closest(key_str, mine);
      if (!near.empty()) {
        what += " (did you mean \"" + near + "\"?)";
      } else {
        // A key of another table written in the wrong one ([run] gravity).
        for (const auto& [table, keys] : all)
          if (table != name_ && std::find(keys.begin(), keys.end(), key_str) != keys.end()) {
            what += std::string(" (it belongs in ") + (is_array_table(table) ? "[[" : "[") + table +
                    (is_array_table(table) ? "]]" : "]") + ")";
            break;
          }
      }
      ctx_.fail(label_ + "." + key_str, what, &v);
    }
  }

  const FileContext& ctx_;
  const toml::table* table_;
  std::string name_, label_;
};

void check_parent_folder(const Section& s, const std::string& k, const std::string& path) {
  const fs::path parent = fs::path(path).parent_path();
  // The error_code form: a name too long for the file system (ENAMETOOLONG)
  // is "does not exist" here, not an exception out of the reader.
  std::error_code ec;
  if (!parent.empty() && !fs::is_directory(parent, ec))
    s.fail(k, "the folder " + printable(parent.string(), 200) + " does not exist" +
                  (ec && ec != std::errc::no_such_file_or_directory ? " (" + ec.message() + ")" : ""));
}

void check_address(const Section& s, const std::string& k, const std::string& address) {
  in_addr a{};
  if (inet_pton(AF_INET, address.c_str(), &a) != 1)
    s.fail(k, quote_value(address) + " is not an IPv4 address (dotted numbers, e.g. \"127.0.0.1\")");
}

// Reads [device]; the keys of another device type are errors (a port on a
// scripted device is a scene that does not do what its author thinks).
void read_device(const Section& s, DeviceConfig& d) {
  d.type = s.choice("type", "scripted", {"scripted", "udp", "plugin", "virtual"});
  const std::vector<std::string> scripted_keys = {"trajectory", "trajectory_prefix"};
  const std::vector<std::string> udp_keys = {
      "bind", "port", "reply_address", "reply_port", "display_address", "display_port", "display_rate"};
  const std::vector<std::string> plugin_keys = {"plugin", "config"};
  const std::vector<std::string> virtual_keys = {"start_position", "start_orientation"};
  // A plugin reports its own name, sensing and workspace; only its limits
  // can be overridden (the *_set flags).
  const std::vector<std::string> not_for_plugin = {"name", "dof_sensed", "workspace"};
  auto refuse = [&](const std::vector<std::string>& keys, const std::string& for_type) {
    for (const std::string& k : keys)
      if (s.has(k)) s.fail(k, "only for type = \"" + for_type + "\" (this device is \"" + d.type + "\")");
  };
  if (d.type != "scripted") refuse(scripted_keys, "scripted");
  if (d.type != "udp") refuse(udp_keys, "udp");
  if (d.type != "plugin") refuse(plugin_keys, "plugin");
  if (d.type != "virtual") refuse(virtual_keys, "virtual");
  if (d.type == "plugin")
    for (const std::string& k : not_for_plugin)
      if (s.has(k)) s.fail(k, "a plugin device reports its own (only its limits can be set here)");

  if (d.type == "scripted") {
    const auto t = s.existing_file("trajectory", kMaxTrajectoryBytes);
    if (!t) s.missing("trajectory", "a scripted device needs a trajectory CSV (docs/trajectory-format.md)");
    d.trajectory = *t;
    d.trajectory_prefix = s.string("trajectory_prefix", "");
  }
  if (d.type == "udp") {
    UdpOptions& u = d.udp;
    u.bind_address = s.string("bind", u.bind_address);
    check_address(s, "bind", u.bind_address);
    u.port = s.integer("port", u.port, 0, 65535);
    u.reply_address = s.string("reply_address", u.reply_address);
    if (!u.reply_address.empty()) check_address(s, "reply_address", u.reply_address);
    u.reply_port = s.integer("reply_port", u.reply_port, 0, 65535);
    if (!u.reply_address.empty() && u.reply_port == 0)
      s.fail("reply_address", "needs a reply_port (or leave both out: replies go to the last pose packet's sender)");
    u.display_address = s.string("display_address", u.display_address);
    check_address(s, "display_address", u.display_address);
    u.display_port = s.integer("display_port", u.display_port, 0, 65535);
    u.display_rate_hz = s.range("display_rate", u.display_rate_hz, kDisplayRate);
  }
  if (d.type == "plugin") {
    const auto p = s.existing_file("plugin", kMaxPluginBytes);
    if (!p) s.missing("plugin", "a plugin device needs the path of its shared library");
    d.plugin = *p;
    d.plugin_config = s.string("config", "");
  }

  if (d.type == "virtual") {
    d.start_set = s.has("start_position") || s.has("start_orientation");
    d.start.position = s.position("start_position");
    d.start.rotation = s.quaternion("start_orientation");
  }

  DeviceInfo& info = d.info;
  info.name = s.string("name", d.type == "plugin" ? info.name : d.type);
  if (info.name.empty()) s.fail("name", "must not be empty");
  auto dof = [&](const std::string& k, int def) {
    const int v = s.integer(k, def, 0, 6);
    if (v != 3 && v != 6) s.fail(k, "must be 3 or 6, got " + std::to_string(v));
    return v;
  };
  d.dof_actuated_set = s.has("dof_actuated");
  info.dof_actuated = dof("dof_actuated", info.dof_actuated);
  info.dof_sensed = dof("dof_sensed", info.dof_sensed);
  if (s.has("workspace")) {
    info.workspace = s.vec3("workspace", info.workspace);
    for (int i = 0; i < 3; ++i)
      if (!(info.workspace[i] >= kWorkspace.lo && info.workspace[i] <= kWorkspace.hi))
        s.fail("workspace", "half extents must be between " + fmt(kWorkspace.lo) + " and " + fmt(kWorkspace.hi) +
                                " m, got " + fmt(info.workspace[i]));
  }
  d.max_force_set = s.has("max_force");
  d.max_torque_set = s.has("max_torque");
  d.max_stiffness_set = s.has("max_stiffness");
  d.max_angular_stiffness_set = s.has("max_angular_stiffness");
  info.max_force = s.range("max_force", info.max_force, kMaxForce);
  info.max_torque = s.range("max_torque", info.max_torque, kMaxTorque);
  info.max_stiffness = s.range("max_stiffness", info.max_stiffness, kMaxStiffness);
  info.max_angular_stiffness = s.range("max_angular_stiffness", info.max_angular_stiffness, kMaxAngularStiffness);
}

Material read_material(const Section& s, Material m) {
  if (s.has("stiffness")) m.stiffness = s.range("stiffness", m.stiffness, kContactStiffness);
  m.mu_static = s.range("mu_static", m.mu_static, kFriction);
  m.mu_dynamic = s.range("mu_dynamic", m.mu_dynamic, kFriction);
  if (m.mu_dynamic > m.mu_static) {
    // Name the key the file set (an inherited value cannot be the mistake).
    const std::string k = s.has("mu_dynamic") ? "mu_dynamic" : "mu_static";
    s.fail(k, "mu_dynamic (" + fmt(m.mu_dynamic) + ") must not exceed mu_static (" + fmt(m.mu_static) + ")");
  }
  return m;
}

// One of the file's tables by name (null when absent: its getters return their defaults).
Section section_of(const FileContext& ctx, const toml::table& root, const std::string& name) {
  return Section(ctx, root[name].as_table(), name, name);
}

// The file's text, parsed.
toml::table parse_scene_file(const std::string& path) {
  // A regular file of at most kMaxSceneFileBytes: a FIFO would block the
  // read and /dev/zero would never end it.
  std::string text;
  try {
    text = read_input_file(path, kMaxSceneFileBytes);
  } catch (const InputFileError& e) {
    throw SceneFileError(path, "", e.problem);
  }

  try {
    return toml::parse(text, path);
  } catch (const toml::parse_error& e) {
    const auto& b = e.source().begin;
    throw SceneFileError(path, "",
                         "line " + std::to_string(b.line) + ", column " + std::to_string(b.column) + ": " +
                             one_line(std::string(e.description())));
  }
}

void check_top_level(const FileContext& ctx, const toml::table& root) {
  // Top level: only the known tables, each of its own kind.
  const auto& all = known_keys();
  for (auto&& [k, v] : root) {
    const std::string name(k.str());
    const auto it = all.find(name);
    if (it == all.end()) {
      std::vector<std::string> tables;
      for (const auto& [t, keys] : all) tables.push_back(t);
      std::string what = v.is_table() || v.is_array_of_tables() ? "unknown table" : "unknown key";
      const std::string near = closest(name, tables);
      if (!near.empty()) {
        what += " (did you mean " + std::string(is_array_table(near) ? "[[" : "[") + near +
                (is_array_table(near) ? "]]" : "]") + "?)";
      } else if (!v.is_table()) {
        for (const auto& [t, keys] : all)
          if (std::find(keys.begin(), keys.end(), name) != keys.end()) {
            what += std::string(" (it belongs in ") + (is_array_table(t) ? "[[" : "[") + t +
                    (is_array_table(t) ? "]]" : "]") + ")";
            break;
          }
      }
      ctx.fail(name, what, &v);
    }
    if (is_array_table(name) && !v.is_array_of_tables())
      ctx.fail(name, std::string("expected an array of tables [[") + name + "]], got " + type_name(v), &v);
    if (!is_array_table(name) && !v.is_table())
      ctx.fail(name, std::string("expected a table [") + name + "], got " + type_name(v), &v);
  }
}

// [run]
void read_run(const Section& s, RunConfig& c) {
  c.duration = s.range("duration", c.duration, kDuration);
  c.lockstep = s.boolean("lockstep", c.lockstep);
  c.sim_every = s.integer("sim_every", c.sim_every, 1, 10'000);
  c.max_step = s.range("max_step", c.max_step, kMaxStep);
  c.backend = s.choice("backend", c.backend, {"cpu", "gl", "auto"});
  // The GL backend's settings: refused where no GL backend can run (a
  // setting that does nothing is a scene that does not do what its author
  // thinks, as a udp key on a scripted device).
  if (c.backend == "cpu" && s.has("gl_search"))
    s.fail("gl_search", "only with backend = \"gl\" or \"auto\" (this scene's backend is \"cpu\")");
  c.gl_search = s.choice("gl_search", c.gl_search, {"compute", "occlusion"});
  if (s.has("occlusion_steps") && (c.backend == "cpu" || c.gl_search != "occlusion"))
    s.fail("occlusion_steps", "only with gl_search = \"occlusion\" (and backend = \"gl\" or \"auto\")");
  c.occlusion_steps = s.integer("occlusion_steps", c.occlusion_steps, 1, 23);
  // The CPU backend's threads (SceneOptions::threads): every hardware
  // thread unless the scene says otherwise; the results do not depend on it.
  c.scene.threads = s.integer("threads", 0, 0, kMaxThreads);
}

// [[object]]: the probe first, then the objects it touches.
void read_objects(const FileContext& ctx, const toml::table& root, RunConfig& c) {
  const toml::array* objects = root["object"].as_array();
  if (!objects || objects->size() < 2)
    ctx.fail("object",
             "a scene needs at least two [[object]] tables (the probe first, then what it touches), got " +
                 std::to_string(objects ? objects->size() : 0),
             objects);
  for (size_t i = 0; i < objects->size(); ++i) {
    const std::string label = "object[" + std::to_string(i) + "]";
    const Section s(ctx, (*objects)[i].as_table(), "object", label);
    ObjectConfig o;
    o.name = s.string("name", "object" + std::to_string(i));
    if (o.name.empty()) s.fail("name", "must not be empty");
    for (size_t j = 0; j < c.objects.size(); ++j)
      if (c.objects[j].name == o.name)
        s.fail("name", quote_value(o.name) + " is also the name of object[" + std::to_string(j) + "]");
    const auto bundle = s.path("bundle");
    if (!bundle) s.missing("bundle", "every object needs the path of its bundle (a *.hbundle folder)");
    std::error_code ec;
    if (!fs::is_directory(*bundle, ec))
      s.fail("bundle", "no bundle folder at " + printable(*bundle, 200) +
                           (ec && ec != std::errc::no_such_file_or_directory ? " (" + ec.message() + ")" : ""));
    o.bundle = *bundle;
    o.pose.position = s.position("position");
    o.pose.rotation = s.quaternion("orientation");
    if (i == 0 && s.has("trajectory"))
      s.fail("trajectory",
             "object[0] is the probe: it follows the device through the coupling, not a trajectory (a scripted "
             "device plays one: [device] trajectory)");
    o.trajectory = s.existing_file("trajectory", kMaxTrajectoryBytes).value_or("");
    c.objects.push_back(std::move(o));
  }
}

// [force]: the texture force model and the contact search.
void read_force(const Section& s, RunConfig& c) {
  ForceOptions& f = c.scene.force;
  f.stiffness = s.range("stiffness", f.stiffness, kContactStiffness);
  f.resolution = s.integer("resolution", f.resolution, 8, kMaxResolution);
  f.lin_step = s.range("lin_step", f.lin_step, kLinStep);
  f.ang_step = s.range("ang_step", f.ang_step, kAngStep);
  f.shortcut = s.boolean("shortcut", f.shortcut);
  // The GL backend implements full re-rasterization only (hrt/gl_depth.h):
  // refused here rather than at the first contact of the session. (auto
  // then keeps to the CPU backend.)
  if (f.shortcut && c.backend == "gl")
    s.fail("shortcut", "the Sec. 5.2 shortcut is implemented by the CPU backend only, and run.backend is \"gl\"");
  {
    const std::string h = s.choice("heights", "surface", {"surface", "coarse", "mesh"});
    parse_height_mode(h, f.heights);  // one of the three, checked by choice()
  }
  c.scene.collision.margin = s.range("margin", c.scene.collision.margin, kMargin);
  ClusterOptions& cl = c.scene.cluster;
  cl.max_patches = s.integer("max_patches", cl.max_patches, 1, 4096);
  cl.auto_resolution = s.boolean("auto_resolution", cl.auto_resolution);
  cl.max_resolution = s.integer("max_resolution", cl.max_resolution, 8, kMaxResolution);
  if (cl.auto_resolution && cl.max_resolution < f.resolution)
    s.fail(s.has("max_resolution") ? "max_resolution" : "resolution",
           "max_resolution (" + std::to_string(cl.max_resolution) + ") must be at least the resolution (" +
               std::to_string(f.resolution) + ")");
  c.session.fade_time = s.range("fade_time", c.session.fade_time, kFadeTime);
}

// [probe]
void read_probe(const Section& s, RunConfig& c) {
  c.session.density = s.range("density", c.session.density, kDensity);
  c.session.gravity = s.vec3("gravity", c.session.gravity);
  if (!(c.session.gravity.norm() <= kGravity.hi))
    s.fail("gravity", "its norm must be at most " + fmt(kGravity.hi) + " m/s^2, got " + fmt(c.session.gravity.norm()));
}

// [coupling]: all four gains or none (then from the device's limits).
void read_coupling(const Section& s, RunConfig& c) {
  c.session.coupling_enabled = s.boolean("enabled", true);
  const char* gains[] = {"k_lin", "b_lin", "k_ang", "b_ang"};
  int given = 0;
  for (const char* g : gains) given += s.has(g) ? 1 : 0;
  if (given != 0 && given != 4)
    for (const char* g : gains)
      if (!s.has(g))
        s.missing(g, "give all four gains k_lin, b_lin, k_ang, b_ang, or none (then they follow the device's limits)");
  if (given == 4) {
    c.session.coupling.k_lin = s.range("k_lin", 0.0, kCouplingK);
    c.session.coupling.b_lin = s.range("b_lin", 0.0, kCouplingB);
    c.session.coupling.k_ang = s.range("k_ang", 0.0, kCouplingKAng);
    c.session.coupling.b_ang = s.range("b_ang", 0.0, kCouplingBAng);
    c.coupling_from_device = false;
  } else {
    // Negative until the caller fills them from the open device
    // (default_coupling): a gain of -1 reaching a Session is visibly wrong.
    c.session.coupling = Coupling{-1.0, -1.0, -1.0, -1.0};
    c.coupling_from_device = c.session.coupling_enabled;
  }
}

// [friction]: the scene's default material; [[material]] per pair.
void read_friction(const FileContext& ctx, const toml::table& root, RunConfig& c) {
  const Section s = section_of(ctx, root, "friction");
  c.session.friction = s.boolean("enabled", c.session.friction);
  c.session.material = read_material(s, c.session.material);
  if (const toml::array* materials = root["material"].as_array()) {
    c.session.materials.assign(c.objects.size(), c.session.material);
    std::vector<int> set_by(c.objects.size(), -1);
    for (size_t i = 0; i < materials->size(); ++i) {
      const std::string label = "material[" + std::to_string(i) + "]";
      const Section s(ctx, (*materials)[i].as_table(), "material", label);
      const auto name = s.string("object");
      if (!name) s.missing("object", "the name of the object (not the probe) this material pairs with the probe");
      int b = -1;
      for (size_t j = 0; j < c.objects.size(); ++j)
        if (c.objects[j].name == *name) b = static_cast<int>(j);
      if (b < 0) {
        std::vector<std::string> names;
        for (size_t j = 1; j < c.objects.size(); ++j) names.push_back(c.objects[j].name);
        const std::string near = closest(*name, names);
        s.fail("object", "no object is named " + quote_value(*name) +
                             (near.empty() ? "" : " (did you mean " + quote_value(near) + "?)"));
      }
      if (b == 0)
        s.fail("object", quote_value(*name) +
                             " is the probe; a material belongs to a pair (probe, object): name the other object");
      if (set_by[static_cast<size_t>(b)] >= 0)
        s.fail("object",
               quote_value(*name) + " already has material[" + std::to_string(set_by[static_cast<size_t>(b)]) + "]");
      set_by[static_cast<size_t>(b)] = static_cast<int>(i);
      c.session.materials[static_cast<size_t>(b)] = read_material(s, c.session.material);
    }
  }
  if (c.session.friction) {
    bool any = c.session.material.mu_static > 0;
    for (const Material& m : c.session.materials) any = any || m.mu_static > 0;
    if (!any)
      section_of(ctx, root, "friction")
          .fail("enabled", "friction is on but no mu_static > 0 is set (in [friction] or a [[material]])");
  }
}

// [workspace]: device frame -> scene, and the grasp on the probe.
void read_workspace(const Section& s, RunConfig& c) {
  WorkspaceMap& m = c.loop.map;
  m.scale = s.range("scale", m.scale, kScale);
  m.offset.position = s.position("offset_position");
  m.offset.rotation = s.quaternion("offset_orientation");
  m.grasp.position = s.position("grasp_position");
  m.grasp.rotation = s.quaternion("grasp_orientation");
}

// [loop]
void read_loop(const FileContext& ctx, const toml::table& root, RunConfig& c) {
  const Section s = section_of(ctx, root, "loop");
  DeviceLoopOptions& l = c.loop;
  l.period = s.range("period", l.period, kPeriod);
  l.watchdog = s.range("watchdog", l.watchdog, kWatchdog);
  l.watchdog_ramp = s.range("watchdog_ramp", l.watchdog_ramp, kWatchdogRamp);
  l.soft_start = s.range("soft_start", l.soft_start, kSoftStart);
  l.max_force_rate = s.range("max_force_rate", l.max_force_rate, kForceRate);
  l.max_torque_rate = s.range("max_torque_rate", l.max_torque_rate, kTorqueRate);
  l.multirate = s.boolean("multirate", l.multirate);
  l.realtime = s.boolean("realtime", l.realtime);
  l.realtime_priority = s.integer("priority", l.realtime_priority, 1, 99);
  if (const auto cap = s.integer("log_capacity", 0, static_cast<int64_t>(kMaxLogCapacity)))
    l.log_capacity = static_cast<size_t>(*cap);
  if (c.max_step < l.period && section_of(ctx, root, "run").has("max_step"))
    section_of(ctx, root, "run")
        .fail("max_step", "must be at least the device period (" + fmt(l.period) + " s), got " + fmt(c.max_step));
}

// [trace]
void read_trace(const FileContext& ctx, const toml::table& root, RunConfig& c) {
  const Section s = section_of(ctx, root, "trace");
  c.trace.path = s.path("path").value_or("");
  c.trace.device_log = s.path("device_log").value_or("");
  // Checked now rather than when the files are written: the device log is
  // written after the session, and a typo must not cost the run.
  if (!c.trace.path.empty()) check_parent_folder(s, "path", c.trace.path);
  if (!c.trace.device_log.empty()) check_parent_folder(s, "device_log", c.trace.device_log);
  c.trace.rate_set = s.has("rate");
  c.trace.rate = s.range("rate", c.trace.rate, kTraceRate);
  c.trace.max_bytes =
      static_cast<uint64_t>(s.range("max_bytes", static_cast<double>(c.trace.max_bytes), kTraceMaxBytes));
  if (!c.trace.device_log.empty() && section_of(ctx, root, "loop").has("log_capacity") && c.loop.log_capacity == 0)
    section_of(ctx, root, "loop").fail("log_capacity", "is 0 but [trace] device_log is set: nothing would be logged");
}

}  // namespace

RunConfig load_run_config(const std::string& path) {
  FileContext ctx;
  ctx.file = path;
  ctx.dir = fs::path(path).parent_path();
  const toml::table root = parse_scene_file(path);
  check_top_level(ctx, root);
  auto section = [&](const std::string& name) { return section_of(ctx, root, name); };

  RunConfig c;
  c.file = path;
  read_run(section("run"), c);
  read_objects(ctx, root, c);
  read_force(section("force"), c);
  read_probe(section("probe"), c);
  read_coupling(section("coupling"), c);
  read_friction(ctx, root, c);
  read_workspace(section("workspace"), c);

  // [device]
  read_device(section("device"), c.device);
  if (c.device.type == "virtual" && !c.device.start_set && !c.objects.empty())
    c.device.start = c.loop.map.to_device(c.objects[0].pose);
  c.session.max_device_stiffness = c.device.info.max_stiffness;
  c.session.max_device_angular_stiffness = c.device.info.max_angular_stiffness;
  if (c.lockstep && c.device.type != "scripted" && c.device.type != "virtual")
    section("run").fail("lockstep",
                        "lockstep runs without a wall clock, so it needs a scripted or virtual device (this one is \"" +
                            c.device.type + "\")");

  read_loop(ctx, root, c);
  read_trace(ctx, root, c);
  c.log_capacity_set = section("loop").has("log_capacity");
  check_run_limits(c);
  return c;
}

// ---------------------------------------------------------------------------
// Limits that depend on several keys, command-line overrides, outputs
// ---------------------------------------------------------------------------

void check_run_limits(RunConfig& c) {
  auto fail = [&](const std::string& key, const std::string& what) { throw SceneFileError(c.file, key, what); };
  // The device loop's ticks in the session (the stop ramp included).
  // (less 1e-9 of a tick inside the ceil: 0.21 / 0.001 is 210.00000000000003 in double)
  const double ticks = std::ceil((c.duration + c.loop.watchdog_ramp) / c.loop.period - 1e-9) + 1.0;
  if (!c.trace.device_log.empty()) {
    if (c.log_capacity_set) {
      if (c.loop.log_capacity == 0)
        fail("loop.log_capacity", "is 0 but a device log is asked for: nothing would be logged");
      // Never more rows than the session has ticks: a capacity of millions
      // for a 0.2 s session would be allocated for nothing.
      c.loop.log_capacity = std::min(c.loop.log_capacity, static_cast<size_t>(ticks));
    } else {
      if (ticks > static_cast<double>(kMaxLogCapacity))
        fail(c.duration_key, "a device log of the whole session (" + fmt(c.duration) + " s at " + fmt(c.loop.period) +
                                 " s per tick) needs " + fmt(ticks) + " ticks, more than the limit of " +
                                 std::to_string(kMaxLogCapacity) +
                                 "; set [loop] log_capacity to log the session's start only, or shorten it");
      c.loop.log_capacity = static_cast<size_t>(ticks);
    }
  } else {
    c.loop.log_capacity = 0;  // nothing reads it: allocate nothing
  }
  if (c.max_step < c.loop.period)
    fail("run.max_step", "must be at least the device period (" + fmt(c.loop.period) + " s), got " + fmt(c.max_step));
  // Traces: real time writes at most trace.rate rows per second of session
  // time (1 kHz unless set; a frame loop out of contact runs at tens of kHz
  // and would write tens of MB a second); lockstep writes every frame unless
  // the rate is set. Either way the file stops growing at max_bytes.
  if (!c.trace.rate_set) c.trace.rate = c.lockstep ? 0.0 : kDefaultRealtimeTraceRate;
}

void apply_overrides(RunConfig& c, const RunOverrides& o) {
  if (o.duration) {
    if (!(*o.duration >= kDuration.lo && *o.duration <= kDuration.hi))
      throw SceneFileError(
          c.file, "--duration",
          "must be between " + fmt(kDuration.lo) + " and " + fmt(kDuration.hi) + " s, got " + fmt(*o.duration));
    c.duration = *o.duration;
    c.duration_key = "--duration";
  }
  if (o.lockstep) c.lockstep = *o.lockstep;
  if (o.sched_fifo) c.loop.realtime = true;
  // Paths given on the command line are relative to the working directory.
  if (!o.trace.empty()) {
    c.trace.path = o.trace;
    c.trace.path_key = "--trace";
  }
  if (!o.device_log.empty()) {
    c.trace.device_log = o.device_log;
    c.trace.device_log_key = "--device-log";
  }
  check_run_limits(c);
}

InputFiles run_inputs(const RunConfig& c) {
  InputFiles in;
  in.add(c.file, "the scene file");
  for (size_t i = 0; i < c.objects.size(); ++i) {
    const ObjectConfig& o = c.objects[i];
    in.add(o.bundle, "a file of the bundle of object " + quote_value(o.name));
    if (!o.trajectory.empty()) in.add(o.trajectory, "the trajectory of object " + quote_value(o.name));
  }
  if (!c.device.trajectory.empty()) in.add(c.device.trajectory, "the device's trajectory");
  if (!c.device.plugin.empty()) in.add(c.device.plugin, "the device plugin");
  return in;
}

void check_run_outputs(const RunConfig& c) {
  const InputFiles in = run_inputs(c);
  if (!c.trace.path.empty()) in.check_output(c.trace.path, c.trace.path_key);
  if (!c.trace.device_log.empty()) {
    in.check_output(c.trace.device_log, c.trace.device_log_key);
    if (!c.trace.path.empty()) {
      InputFiles trace;
      trace.add(c.trace.path, "the trace (" + c.trace.path_key + ")");
      trace.add_path(c.trace.path, "the trace (" + c.trace.path_key + ")");
      trace.check_output(c.trace.device_log, c.trace.device_log_key);
    }
  }
}

void check_device_limits(const DeviceInfo& info, const std::string& source) {
  auto check = [&](const char* key, double v, const Range& r) {
    if (!(v >= r.lo && v <= r.hi))
      throw DeviceError(printable(source, 240) + ": " + key + " " + fmt(v) + " is outside " + fmt(r.lo) + " .. " +
                        fmt(r.hi) + (r.unit[0] ? std::string(" ") + r.unit : "") +
                        " (set it in the scene's [device] table to override the device's own figure)");
  };
  check("max_force", info.max_force, kMaxForce);
  check("max_torque", info.max_torque, kMaxTorque);
  check("max_stiffness", info.max_stiffness, kMaxStiffness);
  check("max_angular_stiffness", info.max_angular_stiffness, kMaxAngularStiffness);
  for (int i = 0; i < 3; ++i) check("workspace", info.workspace[i], kWorkspace);
}

}  // namespace hrt
