// The golden bundles baked by hbake (tests/golden, docs/bundle-format.md
// "Golden bundles"): every bundle loads, its stored texels, bilinear lookups
// and surface samples equal the values hbake.bundle computed
// (<name>.expected.json), and every corrupted variant in tests/golden/corrupt
// is rejected with the class listed in its index.json.
//
// Tolerances: stored texels compare exactly (float32 in, float32 out).
// Lookups (all four channels) and surface positions compare within the
// float32 rounding bound of Atlas::sample4 against the float64 evaluation of
// the same float32 data (sample_tolerance in test_io_writer.h, computed per
// lookup from the four texels read: ~1e-8 m inside a chart of these 40 mm
// parts), and positions also within the file's tolerance.position (1e-6 m).
//
// HRT_GOLDEN_DIR (a compile-time path) can be overridden at run time with the
// environment variable of the same name, to check other bundles the same way.
#include <cstdlib>
#include <filesystem>
#include <map>

#include <gtest/gtest.h>

#include "hrt/model.h"
#include "test_io_writer.h"

using hrt::BundleError;
using namespace hrt_test;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

// The bundle kept in format 1.2 (pieces.ply's map as one list per piece), made
// by tests/golden/make_golden.py next to the current ones.
fs::path format_1_2_bundle() { return fs::path(golden_dir()) / "format-1.2" / "ridged_box_pp.hbundle"; }

// The golden bundles of the current format, and the 1.2 one.
std::vector<fs::path> golden_bundles() {
  std::vector<fs::path> out;
  if (!fs::is_directory(golden_dir())) return out;
  for (const auto& e : fs::directory_iterator(golden_dir()))
    if (e.is_directory() && e.path().extension() == ".hbundle") out.push_back(e.path());
  std::sort(out.begin(), out.end());
  if (fs::is_directory(format_1_2_bundle())) out.push_back(format_1_2_bundle());
  return out;
}

Eigen::Vector3d vec3(const json& j) {
  return Eigen::Vector3d(j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>());
}

