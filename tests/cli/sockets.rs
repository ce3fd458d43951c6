//! The sockets a process really holds, read from the kernel (`/proc/PID/fd` matched against
//! `/proc/PID/net/{tcp,tcp6,udp,udp6}`): what the tests of `prism serve` and `prism view` check
//! their listening addresses against, whatever the command line or the announced line says.

use std::collections::HashSet;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::time::{Duration, Instant};

/// A socket a process holds open for others to reach: a listening TCP socket or a UDP socket.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Held {
    /// `tcp` or `udp`.
    pub protocol: &'static str,
    /// The local address it is bound to.
    pub local: SocketAddr,
}

/// The listening TCP sockets and the UDP sockets of process `pid`.
fn held(pid: u32) -> Vec<Held> {
    let inodes: HashSet<u64> = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .map(|fds| {
            fds.filter_map(|fd| std::fs::read_link(fd.ok()?.path()).ok())
                .filter_map(|target| {
                    let target = target.to_str()?;
                    target
                        .strip_prefix("socket:[")?
                        .strip_suffix(']')?
                        .parse()
                        .ok()
                })
                .collect()
        })
        .unwrap_or_default();
    let mut found = Vec::new();
    for (table, protocol) in [
        ("tcp", "tcp"),
        ("tcp6", "tcp"),
        ("udp", "udp"),
        ("udp6", "udp"),
    ] {
        let Ok(text) = std::fs::read_to_string(format!("/proc/{pid}/net/{table}")) else {
            continue;
        };
        for line in text.lines().skip(1) {
            let fields: Vec<&str> = line.split_whitespace().collect();
            // sl, local_address, rem_address, st, tx:rx, tr:when, retrnsmt, uid, timeout, inode
            let (Some(local), Some(state), Some(inode)) =
                (fields.get(1), fields.get(3), fields.get(9))
            else {
                continue;
            };
            let listening = protocol == "udp" || *state == "0A";
            if listening && inode.parse().is_ok_and(|i: u64| inodes.contains(&i)) {
                found.push(Held {
                    protocol,
                    local: address(local),
                });
            }
        }
    }
    found
}

/// A `/proc/net` address, `0100007F:1F90`: the IP's 32-bit words in hex as the kernel stores
/// them (this machine's byte order), then the port.
fn address(text: &str) -> SocketAddr {
    let (ip, port) = text.split_once(':').expect("ADDRESS:PORT");
    let bytes: Vec<u8> = (0..ip.len() / 8)
        .flat_map(|w| {
            u32::from_str_radix(&ip[8 * w..8 * w + 8], 16)
                .unwrap()
                .to_ne_bytes()
        })
        .collect();
    let ip = match bytes.len() {
        4 => IpAddr::V4(Ipv4Addr::from(<[u8; 4]>::try_from(bytes).unwrap())),
        _ => IpAddr::V6(Ipv6Addr::from(<[u8; 16]>::try_from(bytes).unwrap())),
    };
    SocketAddr::new(ip, u16::from_str_radix(port, 16).unwrap())
}

/// Waits (30 s at most) until process `pid` holds a socket on `port`, then asserts that it
/// holds one on loopback and none on an unspecified address (`0.0.0.0`, `[::]`): `what`
/// listens on loopback only.
pub fn assert_loopback_only(pid: u32, port: u16, what: &str) {
    let start = Instant::now();
    let sockets = loop {
        let sockets = held(pid);
        if sockets.iter().any(|s| s.local.port() == port) {
            break sockets;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "{what}: no socket on port {port} after 30 s (holds {sockets:?})"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(
        sockets
            .iter()
            .any(|s| s.local.port() == port && s.local.ip().is_loopback()),
        "{what}: nothing on loopback port {port}: {sockets:?}"
    );
    let wide: Vec<&Held> = sockets
        .iter()
        .filter(|s| s.local.ip().is_unspecified())
        .collect();
    assert!(
        wide.is_empty(),
        "{what} listens on every interface: {wide:?}"
    );
}
