#include "server/tls.h"

#include <arpa/inet.h>
#include <openssl/bio.h>
#include <openssl/pem.h>
#include <openssl/x509.h>

#include <fstream>
#include <sstream>

#include "grpcpp/security/server_credentials.h"
#include "util/str_util.h"

namespace imucal::server {
namespace {

struct BioFree {
  void operator()(BIO* b) const { BIO_free(b); }
};
struct X509Free {
  void operator()(X509* x) const { X509_free(x); }
};
struct KeyFree {
  void operator()(EVP_PKEY* k) const { EVP_PKEY_free(k); }
};

absl::StatusOr<std::string> ReadPem(std::string_view option, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::InvalidArgumentError(Cat(option, ": cannot read ", path));
  std::ostringstream text;
  text << in.rdbuf();
  if (text.str().empty()) return absl::InvalidArgumentError(Cat(option, ": ", path, " is empty"));
  return text.str();
}

std::unique_ptr<BIO, BioFree> Bio(const std::string& pem) {
  return std::unique_ptr<BIO, BioFree>(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())));
}

absl::StatusOr<std::unique_ptr<X509, X509Free>> FirstCertificate(std::string_view option,
                                                                 const std::string& path,
                                                                 const std::string& pem) {
  auto bio = Bio(pem);
  std::unique_ptr<X509, X509Free> cert(PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr));
  if (cert == nullptr)
    return absl::InvalidArgumentError(Cat(option, ": ", path, " holds no PEM certificate"));
  return cert;
}

// A certificate outside its validity period fails every handshake with a vague error on the
// client's side: say so at start instead.
absl::Status CheckValidNow(std::string_view option, const std::string& path, X509* cert) {
  if (X509_cmp_current_time(X509_get0_notBefore(cert)) > 0)
    return absl::InvalidArgumentError(
        Cat(option, ": the certificate in ", path, " is not valid yet (check the clock)"));
  if (X509_cmp_current_time(X509_get0_notAfter(cert)) < 0)
    return absl::InvalidArgumentError(
        Cat(option, ": the certificate in ", path, " has expired: renew it"));
  return absl::OkStatus();
}

std::string_view HostOf(std::string_view listen) {
  const size_t colon = listen.rfind(':');
  return colon == std::string_view::npos ? listen : listen.substr(0, colon);
}

}  // namespace

bool IsLoopbackHost(std::string_view host) {
  if (host == "localhost") return true;
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']')
    host = host.substr(1, host.size() - 2);
  const std::string text(host);
  in_addr v4{};
  if (inet_pton(AF_INET, text.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  in6_addr v6{};
  if (inet_pton(AF_INET6, text.c_str(), &v6) == 1) return IN6_IS_ADDR_LOOPBACK(&v6);
  return false;
}

absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> ListenerCredentials(
    std::string_view listen, const ListenerSecurity& security) {
  if (security.insecure) {
    if (!security.tls_cert_path.empty() || !security.tls_key_path.empty() ||
        !security.client_ca_path.empty()) {
      return absl::InvalidArgumentError(
          "insecure: plaintext and a TLS certificate exclude each other; drop one");
    }
    if (!IsLoopbackHost(HostOf(listen))) {
      return absl::InvalidArgumentError(
          Cat("insecure: plaintext is allowed only on a loopback address (127.0.0.1, [::1], "
              "localhost), not '",
              HostOf(listen), "'; serve TLS instead (tls_cert, tls_key)"));
    }
    return grpc::InsecureServerCredentials();
  }
  if (security.tls_cert_path.empty() || security.tls_key_path.empty()) {
    return absl::InvalidArgumentError(
        "tls_cert, tls_key: imucald serves TLS and needs a certificate and its key (PEM); for "
        "plaintext on a loopback address (tests, development) set insecure instead");
  }
  absl::StatusOr<std::string> cert_pem = ReadPem("tls_cert", security.tls_cert_path);
  if (!cert_pem.ok()) return cert_pem.status();
  absl::StatusOr<std::string> key_pem = ReadPem("tls_key", security.tls_key_path);
  if (!key_pem.ok()) return key_pem.status();
  absl::StatusOr<std::unique_ptr<X509, X509Free>> cert =
      FirstCertificate("tls_cert", security.tls_cert_path, *cert_pem);
  if (!cert.ok()) return cert.status();
  if (absl::Status s = CheckValidNow("tls_cert", security.tls_cert_path, cert->get()); !s.ok())
    return s;
  {
    auto bio = Bio(*key_pem);
    std::unique_ptr<EVP_PKEY, KeyFree> key(
        PEM_read_bio_PrivateKey(bio.get(), nullptr, nullptr, nullptr));
    if (key == nullptr) {
      return absl::InvalidArgumentError(
          Cat("tls_key: ", security.tls_key_path, " holds no unencrypted PEM private key"));
    }
    if (X509_check_private_key(cert->get(), key.get()) != 1) {
      return absl::InvalidArgumentError(Cat("tls_key: the key in ", security.tls_key_path,
                                            " does not belong to the certificate in ",
                                            security.tls_cert_path));
    }
  }
  grpc::SslServerCredentialsOptions options(GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE);
  options.pem_key_cert_pairs.push_back({*key_pem, *cert_pem});
  if (!security.client_ca_path.empty()) {
    absl::StatusOr<std::string> ca_pem = ReadPem("client_ca", security.client_ca_path);
    if (!ca_pem.ok()) return ca_pem.status();
    absl::StatusOr<std::unique_ptr<X509, X509Free>> ca =
        FirstCertificate("client_ca", security.client_ca_path, *ca_pem);
    if (!ca.ok()) return ca.status();
    options.pem_root_certs = *ca_pem;
    // See the header: robots may present a certificate, technicians need none.
    options.client_certificate_request = GRPC_SSL_REQUEST_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(options);
}

}  // namespace imucal::server
