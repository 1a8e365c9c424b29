// Local geometry patches (model-mediated rendering): what triangles of the
// bodies near the probe a device session's client holds, and the deltas
// (v1::GeometryPatch) that keep that true as the probe and the bodies move.
//
// The region is a sphere of W about the probe's centre of mass, of radius
// the probe's reach (the farthest corner of its mesh bounding box from its
// centre of mass: the client tests those corners, device/local_model.h)
// plus a margin that grows with the probe's speed times the time a patch
// takes to reach the client. For
// every body reaching into it, the client holds every triangle within the
// body's cover (a sphere of the body's mesh frame: the region, seen from the
// body, widened by the body's own motion until the next patch), up to a
// per-body limit that keeps the nearest triangles and shrinks the cover.
//
// One builder per device session, on the session's worker thread; no
// network, so the tests drive it directly. Scratch vectors are kept across
// patches.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "hapticpd/v1/haptic.pb.h"
#include "pd/geometry_model.h"
#include "pd/material.h"
#include "pd/queries.h"
#include "server/scene.h"

namespace hapticpd::server::internal {

/// A body of the session's scene as a patch sees it.
struct PatchBody {
  const BodyState* body = nullptr;         ///< id, uid (the key), model, motion
  const pd::Material* material = nullptr;  ///< the session's effective material
};

/// The probe at the answer a patch goes with.
struct PatchProbe {
  Pose X_WA;                ///< probe mesh frame in W
  std::int64_t now_ns = 0;  ///< server steady clock the bodies' poses are taken at
  double round_trip_s = 0;  ///< the client's reported round trip (0: not known)
};

class PatchBuilder {
 public:
  /// Fastest probe speed (m/s) the margin is sized for: a client's jittery
  /// or hostile timestamps cannot blow the region up beyond this.
  static constexpr double kMaxSpeed = 2.0;
  /// The margin never exceeds this many probe radii (about the centre of
  /// mass), nor the session's min_margin when that is larger.
  static constexpr double kMaxMarginOverRadius = 4.0;
  /// Held triangles stay held until they are this many region radii away
  /// (or the limit needs their room): a probe going back and forth does not
  /// make the client drop and receive the same triangles again.
  static constexpr double kHysteresis = 1.5;
  /// A listed body that moves is re-sent at least this often (ns), so its
  /// cover follows it.
  static constexpr std::int64_t kMovingResendNs = 50'000'000;
  /// Seconds, beyond the round trip, until a patch cut now is in use: the
  /// next patch is cut when the probe has used a quarter of the margin.
  static constexpr double kPatchLatencyS = 0.02;
  /// Time constant (s) of the probe speed's exponential smoothing.
  static constexpr double kSpeedTimeConstantS = 0.03;

  /// `max_triangles_per_body` >= 1; `min_margin` in m, 0: the default (a
  /// quarter of the probe's bounding radius, at least 5 mm).
  PatchBuilder(pd::ModelPtr probe, std::size_t max_triangles_per_body, double min_margin);

  /// Feeds the speed estimate with a probe pose: the client's sample time
  /// (`client_time_ns`) when it advances, else the server's receive time.
  void Observe(const Pose& X_WA, std::int64_t client_time_ns, std::int64_t rx_ns);

  /// Cuts the next patch into `out` when one is due: the first call, a new
  /// scene revision, the probe's centre of mass a quarter margin from the
  /// last region's centre, a faster probe needing a wider region, a moving
  /// body entering the region or due for its periodic re-send. Returns false
  /// (and leaves `out` alone) otherwise. The caller sends every patch, in
  /// order: each is a delta on the ones before.
  bool Build(const PatchProbe& probe, std::uint64_t scene_revision,
             std::span<const PatchBody> bodies, v1::GeometryPatch* out);

  double speed() const { return speed_; }            ///< m/s, smoothed
  double min_margin() const { return min_margin_; }  ///< m, after the default
  std::size_t limit() const { return limit_; }
  /// The margin (m) and region radius (m) a patch cut for this round trip
  /// would use now.
  double Margin(double round_trip_s) const;
  double RegionRadius(double round_trip_s) const { return probe_reach_ + Margin(round_trip_s); }
  /// m, the farthest corner of the probe's mesh bounding box from its centre
  /// of mass: the client holds the patch to cover the probe when those
  /// corners lie in the region, so the region's radius starts from here
  /// (the mesh's radius about the centre of mass is up to sqrt(3) shorter).
  double probe_reach() const { return probe_reach_; }

 private:
  /// What the client holds of one body.
  struct Held {
    std::string id;
    std::uint64_t key = 0;
    std::vector<std::uint8_t> flags;  // per triangle: kHeld, kWanted
    std::vector<std::uint32_t> refs;  // per vertex: held triangles using it
    std::vector<Index> triangles;     // the held ones
    bool listed = false;              // in the patch being cut
  };
  /// The region as seen from one body.
  struct BodyRegion {
    Pose X_WB;      // at the patch's time
    Vec3 center_B;  // the region's centre, body mesh frame
    double radius;  // the body's cover radius before the limit (m)
    bool reaches;   // the body's bounding sphere reaches it
  };

  BodyRegion RegionOf(const BodyState& b, std::int64_t now_ns, const Vec3& c_W, double R,
                      double horizon_s) const;
  bool Due(const PatchProbe& probe, std::uint64_t scene_revision, std::span<const PatchBody> bodies,
           const Vec3& c_W, double margin) const;
  Held* FindHeld(const std::string& id);
  /// Brings `h` to the body's cover and appends the delta to `bp`.
  void CutBody(const PatchBody& pb, const BodyRegion& region, Held* h, v1::BodyPatch* bp);

  const pd::ModelPtr probe_;
  const std::size_t limit_;
  const double probe_radius_;  // about the centre of mass
  const double probe_reach_;   // bounding-box corners about the centre of mass
  const double min_margin_;
  const double max_margin_;

  // Speed estimate.
  bool have_prev_ = false;
  Vec3 prev_c_W_ = Vec3::Zero();
  std::int64_t prev_client_ns_ = 0;
  std::int64_t prev_rx_ns_ = 0;
  double speed_ = 0;

  // The last patch.
  std::uint64_t sequence_ = 0;
  std::uint64_t last_revision_ = 0;
  std::int64_t last_time_ns_ = 0;
  Vec3 last_center_W_ = Vec3::Zero();
  double last_margin_ = 0;

  std::vector<Held> held_;
  // Scratch.
  pd::QueryScratch scratch_;
  std::vector<pd::TriangleDistance> candidates_;
  std::vector<pd::TriangleDistance> kept_;
  std::vector<Index> dropped_;
};

}  // namespace hapticpd::server::internal
