// Numerical stability of PDt and PDg on a catalogue of hard geometric
// cases. Each case is a slow sweep of the probe through the hard
// configuration with one query session (motion coherence on, as in the
// servo loop). For every case and both methods:
//   * every result is finite and no query fails;
//   * every penetrating answer is a real contact, checked by FCL along the
//     answer's own motion (pushed out a hair: free; pulled back: colliding);
//   * the force is continuous: the largest change of the penalty force per
//     micrometre of probe motion is reported, and a change larger than a
//     Lipschitz bound is allowed only where the contact switches (the PD
//     direction turns, or the answer's contact features are all new),
//     which is counted and reported;
//   * the same inputs give the same outputs bit for bit (a second session).
// The catalogue covers coplanar faces, parallel edges, vertex on face and on
// edge, sliver and zero-area triangles, unwelded (duplicate) vertices, an
// open mesh with a hole, a self-intersecting mesh, a plate thinner than the
// contact tolerance, full containment, probes 1000x smaller and larger than
// the scene, coordinates 10 km from the origin, half-turn rotations and a
// sphere-like probe (equal principal moments).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <iostream>
#include <limits>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "pd/geometry_model.h"
#include "pd/material.h"
#include "pd/pdg.h"
#include "pd/pdt.h"
#include "pd/shapes.h"
#include "tests/oracles/fcl_oracle.h"
#include "tests/pd/pd_test_support.h"
#include "tests/pd/random_poses.h"
#include "tests/test_util.h"

