// The viewer's mesh store (client/viewer/mesh_store.h): meshes over the
// display limit are stored simplified by vertex clustering, once per mesh,
// and still look like the mesh (its bounds), whatever its topology. Runs in
// every preset (label services, with the other viewer tests).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>

#include "client/viewer/mesh_store.h"
#include "pd/mesh.h"
#include "pd/shapes.h"
#include "proto/wire/convert.h"
#include "tests/test_util.h"

namespace hapticpd {
namespace {

v1::InlineMesh Inline(const pd::Mesh& m) {
  v1::InlineMesh out;
  wire::ToProto(m, &out);
  return out;
}

std::size_t Triangles(const v1::InlineMesh& m) {
  return static_cast<std::size_t>(m.triangles_size()) / 3;
}

std::array<double, 6> Bounds(const v1::InlineMesh& m) {
  std::array<double, 6> b{HUGE_VAL, HUGE_VAL, HUGE_VAL, -HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  for (int i = 0; i < m.vertices_size(); ++i) {
    b[static_cast<std::size_t>(i % 3)] =
        std::min(b[static_cast<std::size_t>(i % 3)], m.vertices(i));
    b[static_cast<std::size_t>(3 + i % 3)] =
        std::max(b[static_cast<std::size_t>(3 + i % 3)], m.vertices(i));
  }
  return b;
}

void ExpectLooksLike(const v1::InlineMesh& shown, const v1::InlineMesh& mesh, double tol) {
  const auto a = Bounds(shown), b = Bounds(mesh);
  for (std::size_t k = 0; k < 6; ++k) EXPECT_NEAR(a[k], b[k], tol) << "bound " << k;
  for (std::uint32_t i : shown.triangles()) {
    ASSERT_LT(i, static_cast<std::uint32_t>(shown.vertices_size() / 3));
  }
  for (int t = 0; t < shown.triangles_size(); t += 3) {
    EXPECT_TRUE(shown.triangles(t) != shown.triangles(t + 1) &&
                shown.triangles(t + 1) != shown.triangles(t + 2) &&
                shown.triangles(t) != shown.triangles(t + 2))
        << "a collapsed triangle at " << t / 3;
  }
}

TEST(SimplifyForDisplay, FitsTheLimitAndKeepsTheShape) {
  const v1::InlineMesh knot = Inline(pd::shapes::MakeShape(std::string("torusknot")));
  ASSERT_GT(Triangles(knot), 4000u);
  for (const std::size_t limit : {std::size_t{3000}, std::size_t{1000}, std::size_t{200}}) {
    SCOPED_TRACE(limit);
    const v1::InlineMesh shown = viewer::SimplifyForDisplay(knot, limit);
    EXPECT_LE(Triangles(shown), limit);
    EXPECT_GT(Triangles(shown), limit / 4) << "far more simplified than asked";
    const auto b = Bounds(knot);
    ExpectLooksLike(shown, knot, 0.15 * (b[3] - b[0]));
  }
  // Within the limit, or no limit: the mesh itself.
  EXPECT_EQ(viewer::SimplifyForDisplay(knot, Triangles(knot)).SerializeAsString(),
            knot.SerializeAsString());
  EXPECT_EQ(viewer::SimplifyForDisplay(knot, 0).SerializeAsString(), knot.SerializeAsString());
}

TEST(SimplifyForDisplay, TheBunnyWithItsHolesFitsAndLooksLikeItself) {
  const std::filesystem::path bunny =
      std::filesystem::path(HAPTICPD_MODELS_DIR) / "stanford-bunny.obj";
  if (!std::filesystem::exists(bunny)) {
    GTEST_SKIP() << bunny << " is absent (../shared/models not beside the clone)";
  }
  const v1::InlineMesh mesh = Inline(pd::LoadMesh(bunny.string()));
  // At the viewer's default limit.
  const std::size_t limit = viewer::kDefaultDisplayTriangles;
  const v1::InlineMesh shown = viewer::SimplifyForDisplay(mesh, limit);
  EXPECT_LE(Triangles(shown), limit);
  EXPECT_GT(Triangles(shown), limit / 2);
  const auto b = Bounds(mesh);
  ExpectLooksLike(shown, mesh, 0.03 * (b[3] - b[0]));
}

TEST(SimplifyForDisplay, ATriangleSoupWithNonManifoldEdgesAndStrayIndicesIsHandled) {
  // Three triangles on one edge (non-manifold), a duplicate, a degenerate one.
  v1::InlineMesh soup;
  for (double v : {0., 0., 0., 1., 0., 0., 0., 1., 0., 0., -1., 0., 0., 0., 1.}) {
    soup.add_vertices(v);
  }
  for (std::uint32_t i : {0u, 1u, 2u, 0u, 1u, 3u, 0u, 1u, 4u, 0u, 1u, 2u, 2u, 2u, 3u}) {
    soup.add_triangles(i);
  }
  const v1::InlineMesh shown = viewer::SimplifyForDisplay(soup, 3);
  EXPECT_LE(Triangles(shown), 3u);
  // Malformed input is returned as it came (EncodeMesh refuses it later).
  v1::InlineMesh bad = soup;
  bad.add_triangles(99);
  bad.add_triangles(0);
  bad.add_triangles(1);
  EXPECT_EQ(viewer::SimplifyForDisplay(bad, 1).triangles_size(), bad.triangles_size());
}

TEST(MeshStore, AMeshOverTheLimitIsStoredSimplifiedOnceAndDroppedWithItsAlias) {
  const v1::InlineMesh knot = Inline(pd::shapes::MakeShape(std::string("torusknot")));
  viewer::MeshStore full, limited(1000);
  const std::string full_hash = full.Add(knot);
  const std::string shown_hash = limited.Add(knot);
  ASSERT_TRUE(viewer::IsContentHash(shown_hash));
  EXPECT_NE(shown_hash, full_hash);
  EXPECT_EQ(limited.Add(knot), shown_hash) << "the same mesh again: the same stored form";
  const auto blob = limited.Find(shown_hash);
  ASSERT_NE(blob, nullptr);
  std::uint32_t nt = 0;
  std::memcpy(&nt, blob->data() + 12, 4);
  EXPECT_LE(nt, 1000u);
  EXPECT_EQ(viewer::ContentHash(*blob), shown_hash);
  EXPECT_EQ(limited.Find(full_hash), nullptr);
  // A small mesh is stored as it is.
  const v1::InlineMesh ball = Inline(pd::shapes::MakeShape(std::string("box:0.01,0.01,0.01")));
  ASSERT_LE(Triangles(ball), 1000u);
  EXPECT_EQ(limited.Add(ball), full.Add(ball));
  limited.Retain({});
  EXPECT_EQ(limited.size(), 0u);
  EXPECT_EQ(limited.Add(knot), shown_hash) << "simplified again after it was dropped";
  EXPECT_EQ(limited.size(), 1u);
}

}  // namespace
}  // namespace hapticpd
