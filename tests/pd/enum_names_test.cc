// EnumName and the compile-time check that a name table covers its enum.
#include "pd/enum_names.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <utility>

namespace hapticpd {
namespace {

// Enumerators neither from 0 nor contiguous, as the wire-mapped enums are.
enum class Gappy : std::uint8_t { kOne = 1, kTwo = 2, kFive = 5 };

constexpr std::pair<Gappy, const char*> kGappyNames[] = {
    {Gappy::kFive, "five"}, {Gappy::kOne, "one"}, {Gappy::kTwo, "two"}};
constexpr std::pair<Gappy, const char*> kMissesOne[] = {{Gappy::kOne, "one"}, {Gappy::kTwo, "two"}};
constexpr std::pair<Gappy, const char*> kNamesOneTwice[] = {
    {Gappy::kOne, "one"}, {Gappy::kTwo, "two"}, {Gappy::kOne, "five"}};
constexpr std::pair<Gappy, const char*> kHoldsANonEnumerator[] = {
    {Gappy::kOne, "one"}, {Gappy::kTwo, "two"}, {Gappy::kFive, "five"}, {Gappy{3}, "three"}};

static_assert(internal::NamesEveryEnumerator(kGappyNames));
static_assert(!internal::NamesEveryEnumerator(kMissesOne));
static_assert(!internal::NamesEveryEnumerator(kNamesOneTwice));
static_assert(!internal::NamesEveryEnumerator(kHoldsANonEnumerator));

TEST(EnumName, NamesEachEnumeratorAndFallsBackForOtherValues) {
  EXPECT_EQ(std::string(EnumName<kGappyNames>(Gappy::kOne, "?")), "one");
  EXPECT_EQ(std::string(EnumName<kGappyNames>(Gappy::kTwo, "?")), "two");
  EXPECT_EQ(std::string(EnumName<kGappyNames>(Gappy::kFive, "?")), "five");
  EXPECT_EQ(std::string(EnumName<kGappyNames>(Gappy{0}, "?")), "?");
  EXPECT_EQ(std::string(EnumName<kGappyNames>(Gappy{3}, "unknown")), "unknown");
}

}  // namespace
}  // namespace hapticpd
