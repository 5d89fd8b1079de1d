// Loading valid bundles written by the test writer, and the atlas lookup.
//
// The cube bundle's atlas holds the exact affine position map of each chart
// (gutters included), so a bilinear lookup anywhere in a UV triangle must
// return the surface point itself: an independent check of the UV -> texel
// convention (x = u W - 0.5, y = (1 - v) H - 0.5, row 0 = top) and of the
// EXR channel order, since a flipped v, a half-texel shift or swapped
// channels all move the result by at least a texel (1 mm here).
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <random>

#include <gtest/gtest.h>

#include "hrt/model.h"
#include "io/bundle_io.h"
#include "test_io_writer.h"

using hrt::BundleError;
using hrt::BundleErrorClass;
using namespace hrt_test;

namespace {

class CubeBundle : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fresh_dir(::testing::UnitTest::GetInstance()->current_test_info()->name());
    content_ = make_cube();
  }
  void TearDown() override { remove_tree(dir_); }
  std::string dir_;
  BundleContent content_;
};

TEST(IoSha256, KnownVectors) {
  // FIPS 180-2 test vectors.
  EXPECT_EQ(hrt::io::sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(hrt::io::sha256_hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
}

TEST(IoErrorClass, Names) {
  EXPECT_STREQ(hrt::to_string(BundleErrorClass::io), "io");
  EXPECT_STREQ(hrt::to_string(BundleErrorClass::version), "version");
  EXPECT_STREQ(hrt::to_string(BundleErrorClass::schema), "schema");
  EXPECT_STREQ(hrt::to_string(BundleErrorClass::hash), "hash");
  EXPECT_STREQ(hrt::to_string(BundleErrorClass::mesh), "mesh");
  EXPECT_STREQ(hrt::to_string(BundleErrorClass::atlas), "atlas");
  EXPECT_STREQ(hrt::to_string(BundleErrorClass::pieces), "pieces");
}

TEST_F(CubeBundle, LoadsEveryField) {
  write_bundle(dir_, content_);
  const hrt::Model m = hrt::load_bundle(dir_);
  EXPECT_EQ(m.path, dir_);
  EXPECT_EQ(m.name, "cube.ply");
  EXPECT_EQ(m.format_version, "1.0");
  ASSERT_EQ(m.vertices.size(), 8u);
  ASSERT_EQ(m.faces.size(), 12u);
  ASSERT_EQ(m.uvs.size(), 12u);
  const hrt::Vec3 c = cube_center();
  const double a = cube_side();
  for (size_t f = 0; f < 12; ++f) {
    // Outward unit normals along an axis, area a^2 / 2 (float32 corners: 1e-6 relative).
    const hrt::Vec3 centroid =
        (m.vertices[m.faces[f][0]] + m.vertices[m.faces[f][1]] + m.vertices[m.faces[f][2]]) / 3.0;
    EXPECT_NEAR(m.face_normals[f].norm(), 1.0, 1e-12);
    EXPECT_GT(m.face_normals[f].dot(centroid - c), 0.3 * a) << "face " << f << " normal points inward";
    EXPECT_NEAR(m.face_normals[f].cwiseAbs().maxCoeff(), 1.0, 1e-6);
    EXPECT_NEAR(m.face_areas[f], 0.5 * a * a, 1e-6 * a * a);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(m.uvs[f][k].x(), content_.uvs[f][2 * k]);
      EXPECT_EQ(m.uvs[f][k].y(), content_.uvs[f][2 * k + 1]);
    }
  }
  ASSERT_EQ(m.pieces.size(), 2u);
  for (size_t p = 0; p < 2; ++p) {
    ASSERT_EQ(m.pieces[p].vertices.size(), 8u);
    ASSERT_EQ(m.pieces[p].faces.size(), 12u);
    EXPECT_EQ(m.pieces[p].coarse_faces, content_.piece_map[p]);
    for (const auto& t : m.pieces[p].faces)
      for (uint32_t i : t) EXPECT_LT(i, 8u) << "piece faces must use local indices";
  }
  // Piece 1 is the +x half: its vertices have x >= c.x.
  for (const auto& v : m.pieces[1].vertices) EXPECT_GE(v.x(), c.x() - 1e-7);
  EXPECT_EQ(m.atlas.width, 96);
  EXPECT_EQ(m.atlas.height, 64);
  ASSERT_EQ(m.atlas.rgba.size(), 96u * 64u * 4u);
  EXPECT_EQ(m.atlas.rgba, content_.rgba);  // lossless ZIP, channels by name into RGBA order
  EXPECT_EQ(m.mass.basis, "full");
  EXPECT_DOUBLE_EQ(m.mass.volume, a * a * a);
  EXPECT_TRUE(m.mass.center_of_mass.isApprox(c));
  EXPECT_DOUBLE_EQ(m.mass.inertia(1, 1), a * a * a * a * a / 6.0);
  EXPECT_TRUE(m.mass.closed);
  EXPECT_DOUBLE_EQ(m.quality.texel_size, a / 20);
  EXPECT_DOUBLE_EQ(m.quality.min_wavelength, a / 10);
  EXPECT_DOUBLE_EQ(m.quality.bbox_diagonal, std::sqrt(3.0) * a);
  EXPECT_EQ((*m.manifest)["pieces"]["count"], 2);
}

TEST_F(CubeBundle, PizCompressionNoCommentMinorVersionAndUnknownFieldsLoad) {
  content_.coarse_comment = "";
  content_.manifest["format_version"] = "1.7";
  content_.manifest["future_field"] = {{"anything", 1}};
  content_.manifest["quality"]["future_stat"] = 3;
  ExrOptions exr;
  exr.compression = "piz";
  write_bundle(dir_, content_, exr);
  const hrt::Model m = hrt::load_bundle(dir_);
  EXPECT_EQ(m.format_version, "1.7");
  EXPECT_EQ(m.atlas.rgba, content_.rgba);
}

TEST_F(CubeBundle, HashesAreSkippedOnRequest) {
  write_bundle(dir_, content_);
  auto man = read_json(dir_ + "/manifest.json");
  man["files"]["pieces"]["sha256"] = std::string(64, 'a');
  man["files"]["pieces"]["bytes"] = 1;
  write_json(dir_ + "/manifest.json", man);
  EXPECT_THROW(hrt::load_bundle(dir_), BundleError);
  hrt::LoadOptions opts;
  opts.verify_hashes = false;
  EXPECT_NO_THROW(hrt::load_bundle(dir_, opts));
}

TEST_F(CubeBundle, SurfaceSamplesReturnTheSurfacePoint) {
  write_bundle(dir_, content_);
  const hrt::Model m = hrt::load_bundle(dir_);
  std::mt19937 rng(12345);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  const double texel = cube_side() / 20;
  // Float32 bound: position rounding (2^-24 * 0.11 m) plus the texel coordinate
  // error (2 W + 3 H) 2^-24 texel times the 1 mm texel step (sample_tolerance),
  // plus the float32 rounding of the UV itself (W 2^-24 texel).
  const double tol = sample_tolerance(96, 64, 2 * texel, 0.12) + 2 * 96 * kEps32 * texel;
  double worst = 0.0;
  for (int n = 0; n < 2000; ++n) {
    const size_t f = static_cast<size_t>(n % 12);
    double b1 = U(rng), b2 = U(rng);
    if (b1 + b2 > 1) b1 = 1 - b1, b2 = 1 - b2;
    const double b0 = 1 - b1 - b2;
    const auto& t = m.faces[f];
    const hrt::Vec3 p = b0 * m.vertices[t[0]] + b1 * m.vertices[t[1]] + b2 * m.vertices[t[2]];
    const Eigen::Vector2d uv =
        b0 * m.uvs[f][0].cast<double>() + b1 * m.uvs[f][1].cast<double>() + b2 * m.uvs[f][2].cast<double>();
    const Eigen::Vector4f s4 = m.atlas.sample4(static_cast<float>(uv.x()), static_cast<float>(uv.y()));
    const Eigen::Vector3f s3 = m.atlas.sample(static_cast<float>(uv.x()), static_cast<float>(uv.y()));
    EXPECT_EQ(s3, s4.head<3>());
    const double err = (s3.cast<double>() - p).norm();
    worst = std::max(worst, err);
    ASSERT_LT(err, tol) << "face " << f << " uv " << uv.transpose();
  }
  std::printf("surface samples: worst |atlas(uv) - p| = %.3g m (bound %.3g m, texel %.3g m)\n", worst, tol, texel);
}

TEST_F(CubeBundle, SampleAgreesWithIndependentBilinearReference) {
  // Random texel values (not an affine map) stress the weights; UVs beyond
  // [0, 1] test the clamping.
  content_.rgba.clear();
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> T(-1.0f, 1.0f);
  hrt::Atlas a;
  a.width = 37;
  a.height = 23;
  a.rgba.resize(37 * 23 * 4);
  for (float& x : a.rgba) x = T(rng);
  std::uniform_real_distribution<float> UV(-0.2f, 1.2f);
  for (int n = 0; n < 20000; ++n) {
    const float u = UV(rng), v = UV(rng);
    Eigen::Vector4d spread, max_abs;
    const Eigen::Vector4d ref = reference_sample(a, u, v, &spread, &max_abs);
    const Eigen::Vector4f got = a.sample4(u, v);
    for (int c = 0; c < 4; ++c) {
      const double tol = sample_tolerance(a.width, a.height, spread[c], max_abs[c]);
      ASSERT_NEAR(got[c], ref[c], tol) << "u " << u << " v " << v << " channel " << c;
    }
  }
}

TEST(IoAtlasSample, TexelCentresEdgesAndClamping) {
  hrt::Atlas a;
  a.width = 4;
  a.height = 2;
  a.rgba.resize(4 * 2 * 4);
  for (int j = 0; j < 2; ++j)
    for (int i = 0; i < 4; ++i)
      for (int c = 0; c < 4; ++c) a.rgba[(j * 4 + i) * 4 + c] = static_cast<float>(10 * j + i + 100 * c);
  // Texel centre (i, j) is at u = (i + 0.5) / W, v = 1 - (j + 0.5) / H (row 0 on top).
  // With W = 4, H = 2 these are exact binary fractions, so the results are exact.
  EXPECT_EQ(a.sample4(0.125f, 0.75f), Eigen::Vector4f(0, 100, 200, 300));    // texel (0, 0): top row
  EXPECT_EQ(a.sample4(0.375f, 0.25f), Eigen::Vector4f(11, 111, 211, 311));   // texel (1, 1)
  EXPECT_EQ(a.sample(0.25f, 0.75f), Eigen::Vector3f(0.5f, 100.5f, 200.5f));  // between (0,0) and (1,0)
  EXPECT_EQ(a.sample(0.125f, 0.5f), Eigen::Vector3f(5, 105, 205));           // between rows 0 and 1
  EXPECT_EQ(a.sample(0.0f, 1.0f), Eigen::Vector3f(0, 100, 200));             // corner clamps to texel (0, 0)
  EXPECT_EQ(a.sample(1.0f, 0.0f), Eigen::Vector3f(13, 113, 213));            // opposite corner: texel (3, 1)
  EXPECT_EQ(a.sample(5.0f, -3.0f), Eigen::Vector3f(13, 113, 213));           // far outside: clamped
  EXPECT_EQ(a.sample(std::nanf(""), 0.75f), Eigen::Vector3f(0, 100, 200));   // NaN: clamped, no UB
}

// `hrt check` end to end: the binary sits next to hrt_tests in the build directory
// (hrt_test::hrt_binary).
int run(const std::string& cmd, std::string* out) {
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return -1;
  char buf[4096];
  size_t n;
  out->clear();
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) out->append(buf, n);
  const int status = ::pclose(p);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST_F(CubeBundle, HrtCheckCommand) {
  const std::string hrt = hrt_binary();
  if (::access(hrt.c_str(), X_OK) != 0) GTEST_SKIP() << "hrt binary not built next to hrt_tests (" << hrt << ")";
  write_bundle(dir_, content_);
  std::string out;
  ASSERT_EQ(run(hrt + " check " + dir_ + " 2>&1", &out), 0) << out;
  EXPECT_NE(out.find("8 vertices, 12 triangles"), std::string::npos) << out;
  EXPECT_NE(out.find("96 x 64"), std::string::npos) << out;
  ASSERT_EQ(run(hrt + " check --json " + dir_, &out), 0) << out;
  const auto j = nlohmann::json::parse(out);
  EXPECT_EQ(j["ok"], true);
  EXPECT_EQ(j["coarse"]["triangles"], 12);
  EXPECT_EQ(j["pieces"]["count"], 2);
  EXPECT_EQ(j["atlas"]["width"], 96);
  EXPECT_DOUBLE_EQ(j["mass"]["volume"].get<double>(), std::pow(cube_side(), 3));

  // A corrupted bundle: exit code 3, one line on stderr naming class-specific text.
  auto man = read_json(dir_ + "/manifest.json");
  man["format_version"] = "2.0";
  write_json(dir_ + "/manifest.json", man);
  ASSERT_EQ(run(hrt + " check " + dir_ + " 2>&1 >/dev/null", &out), 3) << out;
  EXPECT_EQ(out.rfind("hrt: error: ", 0), 0u) << out;
  EXPECT_NE(out.find("version: "), std::string::npos) << out;
  EXPECT_NE(out.find("unsupported major version 2.0"), std::string::npos) << out;
  EXPECT_EQ(std::count(out.begin(), out.end(), '\n'), 1) << out;
  ASSERT_EQ(run(hrt + " check --json " + dir_ + " 2>/dev/null", &out), 3) << out;
  const auto e = nlohmann::json::parse(out);
  EXPECT_EQ(e["ok"], false);
  EXPECT_EQ(e["error"]["class"], "version");
  ASSERT_EQ(run(hrt + " check " + dir_ + "/does-not-exist 2>&1", &out), 3) << out;
  EXPECT_NE(out.find("bundle directory does not exist"), std::string::npos) << out;
  ASSERT_EQ(run(hrt + " check 2>&1", &out), 2) << out;  // usage error
}

}  // namespace
