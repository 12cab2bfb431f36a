// What the services' unary callback handlers share: finishing with an absl::Status (through
// the one ToGrpcStatus), and the page size of a List call.
#ifndef IMUCAL_SERVER_UNARY_H_
#define IMUCAL_SERVER_UNARY_H_

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "grpcpp/grpcpp.h"
#include "server/status_util.h"

namespace imucal::server {

inline grpc::ServerUnaryReactor* FinishUnary(grpc::CallbackServerContext* context,
                                             const absl::Status& status) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  reactor->Finish(ToGrpcStatus(status));
  return reactor;
}

// Pages are by key (the store's paging): the token is the key of a page's last item. Returns
// the page size to use (0 means 100; at most `max_page_size`).
inline absl::StatusOr<int> PageSize(int page_size, int max_page_size) {
  if (page_size < 0 || page_size > max_page_size)
    return absl::InvalidArgumentError(absl::StrCat("page_size: must be 0..", max_page_size));
  return page_size == 0 ? 100 : page_size;
}

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_UNARY_H_
