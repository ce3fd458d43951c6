//! The `--devices` list: how many local devices, or which served devices, a run trains on.
//!
//! ```text
//! --devices 2                                     two local devices (as before)
//! --devices remote:ws://10.0.0.5:7000,remote:ws://10.0.0.6:7000
//! --devices local,remote:iroh:NODE_ID@10.0.0.7:7001#1
//! ```
//!
//! A remote entry names one device of a `prism serve` process: its device 0, or `#INDEX`.
//! An Iroh entry is the node id the server printed, with `@HOST:PORT` where the server is
//! reached directly (always, on a network without Iroh's relays).

use std::fmt;
use std::net::{SocketAddr, ToSocketAddrs};
use std::str::FromStr;

use burn::remote::EndpointId;

/// One training device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DeviceSpec {
    /// A device of this machine, on the run's `--backend`.
    Local,
    /// Device `index` of the WebSocket server at `url` (`ws://HOST:PORT`).
    WebSocket {
        /// The server's address, `ws://HOST:PORT`.
        url: String,
        /// Which of the server's devices.
        index: u32,
    },
    /// Device `index` of the Iroh server `id`, dialled at `address` when given.
    Iroh {
        /// The server's node id.
        id: EndpointId,
        /// Where to dial it directly (required without relays).
        address: Option<SocketAddr>,
        /// Which of the server's devices.
        index: u32,
    },
}

impl DeviceSpec {
    /// Whether the device is served by another process.
    pub fn is_remote(&self) -> bool {
        !matches!(self, Self::Local)
    }
}

impl fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let index = |i: u32| {
            if i == 0 {
                String::new()
            } else {
                format!("#{i}")
            }
        };
        match self {
            Self::Local => f.write_str("local"),
            Self::WebSocket { url, index: i } => write!(f, "remote:{url}{}", index(*i)),
            Self::Iroh {
                id,
                address,
                index: i,
            } => {
                write!(f, "remote:iroh:{id}")?;
                if let Some(address) = address {
                    write!(f, "@{address}")?;
                }
                f.write_str(&index(*i))
            }
        }
    }
}

/// The devices of a run, the first one the main device (where the model, the optimizer,
/// checkpoints and validation live).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceList(Vec<DeviceSpec>);

impl DeviceList {
    /// `count` local devices.
    pub fn local(count: usize) -> Self {
        Self(vec![DeviceSpec::Local; count])
    }

    /// The devices, in order.
    pub fn specs(&self) -> &[DeviceSpec] {
        &self.0
    }

    /// How many devices.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Whether the list is empty (never, once parsed).
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Whether any device is served by another process.
    pub fn has_remote(&self) -> bool {
        self.0.iter().any(DeviceSpec::is_remote)
    }
}

impl Default for DeviceList {
    fn default() -> Self {
        Self::local(1)
    }
}

impl fmt::Display for DeviceList {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if !self.has_remote() {
            return write!(f, "{}", self.0.len());
        }
        let entries: Vec<String> = self.0.iter().map(ToString::to_string).collect();
        f.write_str(&entries.join(","))
    }
}

/// A `--devices` value that cannot be read.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("--devices `{entry}`: {reason}")]
pub struct SpecError {
    /// The entry at fault.
    pub entry: String,
    /// What is wrong with it.
    pub reason: String,
}

impl FromStr for DeviceList {
    type Err = SpecError;

    fn from_str(text: &str) -> Result<Self, SpecError> {
        let text = text.trim();
        if let Ok(count) = text.parse::<usize>() {
            if count == 0 {
                return Err(error(text, "at least one device is needed"));
            }
            return Ok(Self::local(count));
        }
        let specs = text
            .split(',')
            .map(|entry| entry.trim().parse())
            .collect::<Result<Vec<DeviceSpec>, _>>()?;
        if let Some(spec) = specs
            .iter()
            .enumerate()
            .find_map(|(i, s)| specs[..i].contains(s).then_some(s))
        {
            return Err(error(&spec.to_string(), "the device is listed twice"));
        }
        let websocket = specs
            .iter()
            .any(|s| matches!(s, DeviceSpec::WebSocket { .. }));
        let iroh = specs.iter().any(|s| matches!(s, DeviceSpec::Iroh { .. }));
        if websocket && iroh {
            return Err(error(
                text,
                "one run uses one transport: Burn 0.22 cannot move tensors between an Iroh and \
                 a WebSocket server",
            ));
        }
        Ok(Self(specs))
    }
}

impl FromStr for DeviceSpec {
    type Err = SpecError;

