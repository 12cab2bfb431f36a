#include "server/status_util.h"

#include <cstdint>
#include <cstdio>
#include <mutex>
#include <optional>
#include <string>

#include "absl/strings/cord.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/time/clock.h"
#include "server/log.h"
#include "storage/types.h"
#include "util/db.h"

namespace imucal::server {
namespace {

// A token that names a file: an absolute or relative path, or a database file. Units such as
// "m/s^2" contain a slash too, so only tokens that start like a path count.
bool LooksLikePath(absl::string_view token) {
  while (!token.empty() && (token.front() == '\'' || token.front() == '"' || token.front() == '(' ||
                            token.front() == '['))
    token.remove_prefix(1);
  if (token.empty()) return false;
  if (token.front() == '/' || absl::StartsWith(token, "./") || absl::StartsWith(token, "../") ||
      absl::StartsWith(token, "~/"))
    return true;
  return absl::StrContains(token, ".db") || absl::StrContains(token, ".sqlite");
}

constexpr char kEchoesRequestPayload[] = "imucal.server/echoes-request";

std::string Capped(std::string message) {
  if (message.size() > kMaxStatusMessage) {
    message.resize(kMaxStatusMessage - 3);
    message += "...";
  }
  return message;
}

// The message without the storage operation's name in front of it (storage/types.h).
std::string WithoutOperation(const absl::Status& status) {
  std::string message(status.message());
  if (auto prefix = status.GetPayload(storage::kOperationPayload); prefix.has_value()) {
    const std::string p(*prefix);
    if (const size_t at = message.find(p); at != std::string::npos) message.erase(at, p.size());
  }
  return message;
}

// The detail of a database error, for the operator: at most one line a second per event, so
// that an outage (every call failing alike) does not flood the log; a line says how many were
// left out before it.
void LogDatabaseError(const absl::Status& status) {
  const bool unavailable = status.code() == absl::StatusCode::kUnavailable;
  struct Limiter {
    std::mutex mu;
    absl::Time last = absl::InfinitePast();
    int64_t left_out = 0;
  };
  static Limiter limiters[2];
  Limiter& l = limiters[unavailable ? 0 : 1];
  int64_t left_out = 0;
  {
    std::lock_guard lock(l.mu);
    const absl::Time now = absl::Now();
    if (now - l.last < absl::Seconds(1)) {
      ++l.left_out;
      return;
    }
    l.last = now;
    left_out = l.left_out;
    l.left_out = 0;
  }
  Log(LogLevel::kWarning, unavailable ? "database_unavailable" : "database_error",
      {{"code", absl::StatusCodeToString(status.code())},
       {"error", std::string(status.message())},
       {"left_out", left_out}});
}

grpc::StatusCode ToGrpcCode(absl::StatusCode code) {
  // absl's canonical codes are gRPC's, number for number.
  return static_cast<grpc::StatusCode>(static_cast<int>(code));
}

}  // namespace

std::string ScrubMessage(absl::string_view message) {
  std::vector<std::string> tokens = absl::StrSplit(message, ' ');
  for (std::string& t : tokens)
    if (LooksLikePath(t)) t = "<path>";
  return Capped(absl::StrJoin(tokens, " "));
}

absl::Status EchoesRequest(absl::Status status) {
  if (!status.ok()) status.SetPayload(kEchoesRequestPayload, absl::Cord("1"));
  return status;
}

std::string DatabaseErrorMessage(absl::StatusCode code) {
  switch (code) {
    case absl::StatusCode::kUnavailable:
      return kDatabaseUnavailableMessage;
    case absl::StatusCode::kAlreadyExists:
    case absl::StatusCode::kFailedPrecondition:
    case absl::StatusCode::kAborted:
      return "the calibration service's database refused the change: another one made at the "
             "same time conflicts with it; retry";
    case absl::StatusCode::kResourceExhausted:
      return "the calibration service's database is out of resources (space, memory or "
             "connections)";
    case absl::StatusCode::kCancelled:
    case absl::StatusCode::kDeadlineExceeded:
      return "the calibration service's database did not finish in time; retry";
    case absl::StatusCode::kDataLoss:
      return "stored data is damaged; see the server log";
    default:
      return "the calibration service's database failed; see the server log";
  }
}

std::string ClientMessage(const absl::Status& status) {
  if (sql::IsFromDatabase(status)) {
    LogDatabaseError(status);
    return DatabaseErrorMessage(status.code());
  }
  const std::string message = WithoutOperation(status);
  return status.GetPayload(kEchoesRequestPayload).has_value() ? Capped(message)
                                                              : ScrubMessage(message);
}

grpc::Status ToGrpcStatus(const absl::Status& status) {
  if (status.ok()) return grpc::Status::OK;
  if (sql::IsFromDatabase(status))
    return grpc::Status(ToGrpcCode(status.code()), ClientMessage(status));
  switch (status.code()) {
    case absl::StatusCode::kInternal:
    case absl::StatusCode::kUnknown:
    case absl::StatusCode::kDataLoss:
      std::fprintf(stderr, "imucald: %s\n", status.ToString().c_str());
      return grpc::Status(ToGrpcCode(status.code()),
                          status.code() == absl::StatusCode::kDataLoss
                              ? "stored data is damaged; see the server log"
                              : "internal error; see the server log");
    default:
      return grpc::Status(ToGrpcCode(status.code()), ClientMessage(status));
  }
}

}  // namespace imucal::server
