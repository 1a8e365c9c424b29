// Mesh loading, validation and adjacency.
#include "pd/mesh.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <sstream>

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

// ---------------------------------------------------------------------------
// Our own OFF and PLY readers (pd/mesh_readers.h): a valid file gives exactly
// the mesh the OBJ path (still OpenMesh's reader) gives; a malformed one fails
// with its line (or byte) and problem, without allocating by header counts.

namespace fs = std::filesystem;

// A scratch folder, removed with everything in it at the end of the test.
class ScratchDir {
 public:
  ScratchDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() / ("hapticpd-mesh-test-" + std::to_string(::getpid()) + "-" +
                                        info->test_suite_name() + "-" + info->name());
    fs::create_directories(dir_);
  }
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string Write(const std::string& name, const std::string& bytes) const {
    const fs::path p = dir_ / name;
    std::ofstream(p, std::ios::binary) << bytes;
    return p.string();
  }

 private:
  fs::path dir_;
};

// A polygon soup with coordinates as text (so every format spells them the
// same), triangles, quads and a pentagon.
struct TextSoup {
  std::vector<std::array<std::string, 3>> v;
  std::vector<std::vector<int>> f;
};

TextSoup ProceduralSoup(std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::uniform_int_distribution<int> scale(-3, 3);
  TextSoup s;
  const int nx = 7, ny = 6;
  char buf[64];
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      std::array<std::string, 3> p;
      const double c[3] = {i + 0.3 * u(rng), j + 0.3 * u(rng), u(rng)};
      for (int k = 0; k < 3; ++k) {
        const double x = c[k] * std::pow(10.0, scale(rng));
        // Alternate float-exact and long double-precision spellings: both
        // formats must round them to the same single-precision value.
        std::snprintf(buf, sizeof buf, (i + j + k) % 2 ? "%.9g" : "%.17g", x);
        p[k] = buf;
      }
      s.v.push_back(p);
    }
  }
  auto id = [&](int i, int j) { return j * nx + i; };
  for (int j = 0; j + 1 < ny; ++j) {
    for (int i = 0; i + 1 < nx; ++i) {
      if (i == 2 && j == 2) continue;  // replaced by the pentagon below
      if ((i + j) % 3 == 0) {
        s.f.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
        s.f.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
      } else {
        s.f.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)});
      }
    }
  }
  s.f.push_back({id(2, 2), id(3, 2), id(3, 3), id(2, 3), id(1, 3)});
  return s;
}

std::string AsObj(const TextSoup& s) {
  std::ostringstream o;
  for (const auto& p : s.v) o << "v " << p[0] << " " << p[1] << " " << p[2] << "\n";
  for (const auto& f : s.f) {
    o << "f";
    for (int i : f) o << " " << i + 1;
    o << "\n";
  }
  return o.str();
}

std::string AsOff(const TextSoup& s) {
  std::ostringstream o;
  o << "OFF\n# written by mesh_test\n" << s.v.size() << " " << s.f.size() << " 0\n";
  for (const auto& p : s.v) o << p[0] << " " << p[1] << "\t" << p[2] << "\r\n";
  for (std::size_t k = 0; k < s.f.size(); ++k) {
    o << s.f[k].size();
    for (int i : s.f[k]) o << " " << i;
    if (k % 4 == 1) o << " 255 0 0";  // an optional face colour
    o << "\n";
  }
  return o.str();
}

// ASCII PLY with properties and elements to skip around the ones we read.
std::string AsAsciiPly(const TextSoup& s, const char* coord_type) {
  std::ostringstream o;
  o << "ply\nformat ascii 1.0\ncomment written by mesh_test\nelement material 1\n"
    << "property float shininess\nproperty list uchar float rgb\n"
    << "element vertex " << s.v.size() << "\nproperty " << coord_type << " x\n"
    << "property uchar red\nproperty " << coord_type << " y\nproperty " << coord_type
    << " z\nproperty float nx\n"
    << "element face " << s.f.size() << "\nproperty uchar flags\n"
    << "property list uchar int vertex_indices\nproperty list int float texcoord\n"
    << "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n";
  o << "0.5 3 1 0 0\n";
  for (const auto& p : s.v) o << p[0] << " 7 " << p[1] << " " << p[2] << " -0.25\n";
  for (const auto& f : s.f) {
    o << "1 " << f.size();
    for (int i : f) o << " " << i;
    o << " 2 0.5 0.5\n";
  }
  o << "0 1\n";
  return o.str();
}

