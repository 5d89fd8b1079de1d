// The UDP bridge's wire format (hrt/udp_protocol.h, docs/udp-protocol.md).
#include "hrt/udp_protocol.h"

#include <cmath>
#include <cstring>

namespace hrt {
namespace udp {
namespace {

// Byte-wise little-endian access: correct on any host and at any alignment
// (datagram buffers carry no alignment promise).
uint32_t get_u32(const uint8_t* p) noexcept {
  return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}
uint16_t get_u16(const uint8_t* p) noexcept { return uint16_t(p[0] | p[1] << 8); }
double get_f64(const uint8_t* p) noexcept {
  uint64_t u = 0;
  for (int i = 7; i >= 0; --i) u = u << 8 | p[i];
  double d;
  std::memcpy(&d, &u, sizeof d);
  return d;
}
void put_u32(uint8_t* p, uint32_t v) noexcept {
  for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
}
void put_u16(uint8_t* p, uint16_t v) noexcept {
  p[0] = uint8_t(v);
  p[1] = uint8_t(v >> 8);
}
void put_f64(uint8_t* p, double d) noexcept {
  uint64_t u;
  std::memcpy(&u, &d, sizeof u);
  for (int i = 0; i < 8; ++i) p[i] = uint8_t(u >> (8 * i));
}

bool finite(const double* v, int n) noexcept {
  for (int i = 0; i < n; ++i)
    if (!std::isfinite(v[i])) return false;
  return true;
}

// A quaternion with no usable direction (the receiver normalizes the rest).
bool zero_quaternion(const double q[4]) noexcept {
  return q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] < 1e-12;
}

void put_header(uint8_t* p, MessageType type, const Header& h) noexcept {
  put_u32(p, kMagic);
  put_u16(p + 4, kVersion);
  p[6] = static_cast<uint8_t>(type);
  p[7] = h.flags;
  put_u32(p + 8, h.sequence);
  put_u32(p + 12, 0);  // reserved
  put_f64(p + 16, h.timestamp);
}

// Header check plus the expected type.
Result typed_header(const uint8_t* data, size_t size, MessageType type, Header& out) noexcept {
  const Result r = parse_header(data, size, out);
  if (r != Result::ok) return r;
  if (out.type != type) return Result::bad_type;
  return Result::ok;
}

}  // namespace

const char* to_string(Result r) noexcept {
  switch (r) {
    case Result::ok: return "ok";
    case Result::bad_size: return "bad_size";
    case Result::bad_magic: return "bad_magic";
    case Result::bad_version: return "bad_version";
    case Result::bad_type: return "bad_type";
    case Result::non_finite: return "non_finite";
    case Result::bad_value: return "bad_value";
    case Result::buffer_too_small: return "buffer_too_small";
  }
  return "unknown";
}

Result parse_header(const uint8_t* data, size_t size, Header& out) noexcept {
  if (data == nullptr || size < kHeaderSize) return Result::bad_size;
  if (get_u32(data) != kMagic) return Result::bad_magic;
  if (get_u16(data + 4) != kVersion) return Result::bad_version;
  const uint8_t type = data[6];
  if (type < 1 || type > 3) return Result::bad_type;
  out.type = static_cast<MessageType>(type);
  out.flags = data[7];
  out.sequence = get_u32(data + 8);
  out.timestamp = get_f64(data + 16);
  if (!std::isfinite(out.timestamp)) return Result::non_finite;
  return Result::ok;
}

Result parse_pose(const uint8_t* data, size_t size, PoseMessage& out) noexcept {
  Result r = typed_header(data, size, MessageType::pose, out.header);
  if (r != Result::ok) return r;
  if (size != kPoseSize) return Result::bad_size;
  for (int i = 0; i < 3; ++i) out.position[i] = get_f64(data + 24 + 8 * i);
  for (int i = 0; i < 4; ++i) out.quaternion[i] = get_f64(data + 48 + 8 * i);
  out.buttons = get_u32(data + 80);
  out.clutch = data[84] != 0;
  if (!finite(out.position, 3) || !finite(out.quaternion, 4)) return Result::non_finite;
  if (zero_quaternion(out.quaternion)) return Result::bad_value;
  return Result::ok;
}

Result parse_wrench(const uint8_t* data, size_t size, WrenchMessage& out) noexcept {
  Result r = typed_header(data, size, MessageType::wrench, out.header);
  if (r != Result::ok) return r;
  if (size != kWrenchSize) return Result::bad_size;
  out.answers = get_u32(data + 24);
  for (int i = 0; i < 3; ++i) out.force[i] = get_f64(data + 32 + 8 * i);
  for (int i = 0; i < 3; ++i) out.torque[i] = get_f64(data + 56 + 8 * i);
  if (!finite(out.force, 3) || !finite(out.torque, 3)) return Result::non_finite;
  return Result::ok;
}

Result parse_object_poses(const uint8_t* data, size_t size, ObjectPosesMessage& out, ObjectPose* objects,
                          size_t capacity) noexcept {
  Result r = typed_header(data, size, MessageType::object_poses, out.header);
  if (r != Result::ok) return r;
  if (size < kObjectPosesHeaderSize) return Result::bad_size;
  const uint32_t count = get_u32(data + 24);
  out.total = get_u32(data + 28);
  out.count = 0;
  if (count > kMaxObjectsPerPacket) return Result::bad_value;
  // count <= 1000: no overflow in the product.
  if (size != kObjectPosesHeaderSize + kObjectPoseSize * count) return Result::bad_size;
  if (count > capacity || (count > 0 && objects == nullptr)) return Result::buffer_too_small;
  for (uint32_t k = 0; k < count; ++k) {
    const uint8_t* p = data + kObjectPosesHeaderSize + kObjectPoseSize * k;
    ObjectPose& o = objects[k];
    o.index = get_u32(p);
    for (int i = 0; i < 3; ++i) o.position[i] = get_f64(p + 8 + 8 * i);
    for (int i = 0; i < 4; ++i) o.quaternion[i] = get_f64(p + 32 + 8 * i);
    if (!finite(o.position, 3) || !finite(o.quaternion, 4)) return Result::non_finite;
    if (o.index >= out.total || zero_quaternion(o.quaternion)) return Result::bad_value;
  }
  out.count = count;
  return Result::ok;
}

Result encode_pose(const PoseMessage& m, uint8_t* out, size_t capacity, size_t& written) noexcept {
  written = 0;
  if (!std::isfinite(m.header.timestamp) || !finite(m.position, 3) || !finite(m.quaternion, 4))
    return Result::non_finite;
  if (zero_quaternion(m.quaternion)) return Result::bad_value;
  if (out == nullptr || capacity < kPoseSize) return Result::buffer_too_small;
  put_header(out, MessageType::pose, m.header);
  for (int i = 0; i < 3; ++i) put_f64(out + 24 + 8 * i, m.position[i]);
  for (int i = 0; i < 4; ++i) put_f64(out + 48 + 8 * i, m.quaternion[i]);
  put_u32(out + 80, m.buttons);
  out[84] = m.clutch ? 1 : 0;
  out[85] = out[86] = out[87] = 0;
  written = kPoseSize;
  return Result::ok;
}

Result encode_wrench(const WrenchMessage& m, uint8_t* out, size_t capacity, size_t& written) noexcept {
  written = 0;
  if (!std::isfinite(m.header.timestamp) || !finite(m.force, 3) || !finite(m.torque, 3)) return Result::non_finite;
  if (out == nullptr || capacity < kWrenchSize) return Result::buffer_too_small;
  put_header(out, MessageType::wrench, m.header);
  put_u32(out + 24, m.answers);
  put_u32(out + 28, 0);
  for (int i = 0; i < 3; ++i) put_f64(out + 32 + 8 * i, m.force[i]);
  for (int i = 0; i < 3; ++i) put_f64(out + 56 + 8 * i, m.torque[i]);
  written = kWrenchSize;
  return Result::ok;
}

Result encode_object_poses(const ObjectPosesMessage& m, const ObjectPose* objects, uint8_t* out, size_t capacity,
                           size_t& written) noexcept {
  written = 0;
  if (!std::isfinite(m.header.timestamp)) return Result::non_finite;
  if (m.count > kMaxObjectsPerPacket || (m.count > 0 && objects == nullptr)) return Result::bad_value;
  for (uint32_t k = 0; k < m.count; ++k) {
    if (!finite(objects[k].position, 3) || !finite(objects[k].quaternion, 4)) return Result::non_finite;
    if (objects[k].index >= m.total || zero_quaternion(objects[k].quaternion)) return Result::bad_value;
  }
  const size_t size = kObjectPosesHeaderSize + kObjectPoseSize * m.count;
  if (out == nullptr || capacity < size) return Result::buffer_too_small;
  put_header(out, MessageType::object_poses, m.header);
  put_u32(out + 24, m.count);
  put_u32(out + 28, m.total);
  for (uint32_t k = 0; k < m.count; ++k) {
    uint8_t* p = out + kObjectPosesHeaderSize + kObjectPoseSize * k;
    put_u32(p, objects[k].index);
    put_u32(p + 4, 0);
    for (int i = 0; i < 3; ++i) put_f64(p + 8 + 8 * i, objects[k].position[i]);
    for (int i = 0; i < 4; ++i) put_f64(p + 32 + 8 * i, objects[k].quaternion[i]);
  }
  written = size;
  return Result::ok;
}

}  // namespace udp
}  // namespace hrt
