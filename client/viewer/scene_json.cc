#include "client/viewer/scene_json.h"

#include <google/protobuf/generated_enum_reflection.h>

#include <cctype>
#include <cmath>
#include <cstring>
#include <string>

#include "proto/wire/scene_file.h"

namespace hapticpd::viewer {
namespace {

using nlohmann::json;

/// Rounded to 1e-6 (m, N, N m): the page draws and plots, and the shortest
/// decimal of a rounded double is short on the wire.
double R(double x) { return std::isfinite(x) ? std::round(x * 1e6) / 1e6 : 0.0; }

json Vec(const v1::Vec3& v) { return json::array({R(v.x()), R(v.y()), R(v.z())}); }

json PoseJson(const v1::Pose& p) {
  json q = json::array({1.0, 0.0, 0.0, 0.0});
  if (p.has_orientation()) {
    const auto& o = p.orientation();
    q = json::array({o.w(), o.x(), o.y(), o.z()});
  }
  return {{"p", Vec(p.position())}, {"q", std::move(q)}};
}

/// "pdt", "pdg", "none"; "" when the server left it unset.
const char* ModeName(v1::PdMode m) {
  return m == v1::PD_MODE_UNSPECIFIED ? "" : wire::PdModeName(m);
}

/// The page's name of a proto enum value: its name without the enum's
/// prefix, in lower case with '-' for '_' (CONTACT_STATUS_CAP_REACHED:
/// "cap-reached"); "" for the unspecified value and for one this build does
/// not know.
template <class E>
std::string EnumName(E value) {
  const google::protobuf::EnumDescriptor* d = google::protobuf::GetEnumDescriptor<E>();
  const google::protobuf::EnumValueDescriptor* v = d->FindValueByNumber(value);
  if (v == nullptr || v->number() == 0) return "";
  // The unspecified value (0) names the prefix: CONTACT_STATUS_UNSPECIFIED.
  const std::string& unspecified = d->FindValueByNumber(0)->name();
  std::string name = v->name().substr(unspecified.size() - std::strlen("UNSPECIFIED"));
  for (char& c : name) c = c == '_' ? '-' : static_cast<char>(std::tolower(c));
  return name;
}

json MeshInfoJson(const v1::MeshInfo& m) {
  return {{"triangles", m.triangles()},
          {"vertices", m.vertices()},
          {"aabb_min", Vec(m.aabb_min())},
          {"aabb_max", Vec(m.aabb_max())},
          {"com", Vec(m.center_of_mass())}};
}

/// The mesh's hash (stored in `meshes`), or null when the event carries none.
json MeshRef(const v1::InlineMesh& mesh, MeshStore* meshes) {
  const std::string hash = meshes->Add(mesh);
  return hash.empty() ? json(nullptr) : json(hash);
}

json BodyJson(const v1::Body& b, MeshStore* meshes) {
  return {{"id", b.body_id()},
          {"label", b.label()},
          {"movable", b.movable()},
          {"mesh", MeshRef(b.mesh(), meshes)},
          {"info", MeshInfoJson(b.mesh_info())},
          {"pose", PoseJson(b.pose())}};
}

json SessionJson(const v1::SessionInfo& s, MeshStore* meshes) {
  return {{"id", s.session_id()},
          {"client", s.client_name()},
          {"mode", ModeName(s.mode())},
          {"mesh", MeshRef(s.probe_mesh(), meshes)},
          {"info", MeshInfoJson(s.probe_mesh_info())},
          {"probe_body", s.probe_body_id()}};
}

json ProbeJson(const v1::ProbeState& p) {
  json j = {{"id", p.session_id()},
            {"pose", PoseJson(p.pose())},
            {"force", Vec(p.force())},
            {"depth", R(p.depth())},
            {"seq", p.sequence()}};
  // The include_contacts fields; an older server sends none of them.
  if (p.has_torque()) j["torque"] = Vec(p.torque());
  if (p.status() != v1::CONTACT_STATUS_UNSPECIFIED) j["status"] = EnumName(p.status());
  if (p.mode() != v1::PD_MODE_UNSPECIFIED) j["mode"] = ModeName(p.mode());
  if (p.has_target_pose()) j["target"] = PoseJson(p.target_pose());
  if (p.rows_size() > 0) {
    json rows = json::array();
    for (const v1::ContactRow& r : p.rows()) {
      const std::uint32_t bi = r.body_index();
      rows.push_back({{"p", Vec(r.point())},
                      {"n", Vec(r.normal())},
                      {"d", R(r.depth())},
                      {"body", bi < static_cast<std::uint32_t>(p.body_ids_size())
                                   ? p.body_ids(static_cast<int>(bi))
                                   : std::string()}});
    }
    j["rows"] = std::move(rows);
  }
  return j;
}

json SamplesJson(const v1::WrenchSamples& s) {
  json dt = json::array(), f = json::array(), tau = json::array();
  for (std::uint32_t o : s.offset_us()) dt.push_back(o);
  for (float x : s.force()) f.push_back(R(x));
  for (float x : s.torque()) tau.push_back(R(x));
  return {{"t0", 1e-9 * static_cast<double>(s.start_time_ns())},
          {"dt_us", std::move(dt)},
          {"f", std::move(f)},
          {"tau", std::move(tau)},
          {"lost", s.samples_lost()}};
}

json DeviceStatusJson(const v1::DeviceTelemetry& d) {
  return {{"seq", d.sequence()},
          {"servo_rate_hz", d.servo_rate_hz()},
          {"update_rate_hz", d.update_rate_hz()},
          {"round_trip_ms", d.round_trip_ms()},
          {"ir_age_ms", d.ir_age_ms()},
          {"delay_ms", d.emulated_delay_ms()},
          {"jitter_ms", d.emulated_jitter_ms()},
          {"loss", d.emulated_loss()},
          {"fail_safe", EnumName(d.fail_safe())},
          {"source", EnumName(d.source())},
          {"ticks_server", d.ticks_server()},
          {"ticks_local", d.ticks_local()},
          {"ticks_faded", d.ticks_faded()},
          {"local_rate_hz", d.local_rate_hz()}};
}

json TelemetryJson(const v1::SessionTelemetry& t) {
  json j = {{"id", t.session_id()},
            {"revision", t.scene_revision()},
            {"update_rate_hz", t.update_rate_hz()}};
  if (t.has_device()) {
    j["device"] = DeviceStatusJson(t.device());
    j["commanded"] = SamplesJson(t.device().commanded());
  }
  if (t.has_server()) j["server"] = SamplesJson(t.server());
  return j;
}

}  // namespace

json EventToJson(const v1::SceneEvent& ev, MeshStore* meshes) {
  json j = {{"revision", ev.revision()},
            {"observers", ev.observers()},
            {"server_time_ns", ev.server_time_ns()}};
  switch (ev.event_case()) {
    case v1::SceneEvent::kSnapshot: {
      j["type"] = "scene";
      j["bodies"] = json::array();
      for (const v1::Body& b : ev.snapshot().bodies()) j["bodies"].push_back(BodyJson(b, meshes));
      break;
    }
    case v1::SceneEvent::kChanges: {
      j["type"] = "bodies";
      j["added"] = json::array();
      for (const v1::Body& b : ev.changes().added()) j["added"].push_back(BodyJson(b, meshes));
      j["removed"] = ev.changes().removed();
      break;
    }
    case v1::SceneEvent::kSessions: {
      j["type"] = "sessions";
      j["added"] = json::array();
      for (const auto& s : ev.sessions().added()) j["added"].push_back(SessionJson(s, meshes));
      j["removed"] = ev.sessions().removed();
      break;
    }
    case v1::SceneEvent::kPoses: {
      j["type"] = "poses";
      j["server_dropped"] = ev.frames_dropped();
      j["bodies"] = json::array();
      for (const v1::BodyPose& b : ev.poses().bodies()) {
        j["bodies"].push_back({{"id", b.body_id()}, {"pose", PoseJson(b.pose())}});
      }
      j["probes"] = json::array();
      for (const v1::ProbeState& p : ev.poses().probes()) j["probes"].push_back(ProbeJson(p));
      break;
    }
    case v1::SceneEvent::kTelemetry: {
      j["type"] = "telemetry";
      j["server_dropped"] = ev.telemetry().batches_dropped();
      j["sessions"] = json::array();
      for (const auto& t : ev.telemetry().sessions()) j["sessions"].push_back(TelemetryJson(t));
      break;
    }
    default:
      j["type"] = "unknown";  // a newer server's event: the viewer skips it
      break;
  }
  return j;
}

json LinkJson(bool server_connected, const std::string& error) {
  return {{"type", "link"}, {"server_connected", server_connected}, {"error", error}};
}

void MeshRefs::Apply(const json& msg) {
  const std::string& type = msg.at("type").get_ref<const std::string&>();
  const auto put = [](std::map<std::string, std::string>* m, const json& item) {
    const json& mesh = item.at("mesh");
    if (mesh.is_string()) (*m)[item.at("id")] = mesh.get<std::string>();
  };
  if (type == "scene") {
    bodies_.clear();
    sessions_.clear();  // the server re-sends every session after a snapshot
    for (const json& b : msg.at("bodies")) put(&bodies_, b);
  } else if (type == "bodies" || type == "sessions") {
    auto* m = type == "bodies" ? &bodies_ : &sessions_;
    for (const json& id : msg.at("removed")) m->erase(id.get<std::string>());
    for (const json& item : msg.at("added")) put(m, item);
  }
}

std::set<std::string> MeshRefs::hashes() const {
  std::set<std::string> out;
  for (const auto& [id, h] : bodies_) out.insert(h);
  for (const auto& [id, h] : sessions_) out.insert(h);
  return out;
}

void SceneModel::Apply(const json& msg) {
  const std::string& type = msg.at("type").get_ref<const std::string&>();
  if (type == "link") {
    server_connected_ = msg.at("server_connected").get<bool>();
    link_error_ = msg.at("error").get<std::string>();
    return;
  }
  if (msg.contains("revision")) revision_ = msg["revision"].get<std::uint64_t>();
  if (msg.contains("observers")) observers_ = msg["observers"].get<std::uint32_t>();
  if (msg.contains("server_time_ns")) server_time_ns_ = msg["server_time_ns"].get<std::int64_t>();
  if (type == "scene") {
    bodies_.clear();
    sessions_.clear();
    status_.clear();
    probes_ = json::array();
    for (const json& b : msg.at("bodies")) bodies_[b.at("id")] = b;
  } else if (type == "bodies" || type == "sessions") {
    auto& m = type == "bodies" ? bodies_ : sessions_;
    if (type == "sessions") sessions_announced_ = true;
    for (const json& id : msg.at("removed")) {
      m.erase(id.get<std::string>());
      if (type == "sessions") status_.erase(id.get<std::string>());
    }
    for (const json& item : msg.at("added")) m[item.at("id")] = item;
  } else if (type == "poses") {
    for (const json& bp : msg.at("bodies")) {
      const auto it = bodies_.find(bp.at("id").get_ref<const std::string&>());
      if (it != bodies_.end()) it->second["pose"] = bp.at("pose");
    }
    probes_ = msg.at("probes");
  } else if (type == "telemetry") {
    for (const json& t : msg.at("sessions")) {
      const std::string& id = t.at("id").get_ref<const std::string&>();
      if (sessions_announced_ && sessions_.count(id) == 0) continue;  // ended
      if (t.contains("device")) status_[id] = t["device"];
    }
  }
}

json SceneModel::FullScene() const {
  json bodies = json::array(), sessions = json::array();
  for (const auto& [id, b] : bodies_) bodies.push_back(b);
  for (const auto& [id, s] : sessions_) sessions.push_back(s);
  json status = json::object();
  for (const auto& [id, s] : status_) status[id] = s;
  return {{"type", "scene"},
          {"scene_id", scene_id_},
          {"source", source_},
          {"revision", revision_},
          {"observers", observers_},
          {"server_time_ns", server_time_ns_},
          {"server_connected", server_connected_},
          {"error", link_error_},
          {"bodies", std::move(bodies)},
          {"sessions", std::move(sessions)},
          {"sessions_announced", sessions_announced_},
          {"probes", probes_},
          {"status", std::move(status)}};
}

}  // namespace hapticpd::viewer
