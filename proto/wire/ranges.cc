#include "proto/wire/ranges.h"

#include <cmath>
#include <sstream>

namespace hapticpd::wire {
namespace {

std::string Num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

}  // namespace

std::string Describe(const Range& r) {
  std::ostringstream out;
  out << '[' << r.lo << ", " << r.hi << ']';
  if (r.unit[0] != '\0') out << ' ' << r.unit;
  return out.str();
}

std::vector<NamedRange> AllRanges() {
  return {{"kCoordinate", kCoordinate},
          {"kShapeLength", kShapeLength},
          {"kLinearVelocity", kLinearVelocity},
          {"kAngularVelocity", kAngularVelocity},
          {"kStiffness", kStiffness},
          {"kRotationalStiffness", kRotationalStiffness},
          {"kDamping", kDamping},
          {"kFriction", kFriction},
          {"kGravity", kGravity},
          {"kTextureAmplitude", kTextureAmplitude},
          {"kTextureFrequency", kTextureFrequency},
          {"kProbeMass", kProbeMass},
          {"kProbeInertia", kProbeInertia},
          {"kMaxRateHz", kMaxRateHz},
          {"kWatchRateHz", kWatchRateHz},
          {"kTelemetryRateHz", kTelemetryRateHz},
          {"kTelemetryMs", kTelemetryMs},
          {"kLossFraction", kLossFraction},
          {"kTelemetryForce", kTelemetryForce},
          {"kTelemetryTorque", kTelemetryTorque}};
}

std::string RangeProblem(double v, const Range& r) {
  if (!std::isfinite(v)) return "must be a finite number, got " + Num(v);
  if (r.zero_means_unset && v == 0) return {};
  if (v >= r.lo && v <= r.hi) return {};
  std::ostringstream out;
  out << "must be " << (r.zero_means_unset ? "0 (not given) or " : "") << "in " << Describe(r)
      << ", got " << v;
  return out.str();
}

grpc::Status CheckRange(double v, const Range& r, std::string_view field) {
  std::string p = RangeProblem(v, r);
  if (p.empty()) return grpc::Status::OK;
  return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, std::string(field) + ": " + p);
}

}  // namespace hapticpd::wire
