//! `prism serve`: this machine's devices served to trainers on other machines, through Burn's
//! remote backend (`burn::server`), behind a shared token, answering prism's handshake and
//! running prism's geometry operations (and, with a dataset, loading shares of batches).

use std::fmt;
use std::net::{SocketAddr, TcpListener, UdpSocket};
use std::path::PathBuf;
use std::str::FromStr;

use burn::server::{
    AuthorizationRequest, IrohIdentity, IrohRelays, IrohTransport, PeerAuthorizer, RemoteServer,
    ServerLogging, TokenAuthorizer, Transport, WebSocketTransport,
};
use burn::tensor::Device;

use prism_data::DatasetReader;

use crate::handshake::{self, Fingerprint};
use crate::shard;

/// How trainers reach the server.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TransportKind {
    /// Iroh (QUIC): authenticated and encrypted, across any network. Burn 0.22's
    /// `IrohTransport` binds its UDP port on every interface (`0.0.0.0` and `[::]`, burn-remote
    /// `src/transport/iroh/server.rs`, `bind_endpoint`), so it only serves a listening address
    /// that names every interface ([`TransportKind::check_listen`]).
    Iroh,
    /// A plain WebSocket: unencrypted, for a trusted network. The default: it binds exactly the
    /// address given, loopback unless told otherwise.
    #[default]
    WebSocket,
}

impl TransportKind {
    /// Whether this transport can bind `listen` and nothing more: every address for WebSocket;
    /// for Iroh, which binds every interface whatever it is given, only an address that says so
    /// (`0.0.0.0:PORT` or `[::]:PORT`), so that no server listens wider than its command line
    /// reads.
    ///
    /// # Errors
    /// Iroh with an address of one interface (loopback included).
    pub fn check_listen(self, listen: SocketAddr) -> Result<(), ServeError> {
        if self == Self::Iroh && !listen.ip().is_unspecified() {
            return Err(ServeError::IrohOnOneAddress { address: listen });
        }
        Ok(())
    }
}

impl FromStr for TransportKind {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        match text {
            "iroh" => Ok(Self::Iroh),
            "websocket" | "ws" => Ok(Self::WebSocket),
            _ => Err(format!(
                "unknown transport `{text}` (expected iroh or websocket)"
            )),
        }
    }
}

impl fmt::Display for TransportKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Iroh => "iroh",
            Self::WebSocket => "websocket",
        })
    }
}

/// What `prism serve` serves, where, and to whom.
pub struct ServeOptions {
    /// The address to listen on (`127.0.0.1:7000`; port 0 picks a free one). Iroh needs one
    /// naming every interface ([`TransportKind::check_listen`]).
    pub listen: SocketAddr,
    /// The transport.
    pub transport: TransportKind,
    /// The token trainers must present.
    pub token: String,
    /// The devices served (all of one backend).
    pub devices: Vec<Device>,
    /// The handshake's answer.
    pub fingerprint: Fingerprint,
    /// The dataset the server loads its shares of training batches from, if any (its digest
    /// belongs in `fingerprint`, see [`Fingerprint::with_data`]).
    pub data: Option<DatasetReader>,
    /// Iroh: the file holding the server's secret key (created when missing), so that its node
    /// id survives a restart; a new id at every start without it.
    pub identity: Option<PathBuf>,
    /// Iroh: also reachable through n0's public relays (by node id alone, across NATs).
    pub public_relays: bool,
}

/// A server that cannot start or stopped on an error.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The listening address cannot be bound.
    #[error("cannot listen on {address}: {source}")]
    Listen {
        /// The address.
        address: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
    /// Iroh was asked to listen on one address, which Burn's Iroh transport cannot do.
    #[error(
        "--transport iroh cannot listen on {address} alone: Burn 0.22's Iroh transport binds its \
         UDP port on every interface. Use --transport websocket to listen on one address \
         (loopback by default), or give --listen 0.0.0.0:{port} (or [::]:{port}) to accept \
         every interface",
        port = .address.port()
    )]
    IrohOnOneAddress {
        /// The address asked for.
        address: SocketAddr,
    },
    /// The Iroh identity file cannot be read or created.
    #[error("cannot read or create the Iroh identity {}: {source}", path.display())]
    Identity {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Burn's server failed.
    #[error("{0}")]
    Burn(String),
}

