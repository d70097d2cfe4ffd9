#pragma once
/// @file tls_config.h
/// The TLS identity of the server: its PEM files read and checked at startup, and the OpenSSL
/// server context the HTTPS listener (http_server.h) is built on.

#include <memory>
#include <string>

#include "core/base/status.h"

namespace boost::asio::ssl {
class context;
}

namespace meshdeform::transport {

/// PEM text of a TLS server identity, shared by the gRPC port and the HTTP listener.
struct TlsConfig {
  std::string cert_chain_pem;   ///< the server certificate, then any intermediates
  std::string private_key_pem;  ///< the certificate's key (unencrypted)
  /// Non-empty: clients must present a certificate issued by one of these CAs (mutual TLS).
  std::string client_ca_pem;
};

/// Reads the PEM files of --tls-cert, --tls-key and (optionally, when not empty) --tls-client-ca
/// and checks them with OpenSSL, so that a bad file stops the server at startup with a message
/// naming it rather than failing every handshake later.
/// @return the files' text; InvalidArgument naming the file when it cannot be read, holds no
///         PEM certificate (cert, client CA) or private key (key), or when the key does not
///         belong to the certificate.
[[nodiscard]] Result<TlsConfig> load_tls_config(const std::string& cert_path,
                                                const std::string& key_path,
                                                const std::string& client_ca_path);

/// How make_ssl_context names the three parts in its errors.
struct TlsLabels {
  std::string cert = "the TLS certificate";
  std::string key = "the TLS key";
  std::string client_ca = "the TLS client CA";
};

/// A TLS 1.2+ server context with `tls`'s identity (and client verification with its CAs).
/// @return InvalidArgument naming the part OpenSSL rejects.
[[nodiscard]] Result<std::unique_ptr<boost::asio::ssl::context>> make_ssl_context(
    const TlsConfig& tls, const TlsLabels& labels = {});

}  // namespace meshdeform::transport