    fn from_str(entry: &str) -> Result<Self, SpecError> {
        if entry == "local" {
            return Ok(Self::Local);
        }
        let Some(remote) = entry.strip_prefix("remote:") else {
            return Err(error(
                entry,
                "expected a device count, `local`, `remote:ws://HOST:PORT` or \
                 `remote:iroh:NODE_ID[@HOST:PORT]`",
            ));
        };
        let (target, index) = match remote.rsplit_once('#') {
            Some((target, index)) => {
                let index = index
                    .parse()
                    .map_err(|_| error(entry, "the device index after `#` is not a number"))?;
                (target, index)
            }
            None => (remote, 0),
        };
        if let Some(address) = target.strip_prefix("ws://") {
            resolve(entry, address)?;
            return Ok(Self::WebSocket {
                url: format!("ws://{address}"),
                index,
            });
        }
        if let Some(node) = target.strip_prefix("iroh:") {
            let (id, address) = match node.split_once('@') {
                Some((id, address)) => (id, Some(resolve(entry, address)?)),
                None => (node, None),
            };
            let id = id.parse().map_err(|_| {
                error(
                    entry,
                    "the Iroh node id is not valid (paste the id `prism serve` printed)",
                )
            })?;
            return Ok(Self::Iroh { id, address, index });
        }
        Err(error(
            entry,
            "a remote device is `remote:ws://HOST:PORT` or `remote:iroh:NODE_ID[@HOST:PORT]`",
        ))
    }
}

/// `HOST:PORT` as a socket address (a host name is looked up).
fn resolve(entry: &str, address: &str) -> Result<SocketAddr, SpecError> {
    if !address.contains(':') {
        return Err(error(entry, "the address needs a port: HOST:PORT"));
    }
    address
        .to_socket_addrs()
        .ok()
        .and_then(|mut found| found.next())
        .ok_or_else(|| error(entry, &format!("cannot resolve the address `{address}`")))
}

fn error(entry: &str, reason: &str) -> SpecError {
    SpecError {
        entry: entry.into(),
        reason: reason.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_count_is_that_many_local_devices() {
        let list: DeviceList = "3".parse().unwrap();
        assert_eq!(list, DeviceList::local(3));
        assert!(!list.has_remote());
        assert_eq!(list.to_string(), "3");
    }

    #[test]
    fn remote_entries_parse_and_print_back() {
        let text = "local,remote:ws://127.0.0.1:7000,remote:ws://127.0.0.1:7001#2";
        let list: DeviceList = text.parse().unwrap();
        assert_eq!(list.len(), 3);
        assert_eq!(
            list.specs()[2],
            DeviceSpec::WebSocket {
                url: "ws://127.0.0.1:7001".into(),
                index: 2
            }
        );
        assert_eq!(list.to_string(), text);
    }

    #[test]
    fn iroh_entries_carry_the_node_id_and_an_optional_address() {
        let id = iroh_id();
        let list: DeviceList = format!("remote:iroh:{id}@127.0.0.1:7002,remote:iroh:{id}#1")
            .parse()
            .unwrap();
        let DeviceSpec::Iroh { address, index, .. } = &list.specs()[0] else {
            panic!("not an Iroh device: {:?}", list.specs()[0]);
        };
        assert_eq!(address.unwrap().port(), 7002);
        assert_eq!(*index, 0);
        assert!(matches!(
            list.specs()[1],
            DeviceSpec::Iroh {
                address: None,
                index: 1,
                ..
            }
        ));
    }

    #[test]
    fn malformed_lists_name_the_entry_and_the_fault() {
        let mixed = format!("remote:ws://127.0.0.1:7000,remote:iroh:{}", iroh_id());
        let cases = [
            ("0", "at least one device"),
            ("gpu:0", "expected a device count"),
            ("remote:http://x:1", "a remote device is"),
            ("remote:ws://127.0.0.1", "needs a port"),
            ("remote:ws://127.0.0.1:7000#x", "not a number"),
            ("remote:iroh:not-an-id", "node id is not valid"),
            (
                "remote:ws://127.0.0.1:7000,remote:ws://127.0.0.1:7000",
                "listed twice",
            ),
            ("remote:ws://no-such-host.invalid:7000", "cannot resolve"),
            (mixed.as_str(), "one transport"),
        ];
        for (text, expected) in cases {
            let err = text.parse::<DeviceList>().unwrap_err().to_string();
            assert!(err.contains(expected), "{text}: {err}");
            assert!(err.starts_with("--devices `"), "{text}: {err}");
        }
    }

    /// A valid node id (the id of a fixed secret key).
    fn iroh_id() -> EndpointId {
        burn::server::IrohIdentity::from_bytes([7; 32]).id()
    }
}
