// Physical ranges of every number a client sends (RPCs and scene files
// alike). A value outside its range is rejected with INVALID_ARGUMENT naming
// the field and the range; nothing is clamped. The ranges are wide enough for
// any haptic scene (a 10 km world, micrometre to kilometre shapes, stiffness
// up to 1e7 N/m) and narrow enough that no product of two of them overflows
// a double or loses the precision PD needs.
#pragma once

#include <grpcpp/support/status.h>

#include <string>
#include <string_view>
#include <vector>

namespace hapticpd::wire {

/// A closed interval [lo, hi] in `unit`. `zero_means_unset`: 0 is accepted
/// too and means "not given" (e.g. a probe mass of 0).
struct Range {
  double lo;
  double hi;
  const char* unit;  ///< "m", "N/m", "" for a pure number
  bool zero_means_unset = false;
};

// Lengths and positions.
inline constexpr Range kCoordinate{-1e4, 1e4, "m"};   ///< positions, mesh vertices (10 km world)
inline constexpr Range kShapeLength{1e-6, 1e4, "m"};  ///< a procedural shape's size parameter
inline constexpr double kMinMeshExtent = 1e-6;        ///< m, a mesh's bounding-box diagonal
// Velocities (per component, W).
inline constexpr Range kLinearVelocity{-100, 100, "m/s"};
inline constexpr Range kAngularVelocity{-1e3, 1e3, "rad/s"};
// Materials.
inline constexpr Range kStiffness{0, 1e7, "N/m"};
inline constexpr Range kRotationalStiffness{0, 1e5, "N m/rad"};
inline constexpr Range kDamping{0, 1e5, "N s/m"};
inline constexpr Range kFriction{0, 10, ""};  ///< static and dynamic; dynamic <= static
// Scene configuration.
inline constexpr Range kGravity{-100, 100, "m/s^2"};  ///< per component
inline constexpr Range kTextureAmplitude{0, 10, "N"};
inline constexpr Range kTextureFrequency{0, 500, "Hz"};  ///< above 500 Hz a 1 kHz loop aliases
inline constexpr Range kProbeMass{1e-6, 1e3, "kg", true};
inline constexpr Range kProbeInertia{1e-12, 1e3, "kg m^2", true};
// Rates.
inline constexpr Range kMaxRateHz{0, 1e5, "Hz"};    ///< Hello.max_rate_hz; 0 = unlimited
inline constexpr Range kWatchRateHz{0, 1e3, "Hz"};  ///< WatchRequest.rate_hz; 0 = 60
// Device telemetry (CoupleRequest.telemetry): what the device reports.
inline constexpr Range kTelemetryRateHz{0, 1e6, "Hz"};   ///< servo, update and local model rates
inline constexpr Range kTelemetryMs{0, 1e9, "ms"};       ///< round trip, IR age, emulated delay
inline constexpr Range kLossFraction{0, 1, ""};          ///< emulated loss
inline constexpr Range kTelemetryForce{0, 1e6, "N"};     ///< a commanded force magnitude
inline constexpr Range kTelemetryTorque{0, 1e6, "N m"};  ///< a commanded torque magnitude
/// Most commanded samples one DeviceTelemetry may carry (4 s at 1 kHz).
inline constexpr int kMaxTelemetrySamples = 4096;

/// A range with the name of its constant, for documentation tables.
struct NamedRange {
  const char* name;  ///< e.g. "kStiffness"
  Range range;
};
/// Every Range constant above, in declaration order (proto/README.md's
/// "Ranges" table is checked against this list).
std::vector<NamedRange> AllRanges();

/// "" when `v` is finite and in `r`, else "must be in [lo, hi] UNIT, got V"
/// (or "must be 0 (not given) or in ...", "must be a finite number, got nan").
std::string RangeProblem(double v, const Range& r);
/// INVALID_ARGUMENT "FIELD: <RangeProblem>", or OK.
grpc::Status CheckRange(double v, const Range& r, std::string_view field);
/// "[1e-06, 10000] m" (for documentation and messages).
std::string Describe(const Range& r);

}  // namespace hapticpd::wire
