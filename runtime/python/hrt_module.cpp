// The Python module `hrt._hrt` (nanobind): bundles, scenes and queries of the
// runtime from Python, with numpy arrays in and out (docs/python.md). The
// package runtime/python/hrt/__init__.py re-exports it.
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/shared_ptr.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "hrt/hrt.h"
#include "hrt/runner.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace {

// (Returned through nb::cast where a property returns one: a property's
// default policy, reference_internal, does not apply to an array that
// already has an owner.)
// A numpy array owning a copy of `n` doubles shaped `shape` (results are
// small: a wrench, a few patches; copying them keeps their lifetime simple).
nb::ndarray<nb::numpy, double> array(const double* data, std::initializer_list<size_t> shape) {
  size_t n = 1;
  for (size_t s : shape) n *= s;
  auto* buf = new double[n];
  std::copy(data, data + n, buf);
  nb::capsule owner(buf, [](void* p) noexcept { delete[] static_cast<double*>(p); });
  return nb::ndarray<nb::numpy, double>(buf, shape, owner);
}

nb::ndarray<nb::numpy, double> vec3(const hrt::Vec3& v) { return array(v.data(), {3}); }

hrt::HeightMode height_mode(const std::string& s) {
  hrt::HeightMode m;
  if (!hrt::parse_height_mode(s, m))
    throw std::invalid_argument("heights must be 'surface', 'coarse' or 'mesh', got '" + s + "'");
  return m;
}

// A scene and its preallocated state, with the models kept alive: one query
// at a time (the State is the frame's scratch).
struct PyScene {
  std::vector<std::shared_ptr<hrt::Model>> models;
  std::unique_ptr<hrt::Scene> scene;
  // The depth backend (GL: its context and backend) before the State that
  // points at it, so that the State goes first.
  hrt::gl::BackendSelection selection;
  hrt::DepthBackend* backend = nullptr;  // null: the CPU code inline (as `hrt query`)
  std::unique_ptr<hrt::State> state;

  // Several GL scenes have a context each: a GL scene makes its own current
  // on the calling thread before it draws, and before its GL objects go.
  void make_current() {
    if (selection.context) selection.context->make_current();
  }
  ~PyScene() {
    try {
      make_current();
    } catch (...) {  // a destructor must not throw; the driver then frees the objects with the context
    }
  }
};

// Poses as an (objects, 7) array: x, y, z, qx, qy, qz, qw per object.
void set_poses(PyScene& s, nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu> poses) {
  const size_t n = s.models.size();
  if (poses.shape(0) != n || poses.shape(1) != 7)
    throw std::invalid_argument("poses must be an array of shape (" + std::to_string(n) +
                                ", 7) (x y z qx qy qz qw per " + "object), got (" + std::to_string(poses.shape(0)) +
                                ", " + std::to_string(poses.shape(1)) + ")");
  const double* p = poses.data();
  for (size_t i = 0; i < n; ++i, p += 7) {
    for (int k = 0; k < 7; ++k)
      if (!std::isfinite(p[k])) throw std::invalid_argument("poses[" + std::to_string(i) + "] is not finite");
    const Eigen::Quaterniond q(p[6], p[3], p[4], p[5]);
    const double norm = q.coeffs().stableNorm();
    // The tolerance of `hrt query --pose-a` (a unit quaternion, normalized).
    if (!(std::abs(norm - 1.0) <= 1e-6))
      throw std::invalid_argument("poses[" + std::to_string(i) + "]: the quaternion (qx qy qz qw) has norm " +
                                  std::to_string(norm) + ", expected a unit quaternion");
    hrt::Pose& pose = s.state->poses[i];
    pose.position = hrt::Vec3(p[0], p[1], p[2]);
    pose.rotation = q.normalized();
  }
}