/// Serves `options.devices` until SIGINT or SIGTERM (Ctrl+C elsewhere). `announce` receives,
/// once the signal handlers are in place, the `--devices` list a trainer uses to reach the
/// served devices (one entry per device, `#I` naming device `I` when there are several) (a
/// trainer dialling before the server has bound is answered once it has: Burn's client retries).
///
/// `announce` is a trait object, not a generic parameter, so that Burn's whole server (its
/// transports, protocol and every operation's handler) is compiled once, in this crate, and
/// not again in each crate that calls this (BENCHMARKS.md, "CI on the slow Xeon host, second round").
///
/// # Errors
/// The transport cannot listen on the address alone ([`TransportKind::check_listen`]), the
/// address cannot be bound, or Burn's server fails.
pub fn serve(options: ServeOptions, announce: &dyn Fn(&str)) -> Result<(), ServeError> {
    options.transport.check_listen(options.listen)?;
    let authorizer = Doorkeeper(
        TokenAuthorizer::new(options.token.as_str())
            .map_err(|_| ServeError::Burn("the token is empty".into()))?,
    );
    let count = options.devices.len();
    let Some(first) = options.devices.first() else {
        return Err(ServeError::Burn("no device to serve".into()));
    };
    let mut server = handshake::register(
        RemoteServer::new(options.devices.clone()).with_authorizer(authorizer),
        first,
        &options.fingerprint,
    )
    .map_err(ServeError::Burn)?;
    server = prism_render::served::register(server, first).map_err(ServeError::Burn)?;
    if let Some(reader) = options.data {
        server = shard::register(server, first, reader).map_err(ServeError::Burn)?;
    }
    let (transport, entry) = match options.transport {
        TransportKind::WebSocket => {
            let listener =
                TcpListener::bind(options.listen).map_err(|source| ServeError::Listen {
                    address: options.listen,
                    source,
                })?;
            let bound = listener.local_addr().map_err(|source| ServeError::Listen {
                address: options.listen,
                source,
            })?;
            (
                Transport::from(WebSocketTransport::from_listener(listener)),
                format!("remote:ws://{}", shown(bound)),
            )
        }
        TransportKind::Iroh => {
            let identity = match &options.identity {
                Some(path) => {
                    IrohIdentity::load_or_create(path).map_err(|source| ServeError::Identity {
                        path: path.clone(),
                        source,
                    })?
                }
                None => IrohIdentity::random(),
            };
            let port = free_udp_port(options.listen)?;
            let relays = if options.public_relays {
                IrohRelays::Public
            } else {
                IrohRelays::Disabled
            };
            let transport = IrohTransport::new(identity)
                .with_relays(relays)
                .with_port(port);
            let address = SocketAddr::new(options.listen.ip(), port);
            eprintln!(
                "prism serve: warning: iroh listens on every interface of this machine (UDP port \
                 {port}, IPv4 and IPv6): any host that reaches it can ask for a session, which \
                 only the token refuses"
            );
            let entry = format!("remote:iroh:{}@{}", transport.id(), shown(address));
            (Transport::from(transport), entry)
        }
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| ServeError::Burn(format!("cannot start the runtime: {e}")))?;
    ServerLogging::install();
    runtime.block_on(async move {
        // The handlers are in place before the address is announced: a signal sent as soon as
        // the line is read stops the server cleanly.
        let stop = stop_signal().map_err(|e| ServeError::Burn(format!("signal handlers: {e}")))?;
        let serving = server.serve_async(transport);
        announce(&entries(&entry, count));
        tokio::select! {
            served = serving => served.map_err(|e| ServeError::Burn(e.to_string())),
            () = stop => Ok(()),
        }
    })
}

/// The `--devices` list of `count` devices served at `entry`: the entry itself for one
/// device, `entry#0,entry#1,...` for several.
fn entries(entry: &str, count: usize) -> String {
    if count == 1 {
        return entry.to_string();
    }
    (0..count)
        .map(|i| format!("{entry}#{i}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// Resolves at the first SIGINT or SIGTERM; the handlers are installed when this returns (so a
/// server that announces its address after calling it never misses an early signal). Shared by
/// `prism serve` and `prism view`.
///
/// # Errors
/// When a handler cannot be installed.
#[cfg(unix)]
pub fn stop_signal() -> std::io::Result<impl Future<Output = ()>> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut interrupt = signal(SignalKind::interrupt())?;
    let mut terminate = signal(SignalKind::terminate())?;
    Ok(async move {
        tokio::select! {
            _ = interrupt.recv() => {}
            _ = terminate.recv() => {}
        }
    })
}

/// Resolves at the first Ctrl+C.
///
/// # Errors
/// Never; the signature matches the Unix one.
#[cfg(not(unix))]
pub fn stop_signal() -> std::io::Result<impl Future<Output = ()>> {
    Ok(async {
        let _ = tokio::signal::ctrl_c().await;
    })
}

/// The port to bind Iroh's UDP socket on: `listen`'s, or a free one for port 0.
fn free_udp_port(listen: SocketAddr) -> Result<u16, ServeError> {
    if listen.port() != 0 {
        return Ok(listen.port());
    }
    UdpSocket::bind(listen)
        .and_then(|socket| socket.local_addr())
        .map(|address| address.port())
        .map_err(|source| ServeError::Listen {
            address: listen,
            source,
        })
}

/// `address` as a trainer dials it: an unspecified IP (`0.0.0.0`) shown as this machine's
/// host name.
fn shown(address: SocketAddr) -> String {
    if !address.ip().is_unspecified() {
        return address.to_string();
    }
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "THIS_HOST".into());
    format!("{host}:{}", address.port())
}

/// Burn's token check, with one line on the server's stderr for every session it opens or
/// refuses.
struct Doorkeeper(TokenAuthorizer);

impl PeerAuthorizer for Doorkeeper {
    fn authorize(&self, request: AuthorizationRequest<'_>) -> Result<(), String> {
        let (client, device) = (request.client, request.device_index);
        let verdict = self.0.authorize(request);
        match &verdict {
            Ok(()) => eprintln!("prism serve: session opened for {client} (device {device})"),
            Err(_) => eprintln!(
                "prism serve: refused {client} (device {device}): wrong or missing credential"
            ),
        }
        verdict
    }
}
