#include "server/status_util.h"

#include <cstdio>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"

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

grpc::StatusCode ToGrpcCode(absl::StatusCode code) {
  // absl's canonical codes are gRPC's, number for number.
  return static_cast<grpc::StatusCode>(static_cast<int>(code));
}

}  // namespace

std::string ScrubMessage(absl::string_view message) {
  std::vector<std::string> tokens = absl::StrSplit(message, ' ');
  for (std::string& t : tokens)
    if (LooksLikePath(t)) t = "<path>";
  std::string out = absl::StrJoin(tokens, " ");
  if (out.size() > kMaxStatusMessage) {
    out.resize(kMaxStatusMessage - 3);
    out += "...";
  }
  return out;
}

grpc::Status ToGrpcStatus(const absl::Status& status) {
  if (status.ok()) return grpc::Status::OK;
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
      return grpc::Status(ToGrpcCode(status.code()), ScrubMessage(status.message()));
  }
}

}  // namespace imucal::server