namespace hapticpd::pd {
namespace {

using testing::FclModel;

struct HardCase {
  std::string name;
  Mesh a, b;
  Pose X_WB = Pose::Identity();
  /// The probe's pose along the sweep, s in [0, 1].
  std::function<Pose(double)> path;
  int steps = 160;
};

Mat3 Rot(double angle, const Vec3& axis) {
  return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
}

// A straight slide of a probe at orientation R from p0 to p1.
std::function<Pose(double)> Slide(const Mat3& R, const Vec3& p0, const Vec3& p1) {
  return [=](double s) { return Pose{R, p0 + s * (p1 - p0)}; };
}

// A box whose top face (z = +h.z) is triangulated with slivers and a
// zero-area triangle: a vertex 1e-9 h.x inside the top face's edge and a
// vertex exactly on that edge.
Mesh SliverBox(const Vec3& h) {
  std::vector<Vec3> v = {{-h.x(), -h.y(), -h.z()}, {h.x(), -h.y(), -h.z()}, {h.x(), h.y(), -h.z()},
                         {-h.x(), h.y(), -h.z()},  {-h.x(), -h.y(), h.z()}, {h.x(), -h.y(), h.z()},
                         {h.x(), h.y(), h.z()},    {-h.x(), h.y(), h.z()}};
  v.push_back({0, -h.y(), h.z()});                 // 8: on the top face's front edge
  v.push_back({0, -h.y() + 1e-9 * h.x(), h.z()});  // 9: a hair inside it
  std::vector<Triangle> t = {
      {0, 2, 1}, {0, 3, 2},             // bottom
      {0, 1, 5}, {0, 5, 8}, {0, 8, 4},  // front, with 8 on the top edge
      {1, 2, 6}, {1, 6, 5},             // right
      {2, 3, 7}, {2, 7, 6},             // back
      {3, 0, 4}, {3, 4, 7},             // left
      {4, 8, 9}, {8, 5, 9},             // top: two slivers along the edge
      {5, 6, 9}, {6, 7, 9}, {7, 4, 9},  // top: the rest fans from 9
  };
  return Mesh::FromArrays(std::move(v), std::move(t), "sliver box");
}

// Every triangle with its own three vertices: duplicate vertices, no shared
// edges (topologically a soup of separate triangles).
Mesh Unwelded(const Mesh& m) {
  std::vector<Vec3> v;
  std::vector<Triangle> t;
  for (const Triangle& tri : m.triangles()) {
    const Index base = static_cast<Index>(v.size());
    for (Index k : tri) v.push_back(m.vertices()[k]);
    t.push_back({base, base + 1, base + 2});
  }
  return Mesh::FromArrays(std::move(v), std::move(t), "unwelded " + m.source());
}

// A mesh without the triangles whose normal points along +z (a box with its
// top missing).
Mesh WithoutTop(const Mesh& m) {
  std::vector<Triangle> t;
  for (std::size_t f = 0; f < m.triangles().size(); ++f) {
    if (m.face_normals()[f].z() < 0.9) t.push_back(m.triangles()[f]);
  }
  return Mesh::FromArrays(m.vertices(), std::move(t), "open " + m.source());
}

// Two overlapping boxes in one mesh: the surfaces cross each other.
Mesh TwoCrossingBoxes() {
  const Mesh a = shapes::Box(Vec3(0.05, 0.02, 0.02));
  const Mesh b = shapes::Box(Vec3(0.02, 0.02, 0.05));
  std::vector<Vec3> v = a.vertices();
  std::vector<Triangle> t = a.triangles();
  const Index base = static_cast<Index>(v.size());
  for (const Vec3& p : b.vertices()) v.push_back(p + Vec3(0.02, 0, 0.01));
  for (const Triangle& tri : b.triangles())
    t.push_back({tri[0] + base, tri[1] + base, tri[2] + base});
  return Mesh::FromArrays(std::move(v), std::move(t), "two crossing boxes");
}

// The height of a probe's origin at orientation R such that its lowest
// vertex is `depth` below the plane z = top.
double RestOn(const Mesh& probe, const Mat3& R, double top, double depth) {
  double lowest = std::numeric_limits<double>::infinity();
  for (const Vec3& v : probe.vertices()) lowest = std::min(lowest, (R * v).z());
  return top - lowest - depth;
}

std::vector<HardCase> Catalogue() {
  std::vector<HardCase> c;
  const Vec3 z = Vec3::UnitZ();
  const Mat3 I = Mat3::Identity();
  // An edge of a box pointing down: 45 degrees about x.
  const Mat3 edge_down = Rot(M_PI / 4, Vec3::UnitX());
  // A vertex of a box pointing down.
  const Mat3 vertex_down = Rot(std::atan(std::sqrt(2.0)), Vec3(1, -1, 0)) * I;
  const double d = 1e-3;  // penetration of the sliding cases

  const Mesh cube = shapes::Box(Vec3::Constant(0.01));
  const double h_flat = RestOn(cube, I, 0.05, d);
  const double h_edge = RestOn(cube, edge_down, 0.05, d);
  const double h_vertex = RestOn(cube, vertex_down, 0.05, d);
  const double ridge = 0.05 * std::sqrt(2.0);  // top edge of a box turned 45 degrees about x
  c.push_back({"coplanar-box-on-box", cube, shapes::Box(Vec3::Constant(0.05)), Pose::Identity(),
               Slide(I, Vec3(-0.03, 0.002, h_flat), Vec3(0.055, 0.002, h_flat))});
  c.push_back({"parallel-edges", cube, shapes::Box(Vec3::Constant(0.05)),
               Pose{edge_down, Vec3::Zero()},
               Slide(edge_down, Vec3(-0.03, 0, RestOn(cube, edge_down, ridge, d)),
                     Vec3(0.03, 0.0005, RestOn(cube, edge_down, ridge, d)))});
  c.push_back({"vertex-on-face", cube, shapes::Box(Vec3::Constant(0.05)), Pose::Identity(),
               Slide(vertex_down, Vec3(-0.03, 0.01, h_vertex), Vec3(0.03, -0.01, h_vertex))});
  c.push_back({"vertex-on-edge", cube, shapes::Box(Vec3::Constant(0.05)),
               Pose{edge_down, Vec3::Zero()},
               Slide(vertex_down, Vec3(-0.03, 0, RestOn(cube, vertex_down, ridge, d)),
                     Vec3(0.03, 0, RestOn(cube, vertex_down, ridge, d)))});
  // Across the top face's front edge, where the slivers are.
  c.push_back({"sliver-and-zero-area-triangles", cube, SliverBox(Vec3::Constant(0.05)),
               Pose::Identity(),
               Slide(edge_down, Vec3(0.001, -0.03, h_edge), Vec3(0.002, -0.052, h_edge))});
  c.push_back({"duplicate-vertices", cube, Unwelded(shapes::Box(Vec3::Constant(0.05), 2)),
               Pose::Identity(),
               Slide(vertex_down, Vec3(-0.03, 0.001, h_vertex), Vec3(0.03, 0.002, h_vertex))});
  c.push_back({"open-mesh-with-hole", cube, WithoutTop(shapes::Box(Vec3::Constant(0.05), 2)),
               Pose::Identity(), Slide(I, Vec3(0.06 - d, -0.03, 0.0), Vec3(0.06 - d, 0.03, 0.04))});
  c.push_back({"self-intersecting-mesh", cube, TwoCrossingBoxes(), Pose::Identity(),
               Slide(I, Vec3(-0.04, 0, 0.03 - d), Vec3(0.05, 0, 0.03 - d))});
  // Thinner than the contact tolerance (1e-4 of the probe's 4 cm: 4 um).
  c.push_back({"plate-thinner-than-epsilon", shapes::Sphere(0.02, 2),
               shapes::ThinPlate(0.2, 0.2, 2e-6), Pose::Identity(),
               Slide(I, Vec3(0, 0.001, 0.03), Vec3(0.002, 0, -0.03))});
  c.push_back({"containment", shapes::Sphere(0.01, 2), shapes::Box(Vec3::Constant(0.05)),
               Pose::Identity(), Slide(I, Vec3(0.001, 0.002, 0.0), Vec3(0.03, 0.002, 0.0))});
  c.push_back({"probe-1000x-smaller", shapes::Box(Vec3::Constant(0.5e-3)),
               shapes::Box(Vec3::Constant(0.5)), Pose::Identity(),
               Slide(vertex_down, Vec3(-0.2, 0.1, 0.5 + 0.5e-3 * std::sqrt(3.0) - 0.2e-3),
                     Vec3(0.2, 0.1, 0.5 + 0.5e-3 * std::sqrt(3.0) - 0.2e-3))});
  c.push_back({"probe-1000x-larger", shapes::Box(Vec3::Constant(5.0)),
               shapes::Box(Vec3::Constant(0.005)), Pose::Identity(),
               Slide(I, Vec3(-0.002, 0.001, 5.004), Vec3(0.002, 0.001, 5.003))});
  {
    HardCase far{"10-km-from-the-origin", cube, shapes::Box(Vec3::Constant(0.05)),
                 Pose::FromTranslation(Vec3(1e4, -1e4, 1e4)), nullptr};
    far.path = [=](double s) {
      return Pose{I, Vec3(1e4, -1e4, 1e4) + Vec3(-0.03 + 0.085 * s, 0.002, h_flat)};
    };
    c.push_back(far);
  }
  c.push_back({"half-turn", shapes::Stick(), shapes::Box(Vec3::Constant(0.05)), Pose::Identity(),
               [=](double s) {
                 // The stick lies nearly flat on the box and spins a full
                 // half turn about the vertical while pressed in.
                 const Mat3 R =
                     Rot(M_PI * (0.9 + 0.2 * s), z) * Rot(M_PI / 2 - 0.05, Vec3::UnitY());
                 return Pose{R, Vec3(0, 0, 0.05)};
               }});
  c.push_back(
      {"sphere-like-probe", shapes::Sphere(0.01, 3), shapes::Box(Vec3::Constant(0.05)),
       Pose::Identity(),
       Slide(Rot(0.3, Vec3(1, 2, 3)), Vec3(-0.03, 0, 0.06 - d), Vec3(0.03, 0.01, 0.06 - d))});
  (void)z;
  return c;
}

struct SweepRecord {
  std::vector<PenetrationResult> results;
  std::vector<Wrench> wrenches;
};

bool Finite(const PenetrationResult& r, const Wrench& w) {
  return std::isfinite(r.depth) && r.translation_W.allFinite() && r.X_WA_result.t.allFinite() &&
         r.X_WA_result.R.allFinite() && std::isfinite(r.sigma) && std::isfinite(r.rotation_angle) &&
         r.rotation_axis_W.allFinite() && w.force.allFinite() && w.torque.allFinite();
}

SweepRecord Sweep(const HardCase& hc, const GeometryModel& A, const GeometryModel& B, PdMode mode,
                  const Material& material) {
  SweepRecord rec;
  PdQueryData pdt_data;
  PdgQueryData pdg_data;
  PenetrationRequest request;
  PenetrationResult r;
  for (int k = 0; k <= hc.steps; ++k) {
    const Pose X_WA = hc.path(static_cast<double>(k) / hc.steps);
    if (mode == PdMode::kTranslational) {
      ComputePdt(A, X_WA, B, hc.X_WB, request, &pdt_data, &r);
    } else {
      ComputePdg(A, X_WA, B, hc.X_WB, request, &pdg_data, &r);
    }
    rec.results.push_back(r);
    rec.wrenches.push_back(PdWrench(r, material, X_WA * A.mass().p_MC));
  }
  return rec;
}

bool SameBits(double x, double y) { return std::memcmp(&x, &y, sizeof(double)) == 0; }

class HardCases : public ::testing::TestWithParam<PdMode> {};

TEST_P(HardCases, FiniteVerifiedContinuousAndDeterministic) {
  const PdMode mode = GetParam();
  Material material;
  material.stiffness = 1000;
  int total_penetrating = 0;
  for (const HardCase& hc : Catalogue()) {
    SCOPED_TRACE(hc.name);
    const ModelPtr A = MakeModel(hc.a);
    const ModelPtr B = MakeModel(hc.b);
    const FclModel fa(A->mesh()), fb(B->mesh());
    const SweepRecord rec = Sweep(hc, *A, *B, mode, material);
    int penetrating = 0, switches = 0;
    double max_df_per_um = 0, path_um = 0;
    for (int k = 0; k <= hc.steps; ++k) {
      SCOPED_TRACE(k);
      const PenetrationResult& r = rec.results[k];
      const Pose X_WA = hc.path(static_cast<double>(k) / hc.steps);
      ASSERT_NE(r.status, PdStatus::kFailed) << r.failure;
      ASSERT_TRUE(Finite(r, rec.wrenches[k]));
      if (r.status != PdStatus::kSeparated) {
        ++penetrating;
        if (mode == PdMode::kTranslational) {
          ExpectRealContact(fa, fb, hc.X_WB, r);
        } else {
          ExpectRealContactAlongMotion(fa, fb, hc.X_WB, X_WA, A->mass().p_MC, r);
        }
      }
      if (k == 0) continue;
      // Continuity of the force along the sweep.
      const PenetrationResult& q = rec.results[k - 1];
      const Pose X_prev = hc.path(static_cast<double>(k - 1) / hc.steps);
      const double move =
          (X_WA.t - X_prev.t).norm() +
          Eigen::AngleAxisd(X_WA.R * X_prev.R.transpose()).angle() * A->radius_about_com();
      const double df = (rec.wrenches[k].force - rec.wrenches[k - 1].force).norm();
      path_um += move * 1e6;
      max_df_per_um = std::max(max_df_per_um, df / std::max(move * 1e6, 1e-9));
      // PDt moves by at most the probe's motion while its contact persists;
      // with up to a few regions each adding k (d . n) n, the force changes
      // by at most a few k |motion|. More is a switch of contact, which must
      // be visible in the answer: its direction turns, or none of its
      // contact features were there before.
      const double bound = 4 * material.stiffness * move + 1e-9;
      if (df > bound) {
        bool turned = true, shared = false;
        if (q.depth > 0 && r.depth > 0) {
          turned = q.translation_W.normalized().dot(r.translation_W.normalized()) < std::cos(0.1);
        }
        std::set<std::tuple<int, Index, Index>> before;
        for (const ContactFeature& f : q.features) before.insert({int(f.type), f.a, f.b});
        for (const ContactFeature& f : r.features) {
          shared = shared || before.count({int(f.type), f.a, f.b}) > 0;
        }
        const bool entered_or_left = (q.depth > 0) != (r.depth > 0);
        EXPECT_TRUE(turned || !shared || entered_or_left)
            << "force jump of " << df << " N for " << move * 1e6
            << " um of motion without a contact switch (depth " << q.depth << " -> " << r.depth
            << ")";
        ++switches;
      }
    }
    EXPECT_GT(penetrating, hc.steps / 4) << "the sweep should be mostly in contact";
    total_penetrating += penetrating;
    // Determinism: a second session over the same inputs, bit for bit.
    const SweepRecord again = Sweep(hc, *A, *B, mode, material);
    for (int k = 0; k <= hc.steps; ++k) {
      const PenetrationResult &x = rec.results[k], &y = again.results[k];
      ASSERT_TRUE(SameBits(x.depth, y.depth) && x.status == y.status &&
                  SameBits(x.translation_W.x(), y.translation_W.x()) &&
                  SameBits(x.translation_W.y(), y.translation_W.y()) &&
                  SameBits(x.translation_W.z(), y.translation_W.z()) &&
                  SameBits(x.sigma, y.sigma) && x.features.size() == y.features.size())
          << "not deterministic at step " << k;
    }
    std::cout << "[ stability " << ToString(mode) << " ] " << hc.name << ": " << penetrating << "/"
              << hc.steps + 1 << " penetrating, max |dF| " << max_df_per_um
              << " N per um of motion (k = " << material.stiffness << " N/m), " << switches
              << " contact switches over " << path_um << " um\n";
  }
  EXPECT_GT(total_penetrating, 0);
}

// Property sweep: seeded random poses over the procedural non-convex pairs
// (HAPTICPD_TEST_SEED, HAPTICPD_TEST_COUNT; `--long` runs 20x more), cold
// starts: PDt and PDg finite, verified real contacts by FCL, PDg never
// above PDt, and bit-for-bit repeatable.
TEST(PropertySweep, RandomPosesKeepTheInvariants) {
  std::mt19937_64 rng(testing::TestSeed() + 8);
  const int count = testing::TestCount(40);
  int checked = 0;
  for (const NonConvexCase& pc : NonConvexCases()) {
    SCOPED_TRACE(pc.name);
    const ModelPtr A = MakeModel(pc.a);
    const ModelPtr B = MakeModel(pc.b);
    const FclModel fa(A->mesh()), fb(B->mesh());
    PdQueryData pdt_data, pdt_again;
    PdgQueryData pdg_data, pdg_again;
    PenetrationResult t, g, t2, g2;
    for (int i = 0; i < count; ++i) {
      SCOPED_TRACE(i);
      const Pose X_WA = testing::NearSurfacePose(*A, *B, rng, pc.spread);
      ComputePdt(*A, X_WA, *B, Pose::Identity(), ColdRequest(), &pdt_data, &t);
      ComputePdg(*A, X_WA, *B, Pose::Identity(), ColdRequest(), &pdg_data, &g);
      ASSERT_NE(t.status, PdStatus::kFailed) << t.failure;
      ASSERT_NE(g.status, PdStatus::kFailed) << g.failure;
      ASSERT_TRUE(Finite(t, Wrench{}) && Finite(g, Wrench{}));
      ASSERT_EQ(t.status == PdStatus::kSeparated, g.status == PdStatus::kSeparated);
      if (t.status == PdStatus::kSeparated) continue;
      ++checked;
      ExpectRealContact(fa, fb, Pose::Identity(), t);
      ExpectRealContactAlongMotion(fa, fb, Pose::Identity(), X_WA, A->mass().p_MC, g);
      EXPECT_LE(g.depth, t.depth * (1 + 1e-9)) << "PDg above PDt";
      ComputePdt(*A, X_WA, *B, Pose::Identity(), ColdRequest(), &pdt_again, &t2);
      ComputePdg(*A, X_WA, *B, Pose::Identity(), ColdRequest(), &pdg_again, &g2);
      EXPECT_TRUE(SameBits(t.depth, t2.depth) && SameBits(g.sigma, g2.sigma) &&
                  SameBits(g.X_WA_result.t.x(), g2.X_WA_result.t.x()))
          << "not deterministic";
    }
  }
  EXPECT_GT(checked, count);  // over the pairs, a good share penetrates
}

INSTANTIATE_TEST_SUITE_P(PdtAndPdg, HardCases,
                         ::testing::Values(PdMode::kTranslational, PdMode::kGeneralized),
                         [](const ::testing::TestParamInfo<PdMode>& info) {
                           return info.param == PdMode::kTranslational ? std::string("PDt")
                                                                       : std::string("PDg");
                         });

}  // namespace
}  // namespace hapticpd::pd
