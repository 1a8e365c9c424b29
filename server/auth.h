// Token-file authorisation. A token file maps bearer tokens to roles per
// scene:
//
//   {"tokens": [
//     {"token": "s3cret-device", "name": "lab-arm",
//      "roles": {"default": ["device"], "*": ["observe"]}},
//     {"token": "s3cret-admin", "name": "ops", "roles": {"*": ["admin"]}}
//   ]}
//
// "*" applies to every scene. Roles: observe (GetScene, Watch), inject
// (AddBody, MoveBody, RemoveBody), device (Couple), admin (everything,
// including CreateScene and DeleteScene). inject, device and admin include
// observe. Clients send `authorization: Bearer TOKEN` metadata.
#pragma once

#include <grpcpp/server_context.h>

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace hapticpd::server {

enum class Role : std::uint8_t { kObserve = 1, kInject = 2, kDevice = 4, kAdmin = 8 };

const char* ToString(Role r);

class TokenStore {
 public:
  /// No token file: every request is allowed (the server then listens on
  /// loopback only).
  TokenStore() = default;
  /// Parses a token file; throws std::runtime_error naming the file and the
  /// problem.
  static TokenStore FromFile(const std::string& path);
  /// Parses token-file JSON text; `source` names it in errors.
  static TokenStore FromJson(const std::string& text, const std::string& source);

  bool open() const { return open_; }
  std::size_t size() const { return tokens_.size(); }

  /// OK, UNAUTHENTICATED (no or unknown token) or PERMISSION_DENIED (the
  /// token lacks `role` on `scene`).
  grpc::Status Check(const grpc::ServerContextBase& ctx, const std::string& scene, Role role) const;
  /// Whether the caller may see `scene` at all (any role on it).
  bool CanSee(const grpc::ServerContextBase& ctx, const std::string& scene) const;
  /// UNAUTHENTICATED unless the caller presents a known token (or the store is open).
  grpc::Status CheckAnyToken(const grpc::ServerContextBase& ctx) const;

 private:
  struct Entry {
    std::string name;
    std::map<std::string, std::uint8_t> roles;  // scene -> role bits ("*" = any)
  };
  const Entry* Find(const grpc::ServerContextBase& ctx) const;
  static std::uint8_t Effective(const Entry& e, const std::string& scene);

  bool open_ = true;
  std::map<std::string, Entry> tokens_;
};

}  // namespace hapticpd::server
