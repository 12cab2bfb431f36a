// AdminService: API tokens (admin role only; server/auth.cc).
#include "server/admin_service.h"

#include <string>

#include "server/convert.h"
#include "server/unary.h"

namespace imucal::server {
namespace {

absl::StatusOr<storage::Role> RoleFromProto(v1::Role role) {
  switch (role) {
    case v1::ROLE_ROBOT:
      return storage::Role::kRobot;
    case v1::ROLE_TECHNICIAN:
      return storage::Role::kTechnician;
    case v1::ROLE_ADMIN:
      return storage::Role::kAdmin;
    default:
      return absl::InvalidArgumentError(
          "role: required (ROLE_ROBOT, ROLE_TECHNICIAN or ROLE_ADMIN)");
  }
}

v1::Role RoleToProto(storage::Role role) {
  switch (role) {
    case storage::Role::kRobot:
      return v1::ROLE_ROBOT;
    case storage::Role::kTechnician:
      return v1::ROLE_TECHNICIAN;
    case storage::Role::kAdmin:
      return v1::ROLE_ADMIN;
  }
  return v1::ROLE_UNSPECIFIED;
}

v1::Token TokenToProto(const storage::Token& t) {
  v1::Token out;
  out.set_id(t.id);
  out.set_role(RoleToProto(t.role));
  out.set_device_id(t.device_id);
  out.set_label(t.label);
  ToTimestamp(t.created_at, out.mutable_created_at());
  if (t.revoked_at) ToTimestamp(*t.revoked_at, out.mutable_revoked_at());
  return out;
}

}  // namespace

absl::Status AdminServiceImpl::DoCreateToken(const grpc::CallbackServerContext& context,
                                             const v1::CreateTokenRequest& request,
                                             v1::CreateTokenResponse* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(context, Rpc::kCreateToken);
  if (!who.ok()) return who.status();
  absl::StatusOr<storage::Role> role = RoleFromProto(request.role());
  if (!role.ok()) return role.status();
  absl::StatusOr<storage::NewToken> created =
      auth_->CreateToken(*role, request.device_id(), request.label(), (*who)->actor);
  if (!created.ok()) return created.status();
  *response->mutable_token() = TokenToProto(created->token);
  response->set_secret(created->secret);
  return absl::OkStatus();
}

absl::Status AdminServiceImpl::DoListTokens(const grpc::CallbackServerContext& context,
                                            const v1::ListTokensRequest& request,
                                            v1::ListTokensResponse* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(context, Rpc::kListTokens);
  if (!who.ok()) return who.status();
  absl::StatusOr<std::vector<storage::Token>> tokens = auth_->ListTokens(request.include_revoked());
  if (!tokens.ok()) return tokens.status();
  for (const storage::Token& t : *tokens) *response->add_tokens() = TokenToProto(t);
  return absl::OkStatus();
}

absl::Status AdminServiceImpl::DoRevokeToken(const grpc::CallbackServerContext& context,
                                             const v1::RevokeTokenRequest& request,
                                             v1::Token* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(context, Rpc::kRevokeToken);
  if (!who.ok()) return who.status();
  if (request.id() < 1) return absl::InvalidArgumentError("id: a token id is 1 or more");
  absl::StatusOr<storage::Token> revoked = auth_->RevokeToken(request.id(), (*who)->actor);
  if (!revoked.ok()) return revoked.status();
  *response = TokenToProto(*revoked);
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* AdminServiceImpl::CreateToken(grpc::CallbackServerContext* context,
                                                        const v1::CreateTokenRequest* request,
                                                        v1::CreateTokenResponse* response) {
  return FinishUnary(context, DoCreateToken(*context, *request, response));
}

grpc::ServerUnaryReactor* AdminServiceImpl::ListTokens(grpc::CallbackServerContext* context,
                                                       const v1::ListTokensRequest* request,
                                                       v1::ListTokensResponse* response) {
  return FinishUnary(context, DoListTokens(*context, *request, response));
}

grpc::ServerUnaryReactor* AdminServiceImpl::RevokeToken(grpc::CallbackServerContext* context,
                                                        const v1::RevokeTokenRequest* request,
                                                        v1::Token* response) {
  return FinishUnary(context, DoRevokeToken(*context, *request, response));
}

}  // namespace imucal::server
