// Names for enumerators from one table per enum, checked by the compiler:
// a table that misses an enumerator, names one twice or holds a value that
// is not an enumerator does not compile, as a switch without a default
// warns (-Werror) on a missing case.
//
//   constexpr std::pair<Effect, const char*> kEffectNames[] = {{Effect::kContact, "contact"}, ...};
//   const char* ToString(Effect e) { return EnumName<kEffectNames>(e, "?"); }
//
// Header only, no dependencies: every module may use it (device/ includes
// it without linking pd/).
#pragma once

#include <cstddef>
#include <string_view>
#include <utility>

namespace hapticpd {

namespace internal {

/// Enumerator values are looked for in [0, kEnumScanLimit): a scoped enum
/// whose enumerators lie elsewhere cannot use EnumName.
inline constexpr int kEnumScanLimit = 64;

/// True when kValue is a named enumerator of its enum. GCC and clang spell a
/// named value by its name in the function's signature ("kValue = ns::E::kOk")
/// and any other value as a cast ("kValue = (ns::E)4").
template <auto kValue>
consteval bool IsNamedEnumerator() {
  constexpr std::string_view kSignature = __PRETTY_FUNCTION__;
  constexpr std::string_view kKey = "kValue = ";
  constexpr std::size_t kAt = kSignature.find(kKey);
  static_assert(kAt != std::string_view::npos, "unknown __PRETTY_FUNCTION__ layout");
  return kSignature[kAt + kKey.size()] != '(';
}

template <typename E, int... kI>
consteval int CountNamedEnumerators(std::integer_sequence<int, kI...>) {
  return (int{IsNamedEnumerator<static_cast<E>(kI)>()} + ...);
}

template <typename E, int... kI>
consteval bool IsEnumeratorValue(E e, std::integer_sequence<int, kI...>) {
  return ((static_cast<int>(e) == kI && IsNamedEnumerator<static_cast<E>(kI)>()) || ...);
}

/// True when `names` holds every enumerator of E exactly once and nothing else.
template <typename E, std::size_t N>
consteval bool NamesEveryEnumerator(const std::pair<E, const char*> (&names)[N]) {
  using Scan = std::make_integer_sequence<int, kEnumScanLimit>;
  for (std::size_t i = 0; i < N; ++i) {
    if (!IsEnumeratorValue(names[i].first, Scan{})) return false;
    for (std::size_t j = 0; j < i; ++j) {
      if (names[j].first == names[i].first) return false;
    }
  }
  return static_cast<int>(N) == CountNamedEnumerators<E>(Scan{});
}

// The probe must tell the two apart on this compiler, or every check above
// would be meaningless.
enum class ProbeSelfTest { kA, kB = 2 };
static_assert(IsNamedEnumerator<ProbeSelfTest::kA>() && IsNamedEnumerator<ProbeSelfTest::kB>() &&
                  !IsNamedEnumerator<static_cast<ProbeSelfTest>(1)>(),
              "this compiler spells enumerators differently in __PRETTY_FUNCTION__");

}  // namespace internal

/// The name `kNames` gives `e`, or `unknown` for a value that is no
/// enumerator (a cast from a foreign number). `kNames` is an array of
/// {enumerator, name} pairs with static storage; it must name every
/// enumerator of the enum once (checked at compile time).
template <const auto& kNames, typename E>
constexpr const char* EnumName(E e, const char* unknown) {
  static_assert(internal::NamesEveryEnumerator(kNames),
                "the name table must hold every enumerator exactly once");
  for (const auto& [value, name] : kNames) {
    if (value == e) return name;
  }
  return unknown;
}

}  // namespace hapticpd
