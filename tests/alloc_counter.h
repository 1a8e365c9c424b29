// Counts heap allocations made by the current thread while a CountAllocations
// scope is alive (global operator new is replaced in alloc_counter.cc).
#pragma once

#include <cstddef>

namespace hapticpd::testing {

class CountAllocations {
 public:
  CountAllocations();
  ~CountAllocations();
  CountAllocations(const CountAllocations&) = delete;
  CountAllocations& operator=(const CountAllocations&) = delete;
  std::size_t count() const;
  /// False under sanitizers, which own operator new.
  static bool Available();
};

}  // namespace hapticpd::testing
