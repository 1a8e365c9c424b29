// PDt benchmark: replays scripted probe trajectories sampled at 1 kHz (1 ms
// per frame) that press into a scene's surface, slide while pressed and come
// back out, and times pd::ComputePdt on every frame with one PdQueryData per
// benchmark carried across frames (motion coherence, as in the servo loop).
// On the same poses it times FCL's mesh-mesh collide with all contacts
// enabled, the usual substitute for PD. Three benchmarks (the seed paper's):
//
//   stick  vs the Stanford bunny (69K triangles)
//   spoon  vs cup                 (procedural stand-ins, pd/shapes.h)
//   hammer vs beast.obj decimated to ~20K triangles (OpenMesh quadric
//          decimater), scaled by 1/500 to 0.55 m wide so that it is
//          comparable in size with the 31 cm hammer
//
// Prints per benchmark: triangles, frames, penetrating frames, PDt
// p50/p99/p99.9/max (µs), mean iterations and contacts, FCL all-contacts
// p50/p99 and the PDt/FCL ratio, against the goal p50 <= 100 µs and
// p99 <= 500 µs, and writes a summary CSV (--csv FILE, default bench_pdt.csv)
// and optionally one row per frame (--frames-csv FILE). No assertions on time.
//
//   ./build/release/tests/bench/bench_pdt [--models DIR] [--frames N] [--csv FILE]
//                                         [--frames-csv FILE]
//
// Without ../shared/models the bunny and the statue are replaced by
// procedural torus knots (and the output says so).
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>
#include <OpenMesh/Tools/Decimater/DecimaterT.hh>
#include <OpenMesh/Tools/Decimater/ModQuadricT.hh>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <limits>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "pd/geometry_model.h"
#include "pd/pdt.h"
#include "pd/queries.h"
#include "pd/shapes.h"
#include "tests/oracles/fcl_oracle.h"

namespace hp = hapticpd;
namespace pd = hapticpd::pd;
using hp::Mat3;
using hp::Pose;
using hp::Vec3;

namespace {

constexpr double kGoalP50Us = 100;
constexpr double kGoalP99Us = 500;
constexpr double kFrameBudgetUs = 1000;  // 1 kHz

// ---------------------------------------------------------------------------
// Models

struct OmTraits : OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3d;
  using Normal = OpenMesh::Vec3d;
};
using OmMesh = OpenMesh::TriMesh_ArrayKernelT<OmTraits>;

/// Quadric-error decimation to about `target_faces` triangles. Triangles that
/// OpenMesh's half-edge structure cannot take (complex edges) are skipped and
/// counted in `*skipped`.
pd::Mesh Decimate(const pd::Mesh& in, std::size_t target_faces, const std::string& source,
                  int* skipped) {
  OmMesh om;
  om.request_vertex_status();
  om.request_edge_status();
  om.request_face_status();
  std::vector<OmMesh::VertexHandle> vh;
  vh.reserve(in.num_vertices());
  for (const Vec3& v : in.vertices())
    vh.push_back(om.add_vertex(OmMesh::Point(v.x(), v.y(), v.z())));
  *skipped = 0;
  omerr().disable();  // "complex edge" complaints for non-manifold input
  for (const pd::Triangle& t : in.triangles()) {
    if (!om.add_face(vh[t[0]], vh[t[1]], vh[t[2]]).is_valid()) ++*skipped;
  }
  omerr().enable();
  {
    OpenMesh::Decimater::DecimaterT<OmMesh> decimater(om);
    OpenMesh::Decimater::ModQuadricT<OmMesh>::Handle quadric;
    decimater.add(quadric);
    decimater.module(quadric).unset_max_err();
    decimater.initialize();
    decimater.decimate_to_faces(0, target_faces);
  }
  om.garbage_collection();
  std::vector<Vec3> vertices;
  vertices.reserve(om.n_vertices());
  for (const auto& v : om.vertices()) {
    const auto& p = om.point(v);
    vertices.emplace_back(p[0], p[1], p[2]);
  }
  std::vector<pd::Triangle> triangles;
  triangles.reserve(om.n_faces());
  for (const auto& f : om.faces()) {
    pd::Triangle t{};
    int k = 0;
    for (const auto& v : om.fv_range(f)) t[k++] = static_cast<hp::Index>(v.idx());
    triangles.push_back(t);
  }
  return pd::Mesh::FromArrays(std::move(vertices), std::move(triangles), source);
}