// The patches of a frame's State as arrays (Scene.query's "patches",
// Runner.step's "contacts"), with each patch's window: the corner of texel
// (0, 0), u, v and the side (N x cell).
nb::dict patch_arrays(const hrt::State& st) {
  const int m = st.num_patches;
  std::vector<double> delta(m), n(3 * m), force(3 * m), torque(3 * m), p_a(3 * m), p_b(3 * m), grad(6 * m),
      delta_bound(m), origin(3 * m), u(3 * m), v(3 * m), side(m);
  std::vector<int64_t> ids(m), object_b(m);
  nb::list covered, refused, clamped;
  for (int k = 0; k < m; ++k) {
    const hrt::ContactPatch& c = st.patches[static_cast<size_t>(k)];
    delta[k] = c.delta;
    delta_bound[k] = c.delta_bound;
    ids[k] = static_cast<int64_t>(st.patch_ids[static_cast<size_t>(k)]);
    object_b[k] = c.object_b;
    for (int j = 0; j < 3; ++j) {
      n[3 * k + j] = c.n[j];
      force[3 * k + j] = c.force[j];
      torque[3 * k + j] = c.torque[j];
      p_a[3 * k + j] = c.p_a[j];
      p_b[3 * k + j] = c.p_b[j];
      origin[3 * k + j] = c.window.origin[j];
      u[3 * k + j] = c.u[j];
      v[3 * k + j] = c.v[j];
    }
    side[k] = c.window.cell * c.window.resolution;
    for (int j = 0; j < 6; ++j) grad[6 * k + j] = c.grad[j];
    covered.append(c.covered);
    refused.append(c.refused);
    clamped.append(c.clamped);
  }
  const size_t um = static_cast<size_t>(m);
  nb::dict patches;
  patches["id"] = nb::cast(ids);
  patches["object_b"] = nb::cast(object_b);
  patches["delta"] = array(delta.data(), {um});
  patches["delta_bound"] = array(delta_bound.data(), {um});
  patches["n"] = array(n.data(), {um, 3});
  patches["grad"] = array(grad.data(), {um, 6});
  patches["force"] = array(force.data(), {um, 3});
  patches["torque"] = array(torque.data(), {um, 3});
  patches["p_a"] = array(p_a.data(), {um, 3});
  patches["p_b"] = array(p_b.data(), {um, 3});
  patches["covered"] = covered;
  patches["refused"] = refused;
  patches["clamped"] = clamped;
  patches["window_origin"] = array(origin.data(), {um, 3});
  patches["u"] = array(u.data(), {um, 3});
  patches["v"] = array(v.data(), {um, 3});
  patches["window_side"] = array(side.data(), {um});
  return patches;
}

nb::dict result(const PyScene& s) {
  const hrt::State& st = *s.state;
  nb::dict patches = patch_arrays(st);
  std::vector<double> wb(6 * s.models.size(), 0.0);
  for (size_t b = 1; b < s.models.size(); ++b)
    for (int j = 0; j < 6; ++j) wb[6 * b + j] = st.wrench_b[b][j];
  nb::dict out;
  out["force"] = vec3(st.force);
  out["torque"] = vec3(st.torque);
  out["wrench_b"] = array(wb.data(), {s.models.size(), 6});
  out["pairs"] = st.num_pairs;
  out["patches"] = patches;
  nb::dict t;
  t["collision"] = st.timings.collision_us;
  t["clustering"] = st.timings.clustering_us;
  t["force"] = st.timings.force_us;
  t["total"] = st.timings.total_us;
  out["timings_us"] = t;
  return out;
}

void pose7(const hrt::Pose& p, double* out) {
  out[0] = p.position.x(), out[1] = p.position.y(), out[2] = p.position.z();
  out[3] = p.rotation.x(), out[4] = p.rotation.y(), out[5] = p.rotation.z(), out[6] = p.rotation.w();
}

// A scene file's session in lockstep (hrt::Runner), with its trace written
// by the same writer as `hrt run`'s and its frames collected as arrays.
struct PyRunner {
  std::unique_ptr<hrt::Runner> runner;
  std::unique_ptr<hrt::TraceWriter> trace;
  bool finished = false;
  // Per frame: t, probe pose (7), target pose (7), contact / coupling /
  // device wrenches (6 each), patches.
  std::vector<double> t, probe, target, contact, coupling, device;
  std::vector<int64_t> patches;

