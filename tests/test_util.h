// Helpers shared by the test suites: seeds and counts from the environment,
// the shared model folder, and log expectations.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <string>

namespace hapticpd::testing {

/// True in the sanitizer builds (HAPTICPD_ASAN / HAPTICPD_TSAN, defined by
/// the top CMakeLists.txt from the flags), where code runs several times
/// slower: heavy randomized tests run fewer cases there.
#if defined(HAPTICPD_ASAN) || defined(HAPTICPD_TSAN)
inline constexpr bool kSanitized = true;
#else
inline constexpr bool kSanitized = false;
#endif

/// Seed for randomized tests: HAPTICPD_TEST_SEED, else `fallback`.
inline std::uint64_t TestSeed(std::uint64_t fallback = 20261121) {
  const char* s = std::getenv("HAPTICPD_TEST_SEED");
  return s ? std::strtoull(s, nullptr, 10) : fallback;
}

/// Long mode (`--long` on a test binary's command line, or HAPTICPD_LONG=1):
/// randomized tests run 20x their default count.
inline bool& LongMode() {
  static bool long_mode = [] {
    const char* s = std::getenv("HAPTICPD_LONG");
    return s != nullptr && std::atoi(s) != 0;
  }();
  return long_mode;
}

/// Count for randomized tests: HAPTICPD_TEST_COUNT, else `fallback` (20x in
/// long mode).
inline int TestCount(int fallback) {
  const char* s = std::getenv("HAPTICPD_TEST_COUNT");
  return s ? std::atoi(s) : (LongMode() ? 20 * fallback : fallback);
}

/// The folder of shared public test meshes (../shared/models next to the
/// checkout, or HAPTICPD_MODELS_DIR). Empty when absent.
inline std::filesystem::path ModelsDir() {
  if (const char* env = std::getenv("HAPTICPD_MODELS_DIR")) return env;
#ifdef HAPTICPD_MODELS_DIR
  std::filesystem::path p(HAPTICPD_MODELS_DIR);
  if (std::filesystem::exists(p)) return p;
#endif
  return {};
}

/// Full path of a shared model, or empty when the folder or file is absent.
inline std::filesystem::path SharedModel(const std::string& name) {
  auto dir = ModelsDir();
  if (dir.empty() || !std::filesystem::exists(dir / name)) return {};
  return dir / name;
}

#define HAPTICPD_REQUIRE_MODEL(var, name)                                                \
  const auto var = ::hapticpd::testing::SharedModel(name);                               \
  if (var.empty()) {                                                                     \
    GTEST_SKIP() << "shared model " << name                                              \
                 << " not found (expected in ../shared/models or $HAPTICPD_MODELS_DIR)"; \
  }

/// While alive, warnings and errors logged by project code do not fail the
/// running test (for tests that exercise bad input on purpose).
class ScopedExpectLogs {
 public:
  ScopedExpectLogs();
  ~ScopedExpectLogs();
  ScopedExpectLogs(const ScopedExpectLogs&) = delete;
  ScopedExpectLogs& operator=(const ScopedExpectLogs&) = delete;
};

}  // namespace hapticpd::testing