pd::Mesh Scaled(const pd::Mesh& in, double s, const std::string& source) {
  std::vector<Vec3> v = in.vertices();
  for (Vec3& p : v) p *= s;
  return pd::Mesh::FromArrays(std::move(v), in.triangles(), source);
}

// ---------------------------------------------------------------------------
// Trajectories

/// First hit of the ray o + t d (t > 0) with the mesh (brute force,
/// Möller–Trumbore): the parameter and the face, or nothing.
std::optional<std::pair<double, int>> RayCast(const pd::Mesh& m, const Vec3& o, const Vec3& d) {
  double best = std::numeric_limits<double>::infinity();
  int face = -1;
  const auto& V = m.vertices();
  for (std::size_t f = 0; f < m.num_triangles(); ++f) {
    const auto& t = m.triangles()[f];
    const Vec3 e1 = V[t[1]] - V[t[0]], e2 = V[t[2]] - V[t[0]];
    const Vec3 p = d.cross(e2);
    const double det = e1.dot(p);
    if (std::abs(det) < 1e-300) continue;
    const Vec3 s = o - V[t[0]];
    const double u = s.dot(p) / det;
    if (u < 0 || u > 1) continue;
    const Vec3 q = s.cross(e1);
    const double v = d.dot(q) / det;
    if (v < 0 || u + v > 1) continue;
    const double tt = e2.dot(q) / det;
    if (tt > 0 && tt < best) {
      best = tt;
      face = static_cast<int>(f);
    }
  }
  if (face < 0) return std::nullopt;
  return std::make_pair(best, face);
}

/// Area-weighted normal of the faces with a vertex within `radius` of p: a
/// smoother pressing direction than one face of a scanned mesh.
Vec3 SmoothNormal(const pd::Mesh& m, const Vec3& p, double radius, int face) {
  Vec3 n = Vec3::Zero();
  const auto& V = m.vertices();
  for (std::size_t f = 0; f < m.num_triangles(); ++f) {
    const auto& t = m.triangles()[f];
    if ((V[t[0]] - p).norm() > radius && (V[t[1]] - p).norm() > radius &&
        (V[t[2]] - p).norm() > radius) {
      continue;
    }
    n += (V[t[1]] - V[t[0]]).cross(V[t[2]] - V[t[0]]);  // 2 * area * normal
  }
  if (n.norm() < 1e-300) return m.face_normals()[face];
  return n.normalized();
}

struct Frame {
  Pose X_WA;
  double commanded = 0;  ///< how far the tip is pressed below the surface (m), >= 0
  int phase = 0;         ///< 0 press, 1 slide, 2 release
};

struct Benchmark {
  std::string name;
  std::string probe_name, scene_name;
  pd::ModelPtr probe, scene;
  Vec3 up;           ///< scene's up direction, to pick the start point
  Vec3 tip_dir_A;    ///< direction of the probe's tip in its mesh frame
  double slide = 0;  ///< tangential amplitude (m)
  std::vector<std::string> notes;
  // Filled by MakeTrajectory.
  Vec3 p_start, n_start;
  double press = 0;
  std::vector<Frame> frames;
};

