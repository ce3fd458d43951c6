//! The check a trainer makes before its first step: that every server is a `prism serve` of
//! the same prism release and, when the server was started with a config, of the same model.
//!
//! Burn's remote protocol already refuses a server of another Burn release; a server of
//! another *prism* release speaks the same protocol, so prism adds its own question: a custom
//! operation, registered on every server, whose output is the server's [`Fingerprint`]. A
//! server that does not know the operation is not a prism server (or an older one).

use burn::backend::ir::{BackendIr, CustomOpIr, HandleContainer, TensorIr};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{DispatchDevice, Remote};
use burn::remote::CustomOpClient;
use burn::server::RemoteServer;
use burn::tensor::{DType, Device, Shape, TensorData, read_sync};
use serde::{Deserialize, Serialize};

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
}

impl Fingerprint {
    /// This build's fingerprint, with the digest of `config` (a model config's text).
    pub fn this_build(config: Option<String>) -> Self {
        Self {
            prism: env!("CARGO_PKG_VERSION").to_string(),
            config,
        }
    }

    /// Why a trainer of fingerprint `self` must not train on a server of `served`, if it
    /// must not: another release, or another model config (a server without one accepts any).
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
            _ => None,
        }
    }

    fn encode(&self) -> Vec<f32> {
        let json = serde_json::to_vec(self).expect("a fingerprint serialises");
        let mut values: Vec<f32> = json.iter().map(|&b| f32::from(b)).collect();
        values.resize(ANSWER_LEN, 0.0);
        values
    }

    fn decode(values: &[f32]) -> Option<Self> {
        let bytes: Vec<u8> = values
            .iter()
            .take_while(|&&v| v != 0.0)
            .map(|&v| v as u8)
            .collect();
        serde_json::from_slice(&bytes).ok()
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

/// `server` answering the handshake with `fingerprint` on the backend of `device` (Burn
/// takes custom operations for the served devices' backend only).
///
/// # Errors
/// A device of a backend that cannot be served (a remote device).
#[allow(deprecated)] // burn-ndarray is deprecated upstream; prism's tests still serve it
pub fn register(
    server: RemoteServer,
    device: &Device,
    fingerprint: &Fingerprint,
) -> Result<RemoteServer, String> {
    let answer = fingerprint.encode();
    match device.clone().inner().as_dispatch() {
        DispatchDevice::Flex(_) => {
            use burn::backend::Flex;
            Ok(server.with_custom_op::<Flex, _>(HANDSHAKE_OP, answer_op::<Flex>(answer)))
        }
        DispatchDevice::NdArray(_) => {
            use burn::backend::NdArray;
            Ok(server.with_custom_op::<NdArray, _>(HANDSHAKE_OP, answer_op::<NdArray>(answer)))
        }
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        DispatchDevice::Cube(_) => {
            use burn::backend::Cube;
            Ok(server.with_custom_op::<Cube, _>(HANDSHAKE_OP, answer_op::<Cube>(answer)))
        }
        other => Err(format!("cannot serve the device {other:?}")),
    }
}

/// The handler: the answer as a new tensor on the device.
fn answer_op<B: BackendIr>(
    answer: Vec<f32>,
) -> impl Fn(&mut HandleContainer<B::Handle>, &CustomOpIr, &B::Device) + Send + Sync + 'static {
    move |handles, op, device| {
        let tensor = B::float_from_data(TensorData::new(answer.clone(), [ANSWER_LEN]), device);
        handles.register_float_tensor::<B>(&op.outputs[0].id, tensor);
    }
}

/// Asks the server of the remote `device` for its fingerprint (blocks until it answers).
///
/// # Errors
/// Not a remote device, a failed read, or an answer that is not a fingerprint.
pub fn ask(device: &Device) -> Result<Fingerprint, String> {
    let device = device.clone().inner();
    let DispatchDevice::Remote(remote) = device.as_dispatch() else {
        return Err("not a remote device".into());
    };
    let client = CustomOpClient::new(remote);
    let output = TensorIr::uninit(
        client.create_empty_handle(),
        Shape::from([ANSWER_LEN]),
        DType::F32,
    );
    let answer = client
        .register(CustomOpIr::new(HANDSHAKE_OP, &[], &[output]))
        .remove(0);
    let data = read_sync(<Remote as FloatTensorOps<Remote>>::float_into_data(answer))
        .map_err(|e| format!("reading its answer failed: {e:?}"))?;
    let values = data
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| format!("its answer is not f32: {e:?}"))?;
    Fingerprint::decode(&values).ok_or_else(|| "its answer is not a prism fingerprint".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fingerprints_round_trip_and_mismatches_are_explained() {
        let ours = Fingerprint::this_build(Some(config_digest("tiny")));
        assert_eq!(Fingerprint::decode(&ours.encode()), Some(ours.clone()));
        assert_eq!(ours.mismatch(&ours), None);
        assert_eq!(ours.mismatch(&Fingerprint::this_build(None)), None);

        let older = Fingerprint {
            prism: "0.0.1".into(),
            config: None,
        };
        let why = ours.mismatch(&older).unwrap();
        assert!(why.contains("prism 0.0.1"), "{why}");

        let other = Fingerprint::this_build(Some(config_digest("small")));
        let why = ours.mismatch(&other).unwrap();
        assert!(why.contains("another model config"), "{why}");
        assert_ne!(config_digest("tiny"), config_digest("small"));
    }
}
