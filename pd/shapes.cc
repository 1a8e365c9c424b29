#include "pd/shapes.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <initializer_list>
#include <numbers>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <string_view>
#include <unordered_map>
#include <utility>

namespace hapticpd::pd::shapes {
namespace {

constexpr double kPi = std::numbers::pi;

// ---------------------------------------------------------------------------
// Argument checks. Messages name the function so MakeShape can prefix the spec.

void CheckSize(const char* fn, const char* what, double value) {
  if (!std::isfinite(value) || value <= 0) {
    std::ostringstream os;
    os << fn << ": " << what << " must be positive and finite, got " << value;
    throw MeshError(os.str());
  }
}

void CheckMin(const char* fn, const char* what, int value, int min) {
  if (value < min) {
    std::ostringstream os;
    os << fn << ": " << what << " must be at least " << min << ", got " << value;
    throw MeshError(os.str());
  }
}

void CheckNonNegative(const char* fn, const char* what, double value) {
  if (!std::isfinite(value) || value < 0) {
    std::ostringstream os;
    os << fn << ": " << what << " must be non-negative and finite, got " << value;
    throw MeshError(os.str());
  }
}

// `triangles` is computed in floating point so absurd resolutions cannot overflow.
void CheckCount(const char* fn, double triangles) {
  if (!(triangles <= static_cast<double>(kMaxShapeTriangles))) {
    std::ostringstream os;
    os << fn << ": resolution too high: " << triangles << " triangles, more than the limit of "
       << kMaxShapeTriangles;
    throw MeshError(os.str());
  }
}

std::string Describe(const char* name, std::initializer_list<double> params) {
  std::ostringstream os;
  os << name << '(';
  const char* sep = "";
  for (double p : params) {
    os << sep << p;
    sep = ", ";
  }
  os << ')';
  return os.str();
}

// ---------------------------------------------------------------------------
// Mesh assembly helpers.

// Growing vertex and triangle arrays. A ring is a run of `n` consecutive vertex
// indices around a loop. The stitching helpers make triangles whose normal is
// (direction along the ring) x (direction from the ring behind to the ring
// ahead); Revolve and Sweep order their rings so that this points outward.
struct Builder {
  std::vector<Vec3> vertices;
  std::vector<Triangle> triangles;

  Index Add(const Vec3& p) {
    vertices.push_back(p);
    return static_cast<Index>(vertices.size() - 1);
  }
  void Tri(Index a, Index b, Index c) { triangles.push_back({a, b, c}); }

  // Quads between ring a (behind) and ring b (ahead), n vertices each.
  void Stitch(Index a, Index b, int n) {
    for (int k = 0; k < n; ++k) {
      const Index k1 = (k + 1) % n;
      Tri(a + k, a + k1, b + k1);
      Tri(a + k, b + k1, b + k);
    }
  }
  // Fan from a pole behind the ring (the surface starts at the pole).
  void FanStart(Index pole, Index ring, int n) {
    for (int k = 0; k < n; ++k) Tri(pole, ring + (k + 1) % n, ring + k);
  }
  // Fan to a pole ahead of the ring (the surface ends at the pole).
  void FanEnd(Index ring, Index pole, int n) {
    for (int k = 0; k < n; ++k) Tri(ring + k, ring + (k + 1) % n, pole);
  }

  // Appends `part` with every vertex mapped to A * p + t; det(A) must be > 0 so
  // the winding stays outward.
  void Append(const Builder& part, const Mat3& A = Mat3::Identity(), const Vec3& t = Vec3::Zero()) {
    const Index base = static_cast<Index>(vertices.size());
    for (const Vec3& p : part.vertices) vertices.push_back(A * p + t);
    for (const Triangle& f : part.triangles) Tri(f[0] + base, f[1] + base, f[2] + base);
  }

