#include "tests/alloc_counter.h"

#include <cstdlib>
#include <new>

// Under AddressSanitizer the sanitizer owns operator new/delete (replacing
// them here mixes its new[] with our free); counting is then unavailable.
#if defined(HAPTICPD_ASAN) || defined(HAPTICPD_TSAN)
#define HAPTICPD_COUNT_ALLOCATIONS 0
#else
#define HAPTICPD_COUNT_ALLOCATIONS 1
#endif

namespace {
thread_local bool t_counting = false;
thread_local std::size_t t_count = 0;

[[maybe_unused]] void* Allocate(std::size_t n) {
  if (t_counting) ++t_count;
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
}  // namespace

#if HAPTICPD_COUNT_ALLOCATIONS
void* operator new(std::size_t n) { return Allocate(n); }
void* operator new[](std::size_t n) { return Allocate(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
#endif

namespace hapticpd::testing {
CountAllocations::CountAllocations() {
  t_count = 0;
  t_counting = true;
}
CountAllocations::~CountAllocations() { t_counting = false; }
std::size_t CountAllocations::count() const { return t_count; }
bool CountAllocations::Available() { return HAPTICPD_COUNT_ALLOCATIONS != 0; }
}  // namespace hapticpd::testing