TEST(IoGolden, EveryBundleLoadsAndMatchesItsExpectedValues) {
  const auto bundles = golden_bundles();
  if (bundles.empty())
    GTEST_FAIL() << "no golden bundles in " << golden_dir() << " (tests/golden/make_golden.py writes them)";
  for (const fs::path& path : bundles) {
    SCOPED_TRACE(path.string());
    hrt::Model m;
    try {
      m = hrt::load_bundle(path.string());
    } catch (const BundleError& e) {
      ADD_FAILURE() << "golden bundle rejected: [" << hrt::to_string(e.error_class()) << "] " << e.what();
      continue;
    }
    const fs::path exp_path = path.parent_path() / (path.stem().string() + ".expected.json");
    ASSERT_TRUE(fs::exists(exp_path)) << exp_path;
    const json exp = read_json(exp_path.string());
    EXPECT_EQ(m.format_version, exp["format_version"].get<std::string>());
    EXPECT_EQ(m.atlas.width, exp["atlas"]["width"].get<int>());
    EXPECT_EQ(m.atlas.height, exp["atlas"]["height"].get<int>());
    EXPECT_EQ(m.vertices.size(), exp["coarse"]["vertices"].get<size_t>());
    EXPECT_EQ(m.faces.size(), exp["coarse"]["triangles"].get<size_t>());
    EXPECT_EQ(m.pieces.size(), exp["pieces"]["count"].get<size_t>());
    // The piece -> coarse-triangle map, as hbake's reader reads it (both layouts).
    ASSERT_EQ(exp["pieces"]["coarse_faces"].size(), m.pieces.size());
    for (size_t p = 0; p < m.pieces.size(); ++p)
      EXPECT_EQ(m.pieces[p].coarse_faces, exp["pieces"]["coarse_faces"][p].get<std::vector<uint32_t>>())
          << "piece " << p;
    const double file_tol = exp["tolerance"]["position"].get<double>();
    const int W = m.atlas.width, H = m.atlas.height;

    // Raw texels: exact.
    ASSERT_FALSE(exp["texels"].empty());
    for (const json& t : exp["texels"]) {
      const int i = t["i"], j = t["j"];
      const float* got = m.atlas.texel(i, j);
      for (int c = 0; c < 4; ++c) {
        EXPECT_EQ(got[c], static_cast<float>(t["rgba"][c].get<double>()))
            << "texel (" << i << ", " << j << ") channel " << c;
      }
    }

    // Lookups: Atlas::sample4 within its float32 bound of the float64 values.
    ASSERT_FALSE(exp["lookups"].empty());
    double worst = 0.0, worst_bound = 0.0, worst_a = 0.0;
    for (const json& l : exp["lookups"]) {
      const double ud = l["uv"][0], vd = l["uv"][1];
      const float u = static_cast<float>(ud), v = static_cast<float>(vd);
      ASSERT_EQ(static_cast<double>(u), ud) << "lookup UVs are float32 values by the spec of expected.json";
      ASSERT_EQ(static_cast<double>(v), vd);
      Eigen::Vector4d spread, max_abs;
      reference_sample(m.atlas, u, v, &spread, &max_abs);
      const Eigen::Vector4f got = m.atlas.sample4(u, v);
      for (int c = 0; c < 4; ++c) {
        const double tol = sample_tolerance(W, H, spread[c], max_abs[c]);
        const double err = std::fabs(got[c] - l["rgba"][c].get<double>());
        EXPECT_LE(err, tol) << "lookup at uv (" << u << ", " << v << ") channel " << c;
        if (c < 3) {
          // Positions: also within the file's tolerance. (Not for A: across a
          // 0 -> 1 coverage step the float32 texel coordinate error, ~1e-5 texel,
          // shows directly, so A gets only the float32 bound. The same can happen
          // to RGB where a lookup straddles the edge of the filled gutter, a step
          // of a whole coordinate, so the bound itself may exceed file_tol there.)
          EXPECT_LE(err, file_tol);
          worst = std::max(worst, err);
          worst_bound = std::max(worst_bound, tol);
        } else {
          worst_a = std::max(worst_a, err);
        }
      }
    }
    std::printf(
        "%s: %zu lookups, worst |sample4 - expected| = %.3g m on RGB (float32 bound up to %.3g m, file tolerance "
        "%.3g m), %.3g on A\n",
        path.filename().c_str(), exp["lookups"].size(), worst, worst_bound, file_tol, worst_a);

    // Surface samples: triangle + barycentrics -> uv -> atlas position, height.
    ASSERT_FALSE(exp["surface_samples"].empty());
    for (const json& s : exp["surface_samples"]) {
      const size_t f = s["triangle"];
      ASSERT_LT(f, m.faces.size());
      const double b[3] = {s["barycentrics"][0], s["barycentrics"][1], s["barycentrics"][2]};
      Eigen::Vector2d uv = Eigen::Vector2d::Zero();
      Eigen::Vector3d p = Eigen::Vector3d::Zero();
      for (int k = 0; k < 3; ++k) {
        uv += b[k] * m.uvs[f][k].cast<double>();
        p += b[k] * m.vertices[m.faces[f][k]];
      }
      // Same double-precision arithmetic on the same float32 data: equal to rounding.
      EXPECT_NEAR(uv.x(), s["uv"][0].get<double>(), 1e-12);
      EXPECT_NEAR(uv.y(), s["uv"][1].get<double>(), 1e-12);
      EXPECT_LT((p - vec3(s["coarse_point"])).norm(), 1e-12);
      EXPECT_LT((m.face_normals[f] - vec3(s["normal"])).norm(), 1e-9);
      const float u = static_cast<float>(uv.x()), v = static_cast<float>(uv.y());
      Eigen::Vector4d spread, max_abs;
      reference_sample(m.atlas, u, v, &spread, &max_abs);
      // Plus the float32 rounding of the UV itself: up to (W + H) 2^-24 texel.
      const double sp = spread.head<3>().maxCoeff(), mx = max_abs.head<3>().maxCoeff();
      const double tol = sample_tolerance(W, H, sp, mx) + (W + H) * kEps32 * sp;
      ASSERT_LE(tol, file_tol);
      const Eigen::Vector3d pos = m.atlas.sample(u, v).cast<double>();
      EXPECT_LT((pos - vec3(s["position"])).norm(), std::sqrt(3.0) * tol) << "triangle " << f;
      const double height = (pos - p).dot(m.face_normals[f]);
      EXPECT_NEAR(height, s["height"].get<double>(), std::sqrt(3.0) * tol + 1e-12) << "triangle " << f;
    }
  }
}