/// Start just above a surface point seen from above (the most upward-facing
/// hit of a grid of downward rays over the middle of the scene whose start
/// pose is collision-free, spinning the probe about the normal if needed),
/// press in along the normal to 2 % of the probe's size, slide along a figure
/// eight while pressed (the tip follows the surface height under it), and come
/// back out; the probe tilts slowly by up to 10 degrees about its tip.
void MakeTrajectory(Benchmark* b, int num_frames) {
  const pd::Mesh& scene = b->scene->mesh();
  const pd::Mesh& probe = b->probe->mesh();
  const double probe_size = probe.size();
  b->press = 0.02 * probe_size;
  const double above = 0.01 * probe_size;
  const double max_tilt = 10.0 * std::numbers::pi / 180.0;

  // The probe's tip: centroid of its extreme vertices along tip_dir_A.
  const Vec3 tip_dir = b->tip_dir_A.normalized();
  double top = -std::numeric_limits<double>::infinity();
  for (const Vec3& v : probe.vertices()) top = std::max(top, v.dot(tip_dir));
  Vec3 p_tip_A = Vec3::Zero();
  int count = 0;
  for (const Vec3& v : probe.vertices()) {
    if (v.dot(tip_dir) >= top - 1e-6 * probe_size) {
      p_tip_A += v;
      ++count;
    }
  }
  p_tip_A /= count;

  // Candidate start points, most upward-facing (and central) first.
  struct Candidate {
    double score;
    Vec3 p;
    int face;
  };
  std::vector<Candidate> candidates;
  const Vec3 up = b->up.normalized();
  const Vec3 h1 = up.unitOrthogonal(), h2 = up.cross(h1);
  const Vec3 c = scene.bounds().Center();
  const double span = scene.size();
  for (int i = -4; i <= 4; ++i) {
    for (int j = -4; j <= 4; ++j) {
      const Vec3 off = (0.05 * span) * (i * h1 + j * h2);
      const Vec3 o = c + off + up * span;
      const auto hit = RayCast(scene, o, -up);
      if (!hit) continue;
      const Vec3 n = scene.face_normals()[hit->second];
      candidates.push_back({n.dot(up) - 0.5 * off.norm() / span, o - up * hit->first, hit->second});
    }
  }
  std::sort(candidates.begin(), candidates.end(),
            [](const Candidate& x, const Candidate& y) { return x.score > y.score; });
  pd::QueryScratch scratch;
  pd::CollisionResult collision;
  const pd::CollisionRequest request;
  Mat3 R0 = Mat3::Identity();
  int spin = -1;
  std::size_t rank = 0;
  for (; rank < candidates.size() && spin < 0; ++rank) {
    const Candidate& cand = candidates[rank];
    const Vec3 n = SmoothNormal(scene, cand.p, 0.25 * b->slide, cand.face);
    const Mat3 R_tip = hp::Quat::FromTwoVectors(tip_dir, -n).toRotationMatrix();
    for (int k = 0; k < 12; ++k) {
      const Mat3 R = Eigen::AngleAxisd(k * std::numbers::pi / 6, n) * R_tip;
      const Pose X{R, cand.p + n * above - R * p_tip_A};
      if (!pd::Collide(*b->probe, X, *b->scene, Pose::Identity(), request, &collision, &scratch)) {
        b->p_start = cand.p;
        b->n_start = n;
        R0 = R;
        spin = k * 30;
        break;
      }
    }
  }
  if (spin < 0) throw std::runtime_error(b->name + ": no collision-free start pose found");
  const Vec3 n = b->n_start;
  const Vec3 t1 = n.unitOrthogonal(), t2 = n.cross(t1);

  const int n_press = num_frames / 4, n_release = num_frames / 4;
  const int n_slide = num_frames - n_press - n_release;
  auto smooth = [](double u) { return u * u * (3 - 2 * u); };
  b->frames.clear();
  b->frames.reserve(num_frames);
  Vec3 surface = b->p_start;
  for (int f = 0; f < num_frames; ++f) {
    Frame fr;
    double h = 0;  // height of the tip above the surface along n
    Vec3 offset = Vec3::Zero();
    if (f < n_press) {
      fr.phase = 0;
      h = above + (-b->press - above) * smooth(static_cast<double>(f) / (n_press - 1));
    } else if (f < n_press + n_slide) {
      fr.phase = 1;
      const double v = static_cast<double>(f - n_press) / n_slide;
      offset = b->slide * (std::sin(2 * std::numbers::pi * v) * t1 +
                           0.5 * std::sin(4 * std::numbers::pi * v) * t2);
      h = -b->press;
    } else {
      fr.phase = 2;
      h = -b->press +
          (b->press + above) * smooth(static_cast<double>(f - n_press - n_slide) / (n_release - 1));
    }
    // Follow the surface under the tangential offset.
    const Vec3 o = b->p_start + offset + n * (0.25 * probe_size);
    if (offset.squaredNorm() > 0) {
      if (const auto hit = RayCast(scene, o, -n)) surface = o - n * hit->first;
    } else {
      surface = b->p_start;
    }
    const double u = static_cast<double>(f) / num_frames;
    const Mat3 R = Eigen::AngleAxisd(max_tilt * std::sin(2 * std::numbers::pi * u), t2) *
                   Eigen::AngleAxisd(0.5 * max_tilt * std::sin(4 * std::numbers::pi * u), t1) * R0;
    const Vec3 tip = surface + n * h;
    fr.X_WA = Pose{R, tip - R * p_tip_A};
    fr.commanded = std::max(0.0, -h);
    b->frames.push_back(fr);
  }
  std::ostringstream os;
  os << std::setprecision(4) << "start point (" << b->p_start.x() << ", " << b->p_start.y() << ", "
     << b->p_start.z() << ") (candidate " << rank << " of " << candidates.size() << ", probe spun "
     << spin << " deg about the normal for a free start), normal (" << n.x() << ", " << n.y()
     << ", " << n.z() << "); press " << b->press * 1e3 << " mm (2% of the probe's "
     << probe_size * 1e3 << " mm), slide +-" << b->slide * 1e3 << " mm, tilt up to 10 deg";
  b->notes.push_back(os.str());
}

