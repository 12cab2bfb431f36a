// The robot's local copy of its active parameter set, so that it can boot when the calibration
// service is unreachable. One file per device, written atomically:
//
//   imucal-param-cache v1\n
//   device robot-0042\n
//   version 7\n
//   crc32c e3069283\n          (CRC-32C of the JSON bytes, 8 lower-case hex digits)
//   length 1234\n              (bytes of JSON that follow)
//   \n
//   {...the "imucal-params v1" JSON exactly as the server stored it...}
//
// The header is text so that a technician can `head` the file on the robot; the checksum is the
// server's ParameterSet.crc32c, so the bytes on disk are checked against what the server sent.
#ifndef IMUCAL_CLIENT_SDK_PARAM_CACHE_H_
#define IMUCAL_CLIENT_SDK_PARAM_CACHE_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/params.h"

namespace imucal::sdk {

inline constexpr std::string_view kParamCacheFormat = "imucal-param-cache v1";

// A parameter set as the server hands it out: header fields and the JSON text.
struct StoredParams {
  std::string device_id;
  int version = 0;
  uint32_t crc32c = 0;  // of `json`
  std::string json;     // "imucal-params v1"
};

// A stored parameter set with its JSON parsed.
struct LoadedParams {
  StoredParams stored;
  core::ParamSet params;
};

// Checks that stored.crc32c is the CRC-32C of stored.json (DataLoss otherwise), parses the JSON
// (InvalidArgument as ParamSetFromJson) and checks that its device and version agree with the
// header (DataLoss naming the field otherwise; a JSON without a version, 0, is accepted).
absl::StatusOr<LoadedParams> ParseStoredParams(StoredParams stored);

// Writes `params` to `path` atomically: a temp file beside it, fsync, rename over `path`, fsync
// of the directory. `path` keeps its old content unless the new one is complete.
// InvalidArgument if params.crc32c does not match params.json (nothing is written).
absl::Status SaveParamCache(const std::string& path, const StoredParams& params);

// Reads and verifies a cache file: NotFound if there is none; DataLoss naming the problem if it
// is not a cache file, has another format version, a malformed or truncated header or body, a
// checksum that does not match, or JSON that does not parse or disagrees with the header.
absl::StatusOr<LoadedParams> LoadParamCache(const std::string& path);

}  // namespace imucal::sdk

#endif  // IMUCAL_CLIENT_SDK_PARAM_CACHE_H_
