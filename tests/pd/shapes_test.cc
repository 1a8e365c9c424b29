#include "pd/shapes.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

namespace hapticpd::pd::shapes {
namespace {

constexpr double kPi = std::numbers::pi;

// Divergence-theorem volume: positive for a closed mesh with outward normals.
double SignedVolume(const Mesh& m) {
  double six_v = 0;
  for (const Triangle& t : m.triangles()) {
    const Vec3& a = m.vertices()[t[0]];
    const Vec3& b = m.vertices()[t[1]];
    const Vec3& c = m.vertices()[t[2]];
    six_v += a.dot(b.cross(c));
  }
  return six_v / 6;
}

// Checks closedness independently of Mesh: every directed edge occurs once and
// its reverse occurs once. Also checks every triangle has a non-trivial area
// relative to its longest edge. Returns a description of the first problem.
std::string CheckClosedAndNondegenerate(const Mesh& m) {
  std::map<std::pair<Index, Index>, int> directed;
  for (const Triangle& t : m.triangles()) {
    for (int k = 0; k < 3; ++k) ++directed[{t[k], t[(k + 1) % 3]}];
  }
  for (const auto& [e, count] : directed) {
    if (count != 1) return "directed edge used " + std::to_string(count) + " times";
    if (!directed.contains({e.second, e.first})) return "edge without an opposite half-edge";
  }
  for (std::size_t f = 0; f < m.num_triangles(); ++f) {
    const Triangle& t = m.triangles()[f];
    const Vec3& a = m.vertices()[t[0]];
    const Vec3& b = m.vertices()[t[1]];
    const Vec3& c = m.vertices()[t[2]];
    const double longest =
        std::max({(b - a).squaredNorm(), (c - b).squaredNorm(), (a - c).squaredNorm()});
    // 2 * area / longest^2 is the height-to-base ratio (scale free).
    if ((b - a).cross(c - a).norm() < 1e-4 * longest) {
      return "triangle " + std::to_string(f) + " is (nearly) degenerate";
    }
  }
  return "";
}

// The properties every shape promises.
void ExpectValidShape(const Mesh& m, std::size_t triangles) {
  SCOPED_TRACE(m.source());
  EXPECT_EQ(m.num_triangles(), triangles);
  EXPECT_TRUE(m.watertight()) << "boundary " << m.boundary_edge_count() << ", non-manifold "
                              << m.nonmanifold_edge_count() << ", misoriented "
                              << m.misoriented_edge_count();
  EXPECT_EQ(m.degenerate_triangle_count(), 0);
  EXPECT_EQ(m.dropped_triangle_count(), 0);
  EXPECT_EQ(CheckClosedAndNondegenerate(m), "");
  EXPECT_GT(SignedVolume(m), 0) << "normals point inward";
}

double RelativeError(double value, double exact) { return std::abs(value - exact) / exact; }

TEST(ShapesBox, TwelveTrianglesExactVolume) {
  const Mesh m = Box(Vec3(0.1, 0.2, 0.3));
  ExpectValidShape(m, 12);
  EXPECT_EQ(m.num_vertices(), 8u);
  EXPECT_NEAR(SignedVolume(m), 8 * 0.1 * 0.2 * 0.3, 1e-15);
  EXPECT_TRUE(m.bounds().lo.isApprox(Vec3(-0.1, -0.2, -0.3)));
  EXPECT_TRUE(m.bounds().hi.isApprox(Vec3(0.1, 0.2, 0.3)));
  ExpectValidShape(Box(), 12);
}

TEST(ShapesBox, SubdividedFacesAreGrids) {
  for (int n : {1, 2, 5, 16}) {
    const Mesh m = Box(Vec3(0.05, 0.02, 0.01), n);
    ExpectValidShape(m, 12u * n * n);
    EXPECT_EQ(m.num_vertices(), 6u * n * n + 2);
    EXPECT_NEAR(SignedVolume(m), 8 * 0.05 * 0.02 * 0.01, 1e-15);
    EXPECT_TRUE(m.bounds().hi.isApprox(Vec3(0.05, 0.02, 0.01)));
  }
  // Every vertex lies on the surface: coplanar triangles, no bulging.
  const Mesh m = Box(Vec3(1, 1, 1), 3);
  for (const Vec3& p : m.vertices()) EXPECT_DOUBLE_EQ(p.cwiseAbs().maxCoeff(), 1.0);
}

TEST(ShapesSphere, CountsAndConvergingVolume) {
  const double r = 0.05, exact = 4.0 / 3 * kPi * r * r * r;
  double previous_error = 1;
  for (int n = 0; n <= 5; ++n) {
    const Mesh m = Sphere(r, n);
    ExpectValidShape(m, 20u << (2 * n));
    EXPECT_EQ(m.num_vertices(), (10u << (2 * n)) + 2);
    for (const Vec3& p : m.vertices()) EXPECT_NEAR(p.norm(), r, 1e-15);
    const double error = RelativeError(SignedVolume(m), exact);
    EXPECT_LT(error, previous_error);
    previous_error = error;
  }
  const Mesh m = Sphere();
  ExpectValidShape(m, 1280);
  EXPECT_LT(RelativeError(SignedVolume(m), exact), 0.03);
}

TEST(ShapesCylinder, CountsAndConvergingVolume) {
  const double r = 0.05, h = 0.1, exact = kPi * r * r * 2 * h;
  double previous_error = 1;
  for (int s : {3, 8, 32, 128}) {
    const Mesh m = Cylinder(r, h, s);
    ExpectValidShape(m, 4u * s);
    EXPECT_EQ(m.num_vertices(), 2u * s + 2);
    // An inscribed regular polygon's area is known exactly.
    EXPECT_NEAR(SignedVolume(m), exact * std::sin(2 * kPi / s) * s / (2 * kPi), 1e-12);
    const double error = RelativeError(SignedVolume(m), exact);
    EXPECT_LT(error, previous_error);
    previous_error = error;
  }
  ExpectValidShape(Cylinder(), 128);
  EXPECT_LT(RelativeError(SignedVolume(Cylinder()), exact), 0.01);
}

TEST(ShapesStick, NinetyTwoTrianglesFifteenCentimetres) {
  const Mesh m = Stick();
  ExpectValidShape(m, 92);
  EXPECT_NEAR(m.bounds().Size().z(), 0.15, 1e-12);
  EXPECT_NEAR(m.bounds().hi.x(), 0.005, 1e-12);
  EXPECT_TRUE(m.bounds().Center().isZero(1e-3));
}

TEST(ShapesCapsule, CountsAndConvergingVolume) {
  const double r = 0.02, h = 0.04;
  const double exact = kPi * r * r * 2 * h + 4.0 / 3 * kPi * r * r * r;
  double previous_error = 1;
  for (auto [segments, rings] : {std::pair{3, 1}, {8, 2}, {32, 8}, {96, 24}}) {
    const Mesh m = Capsule(r, h, segments, rings);
    ExpectValidShape(m, 4u * segments * rings);
    const double error = RelativeError(SignedVolume(m), exact);
    EXPECT_LT(error, previous_error);
    previous_error = error;
    EXPECT_NEAR(m.bounds().Size().z(), 2 * (r + h), 1e-12);
  }
  const Mesh m = Capsule();
  ExpectValidShape(m, 1024);
  EXPECT_LT(RelativeError(SignedVolume(m), exact), 0.02);
  // Zero half length: a UV sphere without a duplicated equator.
  const Mesh ball = Capsule(0.03, 0, 16, 4);
  ExpectValidShape(ball, 2u * 16 * (2 * 4 - 1));
  EXPECT_LT(RelativeError(SignedVolume(ball), 4.0 / 3 * kPi * 0.03 * 0.03 * 0.03), 0.1);
}

TEST(ShapesTorus, CountsAndConvergingVolume) {
  const double big = 0.06, small = 0.02, exact = 2 * kPi * kPi * big * small * small;
  double previous_error = 1;
  for (int s : {3, 6, 24, 96}) {
    const Mesh m = Torus(big, small, 2 * s, s);
    ExpectValidShape(m, 4u * s * s);
    const double error = RelativeError(SignedVolume(m), exact);
    EXPECT_LT(error, previous_error);
    previous_error = error;
  }
  const Mesh m = Torus();
  ExpectValidShape(m, 2304);
  EXPECT_LT(RelativeError(SignedVolume(m), exact), 0.02);
  EXPECT_NEAR(m.bounds().Size().z(), 2 * small, 1e-12);
  EXPECT_NEAR(m.bounds().hi.x(), big + small, 1e-12);
}

// The documented centre curve of TorusKnot.
Vec3 KnotPoint(int p, int q, double radius, double t) {
  const double rho = 1 + 0.5 * std::cos(q * t);
  return radius * Vec3(rho * std::cos(p * t), rho * std::sin(p * t), 0.5 * std::sin(q * t));
}

TEST(ShapesTorusKnot, WatertightWithVolumeOfTube) {
  for (auto [p, q] : {std::pair{2, 3}, {3, 2}, {3, 5}, {1, 1}}) {
    for (auto [segments, tube] : {std::pair{64, 6}, {256, 16}}) {
      const Mesh m = TorusKnot(p, q, 0.05, 0.006, segments, tube);
      ExpectValidShape(m, 2u * segments * tube);
      // Pappus: a tube of radius a around a curve of length L has volume
      // pi a^2 L when it does not fold; the polygonal section shrinks it.
      double length = 0;
      const int samples = 20000;
      for (int i = 0; i < samples; ++i) {
        length += (KnotPoint(p, q, 0.05, 2 * kPi * (i + 1) / samples) -
                   KnotPoint(p, q, 0.05, 2 * kPi * i / samples))
                      .norm();
      }
      const double polygon = std::sin(2 * kPi / tube) * tube / (2 * kPi);
      const double expected = kPi * 0.006 * 0.006 * length * polygon;
      EXPECT_LT(RelativeError(SignedVolume(m), expected), segments >= 256 ? 0.01 : 0.05)
          << p << "," << q;
    }
  }
  ExpectValidShape(TorusKnot(), 8192);
}

TEST(ShapesTorusKnot, DefaultTubeDoesNotTouchItself) {
  // Distinct strands of the default trefoil stay more than a tube diameter
  // apart (and the curve bends gently enough), so the default mesh is embedded.
  const double radius = 0.05, tube = 0.008;
  const int n = 720;
  std::vector<Vec3> c(n);
  for (int i = 0; i < n; ++i) c[i] = KnotPoint(2, 3, radius, 2 * kPi * i / n);
  double arc = 0;
  for (int i = 0; i < n; ++i) arc += (c[(i + 1) % n] - c[i]).norm();
  const double step = arc / n;
  double closest = 1;
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) {
      const int gap = std::min(j - i, n - (j - i));
      // Points further apart along the curve than half a turn of a tube-sized
      // circle belong to different strands unless the curve folds back.
      if (gap * step > kPi * 2 * tube) closest = std::min(closest, (c[i] - c[j]).norm());
    }
  }
  EXPECT_GT(closest, 2 * tube * 1.2);
}