// ---------------------------------------------------------------------------
// Replay

struct FrameRecord {
  double pdt_us = 0, fcl_us = 0;
  int iterations = 0, contacts = 0, fcl_contacts = 0;
  pd::PdStatus status = pd::PdStatus::kFailed;
  double depth = 0;
  /// Translation straight back along the pressing normal that separates the
  /// probe (exact CCD; NaN if not computed). The exact PDt never exceeds it.
  double escape = std::numeric_limits<double>::quiet_NaN();
  Vec3 translation = Vec3::Zero();
  /// The answer pose, nudged 1e-5 x the smaller size further along the PD
  /// direction, still collides: the answer is not a contact configuration.
  bool answer_not_free = false;
};

struct Summary {
  std::string name;
  std::size_t probe_tris = 0, scene_tris = 0;
  int frames = 0, penetrating = 0, cap_reached = 0, failed = 0, over_budget = 0, not_free = 0;
  int fcl_colliding = 0, missed_vs_fcl = 0;
  double p50 = 0, p99 = 0, p999 = 0, max = 0;
  double mean_iterations = 0, mean_contacts = 0;
  double fcl_p50 = 0, fcl_p99 = 0, fcl_mean_contacts = 0;
  double max_depth = 0;
  /// Largest change of the PD vector between consecutive penetrating frames
  /// (m): the probe moves micrometres per frame, so a jump here is a force
  /// discontinuity the user feels.
  double max_jump = 0;
  int max_jump_frame = -1;
  int worse_than_escape = 0;  ///< frames with PDt depth > 1.001 x the escape along the normal
  double median_escape_ratio = 0, max_escape_ratio = 0;  ///< PDt depth / escape
  bool goal_met = false;
};

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5);
  return v[std::min(k, v.size() - 1)];
}

double Us(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double, std::micro>(b - a).count();
}

