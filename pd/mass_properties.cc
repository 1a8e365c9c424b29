#include "pd/mass_properties.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

namespace hapticpd::pd {
namespace {

// Second moments of a solid or of a shell, accumulated about the origin of M.
struct Moments {
  double m = 0;  // volume (solid) or area (shell)
  Vec3 first = Vec3::Zero();
  Mat3 second = Mat3::Zero();  // integral of x x^T
};

// Solid integrals over signed tetrahedra (origin, a, b, c). For a tetrahedron
// with vertices 0, a, b, c and determinant D = a·(b×c):
//   V = D/6, ∫x = D/24 (a+b+c), ∫x x^T = D/120 (S S^T + a a^T + b b^T + c c^T)
// with S = a+b+c. Exact for any closed, consistently wound mesh.
Moments SolidMoments(const Mesh& mesh, const Vec3& origin) {
  Moments r;
  const auto& V = mesh.vertices();
  for (const Triangle& t : mesh.triangles()) {
    const Vec3 a = V[t[0]] - origin, b = V[t[1]] - origin, c = V[t[2]] - origin;
    const double d = a.dot(b.cross(c));
    const Vec3 s = a + b + c;
    r.m += d / 6.0;
    r.first += d / 24.0 * s;
    r.second +=
        d / 120.0 * (s * s.transpose() + a * a.transpose() + b * b.transpose() + c * c.transpose());
  }
  return r;
}

// Thin-shell integrals over the triangles' area (for open or flat meshes).
Moments ShellMoments(const Mesh& mesh, const Vec3& origin) {
  Moments r;
  const auto& V = mesh.vertices();
  for (const Triangle& t : mesh.triangles()) {
    const Vec3 a = V[t[0]] - origin, b = V[t[1]] - origin, c = V[t[2]] - origin;
    const double area = 0.5 * (b - a).cross(c - a).norm();
    const Vec3 s = a + b + c;
    r.m += area;
    r.first += area / 3.0 * s;
    r.second += area / 12.0 *
                (s * s.transpose() + a * a.transpose() + b * b.transpose() + c * c.transpose());
  }
  return r;
}

// The unit vector of the plane normal to the unit vector e that lies closest
// to one of the file frame's axes (the axis least aligned with e; ties to
// the lower index).
Vec3 FileAxisInPlane(const Vec3& e) {
  int k = 0;
  for (int i = 1; i < 3; ++i) {
    if (std::abs(e[i]) < std::abs(e[k])) k = i;
  }
  const Vec3 axis = Vec3::Unit(k);
  return (axis - axis.dot(e) * e).normalized();
}

}  // namespace

void CanonicalizeDegenerateAxes(const Vec3& moments, Mat3* R) {
  // Moments within this fraction of the largest are equal: the principal
  // axes of their eigenspace are whatever the eigensolver returns, and a
  // change of the mesh far below float precision (a 1e-9 stretch along a
  // cube's diagonal) turns them by tens of degrees. The object norm is
  // isotropic in such a subspace to within the same fraction, so any basis
  // of it serves; the file frame's axes make the choice stable.
  constexpr double kTolerance = 1e-6;
  const double tol = kTolerance * std::max(std::abs(moments[2]), 1e-300);
  const double gap01 = moments[1] - moments[0];
  const double gap12 = moments[2] - moments[1];
  if (moments[2] - moments[0] <= tol) {
    *R = Mat3::Identity();  // sphere-like: every axis is principal
  } else if (gap01 <= tol && gap01 <= gap12) {
    // Axis 2 is well defined; choose 0 and 1 in the plane normal to it.
    const Vec3 e2 = R->col(2);
    const Vec3 e0 = FileAxisInPlane(e2);
    R->col(0) = e0;
    R->col(1) = e2.cross(e0);
  } else if (gap12 <= tol) {
    const Vec3 e0 = R->col(0);
    const Vec3 e1 = FileAxisInPlane(e0);
    R->col(1) = e1;
    R->col(2) = e0.cross(e1);
  }
}

MassProperties ComputeMassProperties(const Mesh& mesh) {
  MassProperties mp;
  // Integrate about the bounds' centre to keep cancellation small for models
  // far from the origin.
  const Vec3 o = mesh.bounds().Center();
  Moments mom = SolidMoments(mesh, o);
  const double box_volume = std::max(mesh.bounds().Size().prod(), 1e-300);
  const double diag = mesh.size();
  // A meaningful solid encloses at least a tiny fraction of its bounding
  // box; flat and open surfaces fall back to shell properties.
  const bool solid_ok = mom.m > 1e-9 * std::max(box_volume, diag * diag * diag * 1e-6);
  if (!solid_ok) {
    mom = ShellMoments(mesh, o);
    mp.surface_fallback = true;
  }
  mp.exact = mesh.watertight() && !mp.surface_fallback;
  mp.volume = mp.surface_fallback ? std::max(SolidMoments(mesh, o).m, 0.0) : mom.m;
  const double m = std::max(mom.m, 1e-300);
  const Vec3 c_rel = mom.first / m;
  mp.p_MC = o + c_rel;
  // Second moment about C, then inertia I = tr(S) Id - S.
  const Mat3 S = mom.second - m * c_rel * c_rel.transpose();
  mp.I_C_M = S.trace() * Mat3::Identity() - S;
  // For shells, scale the inertia to the unit-density value the enclosed
  // volume would have so the object norm stays in units of length^2.
  if (mp.surface_fallback && mp.volume > 0) mp.I_C_M *= mp.volume / m;
  // With no positive enclosed volume the shell inertia stays unscaled and the
  // norm averages over the area (dividing by the zero volume gave an infinite
  // rotational weight).
  mp.norm_measure = mp.surface_fallback && !(mp.volume > 0) ? m : mp.volume;

  Eigen::SelfAdjointEigenSolver<Mat3> es(0.5 * (mp.I_C_M + mp.I_C_M.transpose()));
  mp.principal_moments = es.eigenvalues();  // ascending
  Mat3 R = es.eigenvectors();
  if (R.determinant() < 0) R.col(2) = -R.col(2);
  mp.X_MB = Pose{R, mp.p_MC};
  CanonicalizeDegenerateAxes(mp.principal_moments, &mp.X_MB.R);
  return mp;
}

Mat6 ObjectNormMetric(const MassProperties& mp) {
  Mat6 M = Mat6::Identity();
  const double v = std::max(mp.norm_measure, 1e-300);
  for (int i = 0; i < 3; ++i) M(i, i) = 4.0 * mp.principal_moments[i] / v;
  return M;
}

}  // namespace hapticpd::pd
