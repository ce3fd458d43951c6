//! A run's `--devices` connected: local devices as they are, served devices through Burn's
//! remote backend with the run's token, each server asked prism's [`handshake`] before any
//! step. Every connection is bounded in time, so an address that never answers is an error,
//! not a hang.

use std::net::{TcpStream, ToSocketAddrs};
use std::sync::mpsc;
use std::thread;
use std::time::Duration;

use burn::remote::{
    ConnectError as BurnConnectError, EndpointAddr, IrohHost, IrohRelays, RemoteHost,
};
use burn::tensor::Device;

use crate::handshake::{self, Fingerprint};
use crate::spec::{DeviceList, DeviceSpec};

/// How long a served device may take to connect and answer the handshake.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(30);

/// A device of the list that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("cannot train on {device}: {reason}")]
pub struct ConnectError {
    /// The `--devices` entry.
    pub device: String,
    /// Why.
    pub reason: String,
}

/// A device of a run's `--devices` list, connected.
#[derive(Clone, Debug)]
pub struct Connected {
    /// The device (without autodiff).
    pub device: Device,
    /// Whether its server loads the device's share of each batch itself (`prism serve
    /// --data`, with the run's dataset); local devices are given theirs.
    pub loads_shares: bool,
}

/// The devices of `list`: `local` for each local entry, the served devices connected with
/// `token` and checked against `fingerprint`.
///
/// # Errors
/// A served device that cannot be reached in [`CONNECT_TIMEOUT`], refuses the token, or is
/// not a `prism serve` of this release and model config; a remote entry without a token.
pub fn connect(
    list: &DeviceList,
    local: &Device,
    token: Option<&str>,
    fingerprint: &Fingerprint,
) -> Result<Vec<Connected>, ConnectError> {
    list.specs()
        .iter()
        .map(|spec| match spec {
            DeviceSpec::Local => Ok(Connected {
                device: local.clone(),
                loads_shares: false,
            }),
            remote => {
                let error = |reason: String| ConnectError {
                    device: remote.to_string(),
                    reason,
                };
                let token = token.ok_or_else(|| error("no credential was given".into()))?;
                connect_one(remote, token, fingerprint).map_err(error)
            }
        })
        .collect()
}

/// Connects one served device and checks its server, within [`CONNECT_TIMEOUT`].
fn connect_one(
    spec: &DeviceSpec,
    token: &str,
    fingerprint: &Fingerprint,
) -> Result<Connected, String> {
    let (host, index) = host_of(spec, token);
    let ours = fingerprint.clone();
    let (send, receive) = mpsc::channel();
    // A thread per connection: Burn's connect and the handshake's read block, and an address
    // that never answers must not hang the trainer.
    thread::spawn(move || {
        let result = Device::remote_options(&host)
            .device_index(index)
            .init()
            .map_err(explain)
            .and_then(|device| {
                let served = handshake::ask(&device).map_err(|e| {
                    format!(
                        "the server did not answer prism's handshake ({e}): is it a `prism serve`?"
                    )
                })?;
                match ours.mismatch(&served) {
                    Some(why) => Err(why),
                    None => Ok(Connected {
                        device,
                        loads_shares: served.data.is_some() && ours.data.is_some(),
                    }),
                }
            });
        let _ = send.send(result);
    });
    receive.recv_timeout(CONNECT_TIMEOUT).unwrap_or_else(|_| {
        Err(format!(
            "no answer within {} s (is `prism serve` running there, and the address right?)",
            CONNECT_TIMEOUT.as_secs()
        ))
    })
}

/// Burn's remote host for a served device, with the credential, and the device's index.
fn host_of(spec: &DeviceSpec, token: &str) -> (RemoteHost, u32) {
    let (host, index) = match spec {
        DeviceSpec::WebSocket { url, index } => (RemoteHost::websocket(url), *index),
        DeviceSpec::Iroh { id, address, index } => {
            let host = IrohHost::new(EndpointAddr::from(*id));
            let host = match address {
                Some(address) => host
                    .with_address(*address)
                    .with_relays(IrohRelays::Disabled),
                None => host,
            };
            (RemoteHost::iroh(host), *index)
        }
        DeviceSpec::Local => unreachable!("local devices are not connected"),
    };
    (host.with_credential(token), index)
}

/// Burn's connect error in the words of a prism user.
fn explain(error: BurnConnectError) -> String {
    match error {
        BurnConnectError::Unauthorized => {
            "the server refused the credential (the trainer's --token-file must hold the \
             server's token)"
                .into()
        }
        other => other.to_string(),
    }
}

/// Whether the server of the served device `spec` accepts connections now: for WebSocket a TCP
/// connection within 3 s; `None` where that cannot be told without a session (Iroh, local).
pub fn accepts_connections(spec: &DeviceSpec) -> Option<bool> {
    let DeviceSpec::WebSocket { url, .. } = spec else {
        return None;
    };
    let address = url.strip_prefix("ws://")?.to_socket_addrs().ok()?.next()?;
    Some(TcpStream::connect_timeout(&address, Duration::from_secs(3)).is_ok())
}