Summary Replay(const Benchmark& b, std::vector<FrameRecord>* records) {
  const Pose X_WB = Pose::Identity();
  records->assign(b.frames.size(), {});
  pd::PdQueryData data;
  pd::PenetrationRequest request;
  pd::PenetrationResult result;
  for (std::size_t i = 0; i < b.frames.size(); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    pd::ComputePdt(*b.probe, b.frames[i].X_WA, *b.scene, X_WB, request, &data, &result);
    const auto t1 = std::chrono::steady_clock::now();
    FrameRecord& r = (*records)[i];
    r.pdt_us = Us(t0, t1);
    r.iterations = result.iterations;
    r.contacts = static_cast<int>(result.features.size());
    r.status = result.status;
    r.depth = result.depth;
    r.translation = result.translation_W;
  }
  // Reference answer, untimed: the escape straight back along the normal.
  {
    pd::QueryScratch scratch;
    pd::CcdResult ccd;
    const pd::CcdRequest ccd_request;
    pd::CollisionResult collision;
    const pd::CollisionRequest collision_request;
    const double far = b.probe->mesh().size() + b.scene->mesh().size();
    const double nudge = 1e-5 * std::min(b.probe->mesh().size(), b.scene->mesh().size());
    for (std::size_t i = 0; i < b.frames.size(); ++i) {
      FrameRecord& r = (*records)[i];
      if (r.status == pd::PdStatus::kSeparated) continue;
      if (r.status != pd::PdStatus::kFailed && r.depth > 0) {
        Pose X = b.frames[i].X_WA;
        X.t += r.translation * (1 + nudge / r.depth);
        r.answer_not_free =
            pd::Collide(*b.probe, X, *b.scene, X_WB, collision_request, &collision, &scratch);
      }
      Pose X0 = b.frames[i].X_WA;
      X0.t += b.n_start * far;
      if (pd::Collide(*b.probe, X0, *b.scene, X_WB, collision_request, &collision, &scratch)) {
        continue;
      }
      const bool hit = pd::TranslationalCcd(*b.probe, X0, -far * b.n_start, *b.scene, X_WB,
                                            ccd_request, &ccd, &scratch);
      (*records)[i].escape = hit ? far * (1 - ccd.toi) : 0.0;
    }
  }
  const hp::testing::FclModel fcl_probe(b.probe->mesh()), fcl_scene(b.scene->mesh());
  for (std::size_t i = 0; i < b.frames.size(); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    const int n = hp::testing::FclContacts(fcl_probe, b.frames[i].X_WA, fcl_scene, X_WB);
    const auto t1 = std::chrono::steady_clock::now();
    (*records)[i].fcl_us = Us(t0, t1);
    (*records)[i].fcl_contacts = n;
  }

  Summary s;
  s.name = b.name;
  s.probe_tris = b.probe->mesh().num_triangles();
  s.scene_tris = b.scene->mesh().num_triangles();
  s.frames = static_cast<int>(records->size());
  std::vector<double> pdt, fcl, ratios;
  long iterations = 0, contacts = 0, fcl_contacts = 0;
  for (std::size_t i = 0; i < records->size(); ++i) {
    const FrameRecord& r = (*records)[i];
    pdt.push_back(r.pdt_us);
    fcl.push_back(r.fcl_us);
    if (r.pdt_us > kFrameBudgetUs) ++s.over_budget;
    if (r.fcl_contacts > 0) {
      ++s.fcl_colliding;
      fcl_contacts += r.fcl_contacts;
      // FCL sees intersecting surfaces: PDt must not call that separated.
      if (r.status == pd::PdStatus::kSeparated) ++s.missed_vs_fcl;
    }
    if (r.status == pd::PdStatus::kPenetratingCapReached) ++s.cap_reached;
    if (r.status == pd::PdStatus::kFailed) ++s.failed;
    if (r.status == pd::PdStatus::kSeparated) continue;
    ++s.penetrating;
    if (i > 0 && (*records)[i - 1].status != pd::PdStatus::kSeparated) {
      const double jump = (r.translation - (*records)[i - 1].translation).norm();
      if (jump > s.max_jump) {
        s.max_jump = jump;
        s.max_jump_frame = static_cast<int>(i);
      }
    }
    if (r.answer_not_free) ++s.not_free;
    iterations += r.iterations;
    contacts += r.contacts;
    s.max_depth = std::max(s.max_depth, r.depth);
    if (r.escape > 0) {
      ratios.push_back(r.depth / r.escape);
      s.max_escape_ratio = std::max(s.max_escape_ratio, r.depth / r.escape);
      if (r.depth > 1.001 * r.escape) ++s.worse_than_escape;
    }
  }
  s.p50 = Percentile(pdt, 0.5);
  s.p99 = Percentile(pdt, 0.99);
  s.p999 = Percentile(pdt, 0.999);
  s.max = Percentile(pdt, 1.0);
  s.fcl_p50 = Percentile(fcl, 0.5);
  s.fcl_p99 = Percentile(fcl, 0.99);
  if (s.penetrating > 0) {
    s.mean_iterations = static_cast<double>(iterations) / s.penetrating;
    s.mean_contacts = static_cast<double>(contacts) / s.penetrating;
  }
  if (s.fcl_colliding > 0)
    s.fcl_mean_contacts = static_cast<double>(fcl_contacts) / s.fcl_colliding;
  s.median_escape_ratio = Percentile(ratios, 0.5);
  s.goal_met = s.p50 <= kGoalP50Us && s.p99 <= kGoalP99Us;
  return s;
}

const char* PhaseName(int phase) {
  static constexpr const char* kNames[] = {"press", "slide", "release"};
  return kNames[phase];
}

