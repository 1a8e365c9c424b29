#include "client/bench/scenarios.h"

#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>
#include <OpenMesh/Tools/Decimater/DecimaterT.hh>
#include <OpenMesh/Tools/Decimater/ModQuadricT.hh>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <limits>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include "pd/pdg.h"
#include "pd/pdt.h"
#include "pd/queries.h"
#include "pd/shapes.h"

namespace hapticpd::bench {

namespace {
struct OmTraits : OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3d;
  using Normal = OpenMesh::Vec3d;
};
using OmMesh = OpenMesh::TriMesh_ArrayKernelT<OmTraits>;

}  // namespace

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

std::string ParseMaxSlope(const std::string& text, double* slope) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (end == text.c_str() || *end != '\0' || !(v >= 0)) {
    return "must be a number >= 0 (inf: no limit), got '" + text + "'";
  }
  *slope = v;
  return {};
}

/// Start just above a surface point seen from above (the most upward-facing
/// hit of a grid of downward rays over the middle of the scene whose start
/// pose is collision-free, spinning the probe about the normal if needed),
/// press in along the normal to 2 % of the probe's size, slide along a figure
/// eight while pressed (the tip follows the surface height under it), and come
/// back out; the probe tilts slowly by up to 10 degrees about its tip.
void MakeTrajectory(Benchmark* b, int num_frames, double max_slope) {
  if (!(max_slope >= 0)) {
    throw std::invalid_argument("trajectory max slope must be >= 0 (infinity: no limit), got " +
                                std::to_string(max_slope));
  }
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
  Vec3 last_offset = Vec3::Zero();
  double max_step = 0;  // of the tip between frames
  Vec3 last_tip = b->p_start;
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
    // Follow the surface under the tangential offset: its height along n
    // changes by at most max_slope times the tangential step, and stays where
    // the ray misses (unlimited: the ray's height as it is).
    if (offset.squaredNorm() > 0) {
      const Vec3 o = b->p_start + offset + n * (0.25 * probe_size);
      const auto hit = RayCast(scene, o, -n);
      if (!std::isfinite(max_slope)) {
        if (hit) surface = o - n * hit->first;
      } else {
        const Vec3 level = surface + (offset - last_offset);  // the same height
        const double rise = hit ? (o - n * hit->first - level).dot(n) : 0.0;
        const double limit = max_slope * (offset - last_offset).norm();
        surface = level + n * std::clamp(rise, -limit, limit);
      }
    } else if (fr.phase == 0) {
      surface = b->p_start;
    }  // the release goes straight out from where the slide ended
    last_offset = offset;
    const double u = static_cast<double>(f) / num_frames;
    const Mat3 R = Eigen::AngleAxisd(max_tilt * std::sin(2 * std::numbers::pi * u), t2) *
                   Eigen::AngleAxisd(0.5 * max_tilt * std::sin(4 * std::numbers::pi * u), t1) * R0;
    const Vec3 tip = surface + n * h;
    if (f > 0) max_step = std::max(max_step, (tip - last_tip).norm());
    last_tip = tip;
    fr.X_WA = Pose{R, tip - R * p_tip_A};
    fr.commanded = std::max(0.0, -h);
    b->frames.push_back(fr);
  }
  std::ostringstream os;
  os << std::setprecision(4) << "start point (" << b->p_start.x() << ", " << b->p_start.y() << ", "
     << b->p_start.z() << ") (candidate " << rank << " of " << candidates.size() << ", probe spun "
     << spin << " deg about the normal for a free start), normal (" << n.x() << ", " << n.y()
     << ", " << n.z() << "); press " << b->press * 1e3 << " mm (2% of the probe's "
     << probe_size * 1e3 << " mm), slide +-" << b->slide * 1e3 << " mm, tilt up to 10 deg; "
     << "the tip follows slopes up to " << max_slope << " and moves at most " << max_step * 1e3
     << " mm between frames";
  b->notes.push_back(os.str());
}

// ---------------------------------------------------------------------------
// Statistics

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5);
  return v[std::min(k, v.size() - 1)];
}

double Us(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double, std::micro>(b - a).count();
}

const char* PhaseName(int phase) {
  static constexpr const char* kNames[] = {"press", "slide", "release"};
  return kNames[phase];
}

// ---------------------------------------------------------------------------
// Setup

namespace {
// " in 'DIR'", or " (no models folder)" when none was found.
std::string Where(const std::string& models_dir) {
  return models_dir.empty() ? " (no models folder)" : " in '" + models_dir + "'";
}
}  // namespace

