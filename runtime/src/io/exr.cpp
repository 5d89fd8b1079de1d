// atlas.exr reader (docs/bundle-format.md, "atlas.exr") on OpenEXR 3.1's C++ API.
//
// The bytes were read (and hashed) once by the loader; OpenEXR reads them
// through an in-memory Imf::IStream, so the verified bytes are the parsed ones
// and a truncated file ends in an exception, never a read past the end.
// Header fields are checked against the manifest before any pixel buffer is
// allocated, so a corrupted data window cannot cause a huge allocation.
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
  if (Imf::getVersion(version) != 2) fail(label, "unsupported OpenEXR file version " + std::to_string(Imf::getVersion(version)));
  if (Imf::isMultiPart(version)) fail(label, "multi-part OpenEXR file (a single-part scanline image is required)");
  if (Imf::isNonImage(version)) fail(label, "storage is deep, not a scanline image");
  if (Imf::isTiled(version)) fail(label, "storage is tiled, not a scanline image");
  if (!Imf::supportsFlags(Imf::getFlags(version))) fail(label, "unknown OpenEXR version flags");

  const int W = spec.width, H = spec.height;
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
      fail(label, "data window starts at (" + std::to_string(dw.min.x) + ", " + std::to_string(dw.min.y) + "), not at (0, 0)");
    }
    if (dw != want) {
      fail(label, "image is " + std::to_string(static_cast<int64_t>(dw.max.x) + 1) + "x" +
                      std::to_string(static_cast<int64_t>(dw.max.y) + 1) + ", the manifest says " + std::to_string(W) + "x" +
                      std::to_string(H));
    }
    if (h.displayWindow() != want) {
      fail(label, "display window is " + box_str(h.displayWindow()) + ", expected " + box_str(want));
    }
    // Channels looked up by name; the file's set must equal the manifest's.
    const Imf::ChannelList& channels = h.channels();
    std::string present;
    for (auto it = channels.begin(); it != channels.end(); ++it) present += (present.empty() ? "" : ", ") + std::string(it.name());
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
    for (char& ch : what) if (ch == '\n') ch = ' ';
    fail(label, stage + what);
  }
  return atlas;
}

}  // namespace hrt::io
