#include "server/shard_map.h"

#include <fmt/format.h>

#include <algorithm>
#include <fstream>
#include <map>
#include <sstream>

#include "proto/wire/text.h"

namespace hapticpd::server {
namespace {

bool IsIdChar(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
         c == '.' || c == '-';
}

/// Empty when `s` is 1-64 characters of the id alphabet, else why not.
std::string CheckName(std::string_view s) {
  if (s.size() > 64) return fmt::format("is {} characters long (at most 64)", s.size());
  for (char c : s) {
    if (!IsIdChar(c)) {
      return fmt::format("holds '{}' (allowed: A-Z a-z 0-9 _ . -)",
                         wire::Printable(std::string_view(&c, 1)));
    }
  }
  return "";
}

std::vector<std::string_view> Fields(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    const std::size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t') ++i;
    if (i > start) out.push_back(line.substr(start, i - start));
  }
  return out;
}

}  // namespace

ShardMap ShardMap::Load(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ShardMapError(fmt::format("{}: cannot open the shard map", path));
  std::ostringstream ss;
  ss << in.rdbuf();
  return Parse(ss.str(), path);
}

ShardMap ShardMap::Parse(std::string_view text, const std::string& path) {
  ShardMap m;
  m.path_ = path;
  std::map<std::string, std::size_t, std::less<>> line_of;  // prefix -> its line
  std::size_t number = 0;
  std::size_t pos = 0;
  while (pos < text.size()) {
    std::size_t end = text.find('\n', pos);
    if (end == std::string_view::npos) end = text.size();
    std::string_view line = text.substr(pos, end - pos);
    pos = end + 1;
    ++number;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const auto fields = Fields(line);
    if (fields.empty() || fields[0].front() == '#') continue;
    auto fail = [&](const std::string& why) {
      return ShardMapError(fmt::format("{}:{}: {}", path, number, why));
    };
    if (fields.size() != 2) {
      throw fail(fmt::format("expected 'PREFIX SHARD' (two fields), got {} in '{}'", fields.size(),
                             wire::Printable(line)));
    }
    if (auto why = CheckName(fields[0]); !why.empty()) {
      throw fail(fmt::format("prefix '{}' {}", wire::Printable(fields[0]), why));
    }
    if (auto why = CheckName(fields[1]); !why.empty()) {
      throw fail(fmt::format("shard '{}' {}", wire::Printable(fields[1]), why));
    }
    const std::string prefix(fields[0]);
    if (auto it = line_of.find(prefix); it != line_of.end()) {
      throw fail(fmt::format("prefix '{}' is already mapped on line {} (one owner per prefix)",
                             prefix, it->second));
    }
    line_of.emplace(prefix, number);
    m.entries_.emplace_back(prefix, std::string(fields[1]));
    if (std::find(m.shards_.begin(), m.shards_.end(), fields[1]) == m.shards_.end()) {
      m.shards_.emplace_back(fields[1]);
    }
  }
  if (m.entries_.empty()) throw ShardMapError(fmt::format("{}: maps no prefix to a shard", path));
  return m;
}

std::string ShardMap::Owner(std::string_view scene_id) const {
  const std::pair<std::string, std::string>* best = nullptr;
  for (const auto& e : entries_) {
    if (scene_id.starts_with(e.first) && (!best || e.first.size() > best->first.size())) best = &e;
  }
  return best ? best->second : std::string();
}

bool ShardMap::HasShard(std::string_view shard) const {
  return std::find(shards_.begin(), shards_.end(), shard) != shards_.end();
}

}  // namespace hapticpd::server
