//! `wss://` and `https://`: a rustls acceptor from PEM certificate and key files.

use std::fs::File;
use std::io::BufReader;
use std::sync::Arc;

use tokio_rustls::rustls;
use tokio_rustls::TlsAcceptor;

use crate::config::TlsFiles;
use crate::error::ServerError;

/// Builds the acceptor; errors name the file and what was wrong with it.
pub fn acceptor(files: &TlsFiles) -> Result<TlsAcceptor, ServerError> {
    let open = |path: &std::path::Path| {
        File::open(path)
            .map(BufReader::new)
            .map_err(|source| ServerError::Tls {
                context: format!("opening {}", path.display()),
                source: Box::new(source),
            })
    };
    let certs = rustls_pemfile::certs(&mut open(&files.cert)?)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|source| ServerError::Tls {
            context: format!("reading certificates from {}", files.cert.display()),
            source: Box::new(source),
        })?;
    if certs.is_empty() {
        return Err(ServerError::Tls {
            context: format!("{} holds no PEM certificate", files.cert.display()),
            source: "no CERTIFICATE block".into(),
        });
    }
    let key = rustls_pemfile::private_key(&mut open(&files.key)?)
        .map_err(|source| ServerError::Tls {
            context: format!("reading the private key from {}", files.key.display()),
            source: Box::new(source),
        })?
        .ok_or_else(|| ServerError::Tls {
            context: format!("{} holds no PEM private key", files.key.display()),
            source: "no PRIVATE KEY block".into(),
        })?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|source| ServerError::Tls {
            context: "choosing TLS versions".into(),
            source: Box::new(source),
        })?
        .with_no_client_auth()
        .with_single_cert(certs, key)
        .map_err(|source| ServerError::Tls {
            context: format!(
                "certificate {} and key {} do not form a usable pair",
                files.cert.display(),
                files.key.display()
            ),
            source: Box::new(source),
        })?;
    Ok(TlsAcceptor::from(Arc::new(config)))
}
