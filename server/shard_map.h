// The shard map: which `hapticpd serve` process owns which scenes when
// several run behind a balancer (docker/README.md "Scaling out"). One text
// file serves both sides: HAProxy reads it with the `map_beg` converter on
// the `x-hapticpd-scene` header to pick the owner's backend, and each server
// reads it to refuse scenes it does not own.
//
// Format (an HAProxy map file): one `PREFIX SHARD` per line, separated by
// spaces or tabs; blank lines and lines starting with `#` are ignored.
// PREFIX is 1-64 characters of the scene-id alphabet [A-Za-z0-9_.-] and
// matches every scene id that starts with it (an exact id is a prefix too:
// `lab` also matches `lab2`); SHARD is a process name from the same
// alphabet. The longest matching prefix wins, whatever the order of the
// lines (HAProxy's map_beg does the same). A scene id no prefix matches is
// owned by no process: every server refuses to create it.
#pragma once

#include <cstddef>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace hapticpd::server {

/// A shard map that cannot be used: "FILE:LINE: reason" (or "FILE: reason").
class ShardMapError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class ShardMap {
 public:
  /// Reads and checks `path`; throws ShardMapError naming the file and line.
  static ShardMap Load(const std::string& path);
  /// The same from text (`path` names it in errors).
  static ShardMap Parse(std::string_view text, const std::string& path);

  /// The shard owning `scene_id` (the longest matching prefix), or empty
  /// when no prefix matches.
  std::string Owner(std::string_view scene_id) const;
  /// True when some line names `shard`.
  bool HasShard(std::string_view shard) const;
  /// Every shard named, in order of first appearance.
  const std::vector<std::string>& shards() const { return shards_; }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  std::vector<std::pair<std::string, std::string>> entries_;  ///< prefix, shard
  std::vector<std::string> shards_;
};

}  // namespace hapticpd::server
