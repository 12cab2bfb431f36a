// Finishing a unary callback RPC with an absl::Status (through the one ToGrpcStatus).
#ifndef IMUCAL_SERVER_UNARY_H_
#define IMUCAL_SERVER_UNARY_H_

#include "absl/status/status.h"
#include "grpcpp/grpcpp.h"
#include "server/status_util.h"

namespace imucal::server {

inline grpc::ServerUnaryReactor* FinishUnary(grpc::CallbackServerContext* context,
                                             const absl::Status& status) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  reactor->Finish(ToGrpcStatus(status));
  return reactor;
}

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_UNARY_H_