  bool keep = true;  // collect the frames (Runner.frames)
  void record(const hrt::SessionFrame& fr) {
    if (trace) trace->row(hrt::TraceRow{&fr, &runner->target()});
    if (!keep) return;
    t.push_back(fr.t);
    double p[7];
    pose7(fr.probe, p);
    probe.insert(probe.end(), p, p + 7);
    pose7(fr.target, p);
    target.insert(target.end(), p, p + 7);
    contact.insert(contact.end(), fr.contact.data(), fr.contact.data() + 6);
    coupling.insert(coupling.end(), fr.coupling.data(), fr.coupling.data() + 6);
    device.insert(device.end(), fr.device.data(), fr.device.data() + 6);
    patches.push_back(fr.patches);
  }
  void finish() {
    if (finished) return;
    finished = true;
    if (trace) trace->close();  // renames the .partial file into place
  }
  nb::dict frame_dict(const hrt::SessionFrame& fr) const {
    double p[7];
    nb::dict d;
    d["t"] = fr.t;
    d["frame"] = fr.frame;
    pose7(fr.probe, p);
    d["probe"] = array(p, {7});
    pose7(fr.target, p);
    d["target"] = array(p, {7});
    d["contact"] = array(fr.contact.data(), {6});
    d["coupling"] = array(fr.coupling.data(), {6});
    d["device"] = array(fr.device.data(), {6});
    d["patches"] = fr.patches;
    const hrt::State& st = runner->session().state();
    d["contacts"] = patch_arrays(st);
    std::vector<double> poses(7 * st.poses.size());
    for (size_t b = 0; b < st.poses.size(); ++b) pose7(st.poses[b], poses.data() + 7 * b);
    d["poses"] = array(poses.data(), {st.poses.size(), 7});
    const hrt::DeviceTarget& tg = runner->target();
    pose7(tg.device, p);
    d["device_pose"] = array(p, {7});
    d["device_output"] = array(tg.output.data(), {6});
    return d;
  }
};

// hrt::BundleError -> hrt.BundleError and the other exceptions.
void bind_errors(nb::module_& m) {
  // hrt::BundleError -> hrt.BundleError (a ValueError) with the C++ message
  // (one line naming the file and the problem) and error_class set by the
  // Python package (hrt/__init__.py parses nothing: it is passed through).
  static nb::object bundle_error = nb::borrow(PyErr_NewException("hrt.BundleError", PyExc_ValueError, nullptr));
  m.attr("BundleError") = bundle_error;
  static nb::object scene_error = nb::borrow(PyErr_NewException("hrt.SceneFileError", PyExc_ValueError, nullptr));
  m.attr("SceneFileError") = scene_error;
  static nb::object device_error = nb::borrow(PyErr_NewException("hrt.DeviceError", PyExc_RuntimeError, nullptr));
  m.attr("DeviceError") = device_error;
  static nb::object gl_error = nb::borrow(PyErr_NewException("hrt.GlError", PyExc_RuntimeError, nullptr));
  m.attr("GlError") = gl_error;
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const hrt::SceneFileError& e) {
      PyErr_SetString(scene_error.ptr(), e.what());
    } catch (const hrt::TrajectoryError& e) {
      PyErr_SetString(scene_error.ptr(), e.what());
    } catch (const hrt::OutputOverwritesInput& e) {
      PyErr_SetString(scene_error.ptr(), e.what());
    } catch (const hrt::DeviceError& e) {
      PyErr_SetString(device_error.ptr(), e.what());
    } catch (const hrt::gl::GlError& e) {
      PyErr_SetString(gl_error.ptr(), e.what());
    } catch (const hrt::BundleError& e) {
      nb::object err = bundle_error(e.what());
      err.attr("error_class") = hrt::to_string(e.error_class());
      PyErr_SetObject(bundle_error.ptr(), err.ptr());
    }
  });
}

