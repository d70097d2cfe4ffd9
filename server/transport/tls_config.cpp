#include "server/transport/tls_config.h"

#include <boost/asio/ssl.hpp>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/ssl.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>

namespace meshdeform::transport {
namespace {

namespace asio = boost::asio;

/// An OpenSSL error as text, e.g. "no start line (PEM routines)".
std::string ssl_message(const boost::system::error_code& error) {
  std::string message = error.message();
  return message.empty() ? "rejected by OpenSSL" : message;
}

bool is_pem_private_key(const std::string& pem) {
  BIO* bio = BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size()));
  if (bio == nullptr) return false;
  EVP_PKEY* key = PEM_read_bio_PrivateKey(bio, nullptr, nullptr, nullptr);
  BIO_free(bio);
  ERR_clear_error();  // a failed parse leaves errors queued for later, unrelated calls
  if (key == nullptr) return false;
  EVP_PKEY_free(key);
  return true;
}

/// @return the file's bytes, or InvalidArgument naming it (`what`) with the system's reason.
Result<std::string> read_file(const std::string& path, const std::string& what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Error(ErrorCode::InvalidArgument, "cannot read " + what + ": " + std::strerror(errno));
  }
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return Error(ErrorCode::InvalidArgument, "cannot read " + what);
  return bytes;
}

}  // namespace

Result<TlsConfig> load_tls_config(const std::string& cert_path, const std::string& key_path,
                                  const std::string& client_ca_path) {
  TlsLabels labels;
  labels.cert = "TLS certificate file '" + cert_path + "'";
  labels.key = "TLS key file '" + key_path + "'";
  labels.client_ca = "TLS client CA file '" + client_ca_path + "'";
  TlsConfig tls;
  MD_ASSIGN_OR_RETURN(tls.cert_chain_pem, read_file(cert_path, labels.cert));
  MD_ASSIGN_OR_RETURN(tls.private_key_pem, read_file(key_path, labels.key));
  if (!client_ca_path.empty()) {
    MD_ASSIGN_OR_RETURN(tls.client_ca_pem, read_file(client_ca_path, labels.client_ca));
  }
  // gRPC takes PEM text too but reports a bad one only as a failed listen: check it here.
  MD_ASSIGN_OR_RETURN(auto checked, make_ssl_context(tls, labels));
  (void)checked;
  return tls;
}

Result<std::unique_ptr<asio::ssl::context>> make_ssl_context(const TlsConfig& tls,
                                                             const TlsLabels& labels) {
  auto context = std::make_unique<asio::ssl::context>(asio::ssl::context::tls_server);
  SSL_CTX* native = context->native_handle();
  // TLS 1.0 and 1.1 are deprecated (RFC 8996); every browser and gRPC client speaks 1.2+.
  SSL_CTX_set_min_proto_version(native, TLS1_2_VERSION);
  context->set_options(asio::ssl::context::default_workarounds |
                       asio::ssl::context::no_compression | asio::ssl::context::single_dh_use);
  boost::system::error_code error;
  context->use_certificate_chain(asio::buffer(tls.cert_chain_pem), error);
  if (error) {
    return Error(ErrorCode::InvalidArgument,
                 labels.cert + " is not a PEM certificate: " + ssl_message(error));
  }
  // OpenSSL checks the key against the certificate while loading it: tell the two failures apart.
  if (!is_pem_private_key(tls.private_key_pem)) {
    return Error(ErrorCode::InvalidArgument, labels.key + " is not a PEM private key");
  }
  context->use_private_key(asio::buffer(tls.private_key_pem), asio::ssl::context::pem, error);
  if (error || SSL_CTX_check_private_key(native) != 1) {
    return Error(ErrorCode::InvalidArgument, labels.key + " does not belong to " + labels.cert);
  }
  if (!tls.client_ca_pem.empty()) {
    context->add_certificate_authority(asio::buffer(tls.client_ca_pem), error);
    if (error) {
      return Error(ErrorCode::InvalidArgument,
                   labels.client_ca + " is not a PEM certificate: " + ssl_message(error));
    }
    context->set_verify_mode(asio::ssl::verify_peer | asio::ssl::verify_fail_if_no_peer_cert);
  }
  return context;
}

}  // namespace meshdeform::transport
