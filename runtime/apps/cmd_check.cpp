// `hrt check BUNDLE [--json] [--no-verify-hashes]`: load a bundle with every
// check of the spec and print a summary. A bundle that fails to load ends in
// main's BundleError handler (one line "hrt: error: <class>: <message>" on
// stderr, exit code 3); with --json a JSON object {"ok": false, "error":
// {"class", "message"}} is printed on stdout first.
#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "commands.h"
#include "hrt/model.h"
#include "hrt/surface.h"

namespace hrt_cli {
namespace {

struct CheckOptions {
  std::string bundle;         // bundle directory
  bool json = false;          // machine-readable output (layout documented in docs/guides/runtime.md)
  bool verify_hashes = true;  // SHA-256 and size of every file against the manifest
};

nlohmann::json summary_json(const hrt::Model& m) {
  size_t piece_vertices = 0, piece_faces = 0, mapped = 0;
  for (const auto& p : m.pieces) {
    piece_vertices += p.vertices.size();
    piece_faces += p.faces.size();
    mapped += p.coarse_faces.size();
  }
  double area = 0.0;
  for (double a : m.face_areas) area += a;
  const auto& mass = m.mass;
  nlohmann::json inertia = nlohmann::json::array();
  for (int i = 0; i < 3; ++i) inertia.push_back({mass.inertia(i, 0), mass.inertia(i, 1), mass.inertia(i, 2)});
  const auto& q = m.quality;
  const hrt::SurfaceCoverage sc = hrt::surface_coverage(m);
  return {
      {"ok", true},
      {"bundle", m.path},
      {"format_version", m.format_version},
      {"source", m.name},
      {"coarse", {{"vertices", m.vertices.size()}, {"triangles", m.faces.size()}, {"area", area}}},
      {"pieces",
       {{"count", m.pieces.size()}, {"vertices", piece_vertices}, {"faces", piece_faces}, {"map_entries", mapped}}},
      {"atlas",
       {{"width", m.atlas.width},
        {"height", m.atlas.height},
        {"compression", m.manifest->at("files").at("atlas").at("compression")},
        {"coverage", m.manifest->at("atlas").at("coverage")},
        {"texel_size", q.texel_size}}},
      {"mass",
       {{"basis", mass.basis},
        {"density", mass.density},
        {"volume", mass.volume},
        {"mass", mass.density * mass.volume},
        {"center_of_mass", {mass.center_of_mass.x(), mass.center_of_mass.y(), mass.center_of_mass.z()}},
        {"inertia", inertia},
        {"closed", mass.closed}}},
      {"quality",
       {{"displacement_outward", q.displacement_outward},
        {"displacement_inward", q.displacement_inward},
        {"hull_deviation", q.hull_deviation},
        {"min_wavelength", q.min_wavelength},
        {"bbox_diagonal", q.bbox_diagonal}}},
      {"surface", {{"quads", sc.quads}, {"cut_quads", sc.cut}, {"widest_cut", sc.widest_cut}}},
      {"warnings", m.manifest->at("warnings")},
  };
}

void print_text(const hrt::Model& m, const nlohmann::json& s) {
  const auto& q = m.quality;
  const auto& mass = m.mass;
  std::printf("bundle      %s (format %s, source %s)\n", m.path.c_str(), m.format_version.c_str(), m.name.c_str());
  std::printf("coarse      %zu vertices, %zu triangles, area %.6g m^2\n", m.vertices.size(), m.faces.size(),
              s["coarse"]["area"].get<double>());
  std::printf("pieces      %zu convex pieces (%zu vertices, %zu faces, %zu piece-triangle map entries)\n",
              m.pieces.size(), s["pieces"]["vertices"].get<size_t>(), s["pieces"]["faces"].get<size_t>(),
              s["pieces"]["map_entries"].get<size_t>());
  std::printf("atlas       %d x %d texels (%s), coverage %.4f, texel %.4g m\n", m.atlas.width, m.atlas.height,
              s["atlas"]["compression"].get<std::string>().c_str(), s["atlas"]["coverage"].get<double>(), q.texel_size);
  std::printf(
      "mass        basis %s, volume %.6g m^3, mass %.6g kg at density %g kg/m^3, centre of mass (%.6g, %.6g, %.6g) m\n",
      mass.basis.c_str(), mass.volume, mass.density * mass.volume, mass.density, mass.center_of_mass.x(),
      mass.center_of_mass.y(), mass.center_of_mass.z());
  std::printf("quality     displacement outward %.4g m, inward %.4g m, hull deviation %.4g m\n", q.displacement_outward,
              q.displacement_inward, q.hull_deviation);
  std::printf("            min wavelength %.4g m, bbox diagonal %.4g m\n", q.min_wavelength, q.bbox_diagonal);
  // The guarantee of the mesh heights holds on usable quads (docs/bundle-format.md).
  const auto& sf = s["surface"];
  const uint64_t cut = sf["cut_quads"].get<uint64_t>();
  std::printf("surface     %llu atlas quads inside the UV triangles, %llu cut by a discontinuity",
              static_cast<unsigned long long>(sf["quads"].get<uint64_t>()), static_cast<unsigned long long>(cut));
  if (cut > 0)
    std::printf(" (--heights mesh sees no surface between their corners, up to %.4g m apart)",
                sf["widest_cut"].get<double>());
  std::printf("\n");
  for (const auto& w : m.manifest->at("warnings")) std::printf("warning     %s\n", w.get<std::string>().c_str());
  std::printf("ok\n");
}

}  // namespace

void register_check(CLI::App& app) {
  auto opts = std::make_shared<CheckOptions>();
  CLI::App* cmd = app.add_subcommand("check", "Load a bundle, verify it against the format spec and print a summary");
  cmd->add_option("bundle", opts->bundle, "bundle directory (NAME.hbundle)")->required();
  cmd->add_flag("--json", opts->json, "print the summary as JSON on stdout");
  cmd->add_flag("!--no-verify-hashes", opts->verify_hashes, "skip the SHA-256 and size checks of the files");
  cmd->callback([opts]() {
    hrt::LoadOptions lo;
    lo.verify_hashes = opts->verify_hashes;
    hrt::Model model;
    try {
      model = hrt::load_bundle(opts->bundle, lo);
    } catch (const hrt::BundleError& e) {
      if (opts->json) {
        const nlohmann::json err = {{"ok", false},
                                    {"bundle", opts->bundle},
                                    {"error", {{"class", hrt::to_string(e.error_class())}, {"message", e.what()}}}};
        std::printf("%s\n", err.dump(2, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
        std::fflush(stdout);
      }
      // main prints "hrt: error: <class>: <message>" (the class as `hbake
      // validate` prints it) and exits with code 3.
      throw;
    }
    const nlohmann::json s = summary_json(model);
    if (opts->json) {
      std::printf("%s\n", s.dump(2, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
    } else {
      print_text(model, s);
    }
  });
}

}  // namespace hrt_cli
