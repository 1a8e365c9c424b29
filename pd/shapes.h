// Procedural closed triangle meshes for tests, demos and benchmarks.
//
// Every shape is returned as a `Mesh` in metres that is closed and consistently
// oriented (`Mesh::watertight()` is true: every edge is shared by exactly two
// faces that traverse it in opposite directions), wound counter-clockwise seen
// from outside (outward normals, positive signed volume) and free of
// degenerate triangles. Each function documents where its origin is and how
// its triangle count follows from its resolution parameters.
//
// The benchmark stand-ins (`Spoon`, `Cup`, `Hammer`) are composites: a few
// closed components that share no vertices and deliberately overlap (a handle
// embedded in a wall). Each component is closed, so the union is closed and
// watertight, but it self-intersects; inside/outside is still well defined by
// the winding number (overlaps count twice in the signed volume).
//
// Every function throws MeshError on invalid arguments (a non-positive or
// non-finite size, a resolution below its minimum, or a result that would
// exceed `kMaxShapeTriangles`).
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "pd/mesh.h"
#include "pd/types.h"

namespace hapticpd::pd::shapes {

/// No procedural shape is built with more triangles than this.
inline constexpr std::size_t kMaxShapeTriangles = 5'000'000;

/// Axis-aligned box centred at the origin with the given half extents [m]:
/// 8 vertices, 12 triangles (each face split along one diagonal).
Mesh Box(const Vec3& half_extents = Vec3::Constant(0.05));

/// Axis-aligned box centred at the origin whose faces are each split into a
/// `subdivisions` x `subdivisions` grid of quads (coplanar triangles, useful
/// for face-face contact tests): 12 * subdivisions^2 triangles,
/// 6 * subdivisions^2 + 2 vertices. `subdivisions` >= 1; 1 equals `Box(h)`.
Mesh Box(const Vec3& half_extents, int subdivisions);

/// Icosphere centred at the origin: a regular icosahedron whose faces are
/// split into four `subdivisions` times, vertices projected onto the sphere of
/// `radius` [m]. 20 * 4^subdivisions triangles, 10 * 4^subdivisions + 2
/// vertices (default 0.05 m, 3 -> 1280 triangles). `subdivisions` in [0, 8].
/// The mesh is inscribed: its volume is below 4/3 pi r^3 (by 0.9 % at 3).
Mesh Sphere(double radius = 0.05, int subdivisions = 3);

/// Capsule centred at the origin with its axis along z: a cylinder of
/// `radius` [m] spanning z in [-half_length, half_length] capped by two
/// hemispheres (total length 2 * (half_length + radius)). `segments` (>= 3)
/// around the axis, `rings` (>= 1) latitude bands per hemisphere;
/// 4 * segments * rings triangles when half_length > 0 and
/// 2 * segments * (2 * rings - 1) when half_length == 0 (a UV sphere).
/// Default 0.02 m, 0.04 m, 32, 8 -> 1024 triangles.
Mesh Capsule(double radius = 0.02, double half_length = 0.04, int segments = 32, int rings = 8);

/// Closed cylinder centred at the origin with its axis along z, spanning z in
/// [-half_length, half_length]. The two caps are triangle fans around a centre
/// vertex. `segments` >= 3: 4 * segments triangles (2 * segments side,
/// 2 * segments cap), 2 * segments + 2 vertices. Default 0.05 m, 0.1 m, 32 ->
/// 128 triangles.
Mesh Cylinder(double radius = 0.05, double half_length = 0.1, int segments = 32);

/// The seed paper's "stick" benchmark object: `Cylinder(0.005, 0.075, 23)`, a
/// rod 5 mm in radius and 15 cm long along z, centred at the origin, with
/// exactly 92 triangles (46 side, 46 cap).
Mesh Stick();

/// Torus in the xy-plane centred at the origin, revolved about z: the tube
/// centre circle has radius `major_radius` [m], the tube `minor_radius` [m]
/// (0 < minor < major). 2 * major_segments * minor_segments triangles
/// (each >= 3). Default 0.06 m, 0.02 m, 48, 24 -> 2304 triangles.
Mesh Torus(double major_radius = 0.06, double minor_radius = 0.02, int major_segments = 48,
           int minor_segments = 24);

/// A tube of radius `tube_radius` [m] swept along the (p, q) torus knot
///   c(t) = radius * ((1 + cos(q t) / 2) cos(p t), (1 + cos(q t) / 2) sin(p t),
///                    sin(q t) / 2),   t in [0, 2 pi),
/// which winds p times around the z axis and q times through the hole of a
/// torus of major radius `radius` and minor radius `radius / 2`, centred at
/// the origin. p, q >= 1 and coprime (otherwise the curve is a link that
/// retraces itself). Frames are rotation minimising (double reflection), with
/// the closing twist spread evenly along the curve, so there is no seam.
/// `segments` (>= 3) samples along the curve, `tube_segments` (>= 3) around
/// the tube: 2 * segments * tube_segments triangles. Default (2, 3) trefoil,
/// 0.05 m, 0.008 m, 256, 16 -> 8192 triangles. The default tube does not
/// intersect itself: it does once `tube_radius` exceeds half the closest
/// distance between strands (0.0144 m, 0.29 * radius, for the trefoil; 0.0113 m
/// for (3, 2)) or the curve's smallest radius of curvature (0.036 m). The mesh
/// then stays watertight but is no longer embedded.
Mesh TorusKnot(int p = 2, int q = 3, double radius = 0.05, double tube_radius = 0.008,
               int segments = 256, int tube_segments = 16);

/// A thin box centred at the origin: `width` [m] along x, `depth` [m] along y
/// and `thickness` [m] along z, i.e. `Box(Vec3(width, depth, thickness) / 2,
/// subdivisions)`: 12 * subdivisions^2 triangles. Default 0.2 m x 0.2 m x
/// 4 mm, 1 -> 12 triangles.
Mesh ThinPlate(double width = 0.2, double depth = 0.2, double thickness = 0.004,
               int subdivisions = 1);

/// Stand-in for the seed paper's spoon (~1.3K triangles): an elliptic bowl
/// shell 6 cm x 4 cm x 8 mm deep, about 1.5 mm thick, opening toward +z, plus
/// a flat handle 13 cm long along -x whose end is embedded in the bowl rim.
/// Origin at the lowest point of the bowl's outer surface; the bowl axis is z.
/// Two closed, overlapping components; 78 * resolution^2 triangles
/// (`resolution` >= 1, default 4 -> 1248).
Mesh Spoon(int resolution = 4);

/// Stand-in for the seed paper's cup (~8.5K triangles): a slightly tapered
/// mug 9.5 cm tall, outer radius 3.5 cm at the foot and 4.1 cm at the rim,
/// revolved about z, with a 3 mm wall, a 5 mm floor, filleted foot and a
/// rounded open rim (a closed, thick-walled genus-0 shell), plus a C-shaped
/// handle tube on the +x side whose capped ends are embedded in the wall.
/// Origin at the centre of the outer bottom; the cup stands on z = 0.
/// Two closed, overlapping components; 528 * resolution^2 triangles
/// (`resolution` >= 1, default 4 -> 8448).
Mesh Cup(int resolution = 4);

/// Stand-in for the seed paper's hammer (~1.7K triangles): a round handle
/// 30 cm long along +z (radius 14 mm at the grip tapering to 11 mm, rounded
/// ends) and a cylindrical mallet head 11 cm long and 32 mm in diameter along
/// x with chamfered faces, centred at (0, 0, 0.29) with the handle top
/// embedded in it. Origin at the butt of the handle. Two closed, overlapping
/// components; 108 * resolution^2 + 12 * resolution triangles
/// (`resolution` >= 1, default 4 -> 1776).
Mesh Hammer(int resolution = 4);

/// One parameter of a shape spec.
struct ShapeParam {
  std::string name;     // e.g. "radius"
  std::string unit;     // "m" for lengths, "" for counts
  std::string meaning;  // one line
  double default_value;
  bool integral;  // an integer (a count or a resolution)
  bool length;    // a length in metres (the wire checks it against its range)
  bool size;      // a size parameter: a spec gives all of them or none
  bool zero_ok;   // a length that may also be 0 (capsule half_length)
  int min = 0;    // smallest value of an integral parameter
};

/// One entry of the shape catalogue for `--help` output.
struct ShapeInfo {
  std::string name;         // e.g. "sphere"
  std::string usage;        // e.g. "sphere[:radius[,subdivisions]]"
  std::string description;  // one line, with defaults
  std::string example;      // a valid spec, e.g. "sphere:0.05,3"
  std::vector<ShapeParam> params;
  std::string triangles;  // the triangle count formula, e.g. "20 * 4^subdivisions"
};

/// Every shape `MakeShape` understands, in a stable order.
std::vector<ShapeInfo> ShapeNames();

/// The catalogue formatted for `--help`: per shape its usage, description
/// and triangle count, then one line per parameter with unit, default and
/// meaning.
std::string ShapeHelp();

/// A shape spec that is well formed: the shape's name and every parameter's
/// value (defaults filled in), known before anything is built.
struct ShapeSpec {
  std::string text;                // the spec as given
  std::string name;                // catalogue name
  std::vector<ShapeParam> params;  // the catalogue's parameters, in order
  std::vector<double> values;      // one per parameter, defaults filled in
  /// Exactly the number of triangles MakeShape builds, computed from the
  /// parameters (in double so absurd resolutions cannot overflow; exact
  /// below 2^53). May exceed kMaxShapeTriangles: MakeShape then throws.
  double triangles = 0;
  /// Bound on |coordinate| of every vertex [m] (the shape's reach from its
  /// origin along any axis), computed from the parameters.
  double reach = 0;
};

/// Thrown for a malformed or invalid spec; `problem()` is the message
/// without the "shape spec '...': " prefix, so a caller can quote the spec
/// its own way.
class ShapeSpecError : public MeshError {
 public:
  ShapeSpecError(const std::string& spec, const std::string& problem);
  const std::string& problem() const { return problem_; }