// hrt.Model and hrt.load_bundle.
void bind_model(nb::module_& m) {
  nb::class_<hrt::Model>(m, "Model", "A loaded haptic bundle (hrt::Model): coarse mesh, atlas, pieces, mass.")
      .def_ro("path", &hrt::Model::path, "The bundle directory as given.")
      .def_ro("name", &hrt::Model::name, "The source mesh's file name (manifest).")
      .def_ro("format_version", &hrt::Model::format_version, "The bundle's format version, \"1.x\".")
      .def_prop_ro(
          "num_faces", [](const hrt::Model& x) { return x.faces.size(); }, "Triangles of the coarse mesh.")
      .def_prop_ro(
          "num_pieces", [](const hrt::Model& x) { return x.pieces.size(); }, "Convex pieces.")
      .def_prop_ro(
          "vertices",
          [](const hrt::Model& x) {
            return nb::cast(array(x.vertices.empty() ? nullptr : x.vertices[0].data(), {x.vertices.size(), 3}));
          },
          "Coarse mesh vertices, (V, 3) float64, metres, object frame (a copy).")
      .def_prop_ro(
          "volume", [](const hrt::Model& x) { return x.mass.volume; }, "Volume, m^3.")
      .def_prop_ro(
          "center_of_mass", [](const hrt::Model& x) { return nb::cast(vec3(x.mass.center_of_mass)); },
          "Centre of mass, object frame, metres.")
      .def("__repr__", [](const hrt::Model& x) {
        return "<hrt.Model '" + x.path + "' (" + x.name + ", format " + x.format_version + ", " +
               std::to_string(x.faces.size()) + " faces, " + std::to_string(x.pieces.size()) + " pieces)>";
      });

  m.def(
      "load_bundle",
      [](const std::string& path, bool verify_hashes) {
        hrt::LoadOptions lo;
        lo.verify_hashes = verify_hashes;
        return std::make_shared<hrt::Model>(hrt::load_bundle(path, lo));
      },
      "path"_a, "verify_hashes"_a = true,
      "Loads and checks a haptic bundle (.hbundle directory). Raises hrt.BundleError (a ValueError, with\n"
      "error_class 'io', 'version', 'schema', 'hash', 'mesh', 'atlas' or 'pieces') on bad input.");
}

