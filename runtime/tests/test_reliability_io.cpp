// Reliability of the bundle loader on hostile input (the limits of
// docs/input-contract.md, "Runtime"): what once overflowed the stack, flooded
// memory or took quadratic time is refused with one line, its class and
// exit code 3, within bounded memory.
//
// Cases that crashed the process before the fix (stack overflow) or
// allocated gigabytes run `hrt check` as a child process, so a regression
// shows as a failed assertion on its exit status and peak RSS (wait4) instead
// of killing the test binary.
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>

#include <gtest/gtest.h>

#include "hrt/model.h"
#include "io/bundle_io.h"
#include "test_io_writer.h"

using hrt::BundleError;
using hrt::BundleErrorClass;
using namespace hrt_test;
using nlohmann::json;

namespace {

class Reliability : public ::testing::Test {
 protected:
  void SetUp() override {
    // hrt is built with hrt_tests (one CMake project): a missing binary is a failure, not a skip.
    ASSERT_EQ(::access(hrt_binary().c_str(), X_OK), 0) << "hrt binary not built next to hrt_tests: " << hrt_binary();
    dir_ = fresh_dir(std::string("rel_") + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    content_ = make_cube();
  }
  void TearDown() override {
    if (!dir_.empty()) remove_tree(dir_);
  }
  // `hrt check DIR`: exit 3, one line "hrt: error: <cls>: ...<fragment>...".
  HrtRun expect_refused(const std::string& cls, const std::string& fragment, long max_rss_mb = 200) {
    HrtRun c = run_hrt({"check", dir_});
    EXPECT_EQ(c.status, 3) << c.err;
    EXPECT_EQ(c.err.rfind("hrt: error: " + cls + ": ", 0), 0u) << c.err;
    EXPECT_NE(c.err.find(fragment), std::string::npos) << c.err;
    EXPECT_EQ(std::count(c.err.begin(), c.err.end(), '\n'), 1) << c.err;
    // posix_spawn shares the parent's memory until exec, and Linux counts
    // that in the child's peak: the parent's own peak is the baseline.
    struct rusage self{};
    ::getrusage(RUSAGE_SELF, &self);
    EXPECT_LT(c.max_rss_kb, max_rss_mb * 1024 + self.ru_maxrss)
        << "peak RSS " << c.max_rss_kb / 1024 << " MB (this process: " << self.ru_maxrss / 1024 << " MB)";
    return c;
  }
  void set_manifest(const std::function<void(json&)>& f) {
    json m = read_json(dir_ + "/manifest.json");
    f(m);
    write_json(dir_ + "/manifest.json", m);
  }
  std::string dir_;
  BundleContent content_;
};

// ---- manifest.json ------------------------------------------------------------

TEST_F(Reliability, LongFormatVersionIsOneVersionLine) {
  // 26.5k digits overflowed the stack in std::regex_match (exit 139).
  write_bundle(dir_, content_);
  set_manifest([](json& m) { m["format_version"] = std::string(30000, '1'); });
  expect_refused("version", "is not MAJOR.MINOR");
  set_manifest([](json& m) { m["format_version"] = std::string(30000, '1') + ".0"; });
  expect_refused("version", "is not MAJOR.MINOR");
  // Leading zeros still count as the number ("01.2" is major 1; the writer's
  // pieces.ply has the layout of 1.0-1.2).
  set_manifest([](json& m) { m["format_version"] = "01.2"; });
  EXPECT_EQ(run_hrt({"check", dir_}).status, 0);
}

std::string nested_arrays(size_t depth, const std::string& inner) {
  return std::string(depth, '[') + inner + std::string(depth, ']');
}

TEST_F(Reliability, DeeplyNestedWrongTypeIsOneSchemaLine) {
  // A field of the wrong type nested 35k deep overflowed the stack in the
  // message formatter (exit 139).
  write_bundle(dir_, content_);
  std::string text = read_bytes(dir_ + "/manifest.json");
  const std::string key = "\"generator\": {";
  const size_t at = text.find(key);
  ASSERT_NE(at, std::string::npos);
  const size_t end = text.find('}', at);
  text.replace(at, end + 1 - at, "\"generator\": " + nested_arrays(35000, "1"));
  write_bytes(dir_ + "/manifest.json", text);
  expect_refused("schema", "nested deeper than 64");
}

TEST_F(Reliability, NestingDepthBoundOnUnknownFields) {
  // Unknown fields are ignored, but their nesting is bounded all the same:
  // 64 levels (the top-level object is level 1) load, 65 do not.
  write_bundle(dir_, content_);
  std::string text = read_bytes(dir_ + "/manifest.json");
  const std::string base = text.substr(0, text.rfind('}'));
  write_bytes(dir_ + "/manifest.json", base + ", \"x_extra\": " + nested_arrays(63, "0") + "}\n");
  EXPECT_NO_THROW(hrt::load_bundle(dir_));
  write_bytes(dir_ + "/manifest.json", base + ", \"x_extra\": " + nested_arrays(64, "0") + "}\n");
  try {
    hrt::load_bundle(dir_);
    ADD_FAILURE() << "65 levels of nesting accepted";
  } catch (const BundleError& e) {
    EXPECT_EQ(e.error_class(), BundleErrorClass::schema) << e.what();
    EXPECT_NE(std::string(e.what()).find("nested deeper than 64 levels"), std::string::npos) << e.what();
  }
  // 200k levels: no stack overflow in parsing, destruction or messages.
  write_bytes(dir_ + "/manifest.json", base + ", \"x_extra\": " + nested_arrays(200000, "0") + "}\n");
  expect_refused("schema", "nested deeper than 64");
}

TEST_F(Reliability, OversizedManifestRefusedBeforeParsing) {
  write_bundle(dir_, content_);
  std::string text = read_bytes(dir_ + "/manifest.json");
  const std::string base = text.substr(0, text.rfind('}'));
  // An array of 1.5M zeros: 3 MB of text, about 50 MB as a JSON DOM.
  std::string big = "[0";
  for (int i = 0; i < 1500000; ++i) big += ",0";
  write_bytes(dir_ + "/manifest.json", base + ", \"x_extra\": " + big + "]}\n");
  expect_refused("io", "bytes, more than the limit of 1048576 bytes for this file", 40);
}

// ---- atlas.exr ----------------------------------------------------------------

// The header of an EXR file as bytes: offset just past the magic and version,
// each attribute's (name, type, offset of its size field), and the offset just
// past the header's terminating null byte.
struct ExrHeader {
  struct Attr {
    std::string name, type;
    size_t size_at;
  };
  std::vector<Attr> attrs;
  size_t end = 0;
};

uint32_t le32(const std::string& b, size_t o) {
  uint32_t v = 0;
  for (int k = 0; k < 4; ++k) v |= static_cast<uint32_t>(static_cast<unsigned char>(b[o + k])) << (8 * k);
  return v;
}
void put32(std::string& b, size_t o, uint32_t v) {
  for (int k = 0; k < 4; ++k) b[o + k] = static_cast<char>((v >> (8 * k)) & 0xff);
}
std::string u32_bytes(uint32_t v) {
  std::string s(4, '\0');
  put32(s, 0, v);
  return s;
}

ExrHeader walk_header(const std::string& b) {
  ExrHeader h;
  size_t p = 8;
  while (b[p] != '\0') {
    ExrHeader::Attr a;
    a.name = std::string(b.c_str() + p);
    p += a.name.size() + 1;
    a.type = std::string(b.c_str() + p);
    p += a.type.size() + 1;
    a.size_at = p;
    p += 4 + le32(b, p);
    h.attrs.push_back(a);
  }
  h.end = p + 1;
  return h;
}

// Inserts an attribute at the end of the header and shifts the scanline
// offset table (absolute file offsets) by the bytes inserted, so the file
// stays a valid EXR; `claimed` overrides the size field.
std::string insert_attr(const std::string& b, int height, const std::string& name, const std::string& type,
                        const std::string& value, int64_t claimed = -1) {
  const ExrHeader h = walk_header(b);
  std::string attr =
      name + '\0' + type + '\0' + u32_bytes(static_cast<uint32_t>(claimed < 0 ? value.size() : claimed)) + value;
  std::string out = b.substr(0, h.end - 1) + attr + b.substr(h.end - 1);
  const size_t table = h.end + attr.size();
  const int chunks = (height + 15) / 16;  // ZIP: 16 scanlines per chunk
  for (int k = 0; k < chunks; ++k) {
    uint64_t off = 0;
    for (int i = 0; i < 8; ++i)
      off |= static_cast<uint64_t>(static_cast<unsigned char>(out[table + 8 * k + i])) << (8 * i);
    off += attr.size();
    for (int i = 0; i < 8; ++i) out[table + 8 * k + i] = static_cast<char>((off >> (8 * i)) & 0xff);
  }
  return out;
}

TEST_F(Reliability, ExrWriterHelperKeepsAValidFile) {
  // The helper itself: a well-formed extra string attribute loads.
  write_bundle(dir_, content_);
  const std::string exr = read_bytes(dir_ + "/atlas.exr");
  write_bytes(dir_ + "/atlas.exr", insert_attr(exr, content_.height, "comments", "string", "baked by a test"));
  rehash(dir_);
  EXPECT_NO_THROW(hrt::load_bundle(dir_));
}

TEST_F(Reliability, ExrAttributeSizeBeyondFileRefused) {
  // A 4 KB file whose string attribute claims 1.67 GB: OpenEXR allocated it.
  write_bundle(dir_, content_);
  const std::string exr = read_bytes(dir_ + "/atlas.exr");
  write_bytes(dir_ + "/atlas.exr", insert_attr(exr, content_.height, "comments", "string", "x", 1670000000));
  rehash(dir_);
  expect_refused("atlas", "attribute 'comments' (string) claims 1670000000 bytes, more than the");
  // The same on a standard attribute, patched in place.
  write_bundle(dir_, content_);
  std::string b = read_bytes(dir_ + "/atlas.exr");
  for (const auto& a : walk_header(b).attrs)
    if (a.name == "channels") put32(b, a.size_at, 0x7fffff00u);
  write_bytes(dir_ + "/atlas.exr", b);
  rehash(dir_);
  expect_refused("atlas", "attribute 'channels' (chlist) claims");
}

TEST_F(Reliability, ExrCountsInsideAttributesBounded) {
  // Counts inside an attribute that fits the file: a preview image claiming
  // 20000 x 20000 pixels in 24 bytes, a string vector whose entry claims 1 GB.
  write_bundle(dir_, content_);
  const std::string exr = read_bytes(dir_ + "/atlas.exr");
  write_bytes(dir_ + "/atlas.exr", insert_attr(exr, content_.height, "preview", "preview",
                                               u32_bytes(20000) + u32_bytes(20000) + std::string(16, '\0')));
  rehash(dir_);
  expect_refused("atlas", "attribute 'preview' (preview) claims 20000 x 20000 pixels");
  // 2^31 x 2^31 pixels in 8 bytes: w h 4 + 8 wraps to 8 in 64 bits.
  write_bytes(dir_ + "/atlas.exr",
              insert_attr(exr, content_.height, "preview", "preview", u32_bytes(1u << 31) + u32_bytes(1u << 31)));
  rehash(dir_);
  expect_refused("atlas", "attribute 'preview' (preview) claims 2147483648 x 2147483648 pixels in 8 bytes");
  write_bytes(dir_ + "/atlas.exr",
              insert_attr(exr, content_.height, "multiView", "stringvector", u32_bytes(1000000000) + "left"));
  rehash(dir_);
  expect_refused("atlas", "attribute 'multiView' (stringvector)");
}

TEST_F(Reliability, ExrDataWindowBoundedBeforeOpenExr) {
  // A data window of 96 x 2^30 scanlines in an otherwise valid file: OpenEXR
  // sized its line tables from it before the loader compared it.
  write_bundle(dir_, content_);
  std::string b = read_bytes(dir_ + "/atlas.exr");
  for (const auto& a : walk_header(b).attrs)
    if (a.name == "dataWindow") put32(b, a.size_at + 4 + 12, (1u << 30) - 1);
  write_bytes(dir_ + "/atlas.exr", b);
  rehash(dir_);
  expect_refused("atlas", "image is 96 x 1073741824 texels, more than the limit", 60);
}

TEST_F(Reliability, AtlasLimitOnManifestAndHeader) {
  // Manifest and EXR header agreeing on 16384 x 16384: 4 GiB of texels
  // allocated before the decoder failed. The limit: sides <= 8192, W H <= 2^24.
  write_bundle(dir_, content_);
  std::string b = read_bytes(dir_ + "/atlas.exr");
  for (const auto& a : walk_header(b).attrs) {
    if (a.name == "dataWindow" || a.name == "displayWindow") {
      put32(b, a.size_at + 4 + 8, 16383);
      put32(b, a.size_at + 4 + 12, 16383);
    }
  }
  write_bytes(dir_ + "/atlas.exr", b);
  set_manifest([](json& m) {
    m["atlas"]["width"] = m["atlas"]["height"] = 16384;
    m["files"]["atlas"]["width"] = m["files"]["atlas"]["height"] = 16384;
  });
  rehash(dir_);
  expect_refused("atlas", "16384 x 16384 texels, more than the limit", 60);
  // On the manifest: 8192 x 2048 (= 2^24 texels) is within the limit (and
  // then differs from the file), 8193 x 1 breaks the side limit, 4096 x 4097
  // the texel count.
  write_bundle(dir_, content_);
  struct Size {
    int w, h;
    bool over;
  };
  for (const Size& sz : {Size{8192, 2048, false}, Size{8193, 1, true}, Size{4096, 4097, true}}) {
    set_manifest([&](json& m) {
      m["atlas"]["width"] = m["files"]["atlas"]["width"] = sz.w;
      m["atlas"]["height"] = m["files"]["atlas"]["height"] = sz.h;
    });
    try {
      hrt::load_bundle(dir_);
      ADD_FAILURE();
    } catch (const BundleError& e) {
      EXPECT_EQ(e.error_class(), BundleErrorClass::atlas);
      const bool limit = std::string(e.what()).find("texels, more than the limit") != std::string::npos;
      EXPECT_EQ(limit, sz.over) << e.what();
    }
  }
  // The header alone (manifest within the limit, EXR header above it).
  write_bundle(dir_, content_);
  hrt::io::AtlasSpec spec;
  spec.width = 96;
  spec.height = 64;
  spec.compression = "zip";
  spec.channels = {"A", "B", "G", "R"};
  try {
    hrt::io::read_atlas_exr(b, "atlas.exr", spec);
    ADD_FAILURE();
  } catch (const BundleError& e) {
    EXPECT_NE(std::string(e.what()).find("16384 x 16384 texels, more than the limit"), std::string::npos) << e.what();
  }
}

TEST_F(Reliability, AtlasChecksCostTheTrianglesNotTheirBoundingBoxes) {
  // 3000 sliver UV triangles across a 1024 x 1024 atlas (a 114 KB coarse.ply):
  // the texel checks walked each triangle's bounding box, 3e9 texel tests
  // (6.8 s). Now per-row spans, and a work bound of 16 tests per texel of
  // the atlas + 64 per triangle, which valid (non-overlapping) UV charts stay
  // far below.
  BundleContent slivers = content_;
  slivers.faces.assign(3000, content_.faces[0]);
  slivers.uvs.assign(3000, {0.0f, 0.0f, 1.0f, 1.0f, 0.5001f, 0.5f});
  slivers.width = slivers.height = 1024;
  slivers.rgba.assign(size_t{1024} * 1024 * 4, 0.0f);
  slivers.manifest["coarse"]["triangles"] = 3000;
  slivers.manifest["atlas"]["width"] = slivers.manifest["atlas"]["height"] = 1024;
  // The same atlas under 200 copies of one triangle over half of it.
  BundleContent overlapping = slivers;
  overlapping.faces.assign(200, content_.faces[0]);
  overlapping.uvs.assign(200, {0.0f, 0.0f, 1.0f, 0.0f, 1.0f, 1.0f});
  overlapping.manifest["coarse"]["triangles"] = 200;
  for (const BundleContent* b : {&slivers, &overlapping}) {
    write_bundle(dir_, *b);
    try {
      hrt::load_bundle(dir_);
      ADD_FAILURE();
    } catch (const BundleError& e) {
      EXPECT_EQ(e.error_class(), BundleErrorClass::atlas);
      EXPECT_NE(
          std::string(e.what()).find("texel tests (16 per texel of the atlas + 64 per triangle): UV triangles overlap"),
          std::string::npos)
          << e.what();
    }
  }
}

// ---- pieces.ply -----------------------------------------------------------------

TEST_F(Reliability, PieceVertexLimit) {
  // 512-gon prism: 1024 vertices, accepted.
  prism(512, 0.005, -0.005, 0.005, content_.piece_vertices[0], content_.piece_faces[0]);
  write_bundle(dir_, content_);
  EXPECT_NO_THROW(hrt::load_bundle(dir_));
  // 2000-gon prism: refused before the vertices x faces convexity check.
  prism(2000, 0.005, -0.005, 0.005, content_.piece_vertices[1], content_.piece_faces[1]);
  write_bundle(dir_, content_);
  try {
    hrt::load_bundle(dir_);
    ADD_FAILURE() << "a piece of 4000 vertices accepted";
  } catch (const BundleError& e) {
    EXPECT_EQ(e.error_class(), BundleErrorClass::pieces);
    EXPECT_NE(std::string(e.what()).find("piece 1 has 4000 vertices, more than the limit 1024"), std::string::npos)
        << e.what();
  }
  // Also without the invariant checks (the limit bounds what later stages get).
  hrt::LoadOptions lo;
  lo.check_invariants = false;
  EXPECT_THROW(hrt::load_bundle(dir_, lo), BundleError);
}

TEST_F(Reliability, PieceFaceLimit) {
  // A piece of 8 vertices with 3000 faces (a convex piece of V <= 1024
  // vertices has at most 2 V - 4 <= 2044 triangles).
  auto& f = content_.piece_faces[0];
  const std::vector<hrt::Tri> once = f;
  while (f.size() < 3000) f.insert(f.end(), once.begin(), once.end());
  write_bundle(dir_, content_);
  try {
    hrt::load_bundle(dir_);
    ADD_FAILURE();
  } catch (const BundleError& e) {
    EXPECT_EQ(e.error_class(), BundleErrorClass::pieces);
    EXPECT_NE(std::string(e.what()).find("piece 0 has 3000 faces, more than the limit 2044"), std::string::npos)
        << e.what();
  }
}

}  // namespace

namespace {

// Positions farther than 1e4 m from the origin along an axis (hbake's input
// limit, docs/input-contract.md) are refused in each file; a fuzz input with a
// coarse vertex 1e7 m away reached an int overflow in the rasterizer.
TEST_F(Reliability, CoordinatesWithinTheContract) {
  write_bundle(dir_, content_);
  EXPECT_NO_THROW(hrt::load_bundle(dir_));
  BundleContent c = content_;
  c.vertices[0][2] = 2e4f;
  write_bundle(dir_, c);
  expect_refused("mesh", "1 vertex farther than 10000 m from the origin along an axis: vertex 0");
  c = content_;
  c.piece_vertices[0][0][1] = -2e4f;
  write_bundle(dir_, c);
  expect_refused("pieces", "1 vertex farther than 10000 m from the origin along an axis (first: vertex 0)");
  c = content_;
  c.rgba[0] = 1e7f;  // texel (0, 0), R
  write_bundle(dir_, c);
  expect_refused("atlas",
                 "1 texel with a position farther than 10000 m from the origin along an axis (first: texel (0, 0))");
}

}  // namespace
