#include "client/viewer/mesh_store.h"

#include <openssl/sha.h>

#include <cstring>

namespace hapticpd::viewer {
namespace {

template <class T>
void Put(std::string* out, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));  // x86-64 and aarch64 are little-endian
  out->append(b, sizeof(T));
}

}  // namespace

std::string EncodeMesh(const v1::InlineMesh& mesh) {
  const int nv3 = mesh.vertices_size(), nt3 = mesh.triangles_size();
  if (nv3 == 0 || nt3 == 0 || nv3 % 3 != 0 || nt3 % 3 != 0) return {};
  const auto nv = static_cast<std::uint32_t>(nv3 / 3);
  std::string out;
  out.reserve(16 + 4 * static_cast<std::size_t>(nv3 + nt3));
  out.append("HPDM", 4);
  Put<std::uint32_t>(&out, 1);
  Put<std::uint32_t>(&out, nv);
  Put<std::uint32_t>(&out, static_cast<std::uint32_t>(nt3 / 3));
  for (double x : mesh.vertices()) Put<float>(&out, static_cast<float>(x));
  for (std::uint32_t i : mesh.triangles()) {
    if (i >= nv) return {};
    Put<std::uint32_t>(&out, i);
  }
  return out;
}

std::string ContentHash(std::string_view blob) {
  unsigned char md[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(blob.data()), blob.size(), md);
  static const char* hex = "0123456789abcdef";
  std::string out;
  for (int i = 0; i < 16; ++i) {
    out += hex[md[i] >> 4];
    out += hex[md[i] & 15];
  }
  return out;
}

bool IsContentHash(std::string_view text) {
  if (text.size() != 32) return false;
  for (char c : text) {
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  }
  return true;
}

std::string MeshStore::Add(const v1::InlineMesh& mesh) {
  auto blob = std::make_shared<std::string>(EncodeMesh(mesh));
  if (blob->empty()) return {};
  std::string hash = ContentHash(*blob);
  std::lock_guard lock(mu_);
  meshes_.try_emplace(hash, std::move(blob));
  return hash;
}

std::shared_ptr<const std::string> MeshStore::Find(std::string_view hash) const {
  std::lock_guard lock(mu_);
  const auto it = meshes_.find(hash);
  return it == meshes_.end() ? nullptr : it->second;
}

void MeshStore::Retain(const std::set<std::string>& keep) {
  std::lock_guard lock(mu_);
  for (auto it = meshes_.begin(); it != meshes_.end();) {
    it = keep.count(it->first) ? std::next(it) : meshes_.erase(it);
  }
}

std::size_t MeshStore::size() const {
  std::lock_guard lock(mu_);
  return meshes_.size();
}

}  // namespace hapticpd::viewer
