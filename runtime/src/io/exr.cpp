// atlas.exr reader (docs/bundle-format.md, "atlas.exr") on OpenEXR 3.1's C++ API.
//
// The bytes were read (and hashed) once by the loader; OpenEXR reads them
// through an in-memory Imf::IStream, so the verified bytes are the parsed ones
// and a truncated file ends in an exception, never a read past the end.
// OpenEXR trusts the sizes and counts its header claims: it allocates a
// string attribute's claimed size, a preview's width x height, a string
// vector entry's length and line tables sized by the data window before it
// reads a byte of them (a 4 KB file claiming 1.67 GB was enough). So the
// header is walked here first, by hand, and every claim is bounded by the
// bytes actually in the file, the data window by the atlas limit and the
// manifest, before OpenEXR sees the file; the texel buffer is allocated only
// after OpenEXR's header agrees with the manifest too.
#include <algorithm>
#include <cctype>
#include <cstring>
#include <thread>

#include <Iex.h>
#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfIO.h>
#include <ImfInputFile.h>
#include <ImfThreading.h>
#include <ImfVersion.h>

#include "io/bundle_io.h"

namespace hrt::io {
namespace {

[[noreturn]] void fail(const std::string& label, const std::string& what) {
  throw BundleError(BundleErrorClass::atlas, label + ": " + what);
}

class MemIStream : public Imf::IStream {
 public:
  MemIStream(const std::string& bytes, const char* name) : Imf::IStream(name), bytes_(bytes) {}
  bool read(char c[], int n) override {
    if (n < 0 || static_cast<uint64_t>(n) > bytes_.size() - pos_) throw Iex::InputExc("unexpected end of file");
    std::memcpy(c, bytes_.data() + pos_, static_cast<size_t>(n));
    pos_ += static_cast<uint64_t>(n);
    return pos_ < bytes_.size();
  }
  uint64_t tellg() override { return pos_; }
  void seekg(uint64_t pos) override {
    // Seeking past the end is allowed by the interface; the next read throws.
    pos_ = pos > bytes_.size() ? bytes_.size() : pos;
  }

