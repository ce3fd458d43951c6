//! `prism serve`'s server and the trainer's connection in one process, on loopback: the
//! handshake refuses another release and another model config, a wrong token is refused
//! while the server keeps serving, and an address where nothing answers fails fast.

use std::net::{SocketAddr, TcpListener};
use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

use burn::tensor::{Device, Tensor};
use prism_remote::{
    DeviceList, Fingerprint, ServeOptions, TransportKind, config_digest, connect, serve,
};

const TOKEN: &str = "test-token";

/// Serves the flex device with `fingerprint` over `transport` on a free port (loopback; every
/// interface for Iroh, which binds no less), in a thread of this process; returns the
/// `--devices` entry it announced, dialling loopback.
fn start(transport: TransportKind, fingerprint: Fingerprint) -> String {
    let (send, receive) = mpsc::channel();
    let listen = match transport {
        TransportKind::Iroh => "0.0.0.0:0",
        TransportKind::WebSocket => "127.0.0.1:0",
    };
    let options = ServeOptions {
        listen: listen.parse().unwrap(),
        transport,
        token: TOKEN.into(),
        devices: vec![Device::flex()],
        fingerprint,
        data: None,
        identity: None,
        public_relays: false,
    };
    thread::spawn(move || {
        let announced = send.clone();
        if let Err(e) = serve(options, &move |entry| {
            announced.send(entry.to_string()).unwrap();
        }) {
            panic!("serve failed: {e}");
        }
    });
    let entry: String = receive.recv_timeout(Duration::from_secs(30)).unwrap();
    // Iroh's entry names this machine by its host name; the test dials loopback.
    match entry.rsplit_once('@') {
        Some((node, address)) => {
            let port = address.rsplit(':').next().unwrap();
            format!("{node}@127.0.0.1:{port}")
        }
        None => entry,
    }
}

fn connect_to(entry: &str, token: &str, ours: &Fingerprint) -> Result<Vec<Device>, String> {
    let list: DeviceList = entry.parse().unwrap();
    connect(&list, &Device::flex(), Some(token), ours)
        .map(|devices| devices.into_iter().map(|c| c.device).collect())
        .map_err(|e| e.to_string())
}

#[test]
fn a_server_of_this_release_and_config_is_used_over_both_transports() {
    let ours = Fingerprint::this_build(Some(config_digest("tiny")));
    for transport in [TransportKind::WebSocket, TransportKind::Iroh] {
        // A server started without a config accepts any model; one with ours, ours.
        for served in [Fingerprint::this_build(None), ours.clone()] {
            let entry = start(transport, served);
            let devices = connect_to(&entry, TOKEN, &ours).unwrap();
            let x = Tensor::<1>::from_floats([1.0, 2.0, 3.0], &devices[0]);
            let y: Vec<f32> = (x * 2.0).into_data().try_to_vec().unwrap();
            assert_eq!(y, [2.0, 4.0, 6.0], "{transport}");
        }
    }
}

#[test]
fn another_release_or_model_config_is_refused_before_any_step() {
    let ours = Fingerprint::this_build(Some(config_digest("tiny")));
    let older = Fingerprint {
        data: None,
        prism: "0.0.1".into(),
        config: None,
    };
    let err = connect_to(&start(TransportKind::WebSocket, older), TOKEN, &ours).unwrap_err();
    assert!(
        err.contains("prism 0.0.1") && err.contains("same release"),
        "{err}"
    );

    let small = Fingerprint::this_build(Some(config_digest("small")));
    let entry = start(TransportKind::Iroh, small);
    let err = connect_to(&entry, TOKEN, &ours).unwrap_err();
    assert!(err.contains("another model config"), "{err}");
    assert!(err.contains(&entry), "the error names the device: {err}");
}

#[test]
fn a_wrong_token_is_refused_and_the_server_keeps_serving() {
    let ours = Fingerprint::this_build(None);
    for transport in [TransportKind::WebSocket, TransportKind::Iroh] {
        let entry = start(transport, ours.clone());
        let err = connect_to(&entry, "not-the-token", &ours).unwrap_err();
        assert!(err.contains("refused the credential"), "{transport}: {err}");
        assert!(connect_to(&entry, TOKEN, &ours).is_ok(), "{transport}");
    }
}

#[test]
fn nothing_listening_fails_fast_with_the_address() {
    // A port that was free a moment ago: nothing answers there.
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let address = SocketAddr::from(([127, 0, 0, 1], port));
    let began = Instant::now();
    let err = connect_to(
        &format!("remote:ws://{address}"),
        TOKEN,
        &Fingerprint::this_build(None),
    )
    .unwrap_err();
    assert!(err.contains(&address.to_string()), "{err}");
    assert!(began.elapsed() < Duration::from_secs(31), "{err}");
}
