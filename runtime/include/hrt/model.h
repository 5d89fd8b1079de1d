// Immutable model of one haptic bundle (docs/bundle-format.md).
//
// A Model is loaded once (load_bundle) and never changes afterwards; all
// dynamic data (poses, contacts, wrenches, timers, warning counters) lives in
// hrt::State (state.h). Units: meters, radians; positions are in the bundle's
// object frame.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <nlohmann/json_fwd.hpp>

#include "hrt/math.h"
#include "hrt/surface.h"

namespace hrt {

using Tri = std::array<uint32_t, 3>;

// Error classes shared with `hbake validate` (docs/bundle-format.md).
enum class BundleErrorClass { io, version, schema, hash, mesh, atlas, pieces };
const char* to_string(BundleErrorClass c);

// Thrown by load_bundle; what() is one specific line naming the file and the problem.
class BundleError : public std::runtime_error {
 public:
  BundleError(BundleErrorClass cls, const std::string& msg) : std::runtime_error(msg), cls_(cls) {}
  BundleErrorClass error_class() const { return cls_; }

 private:
  BundleErrorClass cls_;
};

// The haptic texture: W x H texels, RGBA float32, row 0 = first stored scanline
// (top of the image). RGB = object-space position (m), A = coverage.
struct Atlas {
  int width = 0;
  int height = 0;
  std::vector<float> rgba;  // width * height * 4, row-major

  const float* texel(int i, int j) const { return &rgba[(static_cast<size_t>(j) * width + i) * 4]; }
  // Bilinear lookup of RGB at UV (u, v) with the spec's convention:
  // x = u W - 0.5, y = (1 - v) H - 0.5, texels clamped to the image.
  Eigen::Vector3f sample(float u, float v) const;
  // Same, all four channels.
  Eigen::Vector4f sample4(float u, float v) const;
};

// One convex piece of the coarse mesh (outward CCW faces), plus the coarse
// triangles whose surface lies on it (many-to-many map, see the spec).
struct ConvexPiece {
  std::vector<Vec3> vertices;
  std::vector<Tri> faces;
  std::vector<uint32_t> coarse_faces;
};

struct MassProperties {
  std::string basis;                   // "full", "coarse" or "hull"
  double density = 1.0;                // kg/m^3 used for the figures below
  double volume = 0.0;                 // m^3
  Vec3 center_of_mass = Vec3::Zero();  // object frame, m
  Mat3 inertia = Mat3::Zero();         // about the centre of mass, kg m^2 at `density`
  bool closed = false;
};

struct Quality {
  double displacement_outward = 0.0;  // m, baked surface outside the coarse surface
  double displacement_inward = 0.0;   // m
  double hull_deviation = 0.0;        // m, piece hulls outside the coarse surface
  double texel_size = 0.0;            // m, atlas texel on the coarse surface
  double min_wavelength = 0.0;        // m, shortest relief the atlas represents
  double bbox_diagonal = 0.0;         // m
};

struct Model {
  std::string path;            // bundle directory as given
  std::string name;            // source file name from the manifest
  std::string format_version;  // "1.x"

  // Coarse mesh (object frame, m). uvs[f][c] is the UV of corner c of face f.
  std::vector<Vec3> vertices;
  std::vector<Tri> faces;
  std::vector<std::array<Vec2f, 3>> uvs;
  std::vector<Vec3> face_normals;  // unit outward geometric normals
  std::vector<double> face_areas;  // m^2

  std::vector<ConvexPiece> pieces;
  Atlas atlas;
  MassProperties mass;
  Quality quality;
  // Derived at load (prepare_surface_map, hrt/surface.h): what the depth code
  // needs to evaluate the reconstructed full surface on a texel column.
  SurfaceMap surface;

  // The whole manifest, for fields not mirrored above (set by load_bundle; read it with
  // <nlohmann/json.hpp>). Behind a pointer so that this header needs only JSON's
  // forward declarations; shared by copies of the model (it is never modified).
  std::shared_ptr<const nlohmann::json> manifest;
};

struct LoadOptions {
  bool verify_hashes = true;     // SHA-256 of every file against the manifest
  bool check_invariants = true;  // indices, UV range, convexity, atlas fill
  // Threads that decode atlas.exr: 0 = std::thread::hardware_concurrency(),
  // 1 = the calling thread only. More than 1 grows OpenEXR's process-wide
  // thread pool (Imf::setGlobalThreadCount) to that size if it is smaller;
  // its threads sleep when idle.
  int decode_threads = 0;
};

// Loads and checks a bundle directory field by field against the spec.
// Throws BundleError with one specific message per problem.
Model load_bundle(const std::string& path, const LoadOptions& opts = {});

}  // namespace hrt
