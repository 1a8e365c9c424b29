// Geometric queries between two meshes A and B under rigid poses: collision,
// containment, proximity (feature pairs), distance, and continuous collision
// (translational, exact; rigid motion, conservative advancement).
//
// Conventions for every query here:
//   * X_WA, X_WB: poses of the models' mesh frames in the world W.
//   * Witness points and normals are expressed in W.
//   * A normal `n_W` of a feature pair points from B towards A: moving A
//     along n_W separates the pair locally (it is the direction of a contact
//     plane in translation space, ALGORITHMS.md step 3).
//   * Distances are unsigned and in metres.
// No query allocates once its QueryScratch and result vectors have grown to
// their working size (reuse them across calls).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "pd/geometry_model.h"
#include "pd/types.h"

namespace hapticpd::pd {

/// Per-session scratch memory for traversals (the "data" of the model/data
/// split). Never shared between threads.
struct QueryScratch {
  std::vector<std::pair<Index, Index>> stack;
  struct KeyedPair {
    double key;
    Index a, b;
  };
  std::vector<KeyedPair> heap;        ///< best-first traversals (CCD)
  std::vector<KeyedPair> leaf_pairs;  ///< CCD: leaf pairs met, with entry times
  std::vector<Vec3> points;           ///< PointsEnclosedBy's candidates
  /// Work counters, accumulated over every query using this scratch (reset
  /// them to measure one query): bounding-volume pair tests and triangle
  /// pairs examined.
  std::uint64_t node_tests = 0;
  std::uint64_t triangle_tests = 0;

  /// Translational CCD: A's BVH boxes, triangles and vertices rotated into
  /// B's frame (and B's boxes onto A's axes), computed lazily, once per
  /// node, triangle and vertex, and kept for every later
  /// sweep of the same models under the same rotation (a PDt query's sweeps
  /// all share one). An entry is valid when its stamp equals
  /// `rotated_stamp`; a new model or rotation bumps the stamp.
  struct RotatedTriangle {
    std::array<Vec3, 3> v;  ///< R_BA * vertices (add p_BAo for B's frame)
    Vec3 n;                 ///< R_BA * face normal
  };
  std::vector<internal::RotatedBox> rotated_nodes;  ///< A's (RotateBoxA)
  std::vector<std::uint32_t> rotated_node_stamp;
  std::vector<internal::RotatedBox> rotated_b_nodes;  ///< B's (RotateBoxB)
  std::vector<std::uint32_t> rotated_b_node_stamp;
  std::vector<RotatedTriangle> rotated_triangles;
  std::vector<std::uint32_t> rotated_triangle_stamp;
  std::vector<Vec3> rotated_vertices;  ///< R_BA * vertex (leaf boxes, triangles)
  std::vector<std::uint32_t> rotated_vertex_stamp;
  std::uint32_t rotated_stamp = 0;
  std::uint64_t rotated_model = 0;    ///< GeometryModel::uid() of A, 0: none
  std::uint64_t rotated_b_model = 0;  ///< and of B
  Mat3 rotated_R = Mat3::Zero();