template <typename T>
void Put(std::string* out, T value, bool big) {
  char b[sizeof(T)];
  std::memcpy(b, &value, sizeof(T));
  if (big) std::reverse(b, b + sizeof(T));
  out->append(b, sizeof(T));
}

std::string AsBinaryPly(const TextSoup& s, bool big) {
  std::ostringstream h;
  h << "ply\nformat " << (big ? "binary_big_endian" : "binary_little_endian") << " 1.0\n"
    << "element vertex " << s.v.size() << "\nproperty float x\nproperty uchar red\n"
    << "property float y\nproperty float z\nproperty double nx\n"
    << "element face " << s.f.size() << "\nproperty list ushort uint vertex_indices\n"
    << "property list uchar float texcoord\nelement edge 1\nproperty int vertex1\nend_header\n";
  std::string b = h.str();
  for (const auto& p : s.v) {
    Put(&b, std::strtof(p[0].c_str(), nullptr), big);
    Put(&b, std::uint8_t{7}, big);
    Put(&b, std::strtof(p[1].c_str(), nullptr), big);
    Put(&b, std::strtof(p[2].c_str(), nullptr), big);
    Put(&b, -0.25, big);
  }
  for (const auto& f : s.f) {
    Put(&b, static_cast<std::uint16_t>(f.size()), big);
    for (int i : f) Put(&b, static_cast<std::uint32_t>(i), big);
    Put(&b, std::uint8_t{2}, big);
    Put(&b, 0.5f, big);
    Put(&b, 0.5f, big);
  }
  Put(&b, std::int32_t{3}, big);
  return b;
}

void ExpectSameMesh(const Mesh& want, const Mesh& got) {
  ASSERT_EQ(want.num_vertices(), got.num_vertices());
  for (std::size_t i = 0; i < want.num_vertices(); ++i) {
    ASSERT_EQ(want.vertices()[i], got.vertices()[i]) << "vertex " << i;  // bit for bit
  }
  EXPECT_EQ(want.triangles(), got.triangles());
  EXPECT_EQ(want.dropped_triangle_count(), got.dropped_triangle_count());
  EXPECT_EQ(want.degenerate_triangle_count(), got.degenerate_triangle_count());
}

TEST(MeshReaders, OffAndPlyGiveTheMeshTheObjPathGives) {
  const ScratchDir dir;
  const std::uint64_t seed = hapticpd::testing::TestSeed();
  for (int round = 0; round < hapticpd::testing::TestCount(3); ++round) {
    SCOPED_TRACE("seed " + std::to_string(seed) + " round " + std::to_string(round));
    const TextSoup s = ProceduralSoup(seed + round);
    const Mesh obj = LoadMesh(dir.Write("m.obj", AsObj(s)));
    ASSERT_EQ(obj.num_vertices(), s.v.size());
    ASSERT_GT(obj.num_triangles(), s.f.size());  // the quads were fan-triangulated
    const std::pair<const char*, std::string> files[] = {
        {"m.off", AsOff(s)},
        {"float.ply", AsAsciiPly(s, "float")},
        {"double.ply", AsAsciiPly(s, "double")},
        {"little.ply", AsBinaryPly(s, false)},
        {"big.ply", AsBinaryPly(s, true)},
    };
    for (const auto& [name, bytes] : files) {
      SCOPED_TRACE(name);
      ExpectSameMesh(obj, LoadMesh(dir.Write(name, bytes)));
    }
  }
}

