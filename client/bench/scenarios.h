// The benchmark scenarios of the seed paper, shared by `hapticpd bench`
// (client/cmd_bench.cc), `hapticpd-bench` (client/bench/bench_main.cc) and
// the benchmark programs under tests/bench: the three benchmark pairs and
// their scripted 1 kHz trajectories, plus small timing and statistics
// helpers.
//
//   stick  vs the Stanford bunny (69K triangles)
//   spoon  vs cup                 (procedural stand-ins, pd/shapes.h)
//   hammer vs beast.obj decimated to ~20K triangles (OpenMesh quadric
//          decimater), scaled by 1/500 to 0.55 m wide so that it is
//          comparable in size with the 31 cm hammer
//
// Without the shared models the bunny and the statue are replaced by
// procedural torus knots (and the benchmark notes say so). `tiny` builds
// small procedural versions of all three (a few hundred to a few thousand
// triangles) so that tests can run every code path in milliseconds.
#pragma once

#include <chrono>
#include <cstddef>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "pd/geometry_model.h"
#include "pd/mesh.h"
#include "pd/penetration.h"
#include "pd/types.h"

namespace hapticpd::bench {

namespace hp = hapticpd;
namespace pd = hapticpd::pd;
using hp::Mat3;
using hp::Pose;
using hp::Vec3;

// ---------------------------------------------------------------------------
// Models

/// Quadric-error decimation (OpenMesh) to about `target_faces` triangles.
/// Triangles that OpenMesh's half-edge structure cannot take (complex edges)
/// are skipped and counted in `*skipped`.
pd::Mesh Decimate(const pd::Mesh& in, std::size_t target_faces, const std::string& source,
                  int* skipped);

pd::Mesh Scaled(const pd::Mesh& in, double s, const std::string& source);

// ---------------------------------------------------------------------------
// Trajectories

/// First hit of the ray o + t d (t > 0) with the mesh (brute force,
/// Möller–Trumbore): the parameter and the face, or nothing.
std::optional<std::pair<double, int>> RayCast(const pd::Mesh& m, const Vec3& o, const Vec3& d);

/// Area-weighted normal of the faces with a vertex within `radius` of p: a
/// smoother pressing direction than one face of a scanned mesh.
Vec3 SmoothNormal(const pd::Mesh& m, const Vec3& p, double radius, int face);

struct Frame {
  Pose X_WA;
  double commanded = 0;  ///< how far the tip is pressed below the height it follows (m), >= 0
  int phase = 0;         ///< 0 press, 1 slide, 2 release
};

struct Benchmark {
  std::string name;
  std::string probe_name, scene_name;
  pd::ModelPtr probe, scene;
  Vec3 up;           ///< scene's up direction, to pick the start point
  Vec3 tip_dir_A;    ///< direction of the probe's tip in its mesh frame
  double slide = 0;  ///< tangential amplitude (m)
  std::vector<std::string> notes;
  bool stand_in = false;  ///< a procedural stand-in replaces a shared model
  // Filled by MakeTrajectory.
  Vec3 p_start, n_start;
  double press = 0;
  std::vector<Frame> frames;
};

/// The steepest surface the trajectories' tip follows (rise over run): 45
/// degrees.
inline constexpr double kTrajectoryMaxSlope = 1.0;

/// Reads a --max-slope value: a number >= 0, "inf" for no limit. Returns
/// the problem ("" when `text` is good, *slope then set).
std::string ParseMaxSlope(const std::string& text, double* slope);

/// Start just above a surface point seen from above (the most upward-facing
/// hit of a grid of downward rays over the middle of the scene whose start
/// pose is collision-free, spinning the probe about the normal if needed),
/// press in along the normal to 2 % of the probe's size, slide along a figure
/// eight while pressed, and come back out; the probe tilts slowly by up to 10
/// degrees about its tip. While sliding, the tip follows the surface height
/// under it (a downward ray), its height along the normal changing from one
/// frame to the next by at most `max_slope` times its step along the
/// surface: a hand sliding on the surface does not drop off a ledge onto a
/// layer below, nor jump onto one above, in one millisecond. With
/// `max_slope` infinite it takes the ray's height as it is, which jumps
/// where the ray passes an edge (9.5 cm in one frame on hammer-beast20k): a
/// teleport of the probe inside the coherent run. A note gives the largest
/// step of the tip between frames. Throws std::runtime_error when no
/// collision-free start pose exists.
void MakeTrajectory(Benchmark* b, int num_frames, double max_slope = kTrajectoryMaxSlope);

// ---------------------------------------------------------------------------
// Statistics

/// The q-quantile (0..1, nearest rank) of v; 0 for an empty v.
double Percentile(std::vector<double> v, double q);

/// total / count, or 0 when count is 0 (means over penetrating frames).
inline double MeanOver(double total, int count) { return count > 0 ? total / count : 0; }

/// Microseconds from a to b.
double Us(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b);

const char* PhaseName(int phase);

// ---------------------------------------------------------------------------
// Setup

/// The three benchmarks (stick-bunny, spoon-cup, hammer-beast20k), models
/// from `models_dir` where present, without trajectories (MakeTrajectory);
/// with `only`, just the benchmark of that name (none if no such name).
std::vector<Benchmark> BuildBenchmarks(const std::string& models_dir, bool tiny = false,
                                       const std::string& only = "");

// ---------------------------------------------------------------------------
// Replay

/// One frame of a replay: the time of the PD query and what it answered.
struct FrameOutcome {
  double us = 0;
  pd::PdStatus status = pd::PdStatus::kFailed;
  double depth = 0;
  int iterations = 0;
  int contacts = 0;  ///< feature pairs at the answer
  Pose X_WA_result;
  Vec3 translation_W = Vec3::Zero();
};

/// Replays the frames through ComputePdt or ComputePdg with one query data
/// carried across frames (motion coherence as in the servo loop, when the
/// request enables it). B sits at the identity.
std::vector<FrameOutcome> ReplayPd(const pd::GeometryModel& A, const pd::GeometryModel& B,
                                   const std::vector<Frame>& frames, pd::PdMode mode,
                                   const pd::PenetrationRequest& request);

struct TimingSummary {
  int frames = 0, penetrating = 0, failed = 0, cap_reached = 0;
  double p50_us = 0, p99_us = 0, max_us = 0;
  double mean_iterations = 0, mean_contacts = 0;  ///< over penetrating frames
};

/// Times over all frames (or only the penetrating ones), means over the
/// penetrating frames.
TimingSummary Summarize(const std::vector<FrameOutcome>& outcomes, bool penetrating_only);

inline bool Penetrating(pd::PdStatus s) {
  return s == pd::PdStatus::kPenetratingSolved || s == pd::PdStatus::kPenetratingCapReached;
}

}  // namespace hapticpd::bench
