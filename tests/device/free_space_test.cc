// Free space feels free: with no contact row active and no body within 1 mm
// of the proxy, the force commanded to the device stays at most 0.05 N at
// handle speeds up to 0.3 m/s, and the torque at most 0.005 N m at 3 rad/s,
// on every simulated hand script (the handle's own damping is physics the
// user feels anyway and is not part of the command). Contact keeps its
// stiffness: the same press still pushes back. Both hold with late ticks
// and the catch-up ticks after them, with answers 100 ms late, and with
// stalls longer than the servo loop catches up. Simulated time (Rig), so it
// runs in every preset.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>

#include "device/coupling.h"
#include "tests/device/rig.h"

namespace hapticpd::device::testing {
namespace {

constexpr double kMaxFreeForce = 0.05;    // N
constexpr double kMaxFreeTorque = 0.005;  // N m
constexpr double kMaxSpeed = 0.3;         // m/s, the goal's handle speed
constexpr double kMaxAngSpeed = 3.0;      // rad/s

struct FreeStats {
  int judged = 0;        // no-contact ticks at speeds within the goal
  int fast = 0;          // of those, ticks above 0.2 m/s or 2 rad/s
  double max_force = 0;  // N over the judged ticks
  double max_torque = 0;
  double max_speed = 0;
  double max_ang_speed = 0;
};

/// Runs `script` with the probe's bottom `clearance` above the box; judges
/// the ticks where the proxy is more than 1 mm from the box (the cube
/// probe's bottom face above the top face; the box is wider than every
/// script's reach) and no row is active.
enum class Lateness { kNone, kCatchUp, kStall };

FreeStats RunScript(HandScript script, double clearance, double* max_contact_force = nullptr,
                    Lateness late = Lateness::kNone, int latency_ticks = 1) {
  ScriptParams p;
  p.script = script;
  p.X_DS = StartAbove(kBoxTop, clearance);
  // Lengths and durations that take each script's hand to about 0.3 m/s or
  // 3 rad/s (smooth steps peak at 1.5 times the mean speed).
  p.travel = 0.06;
  p.lateral = 0.12;
  p.angle = 1.2;
  p.radius = 0.06;
  switch (script) {
    case HandScript::kPress:
      p.duration_s = 0.7;
      break;
    case HandScript::kPlate:
      p.duration_s = 0.5;
      break;
    case HandScript::kLoop:
      p.duration_s = 3;
      break;
    default:
      p.duration_s = 2;
  }
  LocalPdOptions options;
  options.latency_ticks = latency_ticks;
  Rig rig(p, CubeProbe(), BoxScene(), ServoConfig{}, options);
  if (late == Lateness::kCatchUp) {
    // As ServoLoop::Run on a busy machine: every 37th tick fires 2.3 ms
    // late, and the ticks whose deadlines passed meanwhile fire right after
    // it, 20 us apart, until the schedule is caught up.
    rig.tick_time_ns = [](std::int64_t n, std::int64_t previous_ns) {
      const std::int64_t deadline = n * 1'000'000 + (n % 37 == 0 ? 2'300'000 : 0);
      return std::max(deadline, previous_ns + 20'000);
    };
  } else if (late == Lateness::kStall) {
    // A stall longer than Run catches up: every 97th tick fires 20 ms late
    // and Run resyncs, so no catch-up ticks follow and the schedule moves on
    // from there.
    rig.tick_time_ns = [](std::int64_t n, std::int64_t previous_ns) {
      return previous_ns + (n % 97 == 0 ? 20'000'000 : 1'000'000);
    };
  }
  FreeStats s;
  rig.Run(p.duration_s + 0.5, [&](const TickRecord& r) {
    const double speed = r.state.v_DH_D.norm();
    const double ang_speed = r.state.w_DH_D.norm();
    s.max_speed = std::max(s.max_speed, speed);
    s.max_ang_speed = std::max(s.max_ang_speed, ang_speed);
    // The cube probe's lowest corner above the top face.
    const Mat3& R = r.proxy.X_WP.R;
    const double reach = kProbeHalf * (std::abs(R(2, 0)) + std::abs(R(2, 1)) + std::abs(R(2, 2)));
    const double gap = r.proxy.X_WP.t.z() - reach - kBoxTop;
    const double F = r.F_cmd_W.force.norm();
    if (max_contact_force && r.ir.active_rows > 0) {
      *max_contact_force = std::max(*max_contact_force, F);
    }
    if (gap <= 1e-3 || r.ir.active_rows > 0) return;
    if (speed > kMaxSpeed || ang_speed > kMaxAngSpeed) return;
    ++s.judged;
    if (speed > 0.2 || ang_speed > 2.0) ++s.fast;
    s.max_force = std::max(s.max_force, F);
    s.max_torque = std::max(s.max_torque, r.F_cmd_W.torque.norm());
  });
  return s;
}

class FreeSpace : public ::testing::TestWithParam<HandScript> {};

TEST_P(FreeSpace, CommandedForceAndTorqueStayBelowWhatAHandNotices) {
  const FreeStats s = RunScript(GetParam(), 0.2);  // never near the box
  std::printf(
      "%s: %d free ticks (%d fast), max %.4f N, %.5f N m; handle up to %.2f m/s, %.2f rad/s\n",
      ToString(GetParam()), s.judged, s.fast, s.max_force, s.max_torque, s.max_speed,
      s.max_ang_speed);
  EXPECT_GT(s.judged, 400);
  EXPECT_LE(s.max_force, kMaxFreeForce);
  EXPECT_LE(s.max_torque, kMaxFreeTorque);
  if (GetParam() != HandScript::kHold) {
    EXPECT_GT(s.fast, 100) << "the script never moved fast enough to test the drag";
  }
}

/// Free space stays free with the given lateness (and answer latency) far
/// from the box, and with `near_too` near it, where the press still pushes
/// back.
void ExpectLatenessNotFelt(HandScript script, Lateness late, int latency_ticks, const char* what,
                           bool near_too) {
  const FreeStats s = RunScript(script, 0.2, nullptr, late, latency_ticks);
  std::printf("%s with %s: %d free ticks, max %.4f N, %.5f N m\n", ToString(script), what, s.judged,
              s.max_force, s.max_torque);
  EXPECT_GT(s.judged, 400);
  EXPECT_LE(s.max_force, kMaxFreeForce);
  EXPECT_LE(s.max_torque, kMaxFreeTorque);
  if (!near_too) return;
  double contact = 0;
  const FreeStats near = RunScript(script, 0.002, &contact, late, latency_ticks);
  EXPECT_LE(near.max_force, kMaxFreeForce);
  EXPECT_LE(near.max_torque, kMaxFreeTorque);
  if (script == HandScript::kPress || script == HandScript::kPlate) {
    EXPECT_GT(contact, 2.0) << "contact lost its stiffness";
  }
}

TEST_P(FreeSpace, LateTicksAndTheirCatchUpTicksAreNotFelt) {
  // The handle moves in real time: a late tick finds it two periods on, and
  // the catch-up ticks after it find it barely moved. A proxy stepped by a
  // fixed period lags, then overshoots, and the hand feels a tap each time.
  ExpectLatenessNotFelt(GetParam(), Lateness::kCatchUp, 1, "late ticks", true);
}

TEST_P(FreeSpace, LateTicksUnderALongLinkDelayAreNotFelt) {
  // 100 ms between a pose and its answer: a moving proxy is outside the
  // validity region of every answer it renders, so no answer says the space
  // around it is free. Late ticks and their catch-up ticks there must not be
  // felt either.
  // (Near the box, answers 100 ms late press the hand deep into it and push
  // the proxy back out later: not free space.)
  ExpectLatenessNotFelt(GetParam(), Lateness::kCatchUp, 100, "late ticks, 100 ms answers", false);
}

TEST_P(FreeSpace, AStallLongerThanTheCatchUpIsNotFelt) {
  // Beyond a few periods Run resyncs instead of catching up: the handle has
  // moved a whole stall on and no catch-up ticks follow.
  ExpectLatenessNotFelt(GetParam(), Lateness::kStall, 1, "20 ms stalls", true);
}

TEST_P(FreeSpace, NoContactTicksOfAScriptThatTouchesStayFreeAndContactStillPushes) {
  double contact = 0;
  // 2 mm above the top: the press and plate scripts go 6 cm down into it.
  const FreeStats s = RunScript(GetParam(), 0.002, &contact);
  std::printf("%s near the box: %d free ticks, max %.4f N; max contact force %.2f N\n",
              ToString(GetParam()), s.judged, s.max_force, contact);
  EXPECT_LE(s.max_force, kMaxFreeForce);
  EXPECT_LE(s.max_torque, kMaxFreeTorque);
  if (GetParam() == HandScript::kPress || GetParam() == HandScript::kPlate) {
    EXPECT_GT(contact, 2.0) << "contact lost its stiffness";
  }
}

INSTANTIATE_TEST_SUITE_P(Scripts, FreeSpace,
                         ::testing::Values(HandScript::kHold, HandScript::kPress,
                                           HandScript::kSlide, HandScript::kTwist,
                                           HandScript::kCircle, HandScript::kLoop,
                                           HandScript::kPlate),
                         [](const ::testing::TestParamInfo<HandScript>& info) {
                           return std::string(ToString(info.param));
                         });

TEST(ContactWeight, OneInsideAndAtTheSurfaceFallingToZeroAtTheMargin) {
  EXPECT_EQ(ContactWeight(0.002, 1e-3), 1.0);
  EXPECT_EQ(ContactWeight(0.0, 1e-3), 1.0);
  EXPECT_DOUBLE_EQ(ContactWeight(-0.5e-3, 1e-3), 0.5);
  EXPECT_EQ(ContactWeight(-1e-3, 1e-3), 0.0);
  EXPECT_EQ(ContactWeight(-std::numeric_limits<double>::infinity(), 1e-3), 0.0);
  EXPECT_EQ(ContactWeight(std::nan(""), 1e-3), 0.0);
}

}  // namespace
}  // namespace hapticpd::device::testing
