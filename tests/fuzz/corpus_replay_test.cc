// Replays every committed seed and crash reproducer under tests/fuzz/corpus/
// through the fuzz targets' entry points, in the normal build (no clang or
// libFuzzer needed): a reproducer that crashes again fails here.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <vector>

#include "tests/fuzz/fuzz_entries.h"

namespace hapticpd::testing {
namespace {

namespace fs = std::filesystem;

TEST(FuzzCorpusReplay, EveryCommittedInputRunsCleanly) {
  const fs::path root(HAPTICPD_FUZZ_CORPUS_DIR);
  for (const auto& target : fuzz::Targets()) {
    SCOPED_TRACE(target.name);
    const fs::path dir = root / target.name;
    ASSERT_TRUE(fs::is_directory(dir)) << "no corpus folder " << dir;
    int files = 0;
    for (const auto& e : fs::directory_iterator(dir)) {
      if (!e.is_regular_file()) continue;
      SCOPED_TRACE(e.path().string());
      std::ifstream in(e.path(), std::ios::binary);
      const std::vector<char> bytes((std::istreambuf_iterator<char>(in)),
                                    std::istreambuf_iterator<char>());
      target.run(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
      ++files;
    }
    EXPECT_GT(files, 0) << "empty corpus " << dir;
  }
}

}  // namespace
}  // namespace hapticpd::testing