TEST(ShapesThinPlate, IsABox) {
  const Mesh m = ThinPlate(0.3, 0.2, 0.002);
  ExpectValidShape(m, 12);
  EXPECT_NEAR(SignedVolume(m), 0.3 * 0.2 * 0.002, 1e-15);
  EXPECT_TRUE(m.bounds().Size().isApprox(Vec3(0.3, 0.2, 0.002)));
  EXPECT_TRUE(m.bounds().Center().isZero(1e-15));
  ExpectValidShape(ThinPlate(), 12);
  ExpectValidShape(ThinPlate(0.3, 0.2, 0.002, 4), 12 * 16);
}

TEST(ShapesBenchmarkObjects, CountsAndSizes) {
  for (int r : {1, 2, 4}) {
    ExpectValidShape(Spoon(r), 78u * r * r);
    ExpectValidShape(Cup(r), 528u * r * r);
    ExpectValidShape(Hammer(r), 108u * r * r + 12u * r);
  }
  const Mesh spoon = Spoon();
  EXPECT_EQ(spoon.num_triangles(), 1248u);
  EXPECT_NEAR(spoon.bounds().Size().x(), 0.03 + 0.026 + 0.13, 0.01);  // bowl half + handle
  EXPECT_NEAR(spoon.bounds().lo.z(), 0, 1e-12);

  const Mesh cup = Cup();
  EXPECT_EQ(cup.num_triangles(), 8448u);
  EXPECT_NEAR(cup.bounds().lo.z(), 0, 1e-12);
  EXPECT_NEAR(cup.bounds().hi.z(), 0.095 + 0.0015, 1e-4);  // rounded rim
  EXPECT_NEAR(cup.bounds().lo.x(), -0.041, 1e-3);
  EXPECT_NEAR(cup.bounds().hi.x(), 0.07, 0.002);  // handle
  // The body is a thin shell: far less material than a solid cylinder.
  EXPECT_LT(SignedVolume(cup), 0.25 * kPi * 0.038 * 0.038 * 0.095);

  const Mesh hammer = Hammer();
  EXPECT_EQ(hammer.num_triangles(), 1776u);
  EXPECT_NEAR(hammer.bounds().lo.z(), 0, 1e-12);
  EXPECT_NEAR(hammer.bounds().hi.z(), 0.29 + 0.016, 1e-3);
  EXPECT_NEAR(hammer.bounds().Size().x(), 0.11, 1e-12);
}

