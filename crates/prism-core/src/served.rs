//! prism's operations on a `prism serve` server: custom operations of Burn's remote backend,
//! registered for the served devices' backend, their calls from the trainer, and the byte
//! messages they exchange.
//!
//! A custom operation carries no arguments besides tensors, so a message (a JSON text) travels
//! as a 1-D `f32` tensor holding one byte per value, zero-padded.

use burn::backend::ir::{BackendIr, CustomOpIr, HandleContainer, TensorIr};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{BackendTypes, DispatchDevice, Remote};
use burn::remote::CustomOpClient;
use burn::server::RemoteServer;
use burn::tensor::{DType, Device, Shape, Tensor, TensorData, read_sync};

/// A tensor of Burn's remote backend (a handle to a tensor on a server).
pub type ServerTensor = <Remote as BackendTypes>::FloatTensorPrimitive;

/// Evaluates `$body` with the type `$B` naming the backend of the served device `$device`
/// (Burn takes a server's custom operations for that backend only): `Ok(body)`, or an error
/// for a device of a backend that cannot be served (a remote device). The GPU backends are
/// included where the calling crate has its `wgpu` or `cuda` feature.
#[macro_export]
macro_rules! for_served_backend {
    ($device:expr, $B:ident => $body:expr) => {{
        #[allow(deprecated)] // burn-ndarray is deprecated upstream; prism's tests serve it
        match $device.clone().inner().as_dispatch() {
            ::burn::backend::DispatchDevice::Flex(_) => {
                type $B = ::burn::backend::Flex;
                Ok($body)
            }
            ::burn::backend::DispatchDevice::NdArray(_) => {
                type $B = ::burn::backend::NdArray;
                Ok($body)
            }
            #[cfg(any(feature = "wgpu", feature = "cuda"))]
            ::burn::backend::DispatchDevice::Cube(_) => {
                type $B = ::burn::backend::Cube;
                Ok($body)
            }
            other => Err(format!("cannot serve the device {other:?}")),
        }
    }};
}

/// One of prism's operations with state (a handler object), as the server runs it on any
/// backend `B`.
pub trait ServedOp: Clone + Send + Sync + 'static {
    /// The operation's id (versioned: a change of its inputs or outputs gets a new id).
    const ID: &'static str;

    /// Runs the operation `op` on `device`: reads its inputs from `handles`, registers its
    /// outputs there.
    fn run<B: BackendIr>(
        &self,
        handles: &mut HandleContainer<B::Handle>,
        op: &CustomOpIr,
        device: &B::Device,
    );
}

/// `server` running `op` on the backend of `device`.
///
/// # Errors
/// A device of a backend that cannot be served (a remote device).
pub fn register<O: ServedOp>(
    server: RemoteServer,
    device: &Device,
    op: O,
) -> Result<RemoteServer, String> {
    for_served_backend!(device, B => server.with_custom_op::<B, _>(O::ID, move |h, ir, d| {
        op.run::<B>(h, ir, d);
    }))
}

/// A message of at most `len` bytes as the values of a tensor.
///
/// # Panics
/// If the message is longer than `len` (prism's messages have fixed bounds).
pub fn encode(message: &[u8], len: usize) -> Vec<f32> {
    assert!(
        message.len() <= len,
        "a message of {} bytes, {len} at most",
        message.len()
    );
    let mut values: Vec<f32> = message.iter().map(|&b| f32::from(b)).collect();
    values.resize(len, 0.0);
    values
}

/// The message held by `values` (up to the first zero).
pub fn decode(values: &[f32]) -> Vec<u8> {
    values
        .iter()
        .take_while(|&&v| v != 0.0)
        .map(|&v| v as u8)
        .collect()
}

/// The message held by the server's tensor `tensor` (blocks until the server answers).
///
/// # Errors
/// A failed read, or values that are not `f32`.
pub fn read_message(tensor: ServerTensor) -> Result<Vec<u8>, String> {
    let data = read_sync(<Remote as FloatTensorOps<Remote>>::float_into_data(tensor))
        .map_err(|e| format!("reading the server's answer failed: {e:?}"))?;
    let values = data
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| format!("the server's answer is not f32: {e:?}"))?;
    Ok(decode(&values))
}

/// The values of input `index` of `op` on the server (empty when they cannot be read).
pub fn input_values<B: BackendIr>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    index: usize,
) -> Vec<f32> {
    let tensor = handles.get_float_tensor::<B>(&op.inputs[index]);
    read_sync(B::float_into_data(tensor))
        .ok()
        .and_then(|data| data.convert::<f32>().try_into_vec::<f32>().ok())
        .unwrap_or_default()
}

/// The message held by input `index` of `op` on the server.
pub fn input_message<B: BackendIr>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    index: usize,
) -> Vec<u8> {
    decode(&input_values::<B>(handles, op, index))
}

/// Registers `values` (of `shape`) on `device` as output `index` of `op`.
pub fn put_output<B: BackendIr>(
    handles: &mut HandleContainer<B::Handle>,
    op: &CustomOpIr,
    index: usize,
    data: TensorData,
    device: &B::Device,
) {
    let tensor = B::float_from_data(data, device);
    handles.register_float_tensor::<B>(&op.outputs[index].id, tensor);
}

/// A call of operation `id` on the server of the remote `device` (a device of Burn's
/// remote backend, with or without autodiff).
pub struct Call {
    client: CustomOpClient,
    inputs: Vec<TensorIr>,
    outputs: Vec<TensorIr>,
    device: Device,
}

impl Call {
    /// A call on `device`.
    ///
    /// # Errors
    /// `device` is not a served device.
    pub fn new(device: &Device) -> Result<Self, String> {
        let bare = device.clone().inner();
        let DispatchDevice::Remote(remote) = bare.as_dispatch() else {
            return Err("not a served device".into());
        };
        Ok(Self {
            client: CustomOpClient::new(remote),
            inputs: Vec::new(),
            outputs: Vec::new(),
            device: bare,
        })
    }

    /// Adds an input: `values` sent to the server.
    pub fn input(self, values: Vec<f32>) -> Self {
        let len = values.len();
        let tensor = Tensor::<1>::from_data(TensorData::new(values, [len]), &self.device);
        let tensor = tensor
            .try_into_primitive::<Remote>()
            .expect("a tensor made on a served device is a remote tensor");
        self.input_tensor(tensor)
    }

    /// Adds an input: a tensor already on the server.
    pub fn input_tensor(mut self, tensor: ServerTensor) -> Self {
        self.inputs.push(tensor.into_ir());
        self
    }

    /// Adds an `f32` output of `shape`.
    pub fn output(mut self, shape: impl Into<Shape>) -> Self {
        self.outputs.push(TensorIr::uninit(
            self.client.create_empty_handle(),
            shape.into(),
            DType::F32,
        ));
        self
    }

    /// Sends the call; its outputs, on the server, in the order they were added.
    pub fn send(self, id: &'static str) -> Vec<ServerTensor> {
        self.client
            .register(CustomOpIr::new(id, &self.inputs, &self.outputs))
    }
}

/// A server's tensor as a tensor of the served device: no gradient flows into it (data).
pub fn served_tensor<const D: usize>(tensor: ServerTensor) -> Tensor<D> {
    Tensor::from_primitive::<Remote>(tensor)
}
