#include "pd/bvh.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace hapticpd::pd {
namespace {

constexpr int kBins = 16;

double HalfArea(const Aabb& b) {
  const Vec3 s = (b.hi - b.lo).cwiseMax(0.0);
  return s.x() * s.y() + s.y() * s.z() + s.z() * s.x();
}

}  // namespace

Bvh::Bvh(const Mesh& mesh) {
  const auto& V = mesh.vertices();
  const auto& T = mesh.triangles();
  const auto n = static_cast<Index>(T.size());
  std::vector<Aabb> boxes(n);
  std::vector<Vec3> centroids(n);
  for (Index f = 0; f < n; ++f) {
    for (int k = 0; k < 3; ++k) boxes[f].Extend(V[T[f][k]]);
    centroids[f] = boxes[f].Center();
  }
  prims_.resize(n);
  for (Index f = 0; f < n; ++f) prims_[f] = f;
  nodes_.reserve(2 * static_cast<std::size_t>(n));
  nodes_.emplace_back();

  struct Task {
    Index node, begin, end;
    int depth;
  };
  std::vector<Task> stack;
  stack.push_back({0, 0, n, 1});
  while (!stack.empty()) {
    const Task task = stack.back();
    stack.pop_back();
    depth_ = std::max(depth_, task.depth);
    Aabb box, cbox;
    for (Index i = task.begin; i < task.end; ++i) {
      box.Extend(boxes[prims_[i]].lo);
      box.Extend(boxes[prims_[i]].hi);
      cbox.Extend(centroids[prims_[i]]);
    }
    const Index count = task.end - task.begin;
    {
      BvhNode& node = nodes_[task.node];
      node.center = box.Center();
      node.half = box.HalfExtent().cwiseMax(0.0);
      node.size = task.end - task.begin;
    }
    if (count <= kMaxLeafSize) {
      nodes_[task.node].first = task.begin;
      nodes_[task.node].count = count;
      continue;
    }
    int axis = 0;
    cbox.Size().maxCoeff(&axis);
    const double lo = cbox.lo[axis];
    const double extent = cbox.hi[axis] - lo;
    Index mid = task.begin + count / 2;
    bool split_done = false;
    if (extent > 0) {
      // Binned surface-area heuristic along the widest centroid axis.
      std::array<Aabb, kBins> bin_box;
      std::array<Index, kBins> bin_count{};
      const double scale = kBins / extent;
      auto bin_of = [&](Index f) {
        return std::min(kBins - 1, static_cast<int>((centroids[f][axis] - lo) * scale));
      };
      for (Index i = task.begin; i < task.end; ++i) {
        const int b = bin_of(prims_[i]);
        ++bin_count[b];
        bin_box[b].Extend(boxes[prims_[i]].lo);
        bin_box[b].Extend(boxes[prims_[i]].hi);
      }
      std::array<double, kBins> right_cost{};
      Aabb acc;
      Index acc_count = 0;
      for (int b = kBins - 1; b > 0; --b) {
        acc.Extend(bin_box[b].lo);
        acc.Extend(bin_box[b].hi);
        acc_count += bin_count[b];
        right_cost[b] = acc_count > 0 ? HalfArea(acc) * acc_count : 0.0;
      }
      acc = Aabb{};
      acc_count = 0;
      double best = std::numeric_limits<double>::infinity();
      int best_bin = -1;
      for (int b = 0; b < kBins - 1; ++b) {
        acc.Extend(bin_box[b].lo);
        acc.Extend(bin_box[b].hi);
        acc_count += bin_count[b];
        if (acc_count == 0 || acc_count == count) continue;
        const double cost = HalfArea(acc) * acc_count + right_cost[b + 1];
        if (cost < best) {
          best = cost;
          best_bin = b;
        }
      }
      if (best_bin >= 0) {
        auto* it = std::partition(prims_.data() + task.begin, prims_.data() + task.end,
                                  [&](Index f) { return bin_of(f) <= best_bin; });
        mid = static_cast<Index>(it - prims_.data());
        split_done = mid > task.begin && mid < task.end;
      }
    }
    if (!split_done) {
      // All centroids in one bin: median split keeps the tree balanced.
      mid = task.begin + count / 2;
      std::nth_element(prims_.data() + task.begin, prims_.data() + mid, prims_.data() + task.end,
                       [&](Index a, Index b) { return centroids[a][axis] < centroids[b][axis]; });
    }
    const auto left = static_cast<Index>(nodes_.size());
    nodes_.emplace_back();
    nodes_.emplace_back();
    nodes_[task.node].first = left;
    nodes_[task.node].count = 0;
    stack.push_back({left + 1, mid, task.end, task.depth + 1});
    stack.push_back({left, task.begin, mid, task.depth + 1});
  }
  nodes_.shrink_to_fit();
}

