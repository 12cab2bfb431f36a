// The fuzz targets in the ordinary build: every seed input (tests/fuzz/corpus/<target>/) and
// every input that once crashed a parser (tests/fuzz/regressions/<target>/) goes through its
// target's function again; a property violation or a crash fails the test.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "tests/fuzz/fuzz_targets.h"

namespace imucal::fuzz {
namespace {

namespace fs = std::filesystem;

std::vector<fs::path> Inputs(const std::string& kind, const std::string& target) {
  std::vector<fs::path> out;
  const fs::path dir = fs::path(IMUCAL_FUZZ_DIR) / kind / target;
  if (!fs::is_directory(dir)) return out;
  for (const fs::directory_entry& e : fs::directory_iterator(dir))
    if (e.is_regular_file()) out.push_back(e.path());
  std::sort(out.begin(), out.end());
  return out;
}

std::string Read(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(FuzzRegressionTest, SeedsAndCrashInputsRunClean) {
  int seeds = 0;
  for (const FuzzTarget& t : kFuzzTargets) {
    const std::vector<fs::path> corpus = Inputs("corpus", t.name);
    EXPECT_FALSE(corpus.empty()) << "no seed corpus for " << t.name;
    seeds += static_cast<int>(corpus.size());
    for (const std::string kind : {"corpus", "regressions"}) {
      for (const fs::path& p : Inputs(kind, t.name)) {
        SCOPED_TRACE(p.string());
        t.run(Read(p));  // aborts (fails the test) on a violated property
      }
    }
  }
  EXPECT_GE(seeds, 6);
}

}  // namespace
}  // namespace imucal::fuzz
