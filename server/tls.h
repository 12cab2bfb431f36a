// The credentials of imucald's listener: TLS with the server's certificate, optionally asking
// robots for a client certificate; or, only when asked for and only on a loopback address,
// plaintext.
//
// Client certificates: with a client CA, the listener uses
// GRPC_SSL_REQUEST_CLIENT_CERTIFICATE_AND_VERIFY: it asks every client for a certificate,
// verifies one that is presented against the client CA (a certificate that does not verify ends
// the handshake), and lets a client without one connect. So robots may authenticate with a
// certificate (mutual TLS; its common name is the device id) while technicians, whose laptops
// carry no certificate, use tokens; every call still needs one or the other (server/auth.h).
// REQUIRE_... would lock technicians out; DONT_REQUEST would make robot certificates useless.
#ifndef IMUCAL_SERVER_TLS_H_
#define IMUCAL_SERVER_TLS_H_

#include <memory>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "grpcpp/security/server_credentials.h"

namespace imucal::server {

struct ListenerSecurity {
  std::string tls_cert_path;   // PEM: the server's certificate (chain), leaf first
  std::string tls_key_path;    // PEM: its private key
  std::string client_ca_path;  // PEM: CA(s) of robot client certificates; empty: none asked
  bool insecure = false;       // plaintext, allowed only on a loopback address
};

// True for 127.0.0.0/8, ::1 (bracketed or not) and "localhost".
bool IsLoopbackHost(std::string_view host);

// The listener's credentials for `listen` ("host:port"). InvalidArgument, naming the option,
// for: insecure on a non-loopback address; insecure together with a certificate; a missing
// certificate or key; a file that cannot be read, holds no PEM certificate or key, a key that
// does not belong to the certificate, or a certificate outside its validity period.
absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> ListenerCredentials(
    std::string_view listen, const ListenerSecurity& security);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_TLS_H_
