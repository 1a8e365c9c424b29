// Conversions between the wire types (hapticpd/v1) and pd types, with the
// boundary validation every request goes through: finiteness, the physical
// ranges of ranges.h, unit quaternions, the shape-spec grammar and triangle
// limits. Each function that can fail returns a grpc::Status whose message
// starts with the field's path (e.g. "header.spec.pose.orientation: ...") so
// a user can find the culprit. The scene-file parser (scene_file.h) uses the
// same checks, so a value accepted by one is accepted by the other.
#pragma once

#include <grpcpp/support/status.h>

#include <optional>
#include <string>
#include <string_view>

#include "hapticpd/v1/haptic.pb.h"
#include "hapticpd/v1/scene.pb.h"
#include "hapticpd/v1/types.pb.h"
#include "pd/geometry_model.h"
#include "pd/material.h"
#include "pd/mesh.h"
#include "pd/shapes.h"
#include "pd/types.h"
#include "proto/wire/ranges.h"

namespace hapticpd::wire {

grpc::Status InvalidArgument(std::string_view field, std::string_view what);

/// Reads a vector whose every component is in `range` (kCoordinate: a
/// position; messages name FIELD.x, .y, .z).
grpc::Status FromProto(const v1::Vec3& v, std::string_view field, Vec3* out,
                       const Range& range = kCoordinate);
/// Reads a pose: translation in kCoordinate, unit quaternion (the rule of
/// IsUnitQuaternion, pd/types.h: normalised when its norm is within 1e-3
/// of 1, refused otherwise). Absent parts mean origin /
/// identity.
grpc::Status FromProto(const v1::Pose& p, std::string_view field, Pose* out);
/// Reads a material: each field in its range (kStiffness,
/// kRotationalStiffness, kDamping, kFriction) and dynamic_friction <=
/// static_friction.
grpc::Status FromProto(const v1::Material& m, std::string_view field, pd::Material* out);
/// "" or "FIELD.sub: problem" for a material (FromProto's checks; the
/// scene-file parser reports the same problems).
std::string MaterialProblem(const v1::Material& m, std::string_view field);
/// Reads a twist: linear in kLinearVelocity, angular in kAngularVelocity
/// (per component).
grpc::Status ValidateTwist(const v1::Twist& t, std::string_view field);

/// A mesh's geometry against the ranges: every vertex coordinate in
/// kCoordinate and a bounding-box diagonal of at least kMinMeshExtent.
/// INVALID_ARGUMENT naming the field.
grpc::Status CheckMeshRanges(const pd::Mesh& mesh, std::string_view field);

/// Builds a mesh from inline arrays. Fails with INVALID_ARGUMENT (naming the
/// field) on empty or malformed arrays, a coordinate outside kCoordinate or
/// an extent below kMinMeshExtent, and with RESOURCE_EXHAUSTED when over
/// `max_triangles`.
grpc::Status MeshFromInline(const v1::InlineMesh& m, std::string_view field,
                            std::size_t max_triangles, std::optional<pd::Mesh>* out);

/// Parses mesh file bytes (OBJ/STL/PLY/OFF) through pd::LoadMesh via a
/// private temporary file, then CheckMeshRanges.
grpc::Status MeshFromBytes(const std::string& bytes, v1::MeshFormat format, std::string_view field,
                           std::size_t max_triangles, std::optional<pd::Mesh>* out);

/// Checks a shape spec without building it, in this order: the grammar
/// (pd::shapes::ParseShapeSpec), every length parameter in kShapeLength
/// (capsule half_length may be 0), the shape's reach within kCoordinate, the
/// builders' size rules, then the triangle count against `max_triangles`
/// (RESOURCE_EXHAUSTED "FIELD: N triangles exceed the server limit of M")
/// and against pd::shapes::kMaxShapeTriangles. Other failures are
/// INVALID_ARGUMENT "FIELD: shape spec 'SPEC': problem". `parsed` (optional)
/// receives the parsed spec.
grpc::Status CheckShapeSpec(const std::string& spec, std::string_view field,
                            std::size_t max_triangles, pd::shapes::ShapeSpec* parsed = nullptr);

/// CheckShapeSpec, then builds the shape (pd::shapes::MakeShape): nothing is
/// built for a spec over the limit.
grpc::Status MeshFromShape(const std::string& spec, std::string_view field,
                           std::size_t max_triangles, std::optional<pd::Mesh>* out);

/// Scene and body ids: 1-64 characters from [A-Za-z0-9_.-].
grpc::Status ValidateId(const std::string& id, std::string_view field);

/// The wire vector as it is, unchecked: for numbers a server sends its
/// clients or ones checked already (FromProto is the checked reading).
Vec3 FromProtoUnchecked(const v1::Vec3& v);
/// The wire pose as it is, unchecked: an absent orientation means identity,
/// a present quaternion is normalised but neither its norm nor its
/// finiteness is checked.
Pose FromProtoUnchecked(const v1::Pose& p);

void ToProto(const Vec3& v, v1::Vec3* out);
void ToProto(const Pose& p, v1::Pose* out);
void ToProto(const pd::Material& m, v1::Material* out);
void ToProto(const pd::Mesh& mesh, v1::InlineMesh* out);
/// What observers and a session's Welcome say of a model's mesh: counts,
/// watertight, convex, bounds, centre of mass, radius and diagnostics.
void ToProto(const pd::GeometryModel& model, v1::MeshInfo* out);

/// Steady-clock nanoseconds (the server's timestamps).
std::int64_t NowNs();

}  // namespace hapticpd::wire
