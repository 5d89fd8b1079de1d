// hrt/hrt.h: the whole public API of the hrt runtime in one include
// (docs/embedding.md). Link hrt::hrtcore (CMake: find_package(hrt)) or
// `pkg-config --cflags --libs hrt` (add --static for the static library).
//
//   hrt::Model a = hrt::load_bundle("probe.hbundle"), b = hrt::load_bundle("plate.hbundle");
//   hrt::Scene scene({&a, &b}, hrt::SceneOptions{});   // static: models, options, collision data
//   hrt::State state(scene);                           // preallocated: poses, contacts, scratch
//   state.poses[0] = ...;  state.poses[1] = ...;
//   hrt::frame(scene, state);                          // collision, patches, Eq. 5-9
//   // state.force, state.torque: the net wrench on the probe; state.patches[0..num_patches)
//
// Conventions (docs/bundle-format.md): metres, N/m, radians; a pose is a
// position and a unit quaternion (x, y, z, w) of a bundle's object frame in
// the world; a patch's n points from the probe A into B, delta > 0 is overlap.
#pragma once

#include "hrt/version.h"

#include "hrt/math.h"     // Vec3, Vec6, Pose, rotation vectors
#include "hrt/model.h"    // Model, load_bundle, LoadOptions, BundleError
#include "hrt/contact.h"  // Window, ContactPatch
#include "hrt/depth.h"    // ForceOptions, HeightMode, Eq. 7-9 on one patch
#include "hrt/force.h"    // the force model, Eq. 3-6 on one patch
#include "hrt/depth_backend.h"
#include "hrt/scene.h"        // Scene, SceneOptions, State, frame()
#include "hrt/dynamics.h"     // probe dynamics and virtual coupling
#include "hrt/clock.h"        // session time: manual (lockstep) or monotonic
#include "hrt/trajectory.h"   // scripted device paths
#include "hrt/device.h"       // device kinds
#include "hrt/device_loop.h"  // the 1 kHz device loop and its per-tick bounds
#include "hrt/session.h"      // a simulation session (probe dynamics, coupling, materials)
#include "hrt/runner.h"       // a scene file's session against its device, as `hrt run` runs it
#include "hrt/run_config.h"   // scene files of `hrt run` (TOML)
#include "hrt/trace.h"        // the session trace and device log (CSV)
#include "hrt/files.h"
#include "hrt/gl_depth.h"  // the GL depth backend (EGL, headless)