namespace internal {

BoxFrame::BoxFrame(const Pose& X_BA) : R(X_BA.R), t(X_BA.t) { absR = R.cwiseAbs().array() + 1e-12; }

bool BoxesOverlap(const BoxFrame& f, const BvhNode& a, const BvhNode& b, double margin,
                  const Vec3& sweep_B) {
  // Box a's centre in B's frame, relative to box b's centre.
  const Vec3 T = f.R * a.center + f.t - b.center;
  const Vec3& ea = a.half;
  const Vec3& eb = b.half;
  const Mat3& R = f.R;
  const Mat3& AR = f.absR;
  // Projection of the sweep segment [0, sweep] onto axis L widens the
  // interval of box a by |sweep . L| on one side; testing the gap against the
  // centre offset moved half-way, with half the sweep added to the radius,
  // is exact for the segment's contribution.
  const Vec3 hs = 0.5 * sweep_B;
  const Vec3 Ts = T + hs;
  // Axes of B (world-aligned in B's frame).
  for (int i = 0; i < 3; ++i) {
    const double ra = AR.row(i).dot(ea) + std::abs(hs[i]);
    if (std::abs(Ts[i]) > ra + eb[i] + margin) return false;
  }
  // Axes of A: column j of R, in B's frame.
  for (int j = 0; j < 3; ++j) {
    const double rb = AR.col(j).dot(eb);
    const double proj = R.col(j).dot(Ts);
    const double ra = ea[j] + std::abs(R.col(j).dot(hs));
    if (std::abs(proj) > ra + rb + margin) return false;
  }
  // Cross axes e_i(B) x a_j(A).
  for (int i = 0; i < 3; ++i) {
    const int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
    for (int j = 0; j < 3; ++j) {
      const int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      // L = e_i x R.col(j); its components: L[i1] = -R(i2,j), L[i2] = R(i1,j).
      const double proj = Ts[i2] * R(i1, j) - Ts[i1] * R(i2, j);
      const double rb = eb[i1] * AR(i2, j) + eb[i2] * AR(i1, j);
      const double ra =
          ea[j1] * AR(i, j2) + ea[j2] * AR(i, j1) + std::abs(hs[i2] * R(i1, j) - hs[i1] * R(i2, j));
      // |L| <= 1; comparing unnormalised projections against unnormalised
      // radii and a margin scaled by |L| keeps the test conservative.
      const double len = std::sqrt(R(i1, j) * R(i1, j) + R(i2, j) * R(i2, j));
      if (std::abs(proj) > ra + rb + margin * len + 1e-12 * (ra + rb)) return false;
    }
  }
  return true;
}

SweptBoxFrame::SweptBoxFrame(const Pose& X_BA, const Vec3& sweep_B) : f(X_BA), sweep(sweep_B) {
  const Mat3& R = f.R;
  for (int i = 0; i < 3; ++i) v[i] = sweep_B[i];
  for (int j = 0; j < 3; ++j) v[3 + j] = R.col(j).dot(sweep_B);
  for (int k = 0; k < 6; ++k) {
    inv[k] = v[k] != 0 ? 1.0 / v[k] : 0.0;
    sgn[k] = v[k] < 0 ? -1.0 : 1.0;
  }
  for (int i = 0; i < 3; ++i) {
    t[i] = f.t[i];
    rtt[i] = R.col(i).dot(f.t);
    for (int j = 0; j < 3; ++j) {
      r[i][j] = f.R(i, j);
      ar[i][j] = f.absR(i, j);
    }
  }
}

bool BoxesSweptEnter(const SweptBoxFrame& sf, const BvhNode& a, const BvhNode& b, double t_max,
                     double* t_enter, double margin) {
  return BoxesSweptEnter(sf, a, RotateBoxA(sf, a), b, RotateBoxB(sf, b), t_max, t_enter, margin);
}

double BoxesDistanceLowerBound(const BoxFrame& f, const BvhNode& a, const BvhNode& b) {
  // The gap along any unit axis is a lower bound on the distance; take the
  // best of the 15 separating axes (face axes alone are weak for boxes at an
  // angle, and distance pruning lives on this bound).
  const Vec3 T = f.R * a.center + f.t - b.center;
  const Mat3& R = f.R;
  const Mat3& AR = f.absR;
  const Vec3& ea = a.half;
  const Vec3& eb = b.half;
  double best = 0;
  for (int i = 0; i < 3; ++i) {
    best = std::max(best, std::abs(T[i]) - AR.row(i).dot(ea) - eb[i]);
  }
  for (int j = 0; j < 3; ++j) {
    best = std::max(best, std::abs(R.col(j).dot(T)) - ea[j] - AR.col(j).dot(eb));
  }
  for (int i = 0; i < 3; ++i) {
    const int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
    for (int j = 0; j < 3; ++j) {
      const int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      const double len2 = R(i1, j) * R(i1, j) + R(i2, j) * R(i2, j);
      if (len2 < 1e-12) continue;  // nearly parallel axes: no usable direction
      const double proj = T[i2] * R(i1, j) - T[i1] * R(i2, j);
      const double rb = eb[i1] * AR(i2, j) + eb[i2] * AR(i1, j);
      const double ra = ea[j1] * AR(i, j2) + ea[j2] * AR(i, j1);
      const double gap = std::abs(proj) - ra - rb;
      if (gap > 0) best = std::max(best, gap / std::sqrt(len2));
    }
  }
  // absR carries +1e-12 per entry, so radii are slight over-estimates and
  // the gaps slight under-estimates: still a valid lower bound.
  return best;
}

}  // namespace internal
}  // namespace hapticpd::pd
