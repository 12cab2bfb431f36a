// The libFuzzer entry point of one target; IMUCAL_FUZZ_TARGET names its function in
// fuzz_targets.h (tests/fuzz/CMakeLists.txt builds one binary per target).
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "tests/fuzz/fuzz_targets.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  imucal::fuzz::IMUCAL_FUZZ_TARGET(std::string_view(reinterpret_cast<const char*>(data), size));
  return 0;
}
