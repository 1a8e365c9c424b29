#include "client/viewer/mesh_store.h"

#include <openssl/sha.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <unordered_map>
#include <unordered_set>
#include <vector>

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

namespace {

/// One clustering pass at cell size `h`: the merged vertices and the
/// triangles that keep three distinct vertices, each once.
void Cluster(const v1::InlineMesh& in, double h, const std::array<double, 3>& lo,
             v1::InlineMesh* out) {
  const int nv = in.vertices_size() / 3;
  std::unordered_map<std::uint64_t, std::uint32_t> cell_of;
  cell_of.reserve(static_cast<std::size_t>(nv));
  std::vector<std::uint32_t> remap(static_cast<std::size_t>(nv));
  std::vector<std::array<double, 4>> sums;  // x, y, z, count per cell
  for (int v = 0; v < nv; ++v) {
    std::uint64_t key = 0;
    for (int k = 0; k < 3; ++k) {
      const double c = std::floor((in.vertices(3 * v + k) - lo[static_cast<std::size_t>(k)]) / h);
      key = (key << 21) | (static_cast<std::uint64_t>(std::clamp(c, 0.0, 2097151.0)) & 0x1fffff);
    }
    const auto [it, added] = cell_of.try_emplace(key, static_cast<std::uint32_t>(sums.size()));
    if (added) sums.push_back({0, 0, 0, 0});
    auto& s = sums[it->second];
    for (int k = 0; k < 3; ++k) s[static_cast<std::size_t>(k)] += in.vertices(3 * v + k);
    s[3] += 1;
    remap[static_cast<std::size_t>(v)] = it->second;
  }
  out->Clear();
  out->mutable_vertices()->Reserve(static_cast<int>(3 * sums.size()));
  for (const auto& s : sums) {
    for (int k = 0; k < 3; ++k) out->add_vertices(s[static_cast<std::size_t>(k)] / s[3]);
  }
  std::unordered_set<std::uint64_t> seen;  // each triangle once, whatever its winding
  for (int t = 0; t + 2 < in.triangles_size(); t += 3) {
    std::array<std::uint32_t, 3> c{remap[in.triangles(t)], remap[in.triangles(t + 1)],
                                   remap[in.triangles(t + 2)]};
    if (c[0] == c[1] || c[1] == c[2] || c[0] == c[2]) continue;
    std::array<std::uint64_t, 3> s{c[0], c[1], c[2]};
    std::sort(s.begin(), s.end());
    if (!seen.insert((s[0] << 42) ^ (s[1] << 21) ^ s[2]).second) continue;
    for (std::uint32_t i : c) out->add_triangles(i);
  }
}

}  // namespace

v1::InlineMesh SimplifyForDisplay(const v1::InlineMesh& mesh, std::size_t max_triangles) {
  const std::size_t nt = static_cast<std::size_t>(mesh.triangles_size()) / 3;
  if (max_triangles == 0 || nt <= max_triangles || EncodeMesh(mesh).empty()) return mesh;
  std::array<double, 3> lo{HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi{-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  for (int i = 0; i < mesh.vertices_size(); ++i) {
    const auto k = static_cast<std::size_t>(i % 3);
    lo[k] = std::min(lo[k], mesh.vertices(i));
    hi[k] = std::max(hi[k], mesh.vertices(i));
  }
  double area = 0;
  const auto P = [&](std::uint32_t i, int k) { return mesh.vertices(static_cast<int>(3 * i) + k); };
  for (int t = 0; t + 2 < mesh.triangles_size(); t += 3) {
    const std::uint32_t a = mesh.triangles(t), b = mesh.triangles(t + 1), c = mesh.triangles(t + 2);
    double u[3], w[3];
    for (int k = 0; k < 3; ++k) {
      u[k] = P(b, k) - P(a, k);
      w[k] = P(c, k) - P(a, k);
    }
    area += 0.5 * std::sqrt(std::pow(u[1] * w[2] - u[2] * w[1], 2) +
                            std::pow(u[2] * w[0] - u[0] * w[2], 2) +
                            std::pow(u[0] * w[1] - u[1] * w[0], 2));
  }
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-9});
  // A surface of area A on cells of side h keeps about 2 A / h^2 triangles;
  // the cell grows by 10 % a pass until they fit (and never passes 2^21 cells a side).
  double h = std::max(std::sqrt(2 * area / static_cast<double>(max_triangles)), extent / 2e6);
  v1::InlineMesh out;
  for (int pass = 0; pass < 64; ++pass, h *= 1.1) {
    Cluster(mesh, h, lo, &out);
    if (static_cast<std::size_t>(out.triangles_size()) / 3 <= max_triangles) return out;
  }
  return out;
}

std::string MeshStore::Add(const v1::InlineMesh& mesh) {
  auto blob = std::make_shared<std::string>(EncodeMesh(mesh));
  if (blob->empty()) return {};
  std::string hash = ContentHash(*blob);
  const std::size_t nt = static_cast<std::size_t>(mesh.triangles_size()) / 3;
  if (max_display_triangles_ > 0 && nt > max_display_triangles_) {
    {
      std::lock_guard lock(mu_);
      const auto it = simplified_.find(hash);
      if (it != simplified_.end() && meshes_.count(it->second) > 0) return it->second;
    }
    auto shown =
        std::make_shared<std::string>(EncodeMesh(SimplifyForDisplay(mesh, max_display_triangles_)));
    std::string shown_hash = ContentHash(*shown);
    std::lock_guard lock(mu_);
    simplified_[hash] = shown_hash;
    meshes_.try_emplace(shown_hash, std::move(shown));
    return shown_hash;
  }
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
  for (auto it = simplified_.begin(); it != simplified_.end();) {
    it = keep.count(it->second) ? std::next(it) : simplified_.erase(it);
  }
}

std::size_t MeshStore::size() const {
  std::lock_guard lock(mu_);
  return meshes_.size();
}

}  // namespace hapticpd::viewer