// Per variant, the message fragment both readers produce (index.json lists the
// class only). A variant not listed here is checked for its class alone.
const std::map<std::string, std::string>& golden_fragments() {
  static const std::map<std::string, std::string> m = {
      {"flipped_byte_atlas", "SHA-256"},
      {"major_version", "unsupported major version 2.0"},
      {"missing_pieces", "pieces.ply: missing"},
      {"schema_missing_field", "'mass' is a required property"},
      {"index_out_of_range", "with a vertex index out of range"},
      {"uv_outside", "with UVs outside [0, 1]"},
      {"degenerate_face", "degenerate face"},
      {"missing_channel", "missing channel 'B'"},
      {"rle_compression", "compression RLE is not allowed"},
      {"nan_texel", "read non-finite texels"},
      {"nonconvex_piece", "not convex"},
      {"map_out_of_range", "out of range (coarse triangle count"},
  };
  return m;
}

TEST(IoGolden, EveryCorruptedVariantIsRejectedWithItsClass) {
  const fs::path dir = fs::path(golden_dir()) / "corrupt";
  const fs::path index = dir / "index.json";
  if (!fs::exists(index)) GTEST_FAIL() << "no " << index << " (tests/golden/make_golden.py writes it)";
  const json idx = read_json(index.string());
  ASSERT_FALSE(idx["variants"].empty());
  size_t checked = 0, with_fragment = 0;
  for (const json& v : idx["variants"]) {
    const std::string name = v["name"], cls = v["class"];
    const std::string path = (dir / v["bundle"].get<std::string>()).string();
    SCOPED_TRACE(name + " (" + v.value("description", "") + ")");
    try {
      hrt::load_bundle(path);
      ADD_FAILURE() << name << ": loaded, expected class " << cls;
    } catch (const BundleError& e) {
      ++checked;
      EXPECT_EQ(hrt::to_string(e.error_class()), cls) << e.what();
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
      const auto it = golden_fragments().find(name);
      if (it != golden_fragments().end()) {
        ++with_fragment;
        EXPECT_NE(std::string(e.what()).find(it->second), std::string::npos)
            << "message: " << e.what() << "\nexpected fragment: " << it->second;
      }
    }
  }
  std::printf("corrupt variants: %zu rejected (%zu with a message fragment checked)\n", checked, with_fragment);
}

}  // namespace

// Format 1.2 (pieces.ply's map as one variable-length list per piece) is still
// read: the bundle that hbake's 1.2 writer made for the ridged block
// (--method pp), kept in tests/golden/format-1.2. Its values are compared with
// the rest above; here, that it is there and read as 1.2, and that the same
// pieces.ply with its version edited to 1.3 is refused (the layout follows the
// version).
TEST(IoGolden, Format12BundleStillLoads) {
  const fs::path path = format_1_2_bundle();
  ASSERT_TRUE(fs::is_directory(path)) << path << " (tests/golden/make_golden.py writes it)";
  const hrt::Model m = hrt::load_bundle(path.string());
  EXPECT_EQ(m.format_version, "1.2");
  const json man = read_json((path / "manifest.json").string());
  ASSERT_EQ(m.pieces.size(), man["pieces"]["count"].get<size_t>());
  size_t rows = 0;
  for (const auto& p : m.pieces) rows += p.coarse_faces.size();
  EXPECT_GT(rows, m.pieces.size());

  // and the command: `hrt check` accepts it
  if (!hrt_binary().empty()) {
    const HrtRun r = run_hrt({"check", path.string()}, true);
    EXPECT_EQ(r.status, 0) << r.err;
    EXPECT_NE(r.out.find("format 1.2"), std::string::npos) << r.out;
  }

  const std::string copy = fresh_dir("format_1_2_as_1_3");
  remove_tree(copy);
  copy_dir(path.string(), copy);
  json edited = man;
  edited["format_version"] = "1.3";
  write_json(copy + "/manifest.json", edited);
  try {
    hrt::load_bundle(copy);
    ADD_FAILURE() << "a 1.2 pieces.ply under format_version 1.3 loaded";
  } catch (const BundleError& e) {
    EXPECT_EQ(e.error_class(), hrt::BundleErrorClass::pieces) << e.what();
    EXPECT_NE(std::string(e.what()).find("in the layout of format 1.0-1.2"), std::string::npos) << e.what();
  }
  remove_tree(copy);
}
