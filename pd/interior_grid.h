#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "pd/types.h"

namespace hapticpd::pd {

class Mesh;

/// Cells of a regular grid over a closed mesh that lie wholly inside it: no
/// surface passes through such a cell, and its points have a nonzero winding
/// number (PointInside holds for each of them). A point in one of these
/// cells is inside the solid, so a probe with a point of its surface there
/// collides with it (its surface crosses the solid's, or it lies inside
/// it); a cold query drops a start on that cheap test before the exact one
/// (PenetrationRequest::cold_interior_cull).
///
/// Surface cells are found conservatively (each triangle by separating axes
/// against the cells of its box that lie near its plane, each cell inflated
/// for round-off); the other cells split into connected components, the one
/// reaching the grid's border is outside, and each enclosed component is
/// classified by one PointInside of its first cell's centre (an enclosed
/// void of a hollow solid stays out).
class InteriorGrid {
 public:
  InteriorGrid() = default;
  /// `inside(p)`: the model's PointInside, for the enclosed components.
  /// `max_cells` is the cell count along the box's longest axis.
  template <typename InsideFn>
  InteriorGrid(const Mesh& mesh, int max_cells, InsideFn&& inside) {
    Build(mesh, max_cells);
    Classify(inside);
  }

  /// At most this many enclosed components are classified (PointInside
  /// each); the rest are left out, so a mesh of very many small enclosed
  /// pockets stays cheap to build.
  static constexpr int kMaxInsideTests = 4096;

  bool empty() const { return inside_count_ == 0; }
  int inside_cells() const { return inside_count_; }
  /// Whether p (mesh frame) lies in an inside cell.
  bool Inside(const Vec3& p) const {
    const Vec3 q = (p - lo_) * inv_h_;
    // In range before the casts (NaN and infinities fail here too).
    if (!((q.array() >= 0).all() && (q.array() < extent_cells_.array()).all())) return false;
    const auto i = static_cast<std::int64_t>(q.x());
    const auto j = static_cast<std::int64_t>(q.y());
    const auto k = static_cast<std::int64_t>(q.z());
    return cells_[static_cast<std::size_t>((k * n_[1] + j) * n_[0] + i)] == kInside;
  }
  /// Whether one of the points, shifted by `shift`, lies in an inside cell.
  bool AnyInside(std::span<const Vec3> points, const Vec3& shift) const {
    for (const Vec3& p : points) {
      if (Inside(p + shift)) return true;
    }
    return false;
  }

 private:
  enum : std::uint8_t { kUnknown = 0, kSurface = 1, kOutside = 2, kInside = 3, kVoid = 4 };
  void Build(const Mesh& mesh, int max_cells);
  // Labels the enclosed components; `inside` decides each one.
  template <typename InsideFn>
  void Classify(InsideFn&& inside) {
    std::vector<std::int64_t> todo;
    int tests = 0;
    for (std::size_t c = 0; c < cells_.size(); ++c) {
      if (cells_[c] != kUnknown) continue;
      const auto ci = static_cast<std::int64_t>(c);
      const Vec3 centre = lo_ + h_ * Vec3(static_cast<double>(ci % n_[0]) + 0.5,
                                          static_cast<double>((ci / n_[0]) % n_[1]) + 0.5,
                                          static_cast<double>(ci / (n_[0] * n_[1])) + 0.5);
      const bool in = ++tests <= kMaxInsideTests && inside(centre);
      Fill(ci, in ? kInside : kVoid, &todo);
    }
  }
  // Labels the component of unknown cells holding `start`.
  void Fill(std::int64_t start, std::uint8_t label, std::vector<std::int64_t>* todo);

  Vec3 lo_ = Vec3::Zero();
  double h_ = 1, inv_h_ = 1;
  std::int64_t n_[3] = {0, 0, 0};
  Vec3 extent_cells_ = Vec3::Zero();  // n_ as doubles
  std::vector<std::uint8_t> cells_;
  int inside_count_ = 0;
};

}  // namespace hapticpd::pd