 private:
  std::string problem_;
};

/// Parses a spec without building anything. Grammar (no whitespace anywhere):
///
///   spec   = NAME | NAME ":" value ("," value)*
///   value  = a decimal number (std::from_chars syntax, e.g. 0.05, 5e-2)
///
/// Either no parameters (every default) or at least all of the shape's size
/// parameters, then optionally its resolution parameters from the left.
/// Names: box, sphere, capsule, cylinder, stick, torus, torusknot, plate,
/// spoon, cup, hammer (ShapeNames() lists each parameter with its unit).
/// Throws ShapeSpecError on an unknown name, whitespace, a malformed,
/// non-finite or non-integral number, a partial size list, too many
/// parameters, a resolution below its minimum or above 1e6, or a torus knot
/// with p, q not coprime. Lengths are only parsed (a caller with its own
/// length range checks that first, then CheckShapeSizes); the triangle count
/// is not checked against kMaxShapeTriangles (`triangles` says what a build
/// would need).
ShapeSpec ParseShapeSpec(const std::string& spec);

/// The size checks of the builders, without building: every length positive
/// and finite (capsule half_length may be 0), a torus's minor_radius below
/// its major_radius. Throws ShapeSpecError.
void CheckShapeSizes(const ShapeSpec& spec);

/// Builds a parsed spec (CheckShapeSizes, then the shape's function).
/// Throws ShapeSpecError, or MeshError over kMaxShapeTriangles.
Mesh MakeShape(const ShapeSpec& spec);

/// ParseShapeSpec then build, e.g. `box`, `box:0.1,0.2,0.3`,
/// `sphere:0.05,3`, `stick`, `cup:2`. Throws ShapeSpecError / MeshError
/// whose message names the spec and the problem.
Mesh MakeShape(const std::string& spec);

}  // namespace hapticpd::pd::shapes