bool SameMesh(const Mesh& a, const Mesh& b) {
  return a.triangles() == b.triangles() && a.vertices() == b.vertices();
}

TEST(ShapesMakeShape, DefaultsMatchFunctions) {
  EXPECT_TRUE(SameMesh(MakeShape("box"), Box()));
  EXPECT_TRUE(SameMesh(MakeShape("sphere"), Sphere()));
  EXPECT_TRUE(SameMesh(MakeShape("capsule"), Capsule()));
  EXPECT_TRUE(SameMesh(MakeShape("cylinder"), Cylinder()));
  EXPECT_TRUE(SameMesh(MakeShape("stick"), Stick()));
  EXPECT_TRUE(SameMesh(MakeShape("torus"), Torus()));
  EXPECT_TRUE(SameMesh(MakeShape("torusknot"), TorusKnot()));
  EXPECT_TRUE(SameMesh(MakeShape("plate"), ThinPlate()));
  EXPECT_TRUE(SameMesh(MakeShape("spoon"), Spoon()));
  EXPECT_TRUE(SameMesh(MakeShape("cup"), Cup()));
  EXPECT_TRUE(SameMesh(MakeShape("hammer"), Hammer()));
  EXPECT_EQ(MakeShape("sphere").num_triangles(), 1280u);
  EXPECT_EQ(MakeShape("capsule").num_triangles(), 1024u);
  EXPECT_EQ(MakeShape("cylinder").num_triangles(), 128u);
  EXPECT_EQ(MakeShape("stick").num_triangles(), 92u);
  EXPECT_EQ(MakeShape("torus").num_triangles(), 2304u);
  EXPECT_EQ(MakeShape("torusknot").num_triangles(), 8192u);
  EXPECT_EQ(MakeShape("plate").num_triangles(), 12u);
  EXPECT_EQ(MakeShape("spoon").num_triangles(), 1248u);
  EXPECT_EQ(MakeShape("cup").num_triangles(), 8448u);
  EXPECT_EQ(MakeShape("hammer").num_triangles(), 1776u);
}