// ---------------------------------------------------------------------------
// Setup

std::vector<Benchmark> BuildBenchmarks(const std::string& models_dir) {
  std::vector<Benchmark> out;
  const std::filesystem::path dir(models_dir);
  auto shared = [&](const char* name) -> std::filesystem::path {
    const auto p = dir / name;
    return !models_dir.empty() && std::filesystem::exists(p) ? p : std::filesystem::path();
  };

  {
    Benchmark b;
    b.name = "stick-bunny";
    b.probe_name = "stick";
    b.probe = pd::MakeModel(pd::shapes::Stick());
    if (const auto p = shared("stanford-bunny.obj"); !p.empty()) {
      b.scene = pd::MakeModel(pd::LoadMesh(p.string()));
      b.scene_name = "stanford-bunny.obj";
      b.up = Vec3::UnitY();
    } else {
      b.scene = pd::MakeModel(pd::shapes::TorusKnot(2, 3, 0.06, 0.015, 1200, 30));
      b.scene_name = "torus knot (bunny stand-in)";
      b.up = Vec3::UnitZ();
      b.notes.push_back("NOTE: stanford-bunny.obj not found in '" + models_dir +
                        "'; using a procedural torus knot instead");
    }
    b.tip_dir_A = Vec3::UnitZ();
    b.slide = 0.015;
    out.push_back(std::move(b));
  }
  {
    Benchmark b;
    b.name = "spoon-cup";
    b.probe_name = "spoon";
    b.probe = pd::MakeModel(pd::shapes::Spoon());
    b.scene_name = "cup";
    b.scene = pd::MakeModel(pd::shapes::Cup());
    b.up = Vec3::UnitZ();
    b.tip_dir_A = Vec3::UnitX();  // the bowl's end: the spoon stands in the cup, stirring
    b.slide = 0.006;
    out.push_back(std::move(b));
  }
  {
    Benchmark b;
    b.name = "hammer-beast20k";
    b.probe_name = "hammer";
    b.probe = pd::MakeModel(pd::shapes::Hammer());
    if (const auto p = shared("beast.obj"); !p.empty()) {
      const auto t0 = std::chrono::steady_clock::now();
      const pd::Mesh full = pd::LoadMesh(p.string());
      int skipped = 0;
      constexpr double kScale = 1.0 / 500.0;
      b.scene = pd::MakeModel(Decimate(Scaled(full, kScale, "beast.obj (scaled)"), 20000,
                                       "beast.obj decimated, scaled 1/500", &skipped));
      const Vec3 size = b.scene->mesh().bounds().Size();
      std::ostringstream os;
      os << std::setprecision(4) << "beast.obj: " << full.num_triangles() << " -> "
         << b.scene->mesh().num_triangles() << " triangles (OpenMesh quadric decimater, " << skipped
         << " non-manifold faces skipped, "
         << (b.scene->mesh().watertight() ? "watertight" : "not watertight") << ", "
         << Us(t0, std::chrono::steady_clock::now()) / 1e3 << " ms), scaled by 1/500 to "
         << size.x() << " x " << size.y() << " x " << size.z() << " m to be comparable with the "
         << b.probe->mesh().bounds().Size().z() << " m hammer";
      b.notes.push_back(os.str());
      b.scene_name = "beast.obj ~20K";
      b.up = Vec3::UnitY();
    } else {
      b.scene = pd::MakeModel(pd::shapes::TorusKnot(2, 3, 0.25, 0.06, 420, 24));
      b.scene_name = "torus knot (statue stand-in)";
      b.up = Vec3::UnitZ();
      b.notes.push_back("NOTE: beast.obj not found in '" + models_dir +
                        "'; using a 20K-triangle procedural torus knot instead");
    }
    // The head's face, turned so that the handle rises from the surface at 17 degrees.
    b.tip_dir_A = Vec3(1, 0, 0.3);
    b.slide = 0.03;
    out.push_back(std::move(b));
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::string models = HAPTICPD_MODELS_DIR;
  std::string csv = "bench_pdt.csv";
  std::string frames_csv;
  int num_frames = 2000;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](const char* flag) -> const char* {
      const std::size_t n = std::strlen(flag);
      if (a.compare(0, n, flag) == 0 && a.size() > n && a[n] == '=') return argv[i] + n + 1;
      if (a == flag && i + 1 < argc) return argv[++i];
      return nullptr;
    };
    if (const char* v = value("--models")) {
      models = v;
    } else if (const char* v = value("--csv")) {
      csv = v;
    } else if (const char* v = value("--frames-csv")) {
      frames_csv = v;
    } else if (const char* v = value("--frames")) {
      num_frames = std::max(8, std::atoi(v));
    } else {
      std::cerr
          << "usage: bench_pdt [--models DIR] [--frames N] [--csv FILE] [--frames-csv FILE]\n";
      return 2;
    }
  }

  std::vector<Benchmark> benchmarks = BuildBenchmarks(models);
  std::vector<Summary> summaries;
  std::ofstream per_frame;
  if (!frames_csv.empty()) {
    per_frame.open(frames_csv);
    per_frame << "benchmark,frame,phase,commanded_m,status,depth_m,escape_m,iterations,contacts,"
                 "pdt_us,fcl_contacts,fcl_us\n";
  }
  std::cout << std::fixed;
  for (Benchmark& b : benchmarks) {
    MakeTrajectory(&b, num_frames);
    std::cout << "== " << b.name << ": probe " << b.probe_name << " ("
              << b.probe->mesh().num_triangles() << " triangles) vs " << b.scene_name << " ("
              << b.scene->mesh().num_triangles() << " triangles), " << b.frames.size()
              << " frames at 1 kHz\n";
    for (const auto& note : b.notes) std::cout << "   " << note << "\n";
    std::vector<FrameRecord> records;
    summaries.push_back(Replay(b, &records));
    // The slowest frames, to see where the time goes.
    std::vector<std::size_t> order(records.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::sort(order.begin(), order.end(),
              [&](std::size_t x, std::size_t y) { return records[x].pdt_us > records[y].pdt_us; });
    for (std::size_t k = 0; k < std::min<std::size_t>(3, order.size()); ++k) {
      const FrameRecord& r = records[order[k]];
      std::cout << "   slow frame " << order[k] << " (" << PhaseName(b.frames[order[k]].phase)
                << "): " << std::setprecision(1) << r.pdt_us << " us, " << pd::ToString(r.status)
                << ", depth " << std::setprecision(3) << r.depth * 1e3 << " mm (escape along "
                << "the normal " << r.escape * 1e3 << " mm, commanded press "
                << b.frames[order[k]].commanded * 1e3 << " mm), " << r.iterations << " iterations, "
                << r.contacts << " contacts\n";
    }
    const Summary& s = summaries.back();
    if (s.failed > 0 || s.missed_vs_fcl > 0 || s.cap_reached > 0 || s.worse_than_escape > 0 ||
        s.not_free > 0) {
      std::cout << "   WARNING: " << s.failed << " failed, " << s.cap_reached << " cap-reached, "
                << s.not_free << " answers still colliding when nudged past the contact, "
                << s.missed_vs_fcl << " frames FCL finds intersecting but PDt calls separated, "
                << s.worse_than_escape
                << " frames with a PDt depth above the escape straight back along the normal "
                << "(worst " << std::setprecision(2) << s.max_escape_ratio << "x)\n";
    }
    if (s.max_jump_frame >= 0) {
      const auto& prev = records[s.max_jump_frame - 1];
      const auto& cur = records[s.max_jump_frame];
      std::cout << "   largest PD jump between consecutive frames: " << std::setprecision(3)
                << s.max_jump * 1e3 << " mm at frame " << s.max_jump_frame << " (depth "
                << prev.depth * 1e3 << " -> " << cur.depth * 1e3 << " mm, "
                << pd::ToString(prev.status) << " -> " << pd::ToString(cur.status) << ")\n";
    }
    if (per_frame) {
      for (std::size_t i = 0; i < records.size(); ++i) {
        const FrameRecord& r = records[i];
        per_frame << std::setprecision(9) << b.name << "," << i << ","
                  << PhaseName(b.frames[i].phase) << "," << b.frames[i].commanded << ","
                  << pd::ToString(r.status) << "," << r.depth << "," << r.escape << ","
                  << r.iterations << "," << r.contacts << "," << std::setprecision(3) << r.pdt_us
                  << "," << r.fcl_contacts << "," << r.fcl_us << "\n";
      }
    }
  }

  std::cout
      << "\nPDt per frame (us) vs FCL collide with all contacts on the same poses; goal p50 <= "
      << kGoalP50Us << " us, p99 <= " << kGoalP99Us << " us\n";
  std::cout << std::left << std::setw(17) << "benchmark" << std::right << std::setw(7) << "tris A"
            << std::setw(8) << "tris B" << std::setw(7) << "frames" << std::setw(6) << "pen"
            << std::setw(9) << "p50" << std::setw(9) << "p99" << std::setw(9) << "p99.9"
            << std::setw(9) << "max" << std::setw(6) << ">1ms" << std::setw(7) << "iters"
            << std::setw(9) << "contacts" << std::setw(6) << "fail" << std::setw(6) << "cap"
            << std::setw(10) << "FCL p50" << std::setw(10) << "FCL p99" << std::setw(8) << "ratio"
            << std::setw(10) << "depth/esc" << std::setw(6) << ">esc"
            << "  goal\n";
  std::ofstream out(csv);
  out << "benchmark,probe_triangles,scene_triangles,frames,penetrating_frames,pdt_p50_us,"
         "pdt_p99_us,pdt_p999_us,pdt_max_us,frames_over_1ms,mean_iterations,mean_contacts,"
         "failed,cap_reached,fcl_colliding_frames,missed_vs_fcl,fcl_mean_contacts,fcl_p50_us,"
         "fcl_p99_us,ratio_p50,answers_not_free,max_depth_m,max_pd_jump_m,median_depth_over_escape,"
         "max_depth_"
         "over_escape,"
         "frames_above_escape,goal_met\n";
  for (const Summary& s : summaries) {
    const double ratio = s.fcl_p50 > 0 ? s.p50 / s.fcl_p50 : 0;
    std::cout << std::left << std::setw(17) << s.name << std::right << std::setw(7) << s.probe_tris
              << std::setw(8) << s.scene_tris << std::setw(7) << s.frames << std::setw(6)
              << s.penetrating << std::setprecision(1) << std::setw(9) << s.p50 << std::setw(9)
              << s.p99 << std::setw(9) << s.p999 << std::setw(9) << s.max << std::setw(6)
              << s.over_budget << std::setprecision(2) << std::setw(7) << s.mean_iterations
              << std::setprecision(1) << std::setw(9) << s.mean_contacts << std::setw(6) << s.failed
              << std::setw(6) << s.cap_reached << std::setw(10) << s.fcl_p50 << std::setw(10)
              << s.fcl_p99 << std::setprecision(2) << std::setw(8) << ratio << std::setw(10)
              << s.median_escape_ratio << std::setw(6) << s.worse_than_escape << "  "
              << (s.goal_met ? "met" : "NOT met") << "\n";
    out << std::setprecision(6) << s.name << "," << s.probe_tris << "," << s.scene_tris << ","
        << s.frames << "," << s.penetrating << "," << s.p50 << "," << s.p99 << "," << s.p999 << ","
        << s.max << "," << s.over_budget << "," << s.mean_iterations << "," << s.mean_contacts
        << "," << s.failed << "," << s.cap_reached << "," << s.fcl_colliding << ","
        << s.missed_vs_fcl << "," << s.fcl_mean_contacts << "," << s.fcl_p50 << "," << s.fcl_p99
        << "," << ratio << "," << s.not_free << "," << s.max_depth << "," << s.max_jump << ","
        << s.median_escape_ratio << "," << s.max_escape_ratio << "," << s.worse_than_escape << ","
        << (s.goal_met ? 1 : 0) << "\n";
  }
  std::cout << "pen = frames PDt finds penetrating; iters, contacts = means over those; ratio = "
               "PDt p50 / FCL p50 (< 1: PDt faster); depth/esc = median PDt depth over the "
               "escape straight back along the pressing normal (exact CCD; the true PDt is never "
               "larger), >esc = frames where PDt exceeds that escape by over 0.1%\n";
  std::cout << "CSV written to " << csv;
  if (!frames_csv.empty()) std::cout << ", per-frame CSV to " << frames_csv;
  std::cout << "\n";
  return 0;
}
