// The immutable per-mesh model shared by every query: the mesh, its BVH and
// its mass properties (MuJoCo's model/data split: this is the model).
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>

#include "pd/bvh.h"
#include "pd/convex.h"
#include "pd/interior_grid.h"
#include "pd/mass_properties.h"
#include "pd/mesh.h"

namespace hapticpd::pd {

class GeometryModel {
 public:
  explicit GeometryModel(Mesh mesh)
      : uid_(NextUid()),
        mesh_(std::move(mesh)),
        bvh_(mesh_),
        mass_(ComputeMassProperties(mesh_)),
        convex_(IsConvexMesh(mesh_)) {
    for (const Vec3& v : mesh_.vertices()) {
      radius_about_com_ = std::max(radius_about_com_, (v - mass_.p_MC).norm());
    }
    if (convex_) gauss_arcs_.emplace(mesh_);
    if (closed()) BuildInterior();
    PickSamplePoints();
  }

  const Mesh& mesh() const { return mesh_; }
  const Bvh& bvh() const { return bvh_; }
  const MassProperties& mass() const { return mass_; }
  /// Inside/outside is defined (point-in-mesh and containment work).
  bool closed() const { return mesh_.watertight(); }
  /// A convex polytope (closed, genus 0, no reflex edge).
  bool convex() const { return convex_; }
  /// The Gauss-map arc tree ConvexPdt needs, for a convex model; else null.
  const GaussArcTree* gauss_arcs() const { return gauss_arcs_ ? &*gauss_arcs_ : nullptr; }
  /// Largest distance of a vertex from the centre of mass (m): bounds the
  /// speed of any point under a rotation about the centre of mass.
  double radius_about_com() const { return radius_about_com_; }
  /// Unique per constructed model in this process (never reused, unlike an
  /// address): keys caches of derived data in query scratch.
  std::uint64_t uid() const { return uid_; }
  /// The cells wholly inside a closed model (empty for an open one, or
  /// where none fits between its walls).
  const InteriorGrid& interior() const { return interior_; }

  /// Up to kSamplePoints points spread over the surface component that
  /// holds triangle 0's first vertex (the vertex a containment test uses),
  /// in the mesh frame: vertices and points inside large triangles, picked
  /// farthest first. One of them inside a closed solid puts that whole
  /// component inside it unless the surfaces cross.
  const std::vector<Vec3>& sample_points() const { return sample_points_; }
  static constexpr int kSamplePoints = 64;
  /// Whether triangle f belongs to that component (the one sample_points()
  /// cover and a containment test looks at).
  bool in_sampled_component(Index f) const {
    return sampled_component_[static_cast<std::size_t>(f)];
  }

  /// Cells along the longest axis of InteriorGrid.
  static constexpr int kInteriorCells = 96;

 private:
  void BuildInterior();     // interior_grid.cc
  void PickSamplePoints();  // interior_grid.cc
  static std::uint64_t NextUid() {
    static std::atomic<std::uint64_t> next{1};
    return next.fetch_add(1, std::memory_order_relaxed);
  }
  std::uint64_t uid_;
  Mesh mesh_;
  Bvh bvh_;
  MassProperties mass_;
  double radius_about_com_ = 0;
  bool convex_ = false;
  std::optional<GaussArcTree> gauss_arcs_;
  InteriorGrid interior_;
  std::vector<Vec3> sample_points_;
  std::vector<bool> sampled_component_;  // per triangle
};

using ModelPtr = std::shared_ptr<const GeometryModel>;

inline ModelPtr MakeModel(Mesh mesh) {
  return std::make_shared<const GeometryModel>(std::move(mesh));
}

}  // namespace hapticpd::pd