TEST(ShapesMakeShape, ParametersFromTheLeft) {
  const Mesh box = MakeShape("box:0.1,0.2,0.3");
  EXPECT_TRUE(box.bounds().hi.isApprox(Vec3(0.1, 0.2, 0.3)));
  // Plate takes full extents where box takes half ones.
  EXPECT_TRUE(MakeShape("plate:0.2,0.4,0.6").bounds().hi.isApprox(Vec3(0.1, 0.2, 0.3)));
  EXPECT_EQ(MakeShape("box:0.1,0.2,0.3,4").num_triangles(), 12u * 16);
  EXPECT_NEAR(MakeShape("sphere:0.02").bounding_radius(), 0.02, 1e-9);
  EXPECT_EQ(MakeShape("sphere:0.05,2").num_triangles(), 320u);
  EXPECT_EQ(MakeShape("cylinder:0.01,0.05,10").num_triangles(), 40u);
  EXPECT_EQ(MakeShape("capsule:0.01,0.02,10,3").num_triangles(), 120u);
  EXPECT_EQ(MakeShape("torus:0.05,0.01,10,5").num_triangles(), 100u);
  EXPECT_EQ(MakeShape("torusknot:3,4,0.05,0.005,100,8").num_triangles(), 1600u);
  EXPECT_NEAR(MakeShape("plate:0.1,0.2,0.003").bounds().Size().z(), 0.003, 1e-15);
  EXPECT_EQ(MakeShape("spoon:2").num_triangles(), 78u * 4);
  EXPECT_EQ(MakeShape("cup:1").num_triangles(), 528u);
  EXPECT_EQ(MakeShape("hammer:2").num_triangles(), 108u * 4 + 24);
  EXPECT_EQ(MakeShape("sphere:5e-2,1").num_triangles(), 80u);
}