std::vector<Benchmark> BuildBenchmarks(const std::string& models_dir, bool tiny,
                                       const std::string& only) {
  std::vector<Benchmark> out;
  auto wanted = [&](const char* name) { return only.empty() || only == name; };
  const std::filesystem::path dir(models_dir);
  auto shared = [&](const char* name) -> std::filesystem::path {
    const auto p = dir / name;
    return !tiny && !models_dir.empty() && std::filesystem::exists(p) ? p : std::filesystem::path();
  };
  // A procedural scene in place of a shared model (z up).
  auto stand_in = [](Benchmark* b, pd::Mesh mesh, const std::string& name,
                     const std::string& note) {
    b->scene = pd::MakeModel(std::move(mesh));
    b->scene_name = name;
    b->up = Vec3::UnitZ();
    b->stand_in = true;
    if (!note.empty()) b->notes.push_back(note);
  };

  if (wanted("stick-bunny")) {
    Benchmark b;
    b.name = "stick-bunny";
    b.probe_name = "stick";
    b.probe = pd::MakeModel(pd::shapes::Stick());
    if (tiny) {
      stand_in(&b, pd::shapes::TorusKnot(2, 3, 0.06, 0.015, 60, 8),
               "small torus knot (tiny bunny stand-in)", "");
    } else if (const auto p = shared("stanford-bunny.obj"); !p.empty()) {
      b.scene = pd::MakeModel(pd::LoadMesh(p.string()));
      b.scene_name = "stanford-bunny.obj";
      b.up = Vec3::UnitY();
    } else {
      stand_in(&b, pd::shapes::TorusKnot(2, 3, 0.06, 0.015, 1200, 30),
               "torus knot (bunny stand-in)",
               "NOTE: stanford-bunny.obj not found" + Where(models_dir) +
                   "; using a procedural torus knot instead");
    }
    b.tip_dir_A = Vec3::UnitZ();
    b.slide = 0.015;
    out.push_back(std::move(b));
  }
  if (wanted("spoon-cup")) {
    Benchmark b;
    b.name = "spoon-cup";
    b.probe_name = "spoon";
    b.probe = pd::MakeModel(pd::shapes::Spoon(tiny ? 1 : 4));
    b.scene_name = tiny ? "cup (resolution 1)" : "cup";
    b.scene = pd::MakeModel(pd::shapes::Cup(tiny ? 1 : 4));
    b.up = Vec3::UnitZ();
    b.tip_dir_A = Vec3::UnitX();  // the bowl's end: the spoon stands in the cup, stirring
    b.slide = 0.006;
    out.push_back(std::move(b));
  }
  if (wanted("hammer-beast20k")) {
    Benchmark b;
    b.name = "hammer-beast20k";
    b.probe_name = "hammer";
    b.probe = pd::MakeModel(pd::shapes::Hammer(tiny ? 1 : 4));
    if (tiny) {
      stand_in(&b, pd::shapes::TorusKnot(2, 3, 0.25, 0.06, 60, 8),
               "small torus knot (tiny statue stand-in)", "");
    } else if (const auto p = shared("beast.obj"); !p.empty()) {
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
      stand_in(&b, pd::shapes::TorusKnot(2, 3, 0.25, 0.06, 420, 24), "torus knot (statue stand-in)",
               "NOTE: beast.obj not found" + Where(models_dir) +
                   "; using a 20K-triangle procedural torus knot instead");
    }
    // The head's face, turned so that the handle rises from the surface at 17 degrees.
    b.tip_dir_A = Vec3(1, 0, 0.3);
    b.slide = 0.03;
    out.push_back(std::move(b));
  }
  return out;
}

// ---------------------------------------------------------------------------
// Replay

std::vector<FrameOutcome> ReplayPd(const pd::GeometryModel& A, const pd::GeometryModel& B,
                                   const std::vector<Frame>& frames, pd::PdMode mode,
                                   const pd::PenetrationRequest& request) {
  std::vector<FrameOutcome> out(frames.size());
  pd::PdQueryData pdt_data;
  pd::PdgQueryData pdg_data;
  pd::PenetrationResult r;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    if (mode == pd::PdMode::kTranslational) {
      pd::ComputePdt(A, frames[i].X_WA, B, Pose::Identity(), request, &pdt_data, &r);
    } else {
      pd::ComputePdg(A, frames[i].X_WA, B, Pose::Identity(), request, &pdg_data, &r);
    }
    const auto t1 = std::chrono::steady_clock::now();
    FrameOutcome& o = out[i];
    o.us = Us(t0, t1);
    o.status = r.status;
    o.depth = r.depth;
    o.iterations = r.iterations;
    o.contacts = static_cast<int>(r.features.size());
    o.X_WA_result = r.X_WA_result;
    o.translation_W = r.translation_W;
  }
  return out;
}

TimingSummary Summarize(const std::vector<FrameOutcome>& outcomes, bool penetrating_only) {
  TimingSummary s;
  std::vector<double> us;
  long iterations = 0, contacts = 0;
  for (const FrameOutcome& o : outcomes) {
    ++s.frames;
    s.failed += o.status == pd::PdStatus::kFailed;
    s.cap_reached += o.status == pd::PdStatus::kPenetratingCapReached;
    const bool pen = Penetrating(o.status);
    if (pen || !penetrating_only) us.push_back(o.us);
    if (!pen) continue;
    ++s.penetrating;
    iterations += o.iterations;
    contacts += o.contacts;
  }
  s.p50_us = Percentile(us, 0.5);
  s.p99_us = Percentile(us, 0.99);
  s.max_us = Percentile(us, 1.0);
  s.mean_iterations = MeanOver(static_cast<double>(iterations), s.penetrating);
  s.mean_contacts = MeanOver(static_cast<double>(contacts), s.penetrating);
  return s;
}

}  // namespace hapticpd::bench
