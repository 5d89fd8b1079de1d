// The probe A (first bundle) against an object B (second bundle) at one
// pose: the texture force and torque on A and its contact patches, printed
// as JSON with the field names of `hrt query --json`.
//   embed A.hbundle B.hbundle  x y z qx qy qz qw  [x y z qx qy qz qw of B]
#include <cstdio>
#include <cstdlib>
#include <exception>

#include <hrt/hrt.h>
#include <nlohmann/json.hpp>  // the output; hrt/hrt.h does not pull in the JSON library

static hrt::Pose pose_from(char** v) {
  hrt::Pose p;
  p.position = hrt::Vec3(std::atof(v[0]), std::atof(v[1]), std::atof(v[2]));
  p.rotation = Eigen::Quaterniond(std::atof(v[6]), std::atof(v[3]), std::atof(v[4]), std::atof(v[5])).normalized();
  return p;
}

int main(int argc, char** argv) {
  if (argc != 10 && argc != 17) {
    std::fprintf(stderr, "usage: embed A.hbundle B.hbundle x y z qx qy qz qw [x y z qx qy qz qw]\n");
    return 2;
  }
  try {
    const hrt::Model a = hrt::load_bundle(argv[1]);
    const hrt::Model b = hrt::load_bundle(argv[2]);
    const hrt::Scene scene({&a, &b}, hrt::SceneOptions{});  // static: models, options, collision data
    hrt::State state(scene);                                // preallocated per-frame state
    state.poses[0] = pose_from(argv + 3);
    if (argc == 17) state.poses[1] = pose_from(argv + 10);
    hrt::frame(scene, state);  // collision, contact patches, directional depth, Eq. 5-7

    nlohmann::json contacts = nlohmann::json::array();
    for (int k = 0; k < state.num_patches; ++k) {
      const hrt::ContactPatch& c = state.patches[static_cast<size_t>(k)];
      contacts.push_back({{"delta", c.delta},
                          {"n", {c.n.x(), c.n.y(), c.n.z()}},
                          {"force", {c.force.x(), c.force.y(), c.force.z()}},
                          {"torque", {c.torque.x(), c.torque.y(), c.torque.z()}}});
    }
    const nlohmann::json out = {{"hrt_version", HRT_VERSION_STRING},
                                {"contacts", contacts},
                                {"force", {state.force.x(), state.force.y(), state.force.z()}},
                                {"torque", {state.torque.x(), state.torque.y(), state.torque.z()}}};
    std::printf("%s\n", out.dump(2).c_str());
    return 0;
  } catch (const hrt::BundleError& e) {  // one line naming the file and the problem
    std::fprintf(stderr, "embed: %s\n", e.what());
    return 3;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "embed: %s\n", e.what());
    return 1;
  }
}
