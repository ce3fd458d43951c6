//! The check a trainer makes before its first step: that every server is a `prism serve` of
//! the same prism release and, when the server was started with a config, of the same model;
//! and, when the server loads data itself (`prism serve --data`), of the same dataset.
//!
//! Burn's remote protocol already refuses a server of another Burn release; a server of
//! another *prism* release speaks the same protocol, so prism adds its own question: a custom
//! operation, registered on every server, whose output is the server's [`Fingerprint`]. A
//! server that does not know the operation is not a prism server (or an older one).

use burn::backend::ir::{BackendIr, CustomOpIr, HandleContainer};
use burn::server::RemoteServer;
use burn::tensor::{Device, TensorData};
use serde::{Deserialize, Serialize};

use prism_core::served::{self as ops, Call, ServedOp};

/// The custom operation's id (versioned: a later change of the answer's layout gets a new id).
pub const HANDSHAKE_OP: &str = "prism.handshake.v1";

/// Length of the answer: the fingerprint's JSON bytes, one per `f32`, zero-padded.
const ANSWER_LEN: usize = 256;

/// What a server is: its prism release and the digest of the model config it was started
/// with, if any.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Fingerprint {
    /// The prism release (`CARGO_PKG_VERSION`).
    pub prism: String,
    /// [`config_digest`] of the model config, when the server was given one.
    pub config: Option<String>,
    /// [`crate::dataset_digest`] of the dataset: on a trainer, the run's dataset; on
    /// a server, the dataset it loads its shares of each batch from (`--data`), if any.
    #[serde(default)]
    pub data: Option<String>,
}

impl Fingerprint {
    /// This build's fingerprint, with the digest of `config` (a model config's text).
    pub fn this_build(config: Option<String>) -> Self {
        Self {
            prism: env!("CARGO_PKG_VERSION").to_string(),
            config,
            data: None,
        }
    }

    /// This fingerprint with the dataset digest `data`.
    #[must_use]
    pub fn with_data(self, data: String) -> Self {
        Self {
            data: Some(data),
            ..self
        }
    }

    /// Why a trainer of fingerprint `self` must not train on a server of `served`, if it
    /// must not: another release, another model config (a server without one accepts any), or
    /// another dataset than the one the server loads from.
    pub fn mismatch(&self, served: &Fingerprint) -> Option<String> {
        if served.prism != self.prism {
            return Some(format!(
                "the server runs prism {}, this trainer prism {}: start both from the same \
                 release",
                served.prism, self.prism
            ));
        }
        match (&served.config, &self.config) {
            (Some(theirs), Some(ours)) if theirs != ours => Some(format!(
                "the server was started with another model config (digest {theirs}, this run's \
                 is {ours}): start it with this run's --config, or without --config"
            )),
            _ => match (&served.data, &self.data) {
                (Some(theirs), Some(ours)) if theirs != ours => Some(format!(
                    "the server loads another dataset (digest {theirs}, this run's is {ours}): \
                     start it with --data at a copy of this run's dataset, or without --data"
                )),
                _ => None,
            },
        }
    }

    fn encode(&self) -> Vec<f32> {
        let json = serde_json::to_vec(self).expect("a fingerprint serialises");
        ops::encode(&json, ANSWER_LEN)
    }
}

/// A digest of a config's canonical text (FNV-1a, 64 bits, hexadecimal): equal configs give
/// equal digests. It detects mistakes, it is not a security check.
pub fn config_digest(text: &str) -> String {
    let hash = text.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |hash, byte| {
        (hash ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3)
    });
    format!("{hash:016x}")
}

/// `server` answering the handshake with `fingerprint` on the backend of `device`.
///
/// # Errors
/// A device of a backend that cannot be served (a remote device).
pub fn register(
    server: RemoteServer,
    device: &Device,
    fingerprint: &Fingerprint,
) -> Result<RemoteServer, String> {
    ops::register(server, device, Answer(fingerprint.encode()))
}

/// The handshake's handler: the answer as a new tensor on the device.
#[derive(Clone)]
struct Answer(Vec<f32>);

impl ServedOp for Answer {
    const ID: &'static str = HANDSHAKE_OP;

    fn run<B: BackendIr>(
        &self,
        handles: &mut HandleContainer<B::Handle>,
        op: &CustomOpIr,
        device: &B::Device,
    ) {
        let data = TensorData::new(self.0.clone(), [ANSWER_LEN]);
        ops::put_output::<B>(handles, op, 0, data, device);
    }
}

/// Asks the server of the remote `device` for its fingerprint (blocks until it answers).
///
/// # Errors
/// Not a remote device, a failed read, or an answer that is not a fingerprint.
pub fn ask(device: &Device) -> Result<Fingerprint, String> {
    let answer = Call::new(device)?
        .output([ANSWER_LEN])
        .send(HANDSHAKE_OP)
        .remove(0);
    let message = ops::read_message(answer)?;
    serde_json::from_slice(&message).map_err(|_| "its answer is not a prism fingerprint".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fingerprints_round_trip_and_mismatches_are_explained() {
        let ours = Fingerprint::this_build(Some(config_digest("tiny")));
        let decoded: Fingerprint = serde_json::from_slice(&ops::decode(&ours.encode())).unwrap();
        assert_eq!(decoded, ours);
        assert_eq!(ours.mismatch(&ours), None);
        assert_eq!(ours.mismatch(&Fingerprint::this_build(None)), None);

        let older = Fingerprint {
            prism: "0.0.1".into(),
            ..Fingerprint::this_build(None)
        };
        let why = ours.mismatch(&older).unwrap();
        assert!(why.contains("prism 0.0.1"), "{why}");

        let other = Fingerprint::this_build(Some(config_digest("small")));
        let why = ours.mismatch(&other).unwrap();
        assert!(why.contains("another model config"), "{why}");
        assert_ne!(config_digest("tiny"), config_digest("small"));

        let loads = |data: &str| Fingerprint::this_build(None).with_data(config_digest(data));
        let ours = ours.with_data(config_digest("people"));
        assert_eq!(ours.mismatch(&loads("people")), None);
        let why = ours.mismatch(&loads("cats")).unwrap();
        assert!(why.contains("another dataset"), "{why}");
    }
}
