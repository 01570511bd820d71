//! The `Host` check against DNS rebinding.
//!
//! A web page whose domain name is made to resolve to this machine can reach the server with
//! its own origin, which then matches its own `Host`: the origin check alone cannot tell it
//! from the viewer page. What such a page cannot choose is the `Host` header: the browser
//! sends the page's domain. So every request, before anything else is looked at, must name
//! the server by one of its own names:
//! - `localhost` (and the loopback addresses `127.0.0.0/8`, `::1`);
//! - the address the server listens on; when it listens on all interfaces (`0.0.0.0`,
//!   `::`), any IP address literal (an address literal cannot be rebound to another machine);
//! - a name listed in the configuration's `allowed_hosts` (e.g. `booth.local`).
//!
//! The port in `Host` is not compared: the name is what a rebinding attacker controls.

use std::net::{IpAddr, SocketAddr};

/// The host part of a `Host` header value (`name`, `name:port`, `[v6]`, `[v6]:port`),
/// lower-cased and without a trailing dot; `None` when it is malformed.
pub fn host_name(header: &str) -> Option<String> {
    let header = header.trim();
    let name = if let Some(rest) = header.strip_prefix('[') {
        let (inside, after) = rest.split_once(']')?;
        if !(after.is_empty() || after.strip_prefix(':').is_some_and(is_port)) {
            return None;
        }
        inside
    } else {
        match header.rsplit_once(':') {
            Some((name, port)) if is_port(port) => name,
            Some(_) => return None,
            None => header,
        }
    };
    let name = name.strip_suffix('.').unwrap_or(name);
    (!name.is_empty()).then(|| name.to_ascii_lowercase())
}

fn is_port(s: &str) -> bool {
    !s.is_empty() && s.len() <= 5 && s.bytes().all(|b| b.is_ascii_digit())
}

/// Whether `header` (the request's `Host`) names this server, listening on `local`, with
/// the extra names `allowed`.
pub fn host_allowed(header: Option<&str>, local: SocketAddr, allowed: &[String]) -> bool {
    let Some(name) = header.and_then(host_name) else {
        return false;
    };
    if name == "localhost" {
        return true;
    }
    if let Ok(ip) = name.parse::<IpAddr>() {
        return ip.is_loopback()
            || ip == local.ip()
            || local.ip().is_unspecified()
            || ipv4_mapped(ip).is_some_and(|v4| v4.is_loopback() || v4 == local.ip());
    }
    allowed.iter().any(|a| {
        let a = a.trim();
        let a = a.strip_suffix('.').unwrap_or(a);
        a.eq_ignore_ascii_case(&name)
    })
}

fn ipv4_mapped(ip: IpAddr) -> Option<IpAddr> {
    match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map(IpAddr::V4),
        IpAddr::V4(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_names_and_ports() {
        assert_eq!(host_name("LocalHost:9870").as_deref(), Some("localhost"));
        assert_eq!(host_name("[::1]:9870").as_deref(), Some("::1"));
        assert_eq!(host_name("[::1]").as_deref(), Some("::1"));
        assert_eq!(host_name("booth.local.").as_deref(), Some("booth.local"));
        assert_eq!(host_name("a:b:c"), None);
        assert_eq!(host_name("[::1]x"), None);
        assert_eq!(host_name(":80"), None);
        assert_eq!(host_name(""), None);
    }

    #[test]
    fn own_names_only() {
        let lo: SocketAddr = "127.0.0.1:9870".parse().unwrap();
        let lan: SocketAddr = "192.168.1.20:9870".parse().unwrap();
        let any: SocketAddr = "0.0.0.0:9870".parse().unwrap();
        let names = vec!["Booth.Local".to_owned()];
        for h in [
            "localhost",
            "127.0.0.1:1",
            "127.3.4.5",
            "[::1]:9870",
            "booth.local:80",
        ] {
            assert!(host_allowed(Some(h), lo, &names), "{h}");
        }
        for h in [
            "evil.example",
            "localhost.evil.example",
            "192.168.1.20",
            "x:y",
        ] {
            assert!(!host_allowed(Some(h), lo, &names), "{h}");
        }
        assert!(!host_allowed(None, lo, &names));
        assert!(host_allowed(Some("192.168.1.20:9870"), lan, &[]));
        assert!(!host_allowed(Some("192.168.1.21"), lan, &[]));
        assert!(host_allowed(Some("10.0.0.7"), any, &[]));
        assert!(!host_allowed(Some("rebind.example"), any, &[]));
    }
}