// Expects MakeShape(spec) to throw MeshError whose message names the spec and
// contains `problem`.
void ExpectSpecError(const std::string& spec, const std::string& problem) {
  SCOPED_TRACE(spec);
  try {
    MakeShape(spec);
    ADD_FAILURE() << "no exception";
  } catch (const MeshError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("'" + spec + "'"), std::string::npos) << what;
    EXPECT_NE(what.find(problem), std::string::npos) << what;
  }
}

TEST(ShapesMakeShape, ClearErrors) {
  ExpectSpecError("teapot", "unknown shape 'teapot'");
  ExpectSpecError("teapot", "known shapes: box, sphere");
  ExpectSpecError("", "empty shape name");
  ExpectSpecError("sphere:abc", "radius 'abc' is not a finite number");
  ExpectSpecError("sphere:0.05x", "is not a finite number");
  ExpectSpecError("sphere:nan", "is not a finite number");
  ExpectSpecError("sphere:", "radius is empty");
  ExpectSpecError("sphere:0.05,", "subdivisions is empty");
  ExpectSpecError("sphere:0.05,2.5", "subdivisions '2.5' must be an integer");
  ExpectSpecError("sphere:-1", "radius must be positive");
  ExpectSpecError("sphere:0", "radius must be positive");
  ExpectSpecError("sphere:0.05,3,1", "takes at most 2 parameters (radius,subdivisions)");
  ExpectSpecError("stick:1", "takes no parameters");
  ExpectSpecError("sphere:0.05,12", "resolution too high");
  ExpectSpecError("sphere:0.05,-1", "subdivisions must be at least 0");
  ExpectSpecError("box:0.1,0.1,0.1,100000", "resolution too high");
  ExpectSpecError("box:0.1,0.1,0.1,1e9", "out of range");
  ExpectSpecError("cylinder:0.1,0.1,2", "segments must be at least 3");
  ExpectSpecError("torus:0.01,0.02", "minor_radius (0.02) must be less than major_radius");
  ExpectSpecError("torusknot:2,4,0.05,0.008", "p (2) and q (4) must be coprime");
  ExpectSpecError("cup:0", "resolution must be at least 1");
  ExpectSpecError("cup:1000", "resolution too high");
  ExpectSpecError("capsule:0.01,-0.01", "half_length must be positive or 0 and finite, got -0.01");
}

