// The UDP bridge's wire format (docs/udp-protocol.md): pure parse and encode
// functions on byte buffers, and the order filter of a pose stream.
//
// Every function here is allocation-free, never reads or writes outside
// [data, data + size) / [out, out + capacity), and never throws, so the
// device thread can call them and a fuzzer can feed them anything
// (runtime/fuzz/fuzz_udp.cpp). All fields are little-endian whatever the host.
#pragma once

#include <cstddef>
#include <cstdint>

namespace hrt {
namespace udp {

constexpr uint32_t kMagic = 0x55545248u;  // the bytes 'H' 'R' 'T' 'U' read as a little-endian uint32
constexpr uint16_t kVersion = 1;
constexpr size_t kHeaderSize = 24;
constexpr size_t kPoseSize = 88;
constexpr size_t kWrenchSize = 80;
constexpr size_t kObjectPosesHeaderSize = 32;  // header + count + total
constexpr size_t kObjectPoseSize = 64;         // per object
// 32 + 64 * 1000 = 64032 bytes, below UDP's 65507-byte payload limit over IPv4.
constexpr uint32_t kMaxObjectsPerPacket = 1000;
constexpr size_t kMaxPacketSize = kObjectPosesHeaderSize + kObjectPoseSize * kMaxObjectsPerPacket;

enum class MessageType : uint8_t {
  pose = 1,          // client -> hrt: the device handle's pose, buttons, clutch
  wrench = 2,        // hrt -> client: the wrench to display
  object_poses = 3,  // hrt -> display: poses of the scene's objects
};

// Header flags.
constexpr uint8_t kFlagRestart = 0x01;  // pose: a new stream starts here (its sequence restarts)

enum class Result {
  ok = 0,
  bad_size,          // shorter than a header, or not the exact size of its type (and count)
  bad_magic,         // not "HRTU"
  bad_version,       // a version other than kVersion
  bad_type,          // unknown type, or not the type the caller parses
  non_finite,        // a NaN or an infinity in a double field (timestamp included)
  bad_value,         // a zero quaternion (norm < 1e-6), an object count above kMaxObjectsPerPacket,
                     // an object index >= total
  buffer_too_small,  // parse: more objects than the caller's array; encode: output capacity
};
const char* to_string(Result r) noexcept;

struct Header {
  MessageType type = MessageType::pose;
  uint8_t flags = 0;
  uint32_t sequence = 0;   // per sender and type, +1 per packet, wraps at 2^32
  double timestamp = 0.0;  // sender's clock, s (hrt: session time)
};

struct PoseMessage {
  Header header;
  double position[3] = {0, 0, 0};       // m, device frame
  double quaternion[4] = {0, 0, 0, 1};  // x y z w, any non-zero norm (the receiver normalizes)
  uint32_t buttons = 0;
  bool clutch = false;  // on the wire a byte, nonzero = held
};

struct WrenchMessage {
  Header header;
  uint32_t answers = 0;          // sequence of the newest pose packet hrt had read when it computed this
  double force[3] = {0, 0, 0};   // N, device frame
  double torque[3] = {0, 0, 0};  // N m, device frame
};

struct ObjectPose {
  uint32_t index = 0;  // the object's index in the scene (0 = the probe)
  double position[3] = {0, 0, 0};
  double quaternion[4] = {0, 0, 0, 1};
};

struct ObjectPosesMessage {
  Header header;
  uint32_t total = 0;  // objects in the scene; a frame of more than kMaxObjectsPerPacket spans packets
  uint32_t count = 0;  // objects in this packet
};

// Checks magic, version and the header's type field and fills `out`; the
// size only as far as the header goes (the typed parsers check the rest).
Result parse_header(const uint8_t* data, size_t size, Header& out) noexcept;

Result parse_pose(const uint8_t* data, size_t size, PoseMessage& out) noexcept;
Result parse_wrench(const uint8_t* data, size_t size, WrenchMessage& out) noexcept;
// Fills objects[0 .. out.count); buffer_too_small when count > capacity.
Result parse_object_poses(const uint8_t* data, size_t size, ObjectPosesMessage& out, ObjectPose* objects,
                          size_t capacity) noexcept;

// Encoders: write the packet (version kVersion, the type of the function, the
// other header fields from the message) into out[0 .. written). They refuse
// what the parsers would reject (non_finite, bad_value) and write nothing then.
Result encode_pose(const PoseMessage& m, uint8_t* out, size_t capacity, size_t& written) noexcept;
Result encode_wrench(const WrenchMessage& m, uint8_t* out, size_t capacity, size_t& written) noexcept;
// m.count objects from `objects`; m.total must exceed every index.
Result encode_object_poses(const ObjectPosesMessage& m, const ObjectPose* objects, uint8_t* out, size_t capacity,
                           size_t& written) noexcept;

// True when `a` is later than `b` in serial-number arithmetic (RFC 1982):
// (a - b) mod 2^32 in [1, 2^31). The sequence wraps from 2^32 - 1 to 0 and stays
// in order.
constexpr bool sequence_after(uint32_t a, uint32_t b) noexcept {
  return a != b && static_cast<uint32_t>(a - b) < 0x80000000u;
}

// The order check of a pose stream (docs/udp-protocol.md, "Order"): a packet
// is accepted when it is later than the last accepted one of its stream.
// A new stream starts (and its first packet is accepted whatever its
// sequence) at the first packet, at a packet with kFlagRestart, and at a
// packet from another source (address and port: a client that restarted
// with a new socket). Duplicates and late packets are rejected.
class SequenceFilter {
 public:
  bool accept(uint32_t sequence, uint8_t flags, uint64_t source) noexcept {
    if (!started_ || (flags & kFlagRestart) || source != source_) {
      started_ = true;
      source_ = source;
      last_ = sequence;
      ++streams_;
      return true;
    }
    if (!sequence_after(sequence, last_)) return false;
    last_ = sequence;
    return true;
  }
  void reset() noexcept { started_ = false; }
  bool started() const noexcept { return started_; }
  uint32_t last() const noexcept { return last_; }
  uint64_t streams() const noexcept { return streams_; }  // streams started so far

 private:
  bool started_ = false;
  uint32_t last_ = 0;
  uint64_t source_ = 0;
  uint64_t streams_ = 0;
};

}  // namespace udp
}  // namespace hrt