  Mesh Finish(std::string source) && {
    return Mesh::FromArrays(std::move(vertices), std::move(triangles), std::move(source));
  }
};

// Surface of revolution about z of a profile polyline of (rho, z) points,
// `segments` copies around the axis. The profile must go counter-clockwise
// around the solid's cross-section in the (rho, z) half-plane (rho to the
// right, z up), i.e. with the material on its left; consecutive points must
// differ and rho > 0 except possibly at the two ends.
//   * open profile starting and ending on the axis (rho == 0): a genus-0 surface
//     with poles, 2 * segments * (n - 2) triangles for n points;
//   * closed profile (`closed`, all rho > 0, last point joined to the first): a
//     torus-like surface, 2 * segments * n triangles.
Builder Revolve(const std::vector<Vec2>& profile, int segments, bool closed) {
  Builder b;
  const int n = static_cast<int>(profile.size());
  const bool pole_start = !closed && profile.front().x() == 0;
  const bool pole_end = !closed && profile.back().x() == 0;
  if (!closed && !(pole_start && pole_end)) {
    throw std::logic_error("Revolve: an open profile must start and end on the axis");
  }
  std::vector<Index> ring(n);
  for (int i = 0; i < n; ++i) {
    const Vec2& q = profile[i];
    if ((i == 0 && pole_start) || (i == n - 1 && pole_end)) {
      ring[i] = b.Add(Vec3(0, 0, q.y()));
      continue;
    }
    ring[i] = static_cast<Index>(b.vertices.size());
    for (int j = 0; j < segments; ++j) {
      const double theta = 2 * kPi * j / segments;
      b.Add(Vec3(q.x() * std::cos(theta), q.x() * std::sin(theta), q.y()));
    }
  }
  for (int i = 0; i + 1 < n; ++i) {
    if (i == 0 && pole_start) {
      b.FanStart(ring[0], ring[1], segments);
    } else if (i + 1 == n - 1 && pole_end) {
      b.FanEnd(ring[i], ring[i + 1], segments);
    } else {
      b.Stitch(ring[i], ring[i + 1], segments);
    }
  }
  if (closed) b.Stitch(ring[n - 1], ring[0], segments);
  return b;
}

// Appends the points of an arc of `radius` about `centre` in the (rho, z)
// plane for angles a0 + (a1 - a0) * i / steps, i in [first, last].
void AddArc(std::vector<Vec2>& profile, const Vec2& centre, double radius, double a0, double a1,
            int steps, int first, int last) {
  for (int i = first; i <= last; ++i) {
    const double a = a0 + (a1 - a0) * i / steps;
    profile.push_back(centre + radius * Vec2(std::cos(a), std::sin(a)));
  }
}

// Tube swept along the polyline `centre`, with an elliptic cross-section of
// semi-axes radii[i] = (along N, along B) in a rotation-minimising frame
// (T, N, B) computed by the double-reflection method (Wang et al. 2008).
// `normal_hint` (not parallel to the first tangent) orients the first N.
//   * closed: the last point joins the first; the frame's holonomy (the angle
//     by which transported N misses the initial one after a full loop) is
//     removed by a twist spread evenly along the curve, so the tube closes
//     without a seam. 2 * n * tube_segments triangles for n points.
//   * open: flat caps (fans around the end points), 2 * n * tube_segments
//     triangles as well (2 * (n - 1) * tube_segments side + 2 * tube_segments).
Builder Sweep(const std::vector<Vec3>& centre, const std::vector<Vec2>& radii, bool closed,
              int tube_segments, const Vec3& normal_hint) {
  const int n = static_cast<int>(centre.size());
  auto point = [&](int i) -> const Vec3& { return centre[closed ? (i % n + n) % n : i]; };
  std::vector<Vec3> tangent(n + 1);
  for (int i = 0; i < n; ++i) {
    const Vec3 ahead = closed || i + 1 < n ? point(i + 1) : point(i);
    const Vec3 behind = closed || i > 0 ? point(i - 1) : point(i);
    tangent[i] = (ahead - behind).normalized();
  }
  tangent[n] = tangent[0];

  // Transport N along the curve; frame n is the transported copy of frame 0.
  std::vector<Vec3> normal(n + 1);
  normal[0] = (normal_hint - normal_hint.dot(tangent[0]) * tangent[0]).normalized();
  const int steps = closed ? n : n - 1;
  for (int i = 0; i < steps; ++i) {
    const Vec3 v1 = point(i + 1) - point(i);
    const double c1 = v1.squaredNorm();
    const Vec3 rl = normal[i] - (2 / c1) * v1.dot(normal[i]) * v1;
    const Vec3 tl = tangent[i] - (2 / c1) * v1.dot(tangent[i]) * v1;
    const Vec3 v2 = tangent[i + 1] - tl;
    const double c2 = v2.squaredNorm();
    const Vec3 r = c2 > 1e-30 ? Vec3(rl - (2 / c2) * v2.dot(rl) * v2) : rl;
    normal[i + 1] = (r - r.dot(tangent[i + 1]) * tangent[i + 1]).normalized();
  }
  if (closed) {
    const double holonomy =
        std::atan2(tangent[0].dot(normal[n].cross(normal[0])), normal[n].dot(normal[0]));
    for (int i = 1; i < n; ++i) {
      normal[i] = Eigen::AngleAxisd(holonomy * i / n, tangent[i]) * normal[i];
    }
  }

  Builder b;
  std::vector<Index> ring(n);
  for (int i = 0; i < n; ++i) {
    const Vec3 bi = tangent[i].cross(normal[i]);
    ring[i] = static_cast<Index>(b.vertices.size());
    for (int k = 0; k < tube_segments; ++k) {
      const double phi = 2 * kPi * k / tube_segments;
      b.Add(point(i) + radii[i].x() * std::cos(phi) * normal[i] +
            radii[i].y() * std::sin(phi) * bi);
    }
  }
  for (int i = 0; i + 1 < n; ++i) b.Stitch(ring[i], ring[i + 1], tube_segments);
  if (closed) {
    b.Stitch(ring[n - 1], ring[0], tube_segments);
  } else {
    b.FanStart(b.Add(point(0)), ring[0], tube_segments);
    b.FanEnd(ring[n - 1], b.Add(point(n - 1)), tube_segments);
  }
  return b;
}

// Quad-grid box; vertices are shared through their integer lattice coordinates.
Builder GridBox(const Vec3& h, int n) {
  Builder b;
  std::unordered_map<long long, Index> index;
  auto vertex = [&](const Eigen::Vector3i& c) {
    const long long key = (static_cast<long long>(c[0]) * (n + 1) + c[1]) * (n + 1) + c[2];
    auto [it, inserted] = index.try_emplace(key, 0);
    if (inserted) {
      const Vec3 p = (2.0 * c.cast<double>() - Vec3::Constant(n)) / n;  // exact +-1 at the faces
      it->second = b.Add(p.cwiseProduct(h));
    }
    return it->second;
  };
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;  // e_u x e_v = e_axis
    for (int side : {0, n}) {
      for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
          Eigen::Vector3i c00, c10, c11, c01;
          c00[axis] = c10[axis] = c11[axis] = c01[axis] = side;
          c00[u] = c01[u] = i;
          c10[u] = c11[u] = i + 1;
          c00[v] = c10[v] = j;
          c01[v] = c11[v] = j + 1;
          const Index q[4] = {vertex(c00), vertex(c10), vertex(c11), vertex(c01)};
          if (side == n) {  // seen from +axis, (u, v) is counter-clockwise
            b.Tri(q[0], q[1], q[2]);
            b.Tri(q[0], q[2], q[3]);
          } else {
            b.Tri(q[0], q[2], q[1]);
            b.Tri(q[0], q[3], q[2]);
          }
        }
      }
    }
  }
  return b;
}

