// Conversions between the wire types (hapticpd/v1) and pd types, with the
// boundary validation every request goes through. Each function that can
// fail returns a grpc::Status whose message starts with the field's path
// (e.g. "header.spec.pose.orientation: ...") so a user can find the culprit.
#pragma once

#include <grpcpp/support/status.h>

#include <optional>
#include <string>
#include <string_view>

#include "hapticpd/v1/haptic.pb.h"
#include "hapticpd/v1/scene.pb.h"
#include "hapticpd/v1/types.pb.h"
#include "pd/material.h"
#include "pd/mesh.h"
#include "pd/types.h"

namespace hapticpd::server {

/// Quaternions whose norm is within this of 1 are normalised; others are
/// rejected (DESIGN.md: "unit quaternions").
inline constexpr double kQuaternionNormTolerance = 1e-3;

grpc::Status InvalidArgument(std::string_view field, std::string_view what);

/// Reads a finite vector.
grpc::Status FromProto(const v1::Vec3& v, std::string_view field, Vec3* out);
/// Reads a pose: finite translation, unit quaternion (normalised when within
/// kQuaternionNormTolerance). Absent parts mean origin / identity.
grpc::Status FromProto(const v1::Pose& p, std::string_view field, Pose* out);
/// Reads a material: every field finite and >= 0.
grpc::Status FromProto(const v1::Material& m, std::string_view field, pd::Material* out);
/// Reads a twist: finite components.
grpc::Status ValidateTwist(const v1::Twist& t, std::string_view field);

/// Builds a mesh from inline arrays. Fails with INVALID_ARGUMENT (naming the
/// field) on empty or malformed arrays and with RESOURCE_EXHAUSTED when over
/// `max_triangles`.
grpc::Status MeshFromInline(const v1::InlineMesh& m, std::string_view field,
                            std::size_t max_triangles, std::optional<pd::Mesh>* out);

/// Parses mesh file bytes (OBJ/STL/PLY/OFF) through pd::LoadMesh via a
/// private temporary file.
grpc::Status MeshFromBytes(const std::string& bytes, v1::MeshFormat format, std::string_view field,
                           std::size_t max_triangles, std::optional<pd::Mesh>* out);

/// Builds a built-in shape (pd::shapes::MakeShape).
grpc::Status MeshFromShape(const std::string& spec, std::string_view field,
                           std::size_t max_triangles, std::optional<pd::Mesh>* out);

/// Scene and body ids: 1-64 characters from [A-Za-z0-9_.-].
grpc::Status ValidateId(const std::string& id, std::string_view field);

void ToProto(const Vec3& v, v1::Vec3* out);
void ToProto(const Pose& p, v1::Pose* out);
void ToProto(const pd::Material& m, v1::Material* out);
void ToProto(const pd::Mesh& mesh, v1::InlineMesh* out);

/// Steady-clock nanoseconds (the server's timestamps).
std::int64_t NowNs();

}  // namespace hapticpd::server
