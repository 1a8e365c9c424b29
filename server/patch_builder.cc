#include "server/patch_builder.h"

#include <algorithm>
#include <cmath>

#include "pd/primitives.h"
#include "server/convert.h"

namespace hapticpd::server::internal {
namespace {

constexpr std::uint8_t kHeld = 1;
constexpr std::uint8_t kWanted = 2;

bool ByDistance(const pd::TriangleDistance& a, const pd::TriangleDistance& b) {
  return a.distance < b.distance || (a.distance == b.distance && a.triangle < b.triangle);
}

double TriangleDistance(const pd::Mesh& mesh, Index f, const Vec3& p_M) {
  const pd::Triangle& t = mesh.triangles()[f];
  const auto& V = mesh.vertices();
  return (pd::internal::ClosestPointOnTriangle(p_M, V[t[0]], V[t[1]], V[t[2]], nullptr) - p_M)
      .norm();
}

double CornerReach(const pd::GeometryModel& m) {
  const pd::Aabb& box = m.mesh().bounds();
  const Vec3 c = m.mass().p_MC;
  return (box.lo - c).cwiseAbs().cwiseMax((box.hi - c).cwiseAbs()).norm();
}

}  // namespace

PatchBuilder::PatchBuilder(pd::ModelPtr probe, std::size_t max_triangles_per_body,
                           double min_margin)
    : probe_(std::move(probe)),
      limit_(std::max<std::size_t>(1, max_triangles_per_body)),
      probe_radius_(probe_->radius_about_com()),
      probe_reach_(std::max(probe_radius_, CornerReach(*probe_))),
      min_margin_(min_margin > 0 ? min_margin
                                 : std::max(0.25 * probe_->mesh().bounding_radius(), 0.005)),
      max_margin_(std::max(min_margin_, kMaxMarginOverRadius * probe_radius_)) {}

void PatchBuilder::Observe(const Pose& X_WA, std::int64_t client_time_ns, std::int64_t rx_ns) {
  const Vec3 c_W = X_WA * probe_->mass().p_MC;
  if (have_prev_) {
    std::int64_t dt_ns = client_time_ns - prev_client_ns_;
    if (dt_ns <= 0) dt_ns = rx_ns - prev_rx_ns_;
    if (dt_ns > 0) {
      const double dt = static_cast<double>(dt_ns) * 1e-9;
      const double v = std::min((c_W - prev_c_W_).norm() / dt, kMaxSpeed);
      // A long gap says nothing of the speed in between: start over from
      // the latest sample rather than averaging across it.
      const double alpha = dt >= 1.0 ? 1.0 : 1.0 - std::exp(-dt / kSpeedTimeConstantS);
      if (std::isfinite(v)) speed_ += alpha * (v - speed_);
    }
  }
  have_prev_ = true;
  prev_c_W_ = c_W;
  prev_client_ns_ = client_time_ns;
  prev_rx_ns_ = rx_ns;
}

double PatchBuilder::Margin(double round_trip_s) const {
  const double horizon = round_trip_s + kPatchLatencyS;
  return std::min(std::max(min_margin_, 2.0 * speed_ * horizon), max_margin_);
}

PatchBuilder::BodyRegion PatchBuilder::RegionOf(const BodyState& b, std::int64_t now_ns,
                                                const Vec3& c_W, double R, double horizon_s) const {
  BodyRegion r;
  r.X_WB = PoseAt(b, now_ns);
  r.center_B = r.X_WB.Inverse() * c_W;
  r.radius = R;
  if (Moving(b)) {
    // The body's surface near the region moves at most at the speed of its
    // point at the region's centre plus the turn over the region's radius;
    // widen the cover by that motion until the next patch, within the same
    // bound as the probe's margin.
    const Vec3 v_c = b.v_W + b.w_W.cross(c_W - r.X_WB.t);
    const double reach =
        (v_c.norm() + b.w_W.norm() * R) * (horizon_s + static_cast<double>(kMovingResendNs) * 1e-9);
    r.radius += std::min(reach, max_margin_);
  }
  const pd::Mesh& mesh = b.model->mesh();
  const Vec3 sphere_W = r.X_WB * mesh.bounds().Center();
  r.reaches = (sphere_W - c_W).norm() - mesh.bounding_radius() <= r.radius;
  return r;
}

PatchBuilder::Held* PatchBuilder::FindHeld(const std::string& id) {
  for (Held& h : held_) {
    if (h.id == id) return &h;
  }
  return nullptr;
}

bool PatchBuilder::Due(const PatchProbe& probe, std::uint64_t scene_revision,
                       std::span<const PatchBody> bodies, const Vec3& c_W, double margin) const {
  if (sequence_ == 0 || scene_revision != last_revision_) return true;
  if ((c_W - last_center_W_).norm() > 0.25 * last_margin_) return true;
  if (margin > 1.25 * last_margin_) return true;
  const double R = probe_reach_ + margin;
  const double horizon = probe.round_trip_s + kPatchLatencyS;
  const bool resend = probe.now_ns - last_time_ns_ >= kMovingResendNs;
  for (const PatchBody& pb : bodies) {
    if (!Moving(*pb.body)) continue;
    bool held = false;
    for (const Held& h : held_) held = held || h.id == pb.body->id;
    if (held && resend) return true;
    if (!held && RegionOf(*pb.body, probe.now_ns, c_W, R, horizon).reaches) return true;
  }
  return false;
}

bool PatchBuilder::Build(const PatchProbe& probe, std::uint64_t scene_revision,
                         std::span<const PatchBody> bodies, v1::GeometryPatch* out) {
  const Vec3 c_W = probe.X_WA * probe_->mass().p_MC;
  const double margin = Margin(probe.round_trip_s);
  if (!Due(probe, scene_revision, bodies, c_W, margin)) return false;
  const double R = probe_reach_ + margin;
  const double horizon = probe.round_trip_s + kPatchLatencyS;
  out->Clear();
  out->set_sequence(++sequence_);
  out->set_scene_revision(scene_revision);
  out->set_server_time_ns(probe.now_ns);
  ToProto(c_W, out->mutable_center());
  out->set_radius(R);
  for (Held& h : held_) h.listed = false;
  for (const PatchBody& pb : bodies) {
    const BodyState& b = *pb.body;
    const BodyRegion region = RegionOf(b, probe.now_ns, c_W, R, horizon);
    if (!region.reaches) continue;
    Held* h = FindHeld(b.id);
    if (h == nullptr) {
      held_.emplace_back();
      h = &held_.back();
      h->id = b.id;
    }
    if (h->key != b.uid) {
      // New geometry under this id (or a body not held yet): the client
      // starts it from nothing.
      const pd::Mesh& mesh = b.model->mesh();
      h->key = b.uid;
      h->flags.assign(mesh.num_triangles(), 0);
      h->refs.assign(mesh.num_vertices(), 0);
      h->triangles.clear();
    }
    h->listed = true;
    CutBody(pb, region, h, out->add_bodies());
  }
  // Bodies no longer reaching the region, removed, or listed under another
  // id are forgotten.
  std::erase_if(held_, [&](const Held& h) {
    if (!h.listed) out->add_dropped_bodies(h.id);
    return !h.listed;
  });
  last_revision_ = scene_revision;
  last_time_ns_ = probe.now_ns;
  last_center_W_ = c_W;
  last_margin_ = margin;
  return true;
}

void PatchBuilder::CutBody(const PatchBody& pb, const BodyRegion& region, Held* h,
                           v1::BodyPatch* bp) {
  const BodyState& b = *pb.body;
  const pd::Mesh& mesh = b.model->mesh();
  const auto& V = mesh.vertices();
  const auto& T = mesh.triangles();
  bp->set_body_id(b.id);
  bp->set_body_key(h->key);
  bp->set_triangle_count(static_cast<std::uint32_t>(mesh.num_triangles()));
  bp->set_vertex_count(static_cast<std::uint32_t>(mesh.num_vertices()));
  ToProto(b.X_WB, bp->mutable_pose());
  ToProto(b.v_W, bp->mutable_velocity()->mutable_linear());
  ToProto(b.w_W, bp->mutable_velocity()->mutable_angular());
  bp->set_pose_time_ns(b.pose_time_ns);
  ToProto(*pb.material, bp->mutable_material());
  ToProto(region.center_B, bp->mutable_cover_center());

  // The cover: every triangle within the radius, or the nearest `limit_`
  // of them with the radius cut to just below the nearest one left out.
  pd::TrianglesWithinSphere(*b.model, region.center_B, region.radius, &candidates_, &scratch_);
  double cover = region.radius;
  if (candidates_.size() > limit_) {
    const auto nth = candidates_.begin() + static_cast<std::ptrdiff_t>(limit_);
    std::nth_element(candidates_.begin(), nth, candidates_.end(), ByDistance);
    const double nearest_out = std::min_element(nth, candidates_.end(), ByDistance)->distance;
    cover = nearest_out > 0 ? std::nextafter(nearest_out, 0.0) : 0.0;
    candidates_.resize(limit_);
    bp->set_truncated(true);
  }
  bp->set_cover_radius(cover);
  for (const pd::TriangleDistance& td : candidates_) h->flags[td.triangle] |= kWanted;

  // Held triangles outside the cover stay while within the hysteresis
  // radius and while the limit leaves room, nearest first.
  kept_.clear();
  dropped_.clear();
  const double keep_radius = kHysteresis * region.radius;
  for (const Index f : h->triangles) {
    if (h->flags[f] & kWanted) continue;
    const double d = TriangleDistance(mesh, f, region.center_B);
    if (d <= keep_radius) {
      kept_.push_back({f, d});
    } else {
      dropped_.push_back(f);
    }
  }
  const std::size_t room = limit_ - candidates_.size();
  if (kept_.size() > room) {
    std::sort(kept_.begin(), kept_.end(), ByDistance);
    for (std::size_t k = room; k < kept_.size(); ++k) dropped_.push_back(kept_[k].triangle);
    kept_.resize(room);
  }
  std::sort(dropped_.begin(), dropped_.end());
  for (const Index f : dropped_) {
    h->flags[f] = 0;
    for (const Index v : T[f]) --h->refs[v];
    bp->add_dropped_triangles(static_cast<std::uint32_t>(f));
  }

  // New triangles, with every vertex they use that no triangle held both
  // before and after this patch uses (the drops above released theirs).
  h->triangles.clear();
  for (const pd::TriangleDistance& td : kept_) h->triangles.push_back(td.triangle);
  std::sort(candidates_.begin(), candidates_.end(),
            [](const pd::TriangleDistance& a, const pd::TriangleDistance& b) {
              return a.triangle < b.triangle;
            });
  for (const pd::TriangleDistance& td : candidates_) {
    const Index f = td.triangle;
    h->triangles.push_back(f);
    if (h->flags[f] & kHeld) {
      h->flags[f] = kHeld;
      continue;
    }
    h->flags[f] = kHeld;
    for (const Index v : T[f]) {
      if (h->refs[v]++ == 0) {
        bp->add_vertex_indices(static_cast<std::uint32_t>(v));
        bp->add_vertices(V[v].x());
        bp->add_vertices(V[v].y());
        bp->add_vertices(V[v].z());
      }
    }
    bp->add_triangle_indices(static_cast<std::uint32_t>(f));
    for (const Index v : T[f]) bp->add_triangles(static_cast<std::uint32_t>(v));
  }
}

}  // namespace hapticpd::server::internal
