// The one place where absl::Status becomes grpc::Status (as TensorFlow Serving's
// grpc_status_util.cc): codes map one to one; messages are capped at kMaxStatusMessage bytes
// and scrubbed of file paths; INTERNAL, UNKNOWN and DATA_LOSS say only what kind of failure it
// was (their details, which may name files or SQLite, go to the server log).
#ifndef IMUCAL_SERVER_STATUS_UTIL_H_
#define IMUCAL_SERVER_STATUS_UTIL_H_

#include <cstddef>
#include <string>

#include "absl/status/status.h"
#include "absl/strings/string_view.h"
#include "grpcpp/support/status.h"

namespace imucal::server {

inline constexpr size_t kMaxStatusMessage = 512;

grpc::Status ToGrpcStatus(const absl::Status& status);

// What ToGrpcStatus does to a message: paths replaced by "<path>", capped. Exposed for tests.
std::string ScrubMessage(absl::string_view message);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_STATUS_UTIL_H_
