// One function per fuzzed parser: feeds `data` through it and checks what must hold for any
// input (an accepted capture satisfies ValidateCapture; an accepted imucal CSV that is writable
// formats and parses back to itself, and so does a bag's metadata.yaml rewritten by yaml-cpp; a
// SampleBatch that validation accepts encodes and decodes to the same samples). A violated property
// aborts with a message (a crash for libFuzzer).
//
// The libFuzzer binaries (tests/fuzz/CMakeLists.txt, IMUCAL_BUILD_FUZZERS) call them; so does
// fuzz_regression_test in the ordinary build, over the seed corpora and every crashing input
// kept in tests/fuzz/regressions/<target>/.
#ifndef IMUCAL_TESTS_FUZZ_FUZZ_TARGETS_H_
#define IMUCAL_TESTS_FUZZ_FUZZ_TARGETS_H_

#include <string_view>

namespace imucal::fuzz {

void FuzzCaptureCsv(std::string_view data);  // importers::ParseImucalCsv (+ format round trip)
void FuzzImuTk(std::string_view data);       // importers::ParseImuTkPair (the bytes cut in two)
void FuzzColumns(std::string_view data);     // importers::ParseColumnCsv (options from byte 0)
void FuzzEuroc(std::string_view data);       // importers::ParseEurocCsv
void FuzzRosbag2Cdr(std::string_view data);  // importers::DecodeImuCdr (sensor_msgs/Imu)
void FuzzRosbag2Metadata(std::string_view data);  // importers::ParseBagMetadata (+ round trip)
void FuzzMcap(std::string_view data);             // importers::McapReader (every Imu topic)
void FuzzSampleBatch(std::string_view data);      // v1::SampleBatch bytes -> server validation

// The targets by name (the directory names under tests/fuzz/corpus and regressions).
struct FuzzTarget {
  const char* name;
  void (*run)(std::string_view);
};
inline constexpr FuzzTarget kFuzzTargets[] = {
    {"capture_csv", FuzzCaptureCsv},
    {"imutk", FuzzImuTk},
    {"columns", FuzzColumns},
    {"euroc", FuzzEuroc},
    {"rosbag2_cdr", FuzzRosbag2Cdr},
    {"sample_batch", FuzzSampleBatch},
    {"rosbag2_metadata", FuzzRosbag2Metadata},
    {"mcap", FuzzMcap},
};

}  // namespace imucal::fuzz

#endif  // IMUCAL_TESTS_FUZZ_FUZZ_TARGETS_H_
