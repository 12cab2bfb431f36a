// The one place where absl::Status becomes grpc::Status (as TensorFlow Serving's
// grpc_status_util.cc): codes map one to one; messages are capped at kMaxStatusMessage bytes
// and scrubbed of file paths; INTERNAL, UNKNOWN and DATA_LOSS say only what kind of failure it
// was (their details, which may name files or SQLite, go to the server log). The name of the
// storage operation that failed ("SetSessionState: ", storage::kOperationPayload) is taken off:
// a client is told what is wrong, not which function found it.
//
// The database's own errors (storage::kDatabaseErrorPayload: libpq's, PostgreSQL's and SQLite's
// text, which names the database's host and port, its constraints, a statement's context) never
// reach a client: it is told a fixed sentence for the code, e.g. UNAVAILABLE "the calibration
// service's database is unavailable", and the detail goes to the server log (event
// database_unavailable or database_error, at most one line a second of each, with the count of
// those left out since).
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

// The message ToGrpcStatus would send for `status` (for errors carried in a response, such as
// SolveJob.error). For a database error it logs the detail, as ToGrpcStatus does.
std::string ClientMessage(const absl::Status& status);

// What a client is told in place of a database error of `code` (see above).
inline constexpr char kDatabaseUnavailableMessage[] =
    "the calibration service's database is unavailable";
std::string DatabaseErrorMessage(absl::StatusCode code);

// Marks a message made of the request's own fields (a rostopic, a capture's name) and ids,
// with nothing of the server's files in it: ToGrpcStatus leaves it unscrubbed (only capped),
// since the scrubber would garble what the client sent ("/imu0" looks like a path).
absl::Status EchoesRequest(absl::Status status);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_STATUS_UTIL_H_
