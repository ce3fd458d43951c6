//! What the in-process tests of prism-remote share.

use std::sync::mpsc;
use std::time::Duration;

use burn::tensor::Device;
use prism_remote::{DeviceList, Fingerprint, ServeOptions, TransportKind, connect, serve};

/// A flex device served over WebSocket by a `prism serve` server in a thread of this
/// process, as a trainer sees it (connected and checked by the handshake).
pub fn served_device() -> Device {
    let (send, receive) = mpsc::channel();
    let options = ServeOptions {
        listen: "127.0.0.1:0".parse().unwrap(),
        transport: TransportKind::WebSocket,
        token: "t".into(),
        devices: vec![Device::flex()],
        fingerprint: Fingerprint::this_build(None),
        data: None,
        identity: None,
        public_relays: false,
    };
    std::thread::spawn(move || serve(options, &move |entry| send.send(entry.into()).unwrap()));
    let entry: String = receive.recv_timeout(Duration::from_secs(30)).unwrap();
    let list: DeviceList = entry.parse().unwrap();
    let fingerprint = Fingerprint::this_build(None);
    let connected = connect(&list, &Device::flex(), Some("t"), &fingerprint).unwrap();
    connected.into_iter().next().unwrap().device
}
