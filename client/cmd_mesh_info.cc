// `hapticpd mesh-info FILE | --shape SPEC`: what a mesh is made of and how it
// will behave as a probe or scene body.
#include <nlohmann/json.hpp>

#include <chrono>
#include <iomanip>
#include <iostream>

#include "client/commands.h"
#include "pd/bvh.h"
#include "pd/mass_properties.h"
#include "pd/mesh.h"
#include "pd/shapes.h"
#include "proto/wire/ranges.h"

namespace hapticpd::cli {
namespace {

struct MeshInfoOptions {
  std::string file;
  std::string shape;
  bool json = false;
  bool strict = false;
};

nlohmann::json Vec(const Vec3& v) { return {v.x(), v.y(), v.z()}; }

void RunMeshInfo(const MeshInfoOptions& o) {
  if (o.file.empty() == o.shape.empty()) {
    throw CommandError("mesh-info: give exactly one of FILE or --shape SPEC");
  }
  pd::MeshOptions mopt;
  if (o.strict) mopt.degenerate = pd::DegeneratePolicy::kReject;
  const auto t0 = std::chrono::steady_clock::now();
  pd::Mesh mesh = o.file.empty() ? pd::shapes::MakeShape(o.shape) : pd::LoadMesh(o.file, mopt);
  const auto t1 = std::chrono::steady_clock::now();
  const pd::MassProperties mp = pd::ComputeMassProperties(mesh);
  const auto t2 = std::chrono::steady_clock::now();
  const pd::Bvh bvh(mesh);
  const auto t3 = std::chrono::steady_clock::now();
  auto ms = [](auto a, auto b) { return std::chrono::duration<double, std::milli>(b - a).count(); };

  nlohmann::json j;
  j["source"] = mesh.source();
  j["triangles"] = mesh.num_triangles();
  j["vertices"] = mesh.num_vertices();
  j["edges"] = mesh.edges().size();
  j["watertight"] = mesh.watertight();
  j["boundary_edges"] = mesh.boundary_edge_count();
  j["nonmanifold_edges"] = mesh.nonmanifold_edge_count();
  j["misoriented_edges"] = mesh.misoriented_edge_count();
  j["degenerate_triangles"] = mesh.degenerate_triangle_count();
  j["dropped_triangles"] = mesh.dropped_triangle_count();
  j["volume"] = mp.volume;
  j["mass_properties_exact"] = mp.exact;
  j["center_of_mass"] = Vec(mp.p_MC);
  j["principal_inertia"] = Vec(mp.principal_moments);
  j["principal_axes"] = {Vec(mp.X_MB.R.col(0)), Vec(mp.X_MB.R.col(1)), Vec(mp.X_MB.R.col(2))};
  j["bounding_box"] = {{"min", Vec(mesh.bounds().lo)}, {"max", Vec(mesh.bounds().hi)}};
  j["load_ms"] = ms(t0, t1);
  j["mass_properties_ms"] = ms(t1, t2);
  j["bvh_build_ms"] = ms(t2, t3);
  j["bvh_nodes"] = bvh.nodes().size();
  j["diagnostics"] = mesh.diagnostics();
  if (o.json) {
    std::cout << j.dump(2) << "\n";
    return;
  }
  auto v3 = [](const Vec3& v) {
    std::ostringstream os;
    os << std::setprecision(6) << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
    return os.str();
  };
  std::cout << std::setprecision(6);
  std::cout << "mesh            " << mesh.source() << "\n"
            << "triangles       " << mesh.num_triangles() << "\n"
            << "vertices        " << mesh.num_vertices() << "\n"
            << "watertight      " << (mesh.watertight() ? "yes" : "no") << "\n"
            << "boundary edges  " << mesh.boundary_edge_count() << "\n"
            << "non-manifold    " << mesh.nonmanifold_edge_count() << " edges\n"
            << "misoriented     " << mesh.misoriented_edge_count() << " edges\n"
            << "degenerate      " << mesh.degenerate_triangle_count() << " zero-area kept, "
            << mesh.dropped_triangle_count() << " dropped\n"
            << "volume          " << mp.volume << " m^3"
            << (mp.exact ? "" : "  (approximate: mesh is not watertight)") << "\n"
            << "centre of mass  " << v3(mp.p_MC) << " m\n"
            << "principal I     " << v3(mp.principal_moments) << " m^5 (unit density)\n"
            << "bounding box    " << v3(mesh.bounds().lo) << " .. " << v3(mesh.bounds().hi) << "\n"
            << "load time       " << ms(t0, t1) << " ms\n"
            << "BVH build       " << ms(t2, t3) << " ms (" << bvh.nodes().size() << " nodes)\n";
  for (const auto& d : mesh.diagnostics()) std::cout << "note            " << d << "\n";
}

}  // namespace

void RegisterMeshInfo(CLI::App& app) {
  auto opts = std::make_shared<MeshInfoOptions>();
  auto* cmd = app.add_subcommand(
      "mesh-info", "Load a mesh (OBJ/OFF/STL/PLY) or a built-in shape and print its properties");
  cmd->add_option("file", opts->file, "Mesh file (.obj, .off, .stl, .ply)");
  std::string shape_help = "Built-in shape instead of a file, e.g. 'cup' or 'box:0.1,0.2,0.3'. ";
  shape_help += "Shapes:";
  for (const auto& s : pd::shapes::ShapeNames()) shape_help += " " + s.name;
  cmd->add_option("--shape", opts->shape, shape_help);
  // The full grammar, parameter by parameter, after the options.
  cmd->footer(
      "Shape specs: NAME, or NAME:P1,P2,... with no spaces; give no parameters (all\n"
      "defaults) or at least every size parameter, then resolutions from the left.\n"
      "Lengths are in metres; a server accepts lengths in " +
      wire::Describe(wire::kShapeLength) + " and shapes within " +
      wire::Describe(wire::kCoordinate) + "\nof their origin.\n\n" + pd::shapes::ShapeHelp());
  cmd->add_flag("--json", opts->json, "Print one JSON object");
  cmd->add_flag("--strict", opts->strict, "Treat degenerate (zero-area) triangles as errors");
  cmd->callback([opts] { RunMeshInfo(*opts); });
}

}  // namespace hapticpd::cli
