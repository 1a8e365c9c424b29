#include "server/auth.h"

#include <nlohmann/json.hpp>

#include <fstream>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace hapticpd::server {
namespace {

std::uint8_t Bit(Role r) { return static_cast<std::uint8_t>(r); }

/// Each role's name in a token file and in messages.
constexpr std::pair<Role, const char*> kRoleNames[] = {{Role::kObserve, "observe"},
                                                       {Role::kInject, "inject"},
                                                       {Role::kDevice, "device"},
                                                       {Role::kAdmin, "admin"}};

std::optional<Role> ParseRole(const std::string& s) {
  for (const auto& [role, name] : kRoleNames) {
    if (s == name) return role;
  }
  return std::nullopt;
}

}  // namespace

const char* ToString(Role r) {
  for (const auto& [role, name] : kRoleNames) {
    if (r == role) return name;
  }
  return "?";
}

TokenStore TokenStore::FromFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open token file");
  std::ostringstream ss;
  ss << in.rdbuf();
  return FromJson(ss.str(), path);
}

TokenStore TokenStore::FromJson(const std::string& text, const std::string& source) {
  TokenStore store;
  store.open_ = false;
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const std::exception& e) {
    throw std::runtime_error(source + ": not valid JSON (" + e.what() + ")");
  }
  if (!j.is_object() || !j.contains("tokens") || !j["tokens"].is_array()) {
    throw std::runtime_error(source + ": expected an object with a \"tokens\" array");
  }
  int i = 0;
  for (const auto& t : j["tokens"]) {
    const std::string where = source + ": tokens[" + std::to_string(i++) + "]";
    if (!t.is_object() || !t.contains("token") || !t["token"].is_string() ||
        t["token"].get<std::string>().empty()) {
      throw std::runtime_error(where + ": needs a non-empty string \"token\"");
    }
    Entry e;
    e.name = t.value("name", std::string("token ") + std::to_string(i - 1));
    if (!t.contains("roles") || !t["roles"].is_object()) {
      throw std::runtime_error(where + ": needs an object \"roles\" (scene -> [roles])");
    }
    for (const auto& [scene, roles] : t["roles"].items()) {
      if (!roles.is_array()) throw std::runtime_error(where + ".roles." + scene + ": not an array");
      std::uint8_t bits = 0;
      for (const auto& r : roles) {
        const auto role = r.is_string() ? ParseRole(r.get<std::string>()) : std::nullopt;
        if (!role) {
          throw std::runtime_error(where + ".roles." + scene + ": unknown role " + r.dump() +
                                   " (observe, inject, device, admin)");
        }
        bits |= Bit(*role);
      }
      e.roles[scene] = bits;
    }
    const std::string token = t["token"].get<std::string>();
    if (store.tokens_.count(token)) throw std::runtime_error(where + ": duplicate token");
    store.tokens_.emplace(token, std::move(e));
  }
  return store;
}

const TokenStore::Entry* TokenStore::Find(const grpc::ServerContextBase& ctx) const {
  const auto& md = ctx.client_metadata();
  auto it = md.find("authorization");
  if (it == md.end()) return nullptr;
  std::string_view v(it->second.data(), it->second.size());
  // RFC 6750: "Bearer TOKEN"; a bare token is not accepted.
  constexpr std::string_view kBearer = "Bearer ";
  if (v.substr(0, kBearer.size()) != kBearer) return nullptr;
  v.remove_prefix(kBearer.size());
  auto t = tokens_.find(std::string(v));
  return t == tokens_.end() ? nullptr : &t->second;
}

std::uint8_t TokenStore::Effective(const Entry& e, const std::string& scene) {
  std::uint8_t bits = 0;
  if (auto it = e.roles.find("*"); it != e.roles.end()) bits |= it->second;
  if (auto it = e.roles.find(scene); it != e.roles.end()) bits |= it->second;
  if (bits & Bit(Role::kAdmin)) bits |= 0xF;
  if (bits & (Bit(Role::kInject) | Bit(Role::kDevice))) bits |= Bit(Role::kObserve);
  return bits;
}

grpc::Status TokenStore::CheckAnyToken(const grpc::ServerContextBase& ctx) const {
  if (open_ || Find(ctx) != nullptr) return grpc::Status::OK;
  const auto& md = ctx.client_metadata();
  if (auto it = md.find("authorization");
      it != md.end() &&
      std::string_view(it->second.data(), it->second.size()).rfind("Bearer ", 0) != 0) {
    return grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                        "the authorization metadata must be 'Bearer TOKEN' (the 'Bearer ' prefix "
                        "is missing)");
  }
  return grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                      "missing or unknown token (send metadata 'authorization: Bearer TOKEN')");
}

grpc::Status TokenStore::Check(const grpc::ServerContextBase& ctx, const std::string& scene,
                               Role role) const {
  if (open_) return grpc::Status::OK;
  const Entry* e = Find(ctx);
  if (e == nullptr) return CheckAnyToken(ctx);
  if (Effective(*e, scene) & Bit(role)) return grpc::Status::OK;
  return grpc::Status(
      grpc::StatusCode::PERMISSION_DENIED,
      "token '" + e->name + "' lacks role '" + ToString(role) + "' on scene '" + scene + "'");
}

bool TokenStore::CanSee(const grpc::ServerContextBase& ctx, const std::string& scene) const {
  if (open_) return true;
  const Entry* e = Find(ctx);
  return e != nullptr && Effective(*e, scene) != 0;
}

}  // namespace hapticpd::server