  /// The last few triangle pairs found crossing (by Collide or a CCD start
  /// check) for one pair of models. A first-crossing query of the same
  /// models tests them before traversing: under motion coherence one of
  /// them usually still crosses (a PDt query's start checks fall at a few
  /// recurring places: the query pose, the previous answer's contact space),
  /// and one crossing settles such a query. The answer is the same either
  /// way; only the work differs.
  static constexpr int kWitnesses = 16;
  std::array<std::pair<Index, Index>, kWitnesses> witnesses{};
  int witness_count = 0;
  int witness_next = 0;               ///< ring position of the next entry
  std::uint64_t witness_model_a = 0;  ///< GeometryModel::uid() of A, 0: none
  std::uint64_t witness_model_b = 0;
};

struct TrianglePair {
  Index a = -1;  ///< triangle of A
  Index b = -1;  ///< triangle of B
};

enum class Containment : std::uint8_t {
  kNone,      ///< neither contains the other (or containment not tested)
  kAInsideB,  ///< A lies wholly inside closed B, no surface crossing
  kBInsideA,  ///< B lies wholly inside closed A, no surface crossing
};

struct CollisionRequest {
  /// Collect every intersecting triangle pair (otherwise stop at the first).
  bool all_pairs = false;
  std::size_t max_pairs = 1u << 20;
  /// Count full containment of one closed mesh in the other as collision.
  bool containment = true;
};

struct CollisionResult {
  bool colliding = false;           ///< surfaces intersect or containment
  bool surfaces_intersect = false;  ///< some triangle pair intersects
  Containment containment = Containment::kNone;
  std::vector<TrianglePair> pairs;  ///< intersecting pairs (all_pairs only)
  bool pairs_truncated = false;     ///< max_pairs was reached
};

/// Do A and B intersect? Closed triangles: touching counts. With
/// request.containment, one closed mesh wholly inside another also counts
/// (open meshes cannot contain anything: documented limitation).
bool Collide(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
             const CollisionRequest& request, CollisionResult* result, QueryScratch* scratch);

/// Point-in-mesh for a closed model: the winding number along a ray (signed
/// crossings, so overlapping closed components count as inside), decided with
/// exact orientation predicates; an ambiguous ray through an edge or vertex is re-cast along
/// another direction). `p_M` in the model's mesh frame. For open models the
/// answer is the parity along one ray and carries no guarantee.
bool PointInside(const GeometryModel& model, const Vec3& p_M, QueryScratch* scratch);

/// Candidates are spaced about A's size / kEnclosedPointSpacing apart.
inline constexpr double kEnclosedPointSpacing = 32;

/// Points of B's surface (B's frame) that lie in A's inside cells
/// (GeometryModel::interior) with A at X_BA, at most out.size() of them,
/// spread over the part of B within A's bounding box: a vertex of B's
/// sampled component (GeometryModel::in_sampled_component) from each BVH
/// node of about A's size / kEnclosedPointSpacing. A at a pose that keeps
/// one of them in an inside cell collides with B for certain: B's surface
/// crosses A's, or that whole component lies inside A, and with it the
/// vertex a containment test looks at. Returns how many were written; none
/// when A has no inside cells (an open A, or one too thin for a cell).
int PointsEnclosedBy(const GeometryModel& A, const Pose& X_BA, const GeometryModel& B,
                     std::span<Vec3> out, QueryScratch* scratch);

/// A triangle near a point: its index in the mesh and its distance (m).
struct TriangleDistance {
  Index triangle = -1;
  double distance = 0;
};

/// Every triangle of `model` whose distance to the point `p_M` (mesh frame)
/// is at most `radius` (m), with that distance (ClosestPointOnTriangle, the
/// same number for the same input), in BVH leaf order. Clears `out` first.
/// Boxes farther than `radius` are skipped; no allocation once `out` and the
/// scratch's stack have grown.
void TrianglesWithinSphere(const GeometryModel& model, const Vec3& p_M, double radius,
                           std::vector<TriangleDistance>* out, QueryScratch* scratch);

enum class FeatureType : std::uint8_t {
  kVertexFace,  ///< vertex of A against a face of B
  kFaceVertex,  ///< face of A against a vertex of B
  kEdgeEdge,    ///< edge of A against an edge of B
};

/// A pair of features closer than a tolerance.
struct FeaturePair {
  FeatureType type = FeatureType::kVertexFace;
  Index a = -1;              ///< vertex, face or edge id in A (by type)
  Index b = -1;              ///< face, vertex or edge id in B (by type)
  Vec3 p_WA = Vec3::Zero();  ///< witness point on A's feature
  Vec3 p_WB = Vec3::Zero();  ///< witness point on B's feature
  /// Unit feature normal from B towards A: VF -> B's face normal; FV -> minus
  /// A's face normal; EE -> the edges' cross product, oriented so that it
  /// separates the two solids' wedges at the edges (in B's normal cone, its
  /// opposite in A's); at an edge whose faces are coplanar, that face's
  /// normal. Zero for an EE pair of two convex edges whose cross product
  /// separates the wedges in neither orientation: such a pair has no
  /// contact plane of its own (the vertex-face pairs around it do).
  Vec3 n_W = Vec3::Zero();
  double distance = 0;  ///< |p_WA - p_WB|
  /// (p_WA - p_WB) . n_W: negative when A's feature lies behind B's.
  double signed_distance = 0;
};

/// Edge-edge pairs count only when both closest points lie inside their
/// edges by more than this fraction of the edge length; at an endpoint the
/// contact is a vertex contact, described by vertex-face pairs.
inline constexpr double kEdgeInterior = 1e-9;

struct ProximityRequest {
  double tolerance = 0;  ///< report pairs with distance <= tolerance (m)
  std::size_t max_pairs = 4096;
  /// Skip edge-edge pairs whose edges are parallel to within this sine
  /// (their normal is undefined; the vertex-face pairs cover them).
  double parallel_sine = 1e-9;
};

struct ProximityResult {
  std::vector<FeaturePair> pairs;
  bool truncated = false;
};

/// Every vertex-face, face-vertex and edge-edge pair closer than the
/// tolerance, each reported once (feature ownership, see Mesh).
void Proximity(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
               const ProximityRequest& request, ProximityResult* result, QueryScratch* scratch);

struct DistanceResult {
  double distance = 0;  ///< 0 when the surfaces intersect
  Vec3 p_WA = Vec3::Zero();
  Vec3 p_WB = Vec3::Zero();
  Index triangle_a = -1;
  Index triangle_b = -1;
};

/// Distance between the surfaces of A and B. Stops early once the
/// distance is known to be below `lower_cutoff` (0 for the exact minimum).
double Distance(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
                DistanceResult* result, QueryScratch* scratch, double lower_cutoff = 0);

struct CcdRequest {
  /// After the time of impact is found, collect the feature pairs within
  /// this distance at the contact configuration (0: do not collect).
  double feature_tolerance = 0;
  std::size_t max_features = 4096;
  /// Rigid-motion CCD only: stop when the distance falls below this (m).
  double distance_tolerance = 1e-6;
  /// Rigid-motion CCD only: iteration cap of conservative advancement.
  int max_iterations = 200;
  /// Translational CCD only: also decide whether A already overlaps B at
  /// t = 0 (surfaces crossing or touching, or containment, exactly as
  /// Collide says), instead of requiring a free start. The check reuses the
  /// traversal, which meets every pair that can touch at t = 0 anyway, so it
  /// is much cheaper than a separate Collide. When the start overlaps, the
  /// query stops with `start_colliding` set and no time of impact.
  bool check_start = false;
  /// Translational CCD with check_start only: before the sweep, look for a
  /// triangle pair crossing at the start by a plain depth-first search
  /// (boxes on both bodies' face axes, no sweep keys, no contact events),
  /// giving up after a few hundred leaf pairs. For callers whose starts usually
  /// overlap (the PDt cold search's escape directions): one crossing drops
  /// such a start at a fraction of the sweep's cost. The answer is the same
  /// either way.
  bool start_crossing_first = false;
  /// Translational CCD only, with a feature tolerance: on a hit also list in
  /// CcdResult::near_pairs every triangle pair whose boxes, inflated by the
  /// feature tolerance, meet by the time of impact. Every triangle pair
  /// closer than feature_tolerance at the contact is among them, so a motion
  /// of the contact pose by less than that distance can only make those
  /// pairs cross (PDg checks its answers with it instead of a Collide).
  bool near_pairs = false;
};

struct CcdResult {
  bool hit = false;                   ///< contact happens for t in [0, 1]
  double toi = 1;                     ///< time of first contact in [0, 1] (1 when no hit)
  Pose X_WA_contact;                  ///< A's pose at toi
  std::vector<FeaturePair> features;  ///< pairs within feature_tolerance at toi
  bool features_truncated = false;
  int iterations = 0;  ///< conservative-advancement steps (rigid CCD)
  /// With CcdRequest::check_start: A overlaps B at t = 0 (then hit is false).
  bool start_colliding = false;
  std::vector<TrianglePair> near_pairs;  ///< with CcdRequest::near_pairs, on a hit
};

/// Exact translational CCD: A moves from X_WA0 by the world displacement
/// d_W over t in [0, 1], B fixed. The time of first contact of the closed
/// triangles (vertex-face, face-vertex and edge-edge events). If A already
/// touches B at t = 0 the answer is toi = 0. Precondition: A does not
/// overlap B at t = 0 (check with Collide); surfaces that already cross are
/// not an event and the answer would be meaningless (or set
/// request.check_start to have the query check it).
bool TranslationalCcd(const GeometryModel& A, const Pose& X_WA0, const Vec3& d_W,
                      const GeometryModel& B, const Pose& X_WB, const CcdRequest& request,
                      CcdResult* result, QueryScratch* scratch);

/// A's pose at parameter t of the rigid interpolating motion from X_WA0 to
/// X_WA1 that moves the centre of mass `p_AC` (in A's mesh frame) on a
/// straight line at constant speed while rotating about it at constant
/// angular velocity.
Pose InterpolateRigid(const Pose& X_WA0, const Pose& X_WA1, const Vec3& p_AC, double t);

/// CCD under that rigid motion by conservative advancement: advances while
/// the distance to B exceeds `distance_tolerance`, using the bound
/// |v(p)| <= |Δc| + θ r_max on any point's speed. The reported toi is a
/// safe time (A is collision-free on [0, toi)) at which the distance is at
/// most distance_tolerance; it under-estimates the exact time by at most
/// distance_tolerance / (|Δc| + θ r_max). If the cap is reached first, hit
/// stays true with the last safe time.
bool RigidCcd(const GeometryModel& A, const Pose& X_WA0, const Pose& X_WA1, const GeometryModel& B,
              const Pose& X_WB, const CcdRequest& request, CcdResult* result,
              QueryScratch* scratch);

}  // namespace hapticpd::pd