TEST(ShapesMakeShape, StrictGrammar) {
  // No whitespace anywhere.
  ExpectSpecError("stick ", "whitespace is not allowed in a shape spec (at byte 5)");
  ExpectSpecError(" box", "whitespace is not allowed in a shape spec (at byte 0)");
  ExpectSpecError("box: 0.1,0.1,0.1", "whitespace is not allowed in a shape spec (at byte 4)");
  // Control characters are quoted escaped.
  try {
    MakeShape("box:0.1,0.1,0.1\n");
    ADD_FAILURE() << "no exception";
  } catch (const ShapeSpecError& e) {
    EXPECT_EQ(std::string(e.what()),
              "shape spec 'box:0.1,0.1,0.1\\x0a': whitespace is not allowed in a shape spec (at "
              "byte 15)");
  }
  // Every size parameter or none.
  ExpectSpecError("box:0.1",
                  "'box' needs all of hx,hy,hz or none (for the defaults); missing hy,hz");
  ExpectSpecError("box:0.1,0.2", "missing hz");
  ExpectSpecError("plate:0.4,0.4", "'plate' needs all of width,depth,thickness or none");
  ExpectSpecError("capsule:0.02", "missing half_length");
  ExpectSpecError("cylinder:0.02", "missing half_length");
  ExpectSpecError("torus:0.06", "missing minor_radius");
  ExpectSpecError("torusknot:2,3", "missing radius,tube_radius");
  ExpectSpecError("box:", "parameter hx is empty");
  ExpectSpecError("spoon:", "parameter resolution is empty");
  // Exactly the sizes, or sizes plus resolutions, are fine.
  EXPECT_EQ(MakeShape("sphere:0.05").num_triangles(), 1280u);
  EXPECT_EQ(MakeShape("torusknot:2,3,0.05,0.008").num_triangles(), 8192u);
  EXPECT_EQ(MakeShape("capsule:0.02,0").num_triangles(), 2u * 32 * 15);
  // A megabyte spec gives a bounded message.
  try {
    MakeShape(std::string(1 << 20, 'x'));
    ADD_FAILURE() << "no exception";
  } catch (const MeshError& e) {
    EXPECT_LT(std::string(e.what()).size(), 400u);
  }
}

// The arithmetic count is the built count, for every shape at several
// parameter sets: the server checks its triangle limit against it before
// building anything.
TEST(ShapesParseShapeSpec, CountIsTheBuiltCount) {
  const char* specs[] = {"box",
                         "box:0.1,0.2,0.3,1",
                         "box:0.1,0.2,0.3,3",
                         "sphere",
                         "sphere:0.1,0",
                         "sphere:0.1,1",
                         "sphere:0.1,4",
                         "capsule",
                         "capsule:0.02,0.04,3,1",
                         "capsule:0.02,0.04,7,5",
                         "capsule:0.02,0,7,5",
                         "capsule:0.02,0,12,1",
                         "cylinder",
                         "cylinder:0.05,0.1,3",
                         "cylinder:0.05,0.1,17",
                         "stick",
                         "torus",
                         "torus:0.06,0.02,3,3",
                         "torus:0.06,0.02,11,5",
                         "torusknot",
                         "torusknot:2,3,0.05,0.008,3,3",
                         "torusknot:3,2,0.05,0.008,40,7",
                         "plate",
                         "plate:0.2,0.2,0.004,1",
                         "plate:0.2,0.2,0.004,5",
                         "spoon:1",
                         "spoon:3",
                         "cup:1",
                         "cup:2",
                         "hammer:1",
                         "hammer:3",
                         "spoon",
                         "cup",
                         "hammer"};
  std::map<std::string, int> seen;
  for (const char* spec : specs) {
    SCOPED_TRACE(spec);
    const ShapeSpec p = ParseShapeSpec(spec);
    ++seen[p.name];
    const Mesh m = MakeShape(p);
    EXPECT_EQ(p.triangles, static_cast<double>(m.num_triangles()));
    const Vec3 far = m.bounds().lo.cwiseAbs().cwiseMax(m.bounds().hi.cwiseAbs());
    EXPECT_LE(far.maxCoeff(), p.reach * (1 + 1e-12));
  }
  EXPECT_EQ(seen.size(), ShapeNames().size()) << "a catalogue shape has no row here";
}

