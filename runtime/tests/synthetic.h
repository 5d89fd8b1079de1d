// In-memory Models with analytic haptic textures, for the depth and force
// tests: a rectangular block whose one face carries a relief known in closed
// form (flat, sinusoidal grating or trapezoidal ridges at any in-plane angle,
// optionally on a gentle paraboloid bump). The atlas of that face is filled
// texel by texel with the exact surface point, so the only approximation
// between the closed form and what the runtime samples is the atlas's
// bilinear interpolation (bounded by relief_interp_error()).
//
// Object frame: the textured face lies over [-sx/2, sx/2] x [-sy/2, sy/2];
// its surface point above (x, y) is (x, y, relief.z(x, y)) (z is the object
// z coordinate, whichever way the face points). face_up: the face's outward
// normal is +z and the body lies in z in [-thickness, 0]; otherwise the
// normal is -z and the body lies in [0, thickness].
#pragma once

#include <cstdint>
#include <vector>

#include "hrt/contact.h"
#include "hrt/model.h"

namespace hrt::synth {

enum class Profile { flat, sine, ridges };

struct Relief {
  Profile profile = Profile::flat;
  double amplitude = 0.0;    // a, m (sine: a sin; ridges: plateaus at +-a)
  double wavelength = 1e-3;  // lambda, m
  double angle = 0.0;        // rad: ridge normal m = (cos angle, sin angle) in the face's (x, y)
  double shift = 0.0;        // m: the profile is a function of m . (x, y) - shift
  double offset = 0.0;       // m: constant added (a "textured" flat face)
  double flank = 0.15;       // ridges: fraction of the period taken by each flank
  double bump = 0.0;         // 1/m: curvature c of the bump - sign * c |x - bump_centre|^2 / 2, see z()
  double bump_x = 0.0, bump_y = 0.0;
  bool face_up = true;  // set by make_block: the bump protrudes outwards

  // Profile value p(xi) in [-1, 1] of the phase coordinate xi = (m.x - shift) / lambda.
  double profile_value(double xi) const;
  // z of the surface point above (x, y) (object frame).
  double z(double x, double y) const;
  // dz/dx, dz/dy.
  Eigen::Vector2d gradient(double x, double y) const;
};

struct BlockSpec {
  double size_x = 0.02, size_y = 0.02;  // m
  double thickness = 0.005;             // m
  bool face_up = true;
  int subdiv = 4;        // the textured face (and the back face) is a subdiv x subdiv grid of quads
  int atlas_size = 512;  // the atlas is atlas_size x atlas_size (>= 64)
  Relief relief;
};

struct SynthBlock {
  Model model;
  std::vector<uint32_t> face_tris;  // the triangles of the textured face
  std::vector<uint32_t> back_tris;  // the triangles of the opposite face
  BlockSpec spec;
  double atlas_texel = 0;  // m, size of one atlas texel on the textured face (largest of x, y)
};

SynthBlock make_block(const BlockSpec& spec);

// The 20 mm block with a sine grating of the given amplitude, wavelength and
// angle on its face (8 x 8 quads, 1024^2 atlas): the B side of the random
// rotated scenes of the shortcut and energy tests.
inline BlockSpec sine_grating_spec(double amplitude, double wavelength, double angle) {
  BlockSpec s;
  s.atlas_size = 1024;
  s.subdiv = 8;
  s.relief.profile = Profile::sine;
  s.relief.amplitude = amplitude;
  s.relief.wavelength = wavelength;
  s.relief.angle = angle;
  return s;
}

// Bound on |bilinear atlas interpolation - closed form| of the textured face's
// z (m): curvature * t^2 / 8 with t the atlas texel diagonal (linear
// interpolation error of a C2 function), 0 for flat faces.
double relief_interp_error(const SynthBlock& b);

// A hand-made contact patch: n, u (v = n x u), a square window of N texels
// of size `cell` centred (in the plane) on `centre`, and the triangle lists.
ContactPatch make_patch(const Vec3& n, const Vec3& u, const Vec3& centre, double cell, int N,
                        const std::vector<uint32_t>& tris_a, const std::vector<uint32_t>& tris_b);

// Rigidly moves everything of a scene (poses and the patch geometry) by Q.
void transform_scene(const Eigen::Isometry3d& Q, Pose& pose_a, Pose& pose_b, ContactPatch& patch);

Pose make_pose(const Vec3& position, const Eigen::Quaterniond& rotation = Eigen::Quaterniond::Identity());

// Number of calls to the global operator new so far in this process (all
// threads). The test binary's operator new / delete are replaced in
// synthetic.cpp to count them, so that tests can check that a hot loop
// allocates nothing (take the difference around the loop).
uint64_t allocation_count();

}  // namespace hrt::synth
