// The bad-input tables of tests/README.md are printed by the tests that check
// their rows: with HAPTICPD_PRINT_TABLE set, a table test prints each case it
// checked as one markdown row on stdout, and tests/update_tables.py copies
// the rows into the README between its `<!-- table:NAME:... -->` markers.
#pragma once

#include <cstdlib>
#include <initializer_list>
#include <iostream>
#include <string>
#include <string_view>

namespace hapticpd::testing {

/// True when HAPTICPD_PRINT_TABLE is set.
inline bool PrintTableRows() { return std::getenv("HAPTICPD_PRINT_TABLE") != nullptr; }

/// Whether `got` is the message `want`. A "…" in `want` stands for text the
/// check skips (one that depends on the machine or a library's version):
/// `got` starts with what comes before it and ends with what comes after.
inline bool MessageMatches(std::string_view got, std::string_view want) {
  constexpr std::string_view kSkip = "\u2026";
  const std::size_t at = want.find(kSkip);
  if (at == std::string_view::npos) return got == want;
  const std::string_view head = want.substr(0, at);
  const std::string_view tail = want.substr(at + kSkip.size());
  return got.size() >= head.size() + tail.size() && got.substr(0, head.size()) == head &&
         got.substr(got.size() - tail.size()) == tail;
}

/// `text` as a markdown code span inside a table cell: `|` escaped, and
/// double backticks around text that holds a backtick.
inline std::string TableCode(std::string_view text) {
  std::string escaped;
  for (const char c : text) {
    if (c == '|') escaped += '\\';
    escaped += c;
  }
  if (text.find('`') != std::string_view::npos) return "`` " + escaped + " ``";
  return "`" + escaped + "`";
}

/// Prints one row, `| cell | ... | `message` |`, when HAPTICPD_PRINT_TABLE is
/// set. `cells` are markdown as they are; `message` is the text the test
/// checked, shown as code.
inline void PrintTableRow(std::initializer_list<std::string_view> cells, std::string_view message) {
  if (!PrintTableRows()) return;
  std::string row = "|";
  for (const std::string_view c : cells) row.append(" ").append(c).append(" |");
  row.append(" ").append(TableCode(message)).append(" |\n");
  std::cout << row << std::flush;
}

}  // namespace hapticpd::testing
