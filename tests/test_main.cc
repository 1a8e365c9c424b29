// Test entry point. Installs a log sink that fails the running test on any
// warning or error logged by project code, unless the test declared it
// expects such logs (hapticpd::testing::ScopedExpectLogs).
#include <gtest/gtest.h>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <iostream>
#include <mutex>
#include <string_view>

#include "tests/test_util.h"

namespace hapticpd::testing {
namespace {
std::atomic<int> g_expect_depth{0};

class FailOnWarningSink final : public spdlog::sinks::base_sink<std::mutex> {
 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    if (msg.level >= spdlog::level::warn && g_expect_depth.load() == 0) {
      ADD_FAILURE() << "unexpected log (" << spdlog::level::to_string_view(msg.level).data()
                    << "): " << std::string(msg.payload.data(), msg.payload.size());
    }
  }
  void flush_() override {}
};
}  // namespace

ScopedExpectLogs::ScopedExpectLogs() { ++g_expect_depth; }
ScopedExpectLogs::~ScopedExpectLogs() { --g_expect_depth; }

}  // namespace hapticpd::testing

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  // Our own flag (gtest leaves arguments it does not know in argv).
  for (int i = 1; i < argc; ++i) {
    if (std::string_view(argv[i]) == "--long") {
      hapticpd::testing::LongMode() = true;
    } else {
      std::cerr << "unknown argument: " << argv[i] << " (gtest flags, or --long)\n";
      return 2;
    }
  }
  auto sink = std::make_shared<hapticpd::testing::FailOnWarningSink>();
  auto logger = std::make_shared<spdlog::logger>("test", sink);
  spdlog::set_default_logger(logger);
  return RUN_ALL_TESTS();
}