// Points sampled uniformly in u in [0, 1] (count points, both ends included).
template <typename F>
std::vector<Vec3> SampleCurve(int count, F curve) {
  std::vector<Vec3> points(count);
  for (int i = 0; i < count; ++i) points[i] = curve(static_cast<double>(i) / (count - 1));
  return points;
}

// The cyclic permutation (x, y, z) -> (y, z, x) of coordinates: maps the z axis
// to x, preserving orientation (det +1).
Mat3 ZToX() {
  Mat3 A;
  A << 0, 0, 1,  //
      1, 0, 0,   //
      0, 1, 0;
  return A;
}

}  // namespace

// ---------------------------------------------------------------------------
// Primitive shapes.

Mesh Box(const Vec3& half_extents) { return Box(half_extents, 1); }

Mesh Box(const Vec3& half_extents, int subdivisions) {
  for (int k = 0; k < 3; ++k) CheckSize("Box", "half extent", half_extents[k]);
  CheckMin("Box", "subdivisions", subdivisions, 1);
  CheckCount("Box", 12.0 * subdivisions * subdivisions);
  return GridBox(half_extents, subdivisions)
      .Finish(Describe("box", {half_extents.x(), half_extents.y(), half_extents.z(),
                               static_cast<double>(subdivisions)}));
}