TEST(MeshReaders, SharedBunnyRoundTripsThroughOffAndPly) {
  HAPTICPD_REQUIRE_MODEL(path, "stanford-bunny.obj");
  const Mesh obj = LoadMesh(path.string());
  TextSoup s;
  char buf[32];
  for (const Vec3& p : obj.vertices()) {
    std::array<std::string, 3> t;
    for (int k = 0; k < 3; ++k) {
      std::snprintf(buf, sizeof buf, "%.9g", p[k]);  // exact for single precision
      t[k] = buf;
    }
    s.v.push_back(t);
  }
  for (const Triangle& t : obj.triangles()) s.f.push_back({t[0], t[1], t[2]});
  const ScratchDir dir;
  ExpectSameMesh(obj, LoadMesh(dir.Write("bunny.off", AsOff(s))));
  ExpectSameMesh(obj, LoadMesh(dir.Write("bunny.ply", AsAsciiPly(s, "float"))));
  ExpectSameMesh(obj, LoadMesh(dir.Write("bunny_le.ply", AsBinaryPly(s, false))));
}

TEST(MeshReaders, RepeatedIndicesAreDroppedAsBefore) {
  const ScratchDir dir;
  const Mesh m = LoadMesh(dir.Write("rep.off",
                                    "OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
                                    "3 0 1 2\n3 0 0 3\n"));
  EXPECT_EQ(m.num_triangles(), 1u);
  EXPECT_EQ(m.dropped_triangle_count(), 1);
}

struct BadText {
  const char* name;
  std::string bytes;
  std::string expected;  // substring of the message after "<path>: "
};

void ExpectErrors(const std::vector<BadText>& cases) {
  const ScratchDir dir;
  for (const BadText& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string path = dir.Write(c.name, c.bytes);
    try {
      (void)LoadMesh(path);
      ADD_FAILURE() << "loaded without error";
    } catch (const MeshError& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.rfind(path + ": ", 0), 0u) << what;  // names the file first
      EXPECT_NE(what.find(c.expected), std::string::npos) << what;
      EXPECT_EQ(what.find('\n'), std::string::npos) << what;  // one line
    }
  }
}

TEST(MeshReaders, MalformedOffNamesLineAndProblem) {
  const std::string head = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n";
  ExpectErrors({
      {"count_larger_than_file.off", "OFF\n1000000000 1 0\n0 0 0\n",
       "truncated after line 3: the header promises 1000000000 vertices, the file holds 1"},
      {"four_numbers.off", "OFF\n3 1 0\n0 0 0\n1 0 1 0\n0 1 0\n3 0 1 2\n",
       "line 4: vertex 1 has 4 numbers, expected 3"},
      {"two_numbers.off", "OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n",
       "line 4: vertex 1 has 2 numbers, expected 3"},
      {"index_out_of_range.off", head + "3 0 1 3\n",
       "line 6: face 0 refers to vertex 3, out of range [0, 3)"},
      {"negative_index.off", head + "3 0 -1 2\n",
       "line 6: face 0 refers to vertex -1, out of range [0, 3)"},
      {"huge_index.off", head + "3 0 1 13333333333333333333333\n",
       "line 6: face 0 refers to vertex 13333333333333333333333, out of range [0, 3)"},
      {"non_numeric_coordinate.off", "OFF\n3 1 0\n0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n",
       "line 4: vertex 1: 'zero' is not a number"},
      {"non_numeric_index.off", head + "3 0 1 two\n",
       "line 6: face 0: vertex index 'two' is not an integer"},
      {"hex_coordinate.off", "OFF\n3 1 0\n0 0 0\n0x1p3 0 0\n0 1 0\n3 0 1 2\n",
       "line 4: vertex 1: '0x1p3' is not a number"},
      {"nan_coordinate.off", "OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n",
       "line 4: vertex 1 has a non-finite coordinate (nan)"},
      {"beyond_float.off", "OFF\n3 1 0\n0 0 0\n1e39 0 0\n0 1 0\n3 0 1 2\n",
       "line 4: vertex 1 has a coordinate beyond single precision (1e39)"},
      {"missing_faces.off", "OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
       "truncated after line 6: the header promises 2 faces, the file holds 1"},
      {"short_face.off", head + "3 0 1\n",
       "line 6: face 0 lists 2 vertex indices, its count says 3"},
      {"two_corner_face.off", head + "2 0 1\n", "line 6: face 0 has 2 vertices, needs at least 3"},
      {"huge_corner_count.off", head + "4000000000 0 1 2\n",
       "line 6: face 0 lists 3 vertex indices, its count says 4000000000"},
      {"junk_after_face.off", head + "3 0 1 2 4444444444`3\n",
       "line 6: face 0 has '4444444444`3' after its 3 vertex indices"},
      {"too_much_after_face.off", head + "3 0 1 2 1 1 1 1 1\n",
       "line 6: face 0 has 5 numbers after its 3 vertex indices"},
      {"more_data.off", head + "3 0 1 2\n3 0 1 2\n",
       "line 7: more data after the 3 vertices and 1 faces the header promises"},
      {"bad_counts.off", "OFF\n3 x 0\n", "line 2: bad element counts"},
      {"variant.off", "COFF\n3 1 0\n", "line 1: OFF variant 'COFF' is not supported"},
  });
}

