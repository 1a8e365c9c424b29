// Mesh loading, validation and adjacency.
#include "pd/mesh.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <set>

#include "pd/shapes.h"
#include "tests/test_util.h"

namespace hapticpd::pd {
namespace {

std::string Data(const std::string& rel) { return std::string(HAPTICPD_TESTDATA_DIR) + "/" + rel; }

TEST(MeshLoad, EveryFormatLoadsTheSameTetrahedron) {
  for (const char* name : {"tetra.obj", "tetra.off", "tetra.ply", "tetra.stl"}) {
    SCOPED_TRACE(name);
    const Mesh m = LoadMesh(Data(std::string("good/") + name));
    EXPECT_EQ(m.num_triangles(), 4u);
    EXPECT_EQ(m.num_vertices(), 4u);  // STL vertices are welded by the reader
    EXPECT_EQ(m.edges().size(), 6u);
    EXPECT_TRUE(m.watertight());
    EXPECT_EQ(m.boundary_edge_count(), 0);
    EXPECT_NEAR(m.bounds().hi.x(), 1.0, 1e-7);
  }
}

TEST(MeshLoad, PolygonsAreFanTriangulated) {
  const Mesh m = LoadMesh(Data("good/quad_cube.obj"));
  EXPECT_EQ(m.num_triangles(), 12u);
  EXPECT_TRUE(m.watertight());
}

TEST(MeshLoad, OpenAndNonManifoldMeshesLoadFlagged) {
  const Mesh open = LoadMesh(Data("good/open_square.obj"));
  EXPECT_FALSE(open.watertight());
  EXPECT_EQ(open.boundary_edge_count(), 4);
  EXPECT_EQ(open.nonmanifold_edge_count(), 0);
  const Mesh nm = LoadMesh(Data("good/nonmanifold.obj"));
  EXPECT_EQ(nm.num_triangles(), 3u);  // nothing split off or dropped
  EXPECT_EQ(nm.nonmanifold_edge_count(), 1);
  EXPECT_FALSE(nm.watertight());
  EXPECT_FALSE(nm.diagnostics().empty());
}

struct BadCase {
  const char* file;
  const char* expected;  // substring of the error message
};

TEST(MeshLoad, MalformedFilesGiveClearErrors) {
  const BadCase cases[] = {
      {"bad/nan_vertex.obj", "non-finite"},
      {"bad/index_out_of_range.obj", "out of range"},
      {"bad/empty.obj", "empty"},
      {"bad/no_faces.obj", "no"},
      {"bad/garbage.stl", "garbage.stl"},
      {"bad/garbage.ply", "garbage.ply"},
      {"bad/truncated.stl", "truncated.stl"},
      {"bad/truncated.ply", "truncated.ply"},
      {"bad/truncated.off", "truncated.off"},
      {"bad/infinite_vertex.off", "infinite_vertex.off"},
      {"bad/degenerate_only.obj", "no non-degenerate triangles"},
      {"bad/unknown.xyz", "unsupported extension"},
      {"bad/does_not_exist.obj", "no such file"},
  };
  for (const BadCase& c : cases) {
    SCOPED_TRACE(c.file);
    try {
      (void)LoadMesh(Data(c.file));
      ADD_FAILURE() << "loaded without error";
    } catch (const MeshError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(c.expected), std::string::npos) << what;
      // Every message names the file.
      EXPECT_NE(what.find(std::filesystem::path(c.file).filename().string()), std::string::npos)
          << what;
    }
  }
}

TEST(MeshArrays, ValidationNamesTheProblem) {
  std::vector<Vec3> v = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)};
  EXPECT_THROW(Mesh::FromArrays(v, {}, "empty"), MeshError);
  EXPECT_THROW(Mesh::FromArrays(v, {{0, 1, 3}}, "range"), MeshError);
  EXPECT_THROW(Mesh::FromArrays(v, {{0, -1, 2}}, "negative"), MeshError);
  auto bad = v;
  bad[1].x() = std::numeric_limits<double>::infinity();
  EXPECT_THROW(Mesh::FromArrays(bad, {{0, 1, 2}}, "inf"), MeshError);
  MeshOptions tight;
  tight.max_triangles = 0;
  EXPECT_THROW(Mesh::FromArrays(v, {{0, 1, 2}}, "limit", tight), MeshError);
}

TEST(MeshArrays, DegenerateTrianglesKeptAndReportedOrRejected) {
  std::vector<Vec3> v = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(2, 0, 0)};
  const Mesh m = Mesh::FromArrays(v, {{0, 1, 2}, {0, 1, 3}, {0, 0, 2}}, "degen");
  EXPECT_EQ(m.num_triangles(), 2u);
  EXPECT_EQ(m.dropped_triangle_count(), 1);
  EXPECT_EQ(m.degenerate_triangle_count(), 1);  // 0,1,3 is collinear
  EXPECT_EQ(m.face_normals()[1], Vec3::Zero());
  EXPECT_NEAR(m.face_normals()[0].z(), 1.0, 1e-15);
  MeshOptions strict;
  strict.degenerate = DegeneratePolicy::kReject;
  try {
    (void)Mesh::FromArrays(v, {{0, 1, 2}, {0, 1, 3}}, "degen", strict);
    ADD_FAILURE();
  } catch (const MeshError& e) {
    EXPECT_NE(std::string(e.what()).find("zero area"), std::string::npos) << e.what();
  }
}

TEST(MeshAdjacency, FeaturesAreOwnedExactlyOnce) {
  for (const Mesh& m : {shapes::Box(Vec3(1, 2, 3)), shapes::Sphere(1.0, 2), shapes::Torus()}) {
    std::vector<int> vcount(m.num_vertices(), 0), ecount(m.edges().size(), 0);
    for (Index f = 0; f < static_cast<Index>(m.num_triangles()); ++f) {
      for (int k = 0; k < 3; ++k) {
        if (m.owned_mask(f) & (1u << k)) ++vcount[m.triangles()[f][k]];
        if (m.owned_mask(f) & (1u << (3 + k))) ++ecount[m.face_edges(f)[k]];
        // face_edges is consistent with the triangle's corners.
        const Edge& e = m.edges()[m.face_edges(f)[k]];
        const std::set<Index> ends = {m.triangles()[f][k], m.triangles()[f][(k + 1) % 3]};
        EXPECT_EQ(ends, (std::set<Index>{e.v[0], e.v[1]}));
      }
    }
    for (int c : vcount) EXPECT_EQ(c, 1);
    for (int c : ecount) EXPECT_EQ(c, 1);
    // Euler characteristic of a closed surface: V - E + F = 2 - 2g.
    const long chi = static_cast<long>(m.num_vertices()) - static_cast<long>(m.edges().size()) +
                     static_cast<long>(m.num_triangles());
    EXPECT_TRUE(chi == 2 || chi == 0) << chi;
  }
}

TEST(MeshLoad, SharedBunnyLoadsAndIsFlaggedOpen) {
  HAPTICPD_REQUIRE_MODEL(path, "stanford-bunny.obj");
  const Mesh m = LoadMesh(path.string());
  EXPECT_EQ(m.num_triangles(), 69451u);
  EXPECT_GT(m.boundary_edge_count(), 0);  // the bunny has holes
  EXPECT_FALSE(m.watertight());
}

}  // namespace
}  // namespace hapticpd::pd
