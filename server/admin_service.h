// AdminService of imucal/v1/imucal.proto: API tokens, for the admin role (server/auth.h).
#ifndef IMUCAL_SERVER_ADMIN_SERVICE_H_
#define IMUCAL_SERVER_ADMIN_SERVICE_H_

#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/auth.h"

namespace imucal::server {

class AdminServiceImpl final : public v1::AdminService::CallbackService {
 public:
  explicit AdminServiceImpl(Authorizer* auth) : auth_(auth) {}
  grpc::ServerUnaryReactor* CreateToken(grpc::CallbackServerContext* context,
                                        const v1::CreateTokenRequest* request,
                                        v1::CreateTokenResponse* response) override;
  grpc::ServerUnaryReactor* ListTokens(grpc::CallbackServerContext* context,
                                       const v1::ListTokensRequest* request,
                                       v1::ListTokensResponse* response) override;
  grpc::ServerUnaryReactor* RevokeToken(grpc::CallbackServerContext* context,
                                        const v1::RevokeTokenRequest* request,
                                        v1::Token* response) override;

 private:
  absl::Status DoCreateToken(const grpc::CallbackServerContext& context,
                             const v1::CreateTokenRequest& request,
                             v1::CreateTokenResponse* response);
  absl::Status DoListTokens(const grpc::CallbackServerContext& context,
                            const v1::ListTokensRequest& request, v1::ListTokensResponse* response);
  absl::Status DoRevokeToken(const grpc::CallbackServerContext& context,
                             const v1::RevokeTokenRequest& request, v1::Token* response);

  Authorizer* auth_;  // not owned
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_ADMIN_SERVICE_H_
