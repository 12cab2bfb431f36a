// grpc::Status <-> absl::Status. The two code enums are the same canonical codes with the same
// numbers, so the mapping is one to one; the server's message is kept as it is.
#ifndef IMUCAL_CLIENT_SDK_GRPC_STATUS_H_
#define IMUCAL_CLIENT_SDK_GRPC_STATUS_H_

#include <string>

#include "absl/status/status.h"
#include "grpcpp/support/status.h"

namespace imucal::sdk {

inline absl::Status FromGrpcStatus(const grpc::Status& status) {
  if (status.ok()) return absl::OkStatus();
  return absl::Status(static_cast<absl::StatusCode>(status.error_code()), status.error_message());
}

// True for the codes that mean "the server could not be reached or the call did not finish",
// as opposed to an answer from the server.
inline bool IsUnreachable(const absl::Status& status) {
  return absl::IsUnavailable(status) || absl::IsDeadlineExceeded(status);
}

// The server answered, but its database cannot be reached: UNAVAILABLE with this message
// (server/status_util.h, kDatabaseUnavailableMessage). Retrying later helps, as for an
// unreachable server, but the server itself is up and says so.
inline constexpr char kDatabaseUnavailableMessage[] =
    "the calibration service's database is unavailable";
inline bool IsDatabaseUnavailable(const absl::Status& status) {
  return absl::IsUnavailable(status) && status.message() == kDatabaseUnavailableMessage;
}

}  // namespace imucal::sdk

#endif  // IMUCAL_CLIENT_SDK_GRPC_STATUS_H_
