// Mass properties of a closed triangle mesh by the divergence theorem.
#pragma once

#include "pd/mesh.h"
#include "pd/types.h"

namespace hapticpd::pd {

/// Unit-density mass properties, all in the mesh frame M unless noted.
struct MassProperties {
  double volume = 0;                      ///< m^3; signed sum, positive for outward winding
  Vec3 p_MC = Vec3::Zero();               ///< centre of mass C
  Mat3 I_C_M = Mat3::Zero();              ///< inertia tensor about C, axes of M (kg m^2 per kg/m^3)
  Vec3 principal_moments = Vec3::Zero();  ///< Ixx <= Iyy <= Izz about C, unit density
  /// Body frame B: origin at C, axes along the principal axes (columns of
  /// X_MB.R, a proper rotation). The object norm is defined in this frame.
  Pose X_MB;
  /// True when the mesh is watertight; for open meshes the numbers come from
  /// the same formula but have no physical meaning (documented, flagged).
  bool exact = false;
  /// Set when the volume is too small relative to the bounding box to give a
  /// meaningful centre of mass (flat or open meshes); C then falls back to the
  /// area-weighted surface centroid and the inertia to that of the surface.
  bool surface_fallback = false;
  /// The measure the object norm averages over (m^3, or m^2 for a surface
  /// that encloses no volume): the volume, except for the surface fallback
  /// when the enclosed volume is not positive (open sheets, inward winding),
  /// where I_C_M is the shell's and this is its area, so that I_C_M /
  /// norm_measure is always a mean second moment (m^2).
  double norm_measure = 0;
};

/// Makes the principal axes of equal moments (within 1e-6 of the largest)
/// well defined: for three equal moments R becomes the identity (the file
/// frame's axes), for two the pair's axes are chosen in the plane normal to
/// the third, the first of them along the projection of the file axis least
/// aligned with that normal. R stays a proper rotation; well-separated axes
/// are kept. Used by ComputeMassProperties.
void CanonicalizeDegenerateAxes(const Vec3& moments, Mat3* R);

/// Computes volume, centre of mass and inertia (Mirtich / Eberly polyhedral
/// integrals). Meshes with a non-positive or negligible volume (open, flat,
/// inward-wound) fall back to surface (shell) properties, flagged in the
/// result, so a body frame always exists.
MassProperties ComputeMassProperties(const Mesh& mesh);

/// The object-norm weight matrix diag(4 Ixx/V, 4 Iyy/V, 4 Izz/V, 1, 1, 1)
/// for z = (v, t), with v the vector part of the unit quaternion and t the
/// translation, both in the body frame (ALGORITHMS.md): z^T M z is the mean
/// squared displacement of the body's points (V = norm_measure).
Mat6 ObjectNormMetric(const MassProperties& mp);

}  // namespace hapticpd::pd