Mesh Sphere(double radius, int subdivisions) {
  CheckSize("Sphere", "radius", radius);
  CheckMin("Sphere", "subdivisions", subdivisions, 0);
  CheckCount("Sphere", 20 * std::pow(4.0, subdivisions));
  const double g = (1 + std::sqrt(5.0)) / 2;
  std::vector<Vec3> v = {{-1, g, 0},  {1, g, 0},  {-1, -g, 0}, {1, -g, 0}, {0, -1, g},  {0, 1, g},
                         {0, -1, -g}, {0, 1, -g}, {g, 0, -1},  {g, 0, 1},  {-g, 0, -1}, {-g, 0, 1}};
  for (Vec3& p : v) p.normalize();
  std::vector<Triangle> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                             {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                             {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                             {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (Triangle& t : f) {  // make every base face wind counter-clockwise seen from outside
    if ((v[t[1]] - v[t[0]]).cross(v[t[2]] - v[t[0]]).dot(v[t[0]]) < 0) std::swap(t[1], t[2]);
  }
  for (int level = 0; level < subdivisions; ++level) {
    std::unordered_map<long long, Index> midpoint;
    auto mid = [&](Index a, Index b) {
      const long long key = (static_cast<long long>(std::min(a, b)) << 32) | std::max(a, b);
      auto [it, inserted] = midpoint.try_emplace(key, 0);
      if (inserted) {
        v.push_back((v[a] + v[b]).normalized());
        it->second = static_cast<Index>(v.size() - 1);
      }
      return it->second;
    };
    std::vector<Triangle> next;
    next.reserve(4 * f.size());
    for (const Triangle& t : f) {
      const Index ab = mid(t[0], t[1]), bc = mid(t[1], t[2]), ca = mid(t[2], t[0]);
      next.push_back({t[0], ab, ca});
      next.push_back({t[1], bc, ab});
      next.push_back({t[2], ca, bc});
      next.push_back({ab, bc, ca});
    }
    f = std::move(next);
  }
  for (Vec3& p : v) p *= radius;
  return Mesh::FromArrays(std::move(v), std::move(f),
                          Describe("sphere", {radius, static_cast<double>(subdivisions)}));
}

Mesh Capsule(double radius, double half_length, int segments, int rings) {
  CheckSize("Capsule", "radius", radius);
  CheckNonNegative("Capsule", "half_length", half_length);
  CheckMin("Capsule", "segments", segments, 3);
  CheckMin("Capsule", "rings", rings, 1);
  CheckCount("Capsule", 4.0 * segments * rings);
  std::vector<Vec2> profile;
  AddArc(profile, Vec2(0, -half_length), radius, -kPi / 2, 0, rings, 0, rings);
  AddArc(profile, Vec2(0, half_length), radius, 0, kPi / 2, rings, half_length > 0 ? 0 : 1, rings);
  profile.front().x() = profile.back().x() = 0;  // exact poles
  return Revolve(profile, segments, false)
      .Finish(Describe("capsule", {radius, half_length, static_cast<double>(segments),
                                   static_cast<double>(rings)}));
}

Mesh Cylinder(double radius, double half_length, int segments) {
  CheckSize("Cylinder", "radius", radius);
  CheckSize("Cylinder", "half_length", half_length);
  CheckMin("Cylinder", "segments", segments, 3);
  CheckCount("Cylinder", 4.0 * segments);
  const std::vector<Vec2> profile = {
      {0, -half_length}, {radius, -half_length}, {radius, half_length}, {0, half_length}};
  return Revolve(profile, segments, false)
      .Finish(Describe("cylinder", {radius, half_length, static_cast<double>(segments)}));
}

Mesh Stick() { return Cylinder(0.005, 0.075, 23); }

Mesh Torus(double major_radius, double minor_radius, int major_segments, int minor_segments) {
  CheckSize("Torus", "major_radius", major_radius);
  CheckSize("Torus", "minor_radius", minor_radius);
  if (minor_radius >= major_radius) {
    std::ostringstream os;
    os << "Torus: minor_radius (" << minor_radius << ") must be less than major_radius ("
       << major_radius << ")";
    throw MeshError(os.str());
  }
  CheckMin("Torus", "major_segments", major_segments, 3);
  CheckMin("Torus", "minor_segments", minor_segments, 3);
  CheckCount("Torus", 2.0 * major_segments * minor_segments);
  std::vector<Vec2> profile;
  AddArc(profile, Vec2(major_radius, 0), minor_radius, 0, 2 * kPi, minor_segments, 0,
         minor_segments - 1);
  return Revolve(profile, major_segments, true)
      .Finish(Describe("torus", {major_radius, minor_radius, static_cast<double>(major_segments),
                                 static_cast<double>(minor_segments)}));
}

Mesh TorusKnot(int p, int q, double radius, double tube_radius, int segments, int tube_segments) {
  CheckMin("TorusKnot", "p", p, 1);
  CheckMin("TorusKnot", "q", q, 1);
  if (std::gcd(p, q) != 1) {
    std::ostringstream os;
    os << "TorusKnot: p and q must be coprime, got (" << p << ", " << q
       << "), which is a link that retraces itself";
    throw MeshError(os.str());
  }
  CheckSize("TorusKnot", "radius", radius);
  CheckSize("TorusKnot", "tube_radius", tube_radius);
  CheckMin("TorusKnot", "segments", segments, 3);
  CheckMin("TorusKnot", "tube_segments", tube_segments, 3);
  CheckCount("TorusKnot", 2.0 * segments * tube_segments);
  std::vector<Vec3> curve(segments);
  for (int i = 0; i < segments; ++i) {
    const double t = 2 * kPi * i / segments;
    const double rho = 1 + 0.5 * std::cos(q * t);
    curve[i] = radius * Vec3(rho * std::cos(p * t), rho * std::sin(p * t), 0.5 * std::sin(q * t));
  }
  const std::vector<Vec2> radii(segments, Vec2::Constant(tube_radius));
  // The first tangent lies in the xy-plane at t = 0, so z is a valid hint.
  return Sweep(curve, radii, true, tube_segments, Vec3::UnitZ())
      .Finish(Describe("torusknot",
                       {static_cast<double>(p), static_cast<double>(q), radius, tube_radius,
                        static_cast<double>(segments), static_cast<double>(tube_segments)}));
}

Mesh ThinPlate(double width, double depth, double thickness, int subdivisions) {
  CheckSize("ThinPlate", "width", width);
  CheckSize("ThinPlate", "depth", depth);
  CheckSize("ThinPlate", "thickness", thickness);
  CheckMin("ThinPlate", "subdivisions", subdivisions, 1);
  CheckCount("ThinPlate", 12.0 * subdivisions * subdivisions);
  return GridBox(Vec3(width, depth, thickness) / 2, subdivisions)
      .Finish(Describe("plate", {width, depth, thickness, static_cast<double>(subdivisions)}));
}

// ---------------------------------------------------------------------------
// Benchmark stand-ins.

Mesh Spoon(int resolution) {
  CheckMin("Spoon", "resolution", resolution, 1);
  CheckCount("Spoon", 78.0 * resolution * resolution);
  const int r = resolution;

  // Bowl: a spherical cap shell revolved about z (6r segments, 2r points per
  // side: 4 * 6r * 2r triangles), stretched 1.5x along x into an ellipse.
  const double rim = 0.02, depth = 0.008, thickness = 0.0015;
  const double big = (rim * rim + depth * depth) / (2 * depth);  // sphere radius
  const double alpha = std::asin(rim / big);                     // cap half-angle
  const Vec2 centre(0, big);
  std::vector<Vec2> profile;
  AddArc(profile, centre, big, -kPi / 2, -kPi / 2 + alpha, 2 * r, 0, 2 * r);  // outer, up
  AddArc(profile, centre, big - thickness, -kPi / 2 + alpha, -kPi / 2, 2 * r, 0, 2 * r);  // inner
  profile.front().x() = profile.back().x() = 0;
  const Builder bowl = Revolve(profile, 6 * r, false);
  const double stretch = 1.5;

  // Handle: flat strip along -x from inside the rim, rising and widening
  // (5r points, 3r around: 2 * 3r * 5r triangles).
  const double x0 = -(stretch * rim - 0.004), z0 = depth, length = 0.13;
  const std::vector<Vec3> curve = SampleCurve(5 * r, [&](double u) {
    return Vec3(x0 - length * u, 0, z0 + 0.012 * (1 - (1 - u) * (1 - u)));
  });
  std::vector<Vec2> radii(curve.size());
  for (std::size_t i = 0; i < radii.size(); ++i) {
    const double u = static_cast<double>(i) / (radii.size() - 1);
    radii[i] = Vec2(0.0015, 0.004 + 0.004 * std::sin(kPi * 0.75 * u));  // (thickness, width)
  }
  const Builder handle = Sweep(curve, radii, false, 3 * r, Vec3::UnitZ());

  Builder spoon;
  spoon.Append(bowl, Mat3(Vec3(stretch, 1, 1).asDiagonal()));
  spoon.Append(handle);
  return std::move(spoon).Finish(Describe("spoon", {static_cast<double>(r)}));
}

Mesh Cup(int resolution) {
  CheckMin("Cup", "resolution", resolution, 1);
  CheckCount("Cup", 528.0 * resolution * resolution);
  const int r = resolution;

  // Body: 24r segments, a profile with 9r points between the two poles
  // (2 * 24r * 9r triangles). Outer: floor (r), foot fillet (r), wall (2r);
  // rim: semicircle (r); inner: wall (2r), fillet (r), floor (r).
  const double height = 0.095, wall = 0.003, floor = 0.005;
  const double foot = 0.035, top = 0.041, fillet = 0.004, inner_fillet = 0.003;
  auto outer = [&](double z) {  // outer wall radius above the foot fillet
    return foot + (top - foot) * (z - fillet) / (height - fillet);
  };
  std::vector<Vec2> profile = {{0, 0}};
  for (int i = 1; i <= r; ++i) profile.emplace_back((foot - fillet) * i / r, 0);
  AddArc(profile, Vec2(foot - fillet, fillet), fillet, -kPi / 2, 0, r, 1, r);
  for (int i = 1; i <= 2 * r; ++i) {
    const double z = fillet + (height - fillet) * i / (2 * r);
    profile.emplace_back(outer(z), z);
  }
  AddArc(profile, Vec2(top - wall / 2, height), wall / 2, 0, kPi, r + 1, 1, r);
  std::vector<Vec2> inside = {{0, floor}};  // built from the inner pole, then reversed
  const double inner_foot = foot - wall;
  for (int i = 1; i <= r; ++i) inside.emplace_back((inner_foot - inner_fillet) * i / r, floor);
  AddArc(inside, Vec2(inner_foot - inner_fillet, floor + inner_fillet), inner_fillet, -kPi / 2, 0,
         r, 1, r);
  for (int i = 1; i <= 2 * r; ++i) {
    const double z = floor + inner_fillet + (height - floor - inner_fillet) * i / (2 * r);
    inside.emplace_back(outer(z) - wall, z);
  }
  profile.insert(profile.end(), inside.rbegin(), inside.rend());
  const Builder body = Revolve(profile, 24 * r, false);

  // Handle: a C-shaped half ellipse on the +x side in the xz-plane whose ends
  // are horizontal and sit mid-wall (12r points, 4r around: 2 * 4r * 12r
  // triangles); oval section 4 mm in the plane, 6 mm across.
  const double zc = 0.05, reach = 0.03, half_height = 0.028;
  const std::vector<Vec3> curve = SampleCurve(12 * r, [&](double u) {
    const double psi = kPi / 2 - kPi * u;
    const double z = zc + half_height * std::sin(psi);
    return Vec3(outer(z) - wall / 2 + reach * std::cos(psi), 0, z);
  });
  const std::vector<Vec2> radii(curve.size(), Vec2(0.004, 0.006));
  const Builder handle = Sweep(curve, radii, false, 4 * r, Vec3::UnitZ());

  Builder cup;
  cup.Append(body);
  cup.Append(handle);
  return std::move(cup).Finish(Describe("cup", {static_cast<double>(r)}));
}

Mesh Hammer(int resolution) {
  CheckMin("Hammer", "resolution", resolution, 1);
  CheckCount("Hammer", 108.0 * resolution * resolution + 12.0 * resolution);
  const int r = resolution;

  // Handle along +z: rounded butt (r arc points), a shaft of 3r intervals
  // tapering from the grip and rounded top (r arc points): 5r + 1 points
  // between the poles, 6r segments.
  const double length = 0.30, grip = 0.014, neck = 0.011, butt = 0.008;
  std::vector<Vec2> handle_profile = {{0, 0}};
  for (int i = 1; i <= r; ++i) {  // quarter ellipse from the pole out to the shaft
    const double a = -kPi / 2 + kPi / 2 * i / (r + 1);
    handle_profile.emplace_back(grip * std::cos(a), butt * (1 + std::sin(a)));
  }
  const double shaft_top = length - neck;
  for (int i = 0; i <= 3 * r; ++i) {
    const double s = static_cast<double>(i) / (3 * r);
    handle_profile.emplace_back(grip + (neck - grip) * s, butt + (shaft_top - butt) * s);
  }
  AddArc(handle_profile, Vec2(0, shaft_top), neck, 0, kPi / 2, r + 1, 1, r);
  handle_profile.emplace_back(0, length);
  const Builder handle = Revolve(handle_profile, 6 * r, false);

  // Head along x: a chamfered cylinder, 4r points between the poles, 6r
  // segments. Face disc (r), chamfer end, side (2r - 2 interior points),
  // chamfer end, face disc (r).
  const double half = 0.055, radius = 0.016, chamfer = 0.003, centre_z = 0.29;
  std::vector<Vec2> head_profile = {{0, -half}};
  for (int i = 1; i <= r; ++i) head_profile.emplace_back((radius - chamfer) * i / r, -half);
  for (int i = 0; i <= 2 * r - 1; ++i) {
    const double z = -half + chamfer + (2 * half - 2 * chamfer) * i / (2 * r - 1);
    head_profile.emplace_back(radius, z);
  }
  for (int i = r; i >= 1; --i) head_profile.emplace_back((radius - chamfer) * i / r, half);
  head_profile.emplace_back(0, half);
  const Builder head = Revolve(head_profile, 6 * r, false);

  Builder hammer;
  hammer.Append(handle);
  hammer.Append(head, ZToX(), Vec3(0, 0, centre_z));
  return std::move(hammer).Finish(Describe("hammer", {static_cast<double>(r)}));
}

// ---------------------------------------------------------------------------
// Spec parsing.

namespace {

ShapeParam Length(const char* name, double def, const char* meaning, bool size = true) {
  return {name, "m", meaning, def, false, true, size, false};
}
ShapeParam Count(const char* name, double def, int min, const char* meaning, bool size = false) {
  return {name, "", meaning, def, true, false, size, false, min};
}

const std::vector<ShapeInfo>& Catalogue() {
  static const std::vector<ShapeInfo> entries = [] {
    ShapeParam half_length = Length("half_length", 0.04,
                                    "half the length of the straight part along z; 0 gives a "
                                    "sphere");
    half_length.zero_ok = true;
    return std::vector<ShapeInfo>{
        {"box",
         "box[:hx,hy,hz[,subdivisions]]",
         "axis-aligned box centred at the origin, from HALF extents",
         "box:0.1,0.2,0.3",
         {Length("hx", 0.05, "half extent along x (the box is 2 hx wide)"),
          Length("hy", 0.05, "half extent along y"), Length("hz", 0.05, "half extent along z"),
          Count("subdivisions", 1, 1, "grid cells along each face edge")},
         "12 * subdivisions^2"},
        {"sphere",
         "sphere[:radius[,subdivisions]]",
         "icosphere centred at the origin",
         "sphere:0.05,3",
         {Length("radius", 0.05, "radius of the circumscribed sphere"),
          Count("subdivisions", 3, 0, "icosahedron refinements (each splits a face into four)")},
         "20 * 4^subdivisions"},
        {"capsule",
         "capsule[:radius,half_length[,segments[,rings]]]",
         "capsule centred at the origin, axis along z, length 2 (half_length + radius)",
         "capsule:0.02,0.04",
         {Length("radius", 0.02, "radius of the cylinder and the two hemispheres"), half_length,
          Count("segments", 32, 3, "segments around the axis"),
          Count("rings", 8, 1, "latitude bands per hemisphere")},
         "4 * segments * rings (2 * segments * (2 * rings - 1) when half_length = 0)"},
        {"cylinder",
         "cylinder[:radius,half_length[,segments]]",
         "closed cylinder centred at the origin, axis along z",
         "cylinder:0.05,0.1,32",
         {Length("radius", 0.05, "radius"),
          Length("half_length", 0.1, "half the length along z (the cylinder spans 2 half_length)"),
          Count("segments", 32, 3, "segments around the axis")},
         "4 * segments"},
        {"stick",
         "stick",
         "the seed paper's stick: a cylinder of radius 5 mm, 15 cm long",
         "stick",
         {},
         "92"},
        {"torus",
         "torus[:major_radius,minor_radius[,major_segments[,minor_segments]]]",
         "torus in the xy-plane centred at the origin",
         "torus:0.06,0.02",
         {Length("major_radius", 0.06, "radius of the tube's centre circle"),
          Length("minor_radius", 0.02, "radius of the tube (less than major_radius)"),
          Count("major_segments", 48, 3, "segments around z"),
          Count("minor_segments", 24, 3, "segments around the tube")},
         "2 * major_segments * minor_segments"},
        {"torusknot",
         "torusknot[:p,q,radius,tube_radius[,segments[,tube_segments]]]",
         "tube along a (p, q) torus knot centred at the origin",
         "torusknot:2,3,0.05,0.008",
         {Count("p", 2, 1, "turns around the z axis (coprime with q)", true),
          Count("q", 3, 1, "turns through the hole", true),
          Length("radius", 0.05, "major radius of the torus the knot lies on"),
          Length("tube_radius", 0.008, "radius of the tube"),
          Count("segments", 256, 3, "samples along the curve"),
          Count("tube_segments", 16, 3, "segments around the tube")},
         "2 * segments * tube_segments"},
        {"plate",
         "plate[:width,depth,thickness[,subdivisions]]",
         "thin box centred at the origin, from FULL extents",
         "plate:0.2,0.2,0.004",
         {Length("width", 0.2, "full extent along x"), Length("depth", 0.2, "full extent along y"),
          Length("thickness", 0.004, "full extent along z"),
          Count("subdivisions", 1, 1, "grid cells along each face edge")},
         "12 * subdivisions^2"},
        {"spoon",
         "spoon[:resolution]",
         "spoon stand-in (bowl + handle, about 19 cm long)",
         "spoon",
         {Count("resolution", 4, 1, "mesh resolution")},
         "78 * resolution^2"},
        {"cup",
         "cup[:resolution]",
         "mug stand-in (thick shell + handle, 9.5 cm tall)",
         "cup",
         {Count("resolution", 4, 1, "mesh resolution")},
         "528 * resolution^2"},
        {"hammer",
         "hammer[:resolution]",
         "hammer stand-in (handle + head, 30 cm long)",
         "hammer",
         {Count("resolution", 4, 1, "mesh resolution")},
         "108 * resolution^2 + 12 * resolution"},
    };
  }();
  return entries;
}

std::string Number(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

// Untrusted spec text quoted in a message: control characters and bytes
// >= 0x7f escaped, cut after `max` bytes, so a megabyte spec cannot make a
// megabyte exception message.
std::string Clip(std::string_view s, std::size_t max = 64) {
  std::string out;
  for (std::size_t i = 0; i < s.size() && i < max; ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c == '\\') {
      out += "\\\\";
    } else if (c < 0x20 || c >= 0x7f) {
      static const char kHex[] = "0123456789abcdef";
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    } else {
      out += static_cast<char>(c);
    }
  }
  if (s.size() > max) out += "...(" + std::to_string(s.size()) + " bytes)";
  return out;
}

std::string Names(const std::vector<ShapeParam>& params, bool sizes_only) {
  std::string list;
  for (const ShapeParam& p : params) {
    if (!sizes_only || p.size) list += (list.empty() ? "" : ",") + p.name;
  }
  return list;
}

// The exact triangle count of the builder for these values (see each
// function's documentation).
double TriangleCount(const std::string& name, const std::vector<double>& v) {
  if (name == "box" || name == "plate") return 12 * v[3] * v[3];
  if (name == "sphere") return 20 * std::pow(4.0, v[1]);
  if (name == "capsule") return v[1] > 0 ? 4 * v[2] * v[3] : 2 * v[2] * (2 * v[3] - 1);
  if (name == "cylinder") return 4 * v[2];
  if (name == "stick") return 92;
  if (name == "torus") return 2 * v[2] * v[3];
  if (name == "torusknot") return 2 * v[4] * v[5];
  if (name == "spoon") return 78 * v[0] * v[0];
  if (name == "cup") return 528 * v[0] * v[0];
  if (name == "hammer") return 108 * v[0] * v[0] + 12 * v[0];
  throw std::logic_error("TriangleCount: no formula for " + name);
}

// A bound on |coordinate| of every vertex.
double Reach(const std::string& name, const std::vector<double>& v) {
  if (name == "box") return std::max({v[0], v[1], v[2]});
  if (name == "plate") return std::max({v[0], v[1], v[2]}) / 2;
  if (name == "sphere") return v[0];
  if (name == "capsule") return v[0] + v[1];
  if (name == "cylinder") return std::max(v[0], v[1]);
  if (name == "torus") return v[0] + v[1];
  if (name == "torusknot") return 1.5 * v[2] + v[3];
  return 0.5;  // stick and the stand-ins: fixed geometry within half a metre
}

}  // namespace

ShapeSpecError::ShapeSpecError(const std::string& spec, const std::string& problem)
    : MeshError("shape spec '" + Clip(spec) + "': " + problem), problem_(problem) {}

std::vector<ShapeInfo> ShapeNames() { return Catalogue(); }

std::string ShapeHelp() {
  std::ostringstream os;
  for (const ShapeInfo& e : Catalogue()) {
    os << "  " << e.usage << "\n      " << e.description << "; " << e.triangles
       << " triangles (e.g. '" << e.example << "')\n";
    for (const ShapeParam& p : e.params) {
      os << "      " << p.name << std::string(p.name.size() < 15 ? 15 - p.name.size() : 1, ' ')
         << (p.unit.empty() ? (p.integral ? "integer >= " + std::to_string(p.min) : "") : p.unit)
         << ", default " << Number(p.default_value) << ": " << p.meaning << '\n';
    }
  }
  return os.str();
}

ShapeSpec ParseShapeSpec(const std::string& text) {
  auto fail = [&](const std::string& problem) { return ShapeSpecError(text, problem); };
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (std::isspace(static_cast<unsigned char>(text[i]))) {
      throw fail("whitespace is not allowed in a shape spec (at byte " + std::to_string(i) + ")");
    }
  }
  const std::size_t colon = text.find(':');
  const std::string name = text.substr(0, colon);
  const ShapeInfo* entry = nullptr;
  for (const ShapeInfo& e : Catalogue()) {
    if (e.name == name) entry = &e;
  }
  if (entry == nullptr) {
    std::string known;
    for (const ShapeInfo& e : Catalogue()) known += (known.empty() ? "" : ", ") + e.name;
    throw fail(name.empty() ? "empty shape name; known shapes: " + known
                            : "unknown shape '" + Clip(name) + "'; known shapes: " + known);
  }
  const std::vector<ShapeParam>& params = entry->params;

  std::vector<double> values;
  if (colon != std::string::npos) {
    std::string_view rest = std::string_view(text).substr(colon + 1);
    if (params.empty()) throw fail("'" + name + "' takes no parameters");
    while (true) {
      const std::size_t comma = rest.find(',');
      const std::string_view token = rest.substr(0, comma);
      const std::size_t i = values.size();
      if (i >= params.size()) {
        throw fail("'" + name + "' takes at most " + std::to_string(params.size()) + " parameter" +
                   (params.size() == 1 ? "" : "s") + " (" + Names(params, false) + ")");
      }
      const ShapeParam& p = params[i];
      if (token.empty()) throw fail("parameter " + p.name + " is empty");
      double value = 0;
      const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
      if (ec != std::errc() || end != token.data() + token.size() || !std::isfinite(value)) {
        throw fail("parameter " + p.name + " '" + Clip(token, 32) + "' is not a finite number");
      }
      if (p.integral) {
        if (value != std::floor(value)) {
          throw fail("parameter " + p.name + " '" + Clip(token, 32) + "' must be an integer");
        }
        if (std::abs(value) > 1e6) {
          throw fail("parameter " + p.name + " '" + Clip(token, 32) + "' is out of range");
        }
        if (value < p.min) {
          throw fail(p.name + " must be at least " + std::to_string(p.min) + ", got " +
                     Number(value));
        }
      }
      values.push_back(value);
      if (comma == std::string_view::npos) break;
      rest = rest.substr(comma + 1);
    }
  }
  // Either every default or every size given: a partial size list (a box
  // with one half extent) would silently take defaults for the rest.
  std::size_t sizes = 0;
  for (const ShapeParam& p : params) sizes += p.size ? 1 : 0;
  if (!values.empty() && values.size() < sizes) {
    std::string missing;
    for (std::size_t i = values.size(); i < sizes; ++i) {
      missing += (missing.empty() ? "" : ",") + params[i].name;
    }
    throw fail("'" + name + "' needs all of " + Names(params, true) +
               " or none (for the defaults); missing " + missing);
  }
  for (std::size_t i = values.size(); i < params.size(); ++i) {
    values.push_back(params[i].default_value);
  }
  if (name == "torusknot" &&
      std::gcd(static_cast<long>(values[0]), static_cast<long>(values[1])) != 1) {
    throw fail("p (" + Number(values[0]) + ") and q (" + Number(values[1]) +
               ") must be coprime (otherwise the curve retraces itself)");
  }
  ShapeSpec out;
  out.text = text;
  out.name = name;
  out.params = params;
  out.values = std::move(values);
  out.triangles = TriangleCount(name, out.values);
  out.reach = Reach(name, out.values);
  return out;
}

void CheckShapeSizes(const ShapeSpec& spec) {
  for (std::size_t i = 0; i < spec.params.size(); ++i) {
    const ShapeParam& p = spec.params[i];
    const double v = spec.values[i];
    if (!p.length || (p.zero_ok && v == 0)) continue;
    if (!std::isfinite(v) || v <= 0) {
      throw ShapeSpecError(spec.text, p.name + " must be positive" +
                                          (p.zero_ok ? std::string(" or 0") : std::string()) +
                                          " and finite, got " + Number(v));
    }
  }
  if (spec.name == "torus" && spec.values[1] >= spec.values[0]) {
    throw ShapeSpecError(spec.text, "minor_radius (" + Number(spec.values[1]) +
                                        ") must be less than major_radius (" +
                                        Number(spec.values[0]) + ")");
  }
}

Mesh MakeShape(const ShapeSpec& spec) {
  CheckShapeSizes(spec);
  const std::vector<double>& a = spec.values;
  auto n = [&](std::size_t i) { return static_cast<int>(a[i]); };
  const std::string& name = spec.name;
  try {
    if (name == "box") return Box(Vec3(a[0], a[1], a[2]), n(3));
    if (name == "sphere") return Sphere(a[0], n(1));
    if (name == "capsule") return Capsule(a[0], a[1], n(2), n(3));
    if (name == "cylinder") return Cylinder(a[0], a[1], n(2));
    if (name == "stick") return Stick();
    if (name == "torus") return Torus(a[0], a[1], n(2), n(3));
    if (name == "torusknot") return TorusKnot(n(0), n(1), a[2], a[3], n(4), n(5));
    if (name == "plate") return ThinPlate(a[0], a[1], a[2], n(3));
    if (name == "spoon") return Spoon(n(0));
    if (name == "cup") return Cup(n(0));
    if (name == "hammer") return Hammer(n(0));
  } catch (const ShapeSpecError&) {
    throw;
  } catch (const MeshError& e) {
    throw ShapeSpecError(spec.text, e.what());
  }
  throw ShapeSpecError(spec.text, "internal error: shape '" + name + "' has no builder");
}

Mesh MakeShape(const std::string& spec) { return MakeShape(ParseShapeSpec(spec)); }

}  // namespace hapticpd::pd::shapes
