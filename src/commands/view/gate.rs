//! Whom `prism view` answers, checked before any handler runs (and so before a body is read):
//!
//! - a request carrying the token of the URL it printed (`?token=`), random at every start: no
//!   other web page and no other user of the machine knows it;
//! - naming the address it listens on, or `localhost`, in `Host`: a web page whose own name an
//!   attacker's DNS points at this machine (DNS rebinding) is refused;
//! - when it sends something (a POST), from its own page: a form or script of another site,
//!   whose browser says so in `Origin`, is refused;
//! - and no more than [`MAX_ADMITTED`] at once: the rest are told the viewer is busy (503)
//!   instead of queueing without bound for the one model.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::sync::Arc;

use anyhow::Context;
use axum::extract::{ConnectInfo, Query, Request, State};
use axum::http::uri::Authority;
use axum::http::{Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::Response;
use burn::server::{AuthorizationRequest, ClientId, Credential, PeerAuthorizer, TokenAuthorizer};
use rand::TryRngCore as _;
use serde::Deserialize;
use tokio::sync::Semaphore;

use super::refusal;

/// Requests admitted at once, computing or waiting for the model: the page keeps one in flight
/// (a frame or a webcam frame), and a download or a person's choice may come beside it. Each
/// holds an upload of at most `MAX_UPLOAD_BYTES`, so this also bounds the memory they take.
pub const MAX_ADMITTED: usize = 4;

/// The checks of one viewer.
pub struct Gate {
    /// The token, compared by Burn's token check (a BLAKE3 digest: constant time).
    token: TokenAuthorizer,
    /// The address the viewer listens on.
    listen: SocketAddr,
    /// One permit per request admitted.
    admission: Semaphore,
}

/// The token, as a request's query carries it.
#[derive(Deserialize)]
struct Presented {
    #[serde(default)]
    token: String,
}

impl Gate {
    /// The checks of a viewer listening on `listen` (its bound address), and the new random
    /// token its URL carries.
    ///
    /// # Errors
    /// The operating system's random source cannot be read.
    pub fn new(listen: SocketAddr) -> anyhow::Result<(Self, String)> {
        let mut bytes = [0u8; 16];
        rand::rngs::OsRng
            .try_fill_bytes(&mut bytes)
            .context("reading the system's random source for the viewer's token")?;
        let token: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
        let gate = Self {
            token: TokenAuthorizer::new(token.as_str()).context("the viewer's token")?,
            listen,
            admission: Semaphore::new(MAX_ADMITTED),
        };
        Ok((gate, token))
    }

    /// The URL the user opens: the page at a loopback address (when listening on every
    /// interface) with the token.
    pub fn page_url(&self, token: &str) -> String {
        let ip = match self.listen.ip() {
            IpAddr::V4(ip) if ip.is_unspecified() => IpAddr::V4(Ipv4Addr::LOCALHOST),
            IpAddr::V6(ip) if ip.is_unspecified() => IpAddr::V6(Ipv6Addr::LOCALHOST),
            ip => ip,
        };
        format!(
            "http://{}/?token={token}",
            SocketAddr::new(ip, self.listen.port())
        )
    }

    /// The middleware: `request` goes on to its handler only past every check, holding a
    /// permit until its answer is made.
    pub async fn check(
        State(gate): State<Arc<Self>>,
        ConnectInfo(peer): ConnectInfo<SocketAddr>,
        request: Request,
        next: Next,
    ) -> Response {
        let host = request
            .headers()
            .get(header::HOST)
            .and_then(|h| h.to_str().ok())
            .unwrap_or("");
        if !gate.names_me(host) {
            return refusal(
                StatusCode::FORBIDDEN,
                format!(
                    "prism view answers requests to {} or localhost, not to `{host}`",
                    gate.listen
                ),
            );
        }
        let presented = Query::<Presented>::try_from_uri(request.uri())
            .map(|q| q.0.token)
            .unwrap_or_default();
        let authorized = gate.token.authorize(AuthorizationRequest {
            client: ClientId::WebSocket(peer),
            device_index: 0,
            credential: &Credential::from(presented),
        });
        if authorized.is_err() {
            return refusal(
                StatusCode::FORBIDDEN,
                "a missing or wrong token: open the address `prism view` printed".into(),
            );
        }
        if !matches!(*request.method(), Method::GET | Method::HEAD) {
            let origin = request.headers().get(header::ORIGIN);
            if let Some(origin) = origin.filter(|o| !gate.is_my_page(o.to_str().unwrap_or(""))) {
                return refusal(
                    StatusCode::FORBIDDEN,
                    format!("a request from another site ({origin:?}) is refused"),
                );
            }
        }
        let Ok(_permit) = gate.admission.try_acquire() else {
            return refusal(
                StatusCode::SERVICE_UNAVAILABLE,
                format!("the viewer is busy ({MAX_ADMITTED} requests at once): try again"),
            );
        };
        next.run(request).await
    }

    /// Whether `host` (a `Host` header) is this viewer's address, or `localhost`, at its port:
    /// the IP it listens on, any IP when it listens on every interface, never another name.
    fn names_me(&self, host: &str) -> bool {
        let Ok(authority) = host.parse::<Authority>() else {
            return false;
        };
        if authority.port_u16().unwrap_or(80) != self.listen.port() {
            return false;
        }
        let name = authority.host();
        if name.eq_ignore_ascii_case("localhost") {
            return true;
        }
        let literal = name.trim_start_matches('[').trim_end_matches(']');
        literal
            .parse::<IpAddr>()
            .is_ok_and(|ip| ip == self.listen.ip() || self.listen.ip().is_unspecified())
    }

    /// Whether `origin` (an `Origin` header) is this viewer's own page.
    fn is_my_page(&self, origin: &str) -> bool {
        origin
            .strip_prefix("http://")
            .is_some_and(|host| self.names_me(host))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_listening_address_or_localhost_at_its_port_is_named() {
        let (gate, token) = Gate::new("127.0.0.1:8080".parse().unwrap()).unwrap();
        assert_eq!(token.len(), 32);
        for host in ["127.0.0.1:8080", "localhost:8080", "LOCALHOST:8080"] {
            assert!(gate.names_me(host), "{host}");
        }
        for host in [
            "evil.example:8080",
            "127.0.0.1:8081",
            "127.0.0.1",
            "10.0.0.1:8080",
            "127.0.0.1.evil.example:8080",
            "",
        ] {
            assert!(!gate.names_me(host), "{host}");
        }
        assert!(gate.is_my_page("http://localhost:8080"));
        assert!(!gate.is_my_page("http://evil.example"));
        assert!(!gate.is_my_page("null"));
        let (everywhere, _) = Gate::new("[::]:80".parse().unwrap()).unwrap();
        assert!(everywhere.names_me("[::1]") && everywhere.names_me("10.0.0.7:80"));
        assert!(!everywhere.names_me("evil.example"));
        assert_eq!(everywhere.page_url("t"), "http://[::1]:80/?token=t");
    }
}