 private:
  const std::string& bytes_;
  uint64_t pos_ = 0;
};

const char* compression_name(Imf::Compression c) {
  switch (c) {
    case Imf::NO_COMPRESSION: return "no";
    case Imf::RLE_COMPRESSION: return "rle";
    case Imf::ZIPS_COMPRESSION: return "zips";
    case Imf::ZIP_COMPRESSION: return "zip";
    case Imf::PIZ_COMPRESSION: return "piz";
    case Imf::PXR24_COMPRESSION: return "pxr24";
    case Imf::B44_COMPRESSION: return "b44";
    case Imf::B44A_COMPRESSION: return "b44a";
    case Imf::DWAA_COMPRESSION: return "dwaa";
    case Imf::DWAB_COMPRESSION: return "dwab";
    default: return "unknown";
  }
}

std::string upper(std::string s) {
  for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

std::string box_str(const Imath::Box2i& b) {
  return "(" + std::to_string(b.min.x) + ", " + std::to_string(b.min.y) + ") - (" + std::to_string(b.max.x) + ", " +
         std::to_string(b.max.y) + ")";
}

// The atlas limit of docs/input-contract.md (shared with hbake): each side in
// [1, 8192], at most 2^24 texels (256 MiB of float32 RGBA).
bool within_atlas_limit(int64_t w, int64_t h) {
  return w >= 1 && h >= 1 && w <= kMaxAtlasSide && h <= kMaxAtlasSide && w * h <= kMaxAtlasTexels;
}

// Bounds of the header walk. OpenEXR's own headers are about 350 bytes with
// 8 attributes and the atlas has 4 channels: these are generous.
constexpr size_t kMaxHeaderBytes = 1 << 20;
constexpr int kMaxAttributes = 1024;
constexpr int kMaxChannels = 64;

uint32_t get_u32(const std::string& b, size_t o) {
  return static_cast<uint32_t>(static_cast<unsigned char>(b[o])) |
         static_cast<uint32_t>(static_cast<unsigned char>(b[o + 1])) << 8 |
         static_cast<uint32_t>(static_cast<unsigned char>(b[o + 2])) << 16 |
         static_cast<uint32_t>(static_cast<unsigned char>(b[o + 3])) << 24;
}
int32_t get_i32(const std::string& b, size_t o) {
  const uint32_t u = get_u32(b, o);
  int32_t v;
  std::memcpy(&v, &u, 4);
  return v;
}

std::string printable(const std::string& s) {
  std::string out;
  for (char c : s) out += (c >= 0x20 && c < 0x7f) ? c : '?';
  return out;
}

// Walks the header of a single-part scanline EXR (magic and version already
// checked): attributes are `name\0 type\0 int32 size, value`, ended by a
// null byte. Refuses any claim beyond the file, then the data window against
// the atlas limit and the manifest. Messages: "cannot read the OpenEXR header:
// ..." for a malformed header, the loader's usual ones for the data window.
void check_header_bounds(const std::string& b, const std::string& label, const AtlasSpec& spec, int version) {
  const std::string bad = "cannot read the OpenEXR header: ";
  const size_t n = b.size();
  // Attribute names and type names: 31 characters, 255 with the long-names flag.
  const size_t max_name = (version & Imf::LONG_NAMES_FLAG) ? 255 : 31;
  size_t p = 8;
  auto cstr = [&](const char* what) {
    const size_t end = b.find('\0', p);
    if (end == std::string::npos || end - p > max_name) {
      fail(label, bad + "attribute " + what + " at byte " + std::to_string(p) + " is not a string of at most " +
                      std::to_string(max_name) + " characters within the file");
    }
    std::string out = b.substr(p, end - p);
    p = end + 1;
    return out;
  };
  bool have_dw = false;
  int32_t dw[4] = {0, 0, 0, 0};  // xMin, yMin, xMax, yMax
  for (int count = 0;; ++count) {
    if (p >= n) fail(label, bad + "the header is truncated (no end-of-header byte)");
    if (b[p] == '\0') break;
    if (count >= kMaxAttributes) fail(label, bad + "more than " + std::to_string(kMaxAttributes) + " attributes");
    const std::string name = cstr("name"), type = cstr("type name");
    const std::string what = "attribute '" + printable(name) + "' (" + printable(type) + ")";
    if (n - p < 4) fail(label, bad + "the header is truncated in " + what);
    const int32_t size = get_i32(b, p);
    p += 4;
    // Attribute values are stored uncompressed: none can exceed the bytes left.
    if (size < 0 || static_cast<uint64_t>(size) > n - p) {
      fail(label, bad + what + " claims " + std::to_string(size) + " bytes, more than the " + std::to_string(n - p) +
                      " bytes left in the file");
    }
    const size_t v = p, vs = static_cast<size_t>(size);
    // Counts inside a value, which OpenEXR allocates before reading.
    if (type == "preview") {
      if (vs < 8) fail(label, bad + what + " has " + std::to_string(vs) + " bytes (at least 8 needed)");
      const uint64_t w = get_u32(b, v), h = get_u32(b, v + 4);
      // In 128 bits: w h 4 + 8 overflows 64 bits for w, h near 2^32.
      if (static_cast<unsigned __int128>(w) * h * 4 + 8 != vs) {
        fail(label, bad + what + " claims " + std::to_string(w) + " x " + std::to_string(h) + " pixels in " +
                        std::to_string(vs) + " bytes");
      }
    } else if (type == "stringvector") {
      size_t q = 0;
      for (int k = 0; q < vs; ++k) {
        if (vs - q < 4) fail(label, bad + what + " entry " + std::to_string(k) + " is truncated");
        const int32_t len = get_i32(b, v + q);
        q += 4;
        if (len < 0 || static_cast<uint64_t>(len) > vs - q) {
          fail(label, bad + what + " entry " + std::to_string(k) + " claims " + std::to_string(len) +
                          " bytes, more than the " + std::to_string(vs - q) + " left in the attribute");
        }
        q += static_cast<size_t>(len);
      }
    } else if (type == "chlist") {
      // name\0, pixel type int32, pLinear u8, 3 reserved, x/y sampling int32; a null byte ends it.
      size_t q = 0;
      for (int k = 0;; ++k) {
        if (q >= vs) fail(label, bad + what + " is truncated");
        if (b[v + q] == '\0') break;
        if (k >= kMaxChannels) fail(label, bad + what + " has more than " + std::to_string(kMaxChannels) + " channels");
        const size_t end = b.find('\0', v + q);
        if (end == std::string::npos || end >= v + vs || end - (v + q) > 255 || v + vs - (end + 1) < 16) {
          fail(label, bad + what + " is truncated in channel " + std::to_string(k));
        }
        q = end + 1 + 16 - v;
      }
    } else if (name == "dataWindow") {
      if (type != "box2i" || vs != 16) fail(label, bad + what + " is not a box2i of 16 bytes");
      for (int k = 0; k < 4; ++k) dw[k] = get_i32(b, v + 4 * k);
      have_dw = true;
    }
    p += vs;
    if (p - 8 > kMaxHeaderBytes)
      fail(label, bad + "the header is larger than " + std::to_string(kMaxHeaderBytes) + " bytes");
  }
  if (!have_dw) fail(label, bad + "no dataWindow attribute");
  // The same messages as the checks on OpenEXR's header below, so the order
  // of the checks does not change what a bundle is told.
  if (dw[0] != 0 || dw[1] != 0) {
    fail(label, "data window starts at (" + std::to_string(dw[0]) + ", " + std::to_string(dw[1]) + "), not at (0, 0)");
  }
  const int64_t w = static_cast<int64_t>(dw[2]) + 1, h = static_cast<int64_t>(dw[3]) + 1;
  if (!within_atlas_limit(w, h)) {
    fail(label, "image is " + std::to_string(w) + " x " + std::to_string(h) + " texels, more than the limit" +
                    kAtlasLimitText);
  }
  if (w != spec.width || h != spec.height) {
    fail(label, "image is " + std::to_string(w) + "x" + std::to_string(h) + ", the manifest says " +
                    std::to_string(spec.width) + "x" + std::to_string(spec.height));
  }
}

}  // namespace

Atlas read_atlas_exr(const std::string& bytes, const std::string& label, const AtlasSpec& spec, int threads) {
  // Magic number and version flags first: a clear message for "not an EXR",
  // and refuse tiled, deep and multi-part files before OpenEXR interprets them.
  if (bytes.size() < 8) fail(label, "not an OpenEXR file (" + std::to_string(bytes.size()) + " bytes)");
  auto le32 = [&](size_t o) {
    return static_cast<int>(static_cast<uint32_t>(static_cast<unsigned char>(bytes[o])) |
                            static_cast<uint32_t>(static_cast<unsigned char>(bytes[o + 1])) << 8 |
                            static_cast<uint32_t>(static_cast<unsigned char>(bytes[o + 2])) << 16 |
                            static_cast<uint32_t>(static_cast<unsigned char>(bytes[o + 3])) << 24);
  };
  if (le32(0) != Imf::MAGIC) fail(label, "not an OpenEXR file (bad magic number)");
  const int version = le32(4);
  if (Imf::getVersion(version) != 2)
    fail(label, "unsupported OpenEXR file version " + std::to_string(Imf::getVersion(version)));
  if (Imf::isMultiPart(version)) fail(label, "multi-part OpenEXR file (a single-part scanline image is required)");
  if (Imf::isNonImage(version)) fail(label, "storage is deep, not a scanline image");
  if (Imf::isTiled(version)) fail(label, "storage is tiled, not a scanline image");
  if (!Imf::supportsFlags(Imf::getFlags(version))) fail(label, "unknown OpenEXR version flags");

  const int W = spec.width, H = spec.height;
  // The manifest's size bounds the texel buffer (load_bundle checked it; a
  // direct caller may not have).
  if (!within_atlas_limit(W, H)) {
    fail(label, "the manifest's atlas is " + std::to_string(W) + " x " + std::to_string(H) +
                    " texels, more than the limit" + kAtlasLimitText);
  }
  check_header_bounds(bytes, label, spec, version);
  Atlas atlas;
  const char* stage = "cannot read the OpenEXR header: ";
  try {
    MemIStream stream(bytes, label.c_str());
    // ZIP/PIZ decoding dominates the load of a large atlas (about 1 s for
    // 2048 x 2048 on one core); OpenEXR decodes blocks of scanlines in
    // parallel on its global thread pool, which must have the threads.
    if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    if (threads > 1 && Imf::globalThreadCount() < threads) Imf::setGlobalThreadCount(threads);
    Imf::InputFile file(stream, threads > 1 ? threads : 0);
    const Imf::Header& h = file.header();

    if (h.hasTileDescription()) fail(label, "storage is tiled, not a scanline image");
    const Imf::Compression comp = h.compression();
    const std::string cname = compression_name(comp);
    if (comp != Imf::ZIP_COMPRESSION && comp != Imf::PIZ_COMPRESSION) {
      fail(label, "compression " + upper(cname) + " is not allowed (ZIP or PIZ only)");
    }
    if (spec.compression != cname) {
      fail(label, "compression is " + upper(cname) + ", the manifest says " + upper(spec.compression));
    }
    const Imath::Box2i want(Imath::V2i(0, 0), Imath::V2i(W - 1, H - 1));
    const Imath::Box2i dw = h.dataWindow();
    if (dw.min.x != 0 || dw.min.y != 0) {
      fail(label,
           "data window starts at (" + std::to_string(dw.min.x) + ", " + std::to_string(dw.min.y) + "), not at (0, 0)");
    }
    if (dw != want) {
      fail(label, "image is " + std::to_string(static_cast<int64_t>(dw.max.x) + 1) + "x" +
                      std::to_string(static_cast<int64_t>(dw.max.y) + 1) + ", the manifest says " + std::to_string(W) +
                      "x" + std::to_string(H));
    }
    if (h.displayWindow() != want) {
      fail(label, "display window is " + box_str(h.displayWindow()) + ", expected " + box_str(want));
    }
    // Channels looked up by name; the file's set must equal the manifest's.
    const Imf::ChannelList& channels = h.channels();
    std::string present;
    for (auto it = channels.begin(); it != channels.end(); ++it)
      present += (present.empty() ? "" : ", ") + std::string(it.name());
    for (const std::string& name : spec.channels) {
      if (!channels.findChannel(name)) {
        fail(label, "missing channel '" + name + "' (channels present: " + (present.empty() ? "none" : present) + ")");
      }
    }
    for (auto it = channels.begin(); it != channels.end(); ++it) {
      if (std::find(spec.channels.begin(), spec.channels.end(), it.name()) == spec.channels.end()) {
        fail(label, std::string("channels ") + it.name() + " are not declared in the manifest");
      }
    }
    for (auto it = channels.begin(); it != channels.end(); ++it) {
      const Imf::Channel& ch = it.channel();
      if (ch.xSampling != 1 || ch.ySampling != 1) {
        fail(label, std::string("channel '") + it.name() + "' is subsampled (" + std::to_string(ch.xSampling) + "x" +
                        std::to_string(ch.ySampling) + ")");
      }
    }
    for (auto it = channels.begin(); it != channels.end(); ++it) {
      const Imf::PixelType t = it.channel().type;
      if (t != Imf::FLOAT) {
        fail(label, std::string("channel '") + it.name() + "' has pixel type " + (t == Imf::HALF ? "HALF" : "UINT") +
                        ", the manifest says FLOAT");
      }
    }
    static const char* kNames[4] = {"R", "G", "B", "A"};

    atlas.width = W;
    atlas.height = H;
    atlas.rgba.assign(static_cast<size_t>(W) * static_cast<size_t>(H) * 4, 0.0f);
    Imf::FrameBuffer fb;
    const size_t xs = 4 * sizeof(float), ys = xs * static_cast<size_t>(W);
    char* base = reinterpret_cast<char*>(atlas.rgba.data());
    for (int c = 0; c < 4; ++c) {
      // Data window starts at (0, 0), so the slice base is the buffer itself.
      fb.insert(kNames[c], Imf::Slice(Imf::FLOAT, base + c * sizeof(float), xs, ys, 1, 1, 0.0));
    }
    file.setFrameBuffer(fb);
    stage = "cannot decode the pixel data: ";
    file.readPixels(0, H - 1);
  } catch (const BundleError&) {
    throw;
  } catch (const std::exception& e) {
    std::string what = e.what();
    if (what.size() > 200) what = what.substr(0, 200) + "...";
    for (char& ch : what)
      if (ch == '\n') ch = ' ';
    fail(label, stage + what);
  }
  return atlas;
}

}  // namespace hrt::io