// hrt.Scene: frames at given poses.
void bind_scene(nb::module_& m) {
  nb::class_<PyScene>(m, "Scene",
                      "A scene (the probe A first, then the objects B) and its preallocated frame state.\n"
                      "One query at a time per Scene (it owns the frame's scratch).")
      .def(
          "__init__",
          [](PyScene* self, std::vector<std::shared_ptr<hrt::Model>> models, int resolution, double stiffness,
             double lin_step, double ang_step, bool shortcut, const std::string& heights, double margin,
             int max_patches, int threads, const std::string& backend, const std::string& gl_search) {
            // Everything is built first: an exception leaves *self unconstructed.
            for (const auto& p : models)
              if (!p) throw std::invalid_argument("a scene object is None");
            hrt::SceneOptions o;
            o.force.resolution = resolution;
            o.force.stiffness = stiffness;
            o.force.lin_step = lin_step;
            o.force.ang_step = ang_step;
            o.force.shortcut = shortcut;
            o.force.heights = height_mode(heights);
            o.collision.margin = margin;
            o.cluster.max_patches = max_patches;
            o.threads = threads;
            std::vector<const hrt::Model*> objects;
            for (const auto& p : models) objects.push_back(p.get());
            hrt::BackendChoice choice;
            if (!hrt::parse_backend_choice(backend, choice))
              throw std::invalid_argument("backend must be 'cpu', 'gl' or 'auto', got '" + backend + "'");
            hrt::gl::GlDepthOptions gl;
            if (gl_search == "occlusion")
              gl.search = hrt::gl::MaxSearch::occlusion;
            else if (gl_search != "compute")
              throw std::invalid_argument("gl_search must be 'compute' or 'occlusion', got '" + gl_search + "'");
            auto scene = std::make_unique<hrt::Scene>(objects, o);
            hrt::gl::BackendSelection selection = hrt::gl::select_backend(choice, objects, o, gl);
            hrt::DepthBackend* chosen = dynamic_cast<hrt::gl::GlDepthBackend*>(selection.backend.get());
            auto state = std::make_unique<hrt::State>(*scene);
            state->depth_backend = chosen;
            new (self) PyScene{std::move(models), std::move(scene), std::move(selection), chosen, std::move(state)};
          },
          "models"_a, "resolution"_a = hrt::kDefaultResolution, "stiffness"_a = hrt::kDefaultStiffness,
          "lin_step"_a = 0.0, "ang_step"_a = 0.0, "shortcut"_a = false, "heights"_a = "surface", "margin"_a = -1.0,
          "max_patches"_a = 32, "threads"_a = 1, "backend"_a = "cpu", "gl_search"_a = "compute",
          "models: [probe A, B, ...] from load_bundle (the same Model may appear twice). The options are\n"
          "`hrt query`'s: grid resolution N, stiffness k (N/m), finite-difference steps (0: automatic),\n"
          "the Sec. 5.2 shortcut, heights 'surface'|'coarse'|'mesh', collision margin (m, -1: automatic),\n"
          "most patches per frame, threads (0: every hardware thread), the depth backend 'cpu', 'gl'\n"
          "(headless OpenGL through EGL; hrt.GlError when none can be made) or 'auto', and the GL\n"
          "backend's maximum search 'compute' or 'occlusion'. Raises ValueError on bad options.")
      .def(
          "query",
          [](PyScene& s, nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu> poses) {
            set_poses(s, poses);
            {
              nb::gil_scoped_release release;
              s.make_current();
              hrt::frame(*s.scene, *s.state);
            }
            return result(s);
          },
          "poses"_a,
          "One frame at the given poses ((objects, 7) float64: x y z qx qy qz qw per object, world\n"
          "frame). Returns a dict: force and torque on the probe (world, torque about its centre of\n"
          "mass), wrench_b (objects, 6), pairs, patches (arrays per patch: id, object_b, delta,\n"
          "delta_bound, n, grad, force, torque, p_a, p_b, covered, refused, clamped) and timings_us.\n"
          "Successive queries are successive frames of one session: patches keep their identity\n"
          "(id, u, texel size) from one query to the next, as in `hrt run`. A query after reset(),\n"
          "or the first, equals `hrt query --json` at the same poses, bit for bit.")
      .def(
          "reset",
          [](PyScene& s) {
            s.state = std::make_unique<hrt::State>(*s.scene);
            s.state->depth_backend = s.backend;
          },
          "Forgets the previous frames (a fresh State): the next query is like a first one.")
      .def_prop_ro(
          "size", [](const PyScene& s) { return s.models.size(); }, "Objects in the scene.")
      .def_prop_ro(
          "backend", [](const PyScene& s) { return std::string(s.backend ? s.backend->name() : "cpu"); },
          "The depth backend the queries run on: 'cpu' or 'gl'.")
      .def_prop_ro(
          "backend_message", [](const PyScene& s) { return s.selection.message; },
          "Which backend was chosen and why (one line, as `hrt query --backend` prints it).")
      .def(
          "tolerance",
          [](const PyScene& s, int b) {
            if (b < 1 || b >= static_cast<int>(s.models.size())) throw nb::index_error("object index out of range");
            return s.scene->tolerance(b);
          },
          "b"_a, "The pair tolerance of object b >= 1 against the probe (m).");
}