TEST(MeshReaders, MalformedPlyNamesLineAndProblem) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
  const std::string verts = "0 0 0\n1 0 0\n0 1 0\n";
  std::string header100 = header;
  header100.replace(header100.find("vertex 3"), 8, "vertex 100");
  std::string bin =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
      "property float y\nproperty float z\nelement face 1\n"
      "property list int int vertex_indices\nend_header\n";
  const std::size_t body = bin.size();
  for (int k = 0; k < 9; ++k) Put(&bin, static_cast<float>(k % 2), false);
  std::string bin_long_list = bin, bin_range = bin, bin_short = bin;
  Put(&bin_long_list, std::int32_t{1000000000}, false);
  Put(&bin_long_list, std::int32_t{0}, false);
  Put(&bin_range, std::int32_t{3}, false);
  for (std::int32_t i : {0, 1, 7}) Put(&bin_range, i, false);
  bin_short.resize(body + 20);  // inside the second vertex
  const std::string at_list = "byte " + std::to_string(body + 36) + ": ";
  ExpectErrors({
      {"count_larger_than_file.ply", header100 + verts,
       "truncated after line 12: the header promises 100 vertex elements, the file holds 3"},
      {"vertex_four_values.ply", header + "0 0 0\n1 0 0 5\n0 1 0\n3 0 1 2\n",
       "line 11: vertex 1 has 4 values, expected 3"},
      {"vertex_two_values.ply", header + "0 0 0\n1 0\n0 1 0\n3 0 1 2\n",
       "line 11: vertex 1 has 2 values, expected 3"},
      {"face_short.ply", header + verts + "3 0 1\n", "line 13: face 0 has 3 values, expected 4"},
      {"face_long.ply", header + verts + "3 0 1 2 2\n", "line 13: face 0 has 5 values, expected 4"},
      {"index_out_of_range.ply", header + verts + "3 0 13333333333333333 3\x0e\n",
       "line 13: face 0 refers to vertex 13333333333333333, out of range [0, 3)"},
      {"non_numeric.ply", header + "0 0 0\n1 O 0\n0 1 0\n3 0 1 2\n",
       "line 11: vertex 1: 'O' is not a number"},
      {"two_corners.ply", header + verts + "2 0 1\n",
       "line 13: face 0 has 2 vertices, needs at least 3"},
      {"truncated_faces.ply", header + verts,
       "truncated after line 12: the header promises 1 face elements, the file holds 0"},
      {"more_data.ply", header + verts + "3 0 1 2\n3 0 1 2\n",
       "line 14: more data after the elements the header declares"},
      {"no_vertex_indices.ply",
       "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
       "property float z\nelement face 1\nproperty list uchar int corners\nend_header\n" +
           verts + "3 0 1 2\n",
       "not a valid PLY: element face has no 'list <count type> <index type> vertex_indices'"},
      {"no_z.ply",
       "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
       "end_header\n0 0\n1 0\n0 1\n",
       "not a valid PLY: element vertex has no 'z' property"},
      {"list_past_end.ply", bin_long_list,
       at_list + "face 0: list vertex_indices of 1000000000 entries runs past the end of the file"},
      {"binary_out_of_range.ply", bin_range,
       "byte " + std::to_string(body + 48) + ": face 0 refers to vertex 7, out of range [0, 3)"},
      {"binary_truncated.ply", bin_short,
       "truncated at byte " + std::to_string(body + 20) +
           ": the header promises 3 vertex elements, the file ends inside vertex 1"},
  });
}

}  // namespace
}  // namespace hapticpd::pd
