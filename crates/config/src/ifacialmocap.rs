//! `[ifacialmocap]`: one character's face as the iFacialMocap app streams it
//! (docs/ifacialmocap.md). Off by default.

use super::*;

/// `[ifacialmocap]` as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IfacialmocapConfig {
    /// Listen for receivers' handshakes and stream to them.
    pub enabled: bool,
    /// The address handshakes are listened for on (an IP address; loopback by default:
    /// anyone who can reach the port gets the face).
    pub address: String,
    /// The UDP port handshakes are listened for on (1 to 65535; the app's is 49983).
    pub port: u32,
    /// The port frames go to on a receiver's host: the app's, 49983, where receivers listen;
    /// 0: the port the receiver's handshake came from.
    pub reply_port: u32,
    /// The character sent; `None`: the first configured character.
    pub character: Option<String>,
}

impl Default for IfacialmocapConfig {
    fn default() -> Self {
        IfacialmocapConfig {
            enabled: false,
            address: "127.0.0.1".to_owned(),
            port: 49983,
            reply_port: 49983,
            character: None,
        }
    }
}

impl IfacialmocapConfig {
    /// The address to listen on (a loaded configuration's parses).
    pub fn listen(&self) -> Result<SocketAddr, String> {
        let ip: std::net::IpAddr = self.address.parse().map_err(|_| {
            format!(
                "expected an IP address, got {}",
                quote_excerpt(&self.address)
            )
        })?;
        let port = u16::try_from(self.port)
            .ok()
            .filter(|p| *p > 0)
            .ok_or_else(|| format!("expected a port 1 to 65535, got {}", self.port))?;
        Ok(SocketAddr::new(ip, port))
    }

    /// One word for the summary line.
    pub fn summary(&self) -> String {
        if !self.enabled {
            return "off".to_owned();
        }
        format!("{}:{}", self.address, self.port)
    }

    pub(crate) fn validate(
        &self,
        fail: &dyn Fn(&str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        if self.address.parse::<std::net::IpAddr>().is_err() {
            return Err(fail(
                "ifacialmocap.address",
                format!(
                    "expected an IP address (such as 127.0.0.1 or 0.0.0.0), got {}",
                    quote_excerpt(&self.address)
                ),
            ));
        }
        if !(1..=65535).contains(&self.port) {
            return Err(fail(
                "ifacialmocap.port",
                format!("expected a port 1 to 65535, got {}", self.port),
            ));
        }
        if self.reply_port > 65535 {
            return Err(fail(
                "ifacialmocap.reply_port",
                format!(
                    "expected a port 1 to 65535, or 0 for the handshake's own port, got {}",
                    self.reply_port
                ),
            ));
        }
        if self.character.as_deref() == Some("") {
            return Err(fail(
                "ifacialmocap.character",
                "expected a character's name, got \"\"".into(),
            ));
        }
        Ok(())
    }
}