TEST(ShapesParseShapeSpec, ValuesDefaultsAndLengths) {
  const ShapeSpec box = ParseShapeSpec("box:0.1,0.2,0.3");
  EXPECT_EQ(box.name, "box");
  EXPECT_EQ(box.values, (std::vector<double>{0.1, 0.2, 0.3, 1}));
  ASSERT_EQ(box.params.size(), 4u);
  EXPECT_TRUE(box.params[0].length);
  EXPECT_EQ(box.params[0].unit, "m");
  EXPECT_FALSE(box.params[3].length);
  EXPECT_EQ(ParseShapeSpec("sphere").values, (std::vector<double>{0.05, 3}));
  // Counted, not built: far beyond kMaxShapeTriangles parses and says so.
  const ShapeSpec huge = ParseShapeSpec("box:0.1,0.1,0.1,1000000");
  EXPECT_EQ(huge.triangles, 12e12);
  EXPECT_THROW(MakeShape(huge), MeshError);
  EXPECT_EQ(ParseShapeSpec("sphere:0.1,1000000").triangles,
            std::numeric_limits<double>::infinity());
  // Lengths are only parsed; CheckShapeSizes applies the builders' rules.
  const ShapeSpec negative = ParseShapeSpec("sphere:-1");
  EXPECT_THROW(CheckShapeSizes(negative), ShapeSpecError);
  EXPECT_THROW(CheckShapeSizes(ParseShapeSpec("torus:0.02,0.03")), ShapeSpecError);
}

TEST(ShapesMakeShape, HelpDocumentsEveryParameter) {
  const std::string help = ShapeHelp();
  for (const ShapeInfo& info : ShapeNames()) {
    SCOPED_TRACE(info.name);
    EXPECT_FALSE(info.triangles.empty());
    EXPECT_NE(help.find(info.triangles), std::string::npos);
    for (const ShapeParam& p : info.params) {
      EXPECT_FALSE(p.meaning.empty()) << p.name;
      EXPECT_EQ(p.unit, p.length ? "m" : "") << p.name;
      EXPECT_NE(help.find("      " + p.name + " "), std::string::npos) << p.name;
    }
  }
  EXPECT_NE(help.find("hx             m, default 0.05: half extent along x"), std::string::npos)
      << help;
  EXPECT_NE(help.find("width          m, default 0.2: full extent along x"), std::string::npos)
      << help;
}

TEST(ShapesMakeShape, CatalogueExamplesBuild) {
  const std::vector<ShapeInfo> names = ShapeNames();
  ASSERT_EQ(names.size(), 11u);
  const std::string help = ShapeHelp();
  for (const ShapeInfo& info : names) {
    SCOPED_TRACE(info.name);
    EXPECT_FALSE(info.description.empty());
    EXPECT_EQ(info.usage.rfind(info.name, 0), 0u);
    EXPECT_NE(help.find(info.usage), std::string::npos);
    const Mesh m = MakeShape(info.example);
    EXPECT_TRUE(m.watertight());
    EXPECT_GT(SignedVolume(m), 0);
  }
}

TEST(ShapesArguments, FunctionsRejectBadInput) {
  EXPECT_THROW(Box(Vec3(0.1, 0, 0.1)), MeshError);
  EXPECT_THROW(Box(Vec3(0.1, 0.1, 0.1), 0), MeshError);
  EXPECT_THROW(Sphere(std::nan("")), MeshError);
  EXPECT_THROW(Sphere(0.1, 9), MeshError);
  EXPECT_THROW(Capsule(0.1, 0.1, 32, 0), MeshError);
  EXPECT_THROW(Cylinder(0.1, -0.1), MeshError);
  EXPECT_THROW(Torus(0.1, 0.1), MeshError);
  EXPECT_THROW(TorusKnot(0, 3), MeshError);
  EXPECT_THROW(TorusKnot(2, 3, 0.05, 0.008, 2), MeshError);
  EXPECT_THROW(ThinPlate(0.1, 0.1, 0), MeshError);
  EXPECT_THROW(Spoon(0), MeshError);
  EXPECT_THROW(Hammer(-1), MeshError);
}

}  // namespace
}  // namespace hapticpd::pd::shapes