// hrt.Runner: __init__.
void bind_runner_init(nb::class_<PyRunner>& cls) {
  cls.def(
      "__init__",
      [](PyRunner* self, const std::string& scene, nb::object duration, const std::string& trace,
         const std::string& device, bool write_trace, bool keep_frames) {
        if (device != "file" && device != "virtual")
          throw std::invalid_argument("device must be \"file\" or \"virtual\", got \"" + device + "\"");
        hrt::RunConfig cfg = hrt::load_run_config(scene);
        hrt::RunOverrides o;
        o.lockstep = true;
        if (!duration.is_none()) o.duration = nb::cast<double>(duration);
        o.trace = trace;
        hrt::apply_overrides(cfg, o);
        if (!write_trace) cfg.trace.path.clear(), cfg.trace.device_log.clear();
        if (device == "virtual" && cfg.device.type != "virtual") {
          // The file's device replaced by a virtual handle holding the
          // probe's initial pose (its limits and workspace kept; a
          // plugin's limits are its own, so the file's defaults apply).
          cfg.device.type = "virtual";
          cfg.device.start = cfg.loop.map.to_device(cfg.objects.at(0).pose);
          cfg.device.start_set = false;
        }
        hrt::check_run_outputs(cfg);
        if (cfg.device.type != "scripted" && cfg.device.type != "virtual")
          throw std::invalid_argument(cfg.file + ": lockstep needs a scripted or virtual device (device.type = \"" +
                                      cfg.device.type + "\")");
        auto runner = std::make_unique<hrt::Runner>(cfg);
        runner->open();
        std::unique_ptr<hrt::TraceWriter> writer;
        if (!runner->config().trace.path.empty()) {
          writer = std::make_unique<hrt::TraceWriter>();
          writer->open(runner->config().trace.path, runner->config().trace);
        }
        new (self) PyRunner();
        self->runner = std::move(runner);
        self->trace = std::move(writer);
        self->keep = keep_frames;
      },
      "scene"_a, "duration"_a = nb::none(), "trace"_a = "", "device"_a = "file", "write_trace"_a = true,
      "keep_frames"_a = true,
      "Loads the scene file (its bundles, trajectories and scripted or virtual device) and opens the\n"
      "session. duration (s) and trace (a path) override the file's, as `hrt run --duration --trace`\n"
      "do. device=\"virtual\" replaces the file's device with a virtual one (set_device_pose) that\n"
      "starts where the probe starts, keeping the file's limits and workspace map. write_trace=False\n"
      "writes no trace even where the file names one; keep_frames=False keeps no frames in `frames`\n"
      "(a long interactive session).\n"
      "Raises hrt.SceneFileError, hrt.BundleError, hrt.DeviceError or ValueError.");
}

// hrt.Runner: step, set_device_pose, target_to_device, run.
void bind_runner_steps(nb::class_<PyRunner>& cls) {
  cls.def(
         "step",
         [](PyRunner& r) -> nb::object {
           if (r.finished) return nb::none();
           const hrt::SessionFrame* fr = nullptr;
           {
             nb::gil_scoped_release release;
             fr = r.runner->step();
           }
           if (!fr) {
             r.finish();
             return nb::none();
           }
           r.record(*fr);
           return r.frame_dict(*fr);
         },
         "Runs the device loop to the next simulation frame and returns it (t, frame, probe and target\n"
         "poses (7,), contact, coupling and device wrenches (6,), patches), or None at the end.")
      .def(
          "set_device_pose",
          [](PyRunner& r, nb::ndarray<const double, nb::shape<7>, nb::c_contig, nb::device::cpu> pose, bool clutch) {
            hrt::VirtualDevice* dev = r.runner->virtual_device();
            if (!dev)
              throw std::invalid_argument("set_device_pose: the device is \"" + r.runner->config().device.type +
                                          "\", not \"virtual\"");
            const double* p = pose.data();
            hrt::Pose d;
            d.position = hrt::Vec3(p[0], p[1], p[2]);
            d.rotation = Eigen::Quaterniond(p[6], p[3], p[4], p[5]);
            if (!dev->set_pose(d, clutch))
              throw std::invalid_argument("set_device_pose: the pose must be finite with a non-zero quaternion");
          },
          "pose"_a, "clutch"_a = false,
          "A virtual device ([device] type = \"virtual\"): the handle's pose (x y z qx qy qz qw, device\n"
          "frame) read by every device tick from the next step() on, and its clutch.")
      .def(
          "target_to_device",
          [](const PyRunner& r, nb::ndarray<const double, nb::shape<7>, nb::c_contig, nb::device::cpu> pose) {
            const double* p = pose.data();
            hrt::Pose t;
            t.position = hrt::Vec3(p[0], p[1], p[2]);
            t.rotation = Eigen::Quaterniond(p[6], p[3], p[4], p[5]);
            if (!t.position.allFinite() || !(t.rotation.norm() > 1e-12))
              throw std::invalid_argument("target_to_device: the pose must be finite with a non-zero quaternion");
            double out[7];
            pose7(r.runner->config().loop.map.to_device(t), out);
            return array(out, {7});
          },
          "pose"_a,
          "The handle pose (device frame) whose coupling target is `pose` (the probe's object frame in\n"
          "the scene): the inverse of the scene file's [workspace] map (before any clutch re-indexing).")
      .def(
          "run",
          [](PyRunner& r) {
            {
              nb::gil_scoped_release release;
              while (!r.finished) {
                const hrt::SessionFrame* fr = r.runner->step();
                if (!fr) break;
                r.record(*fr);
              }
            }
            r.finish();
          },
          "Runs the rest of the session (and closes its trace).");
}

