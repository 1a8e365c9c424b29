// From a scene PD answer to what a haptic loop renders between answers: the
// contact rows (one linearised constraint per contact region), the PD target
// (PDg), the wrench at the answered pose and the region around it where the
// rows are trusted. One rule, used by the server (which encodes it as a
// ContactUpdate), the device side's local PD source and its in-process
// sources, so the same PD answer is felt the same wherever it is computed.
//
// Rows: a region's representative point p, unit normal n (from the body
// towards the probe), depth d > 0 and the body's material. A PD answer
// without regions (PDg, or PDt that found none) is one row at the probe's
// centre of mass c along the answer's translation, depth its length. The
// moment of a row about c is (p - c) x n (callers that render force only
// leave it out).
//
// Validity: the rows are a linearisation around the answered pose; they are
// trusted within `validity_fraction` of the probe's bounding radius plus the
// deepest depth (linear), and that distance over the probe's radius about
// its centre of mass (angular).
#pragma once

#include <vector>

#include "pd/geometry_model.h"
#include "pd/scene_pd.h"
#include "pd/types.h"

namespace hapticpd::pd {

struct ContactRow {
  Vec3 p_W = Vec3::Zero();  ///< representative contact point at the answered pose
  Vec3 n_W = Vec3::Zero();  ///< unit normal from the body towards the probe
  double depth = 0;         ///< m, > 0
  int body = 0;             ///< index into the scene's bodies
  Material material;        ///< the body's effective material (stiffness, friction, damping)
};

/// How a contact answer ends up, over all bodies.
enum class ContactOutcome {
  kSeparated,    ///< no body penetrated
  kPenetrating,  ///< PD solved against at least one body
  kCapReached,   ///< an iteration cap or budget was hit for a body; best verified answer
  kFailed,       ///< PD failed for a body; rows from the others
};

struct ContactModel {
  ContactOutcome outcome = ContactOutcome::kSeparated;
  std::vector<ContactRow> rows;
  Vec3 c_W = Vec3::Zero();  ///< the probe's centre of mass at the answered pose
  /// The deepest body's answer (-1: none): depth (PDt: |translation|, PDg:
  /// sqrt(sigma)), PD translation, and the nearest free probe pose (X_WA).
  int deepest = -1;
  double depth = 0;
  Vec3 pd_translation_W = Vec3::Zero();
  Pose X_WA_target;
  /// The PD target spring of the deepest body (its effective material).
  double target_stiffness = 0;
  double target_rotational_stiffness = 0;
  /// PDg only: sigma (m^2) and the rotation from the answered pose to the
  /// target (angle, unit axis in W); zero for PDt.
  bool generalized = false;
  double sigma = 0;
  double rotation_angle = 0;
  Vec3 rotation_axis_W = Vec3::Zero();
  Wrench wrench;               ///< penalty wrench at the answered pose (torque about c_W)
  double validity_radius = 0;  ///< m
  double validity_angle = 0;   ///< rad
};

struct ContactModelOptions {
  /// Fraction of the probe's bounding radius the rows are trusted over,
  /// beyond the deepest depth.
  double validity_fraction = 0.1;
};

/// The contact model of `result`, a scene PD answer for `probe` at X_WA
/// against `bodies` (their materials are the effective ones: probe and body
/// in series where the caller combined them). Reuses out's storage.
void BuildContactModel(const GeometryModel& probe, const Pose& X_WA,
                       const std::vector<SceneBody>& bodies, const ScenePdResult& result,
                       const ContactModelOptions& options, ContactModel* out);

/// The model for an answer computed without PD (mode none, or a scene that
/// declares no contact effect): separated, target at X_WA, validity from
/// the probe's size alone.
void EmptyContactModel(const GeometryModel& probe, const Pose& X_WA,
                       const ContactModelOptions& options, ContactModel* out);

}  // namespace hapticpd::pd