// hrt.Runner: frames, done, device_loop.
void bind_runner_results(nb::class_<PyRunner>& cls) {
  cls.def_prop_ro(
         "frames",
         [](const PyRunner& r) {
           const size_t f = r.t.size();
           nb::dict d;
           d["t"] = array(r.t.data(), {f});
           d["probe"] = array(r.probe.data(), {f, 7});
           d["target"] = array(r.target.data(), {f, 7});
           d["contact"] = array(r.contact.data(), {f, 6});
           d["coupling"] = array(r.coupling.data(), {f, 6});
           d["device"] = array(r.device.data(), {f, 6});
           d["patches"] = nb::cast(r.patches);
           return d;
         },
         "Every frame so far as arrays: t (F,), probe and target (F, 7) poses, contact, coupling and\n"
         "device (F, 6) wrenches (torques about the probe's centre of mass), patches (F,).")
      .def_prop_ro(
          "done", [](const PyRunner& r) { return r.finished; }, "True once the session has run.")
      .def_prop_ro(
          "device_loop",
          [](const PyRunner& r) {
            const hrt::DeviceLoopStats& st = r.runner->loop().stats();
            nb::dict d;
            d["ticks"] = st.ticks;
            d["force_clamps"] = st.force_clamps;
            d["torque_clamps"] = st.torque_clamps;
            d["rate_limited"] = st.rate_limited;
            d["non_finite"] = st.non_finite;
            d["watchdog_events"] = st.watchdog_events;
            d["commands"] = st.commands;
            return d;
          },
          "The device loop's counters (ticks, clamps, watchdog events, ...), as `hrt run --json` prints.");
}

// hrt.Runner: a scene file's session in lockstep.
void bind_runner(nb::module_& m) {
  nb::class_<PyRunner> cls(
      m, "Runner",
      "A scene file's haptic session (docs/scene-format.md) in lockstep: the scripted or virtual device,\n"
      "the device loop and the simulation of `hrt run --lockstep`, frame by frame.");
  bind_runner_init(cls);
  bind_runner_steps(cls);
  bind_runner_results(cls);
}

}  // namespace

NB_MODULE(_hrt, m) {
  m.doc() = "hrt: haptic rendering of textured models (the C++ runtime, bound with nanobind)";
  m.attr("__version__") = HRT_VERSION_STRING;
  m.attr("BUNDLE_FORMAT_MAJOR") = HRT_BUNDLE_FORMAT_MAJOR;
  m.attr("BUNDLE_FORMAT_MINOR") = HRT_BUNDLE_FORMAT_MINOR;
  bind_errors(m);
  bind_model(m);
  bind_scene(m);
  bind_runner(m);
}
