//! Host memory views of the CPU backends' tensors, for the fused kernels: flex lends its
//! buffer (no copy when the tensor is contiguous) and takes the result's `Vec` as its buffer;
//! ndarray's values are copied out of its array, and results go in through `TensorData`.

// burn-ndarray is deprecated upstream, but the project's tests run on it.
#![allow(deprecated)]

use std::any::Any;
use std::ops::Deref;
use std::sync::Arc;

use burn::backend::flex::{FlexTensor, Layout};
use burn::backend::ndarray::NdArrayTensor;
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Flex, NdArray, TensorMetadata};
use burn::tensor::{Bytes, DType, Shape, TensorData};

use crate::packed::SharedBuffer;

/// An f32 tensor's values in host memory, borrowed or owned.
pub enum HostValues {
    /// A contiguous flex tensor, read in place.
    Flex(FlexTensor),
    /// A copy.
    Owned(Vec<f32>),
}

impl Deref for HostValues {
    type Target = [f32];

    fn deref(&self) -> &[f32] {
        match self {
            Self::Flex(t) => t.as_slice::<f32>().expect("contiguous f32 flex tensor"),
            Self::Owned(v) => v,
        }
    }
}

/// A CPU backend whose f32 tensors the fused kernels read and write as slices.
pub trait HostTensors: Backend {
    /// The values of an f32 tensor, row-major.
    fn values(tensor: FloatTensor<Self>) -> HostValues;

    /// A tensor of `shape` holding `values` (row-major) on `device`.
    fn tensor(values: Vec<f32>, shape: Shape, device: &Self::Device) -> FloatTensor<Self>;

    /// The buffer holding `tensor`'s values, where the backend shares buffers between tensors
    /// and the tensor reads its buffer contiguously (flex); `None` elsewhere (ndarray's values
    /// are copied out at every call).
    fn shared_buffer(_tensor: &FloatTensor<Self>) -> Option<SharedBuffer> {
        None
    }

    /// `tensor` with `f` applied to its values (row-major), in place where the backend can
    /// lend them mutably (flex: a contiguous tensor no one else holds), else on a copy: an
    /// element-wise op then writes no new buffer, which would first be zeroed.
    fn update(tensor: FloatTensor<Self>, f: impl FnOnce(&mut [f32])) -> FloatTensor<Self> {
        updated_copy::<Self>(tensor, f)
    }

    /// `tensor` through an element-wise op: `in_place` on its values where the backend can
    /// lend them mutably (as [`HostTensors::update`]), else `copied` from them into a new
    /// buffer, in one pass that reads the values and writes the result.
    fn map(
        tensor: FloatTensor<Self>,
        _in_place: impl FnOnce(&mut [f32]),
        copied: impl FnOnce(&[f32]) -> Vec<f32>,
    ) -> FloatTensor<Self> {
        mapped_copy::<Self>(tensor, copied)
    }
}

/// A new tensor holding `copied` of `tensor`'s values.
fn mapped_copy<B: HostTensors>(
    tensor: FloatTensor<B>,
    copied: impl FnOnce(&[f32]) -> Vec<f32>,
) -> FloatTensor<B> {
    let (shape, device) = (tensor.shape(), tensor.device());
    let values = copied(&B::values(tensor));
    B::tensor(values, shape, &device)
}

/// A new tensor holding `f` applied to a copy of `tensor`'s values.
fn updated_copy<B: HostTensors>(
    tensor: FloatTensor<B>,
    f: impl FnOnce(&mut [f32]),
) -> FloatTensor<B> {
    mapped_copy::<B>(tensor, |values| {
        let mut values = values.to_vec();
        f(&mut values);
        values
    })
}

impl HostTensors for Flex {
    fn values(tensor: FloatTensor<Self>) -> HostValues {
        assert_eq!(tensor.dtype(), DType::F32, "fused kernels take f32 tensors");
        let tensor = if tensor.as_slice::<f32>().is_some() {
            tensor
        } else {
            tensor.to_contiguous()
        };
        HostValues::Flex(tensor)
    }

    fn tensor(values: Vec<f32>, shape: Shape, _device: &Self::Device) -> FloatTensor<Self> {
        assert_eq!(
            values.len(),
            shape.num_elements(),
            "values do not fill the shape"
        );
        FlexTensor::new(
            Bytes::from_elems(values),
            Layout::contiguous(shape),
            DType::F32,
        )
    }

    fn shared_buffer(tensor: &FloatTensor<Self>) -> Option<SharedBuffer> {
        if tensor.dtype() != DType::F32 {
            return None;
        }
        let (start, _) = tensor.layout().contiguous_offsets()?;
        let data = tensor.data_arc();
        Some(SharedBuffer {
            address: Arc::as_ptr(&data) as usize,
            start,
            alive: Arc::downgrade(&data),
        })
    }

    fn update(mut tensor: FloatTensor<Self>, f: impl FnOnce(&mut [f32])) -> FloatTensor<Self> {
        if let Some(values) = lent_values(&mut tensor) {
            f(values);
            return tensor;
        }
        updated_copy::<Self>(tensor, f)
    }

    fn map(
        mut tensor: FloatTensor<Self>,
        in_place: impl FnOnce(&mut [f32]),
        copied: impl FnOnce(&[f32]) -> Vec<f32>,
    ) -> FloatTensor<Self> {
        if let Some(values) = lent_values(&mut tensor) {
            in_place(values);
            return tensor;
        }
        mapped_copy::<Self>(tensor, copied)
    }
}

/// The values of an f32 flex tensor, lent mutably when it is contiguous and no one else holds
/// its buffer.
fn lent_values(tensor: &mut FlexTensor) -> Option<&mut [f32]> {
    assert_eq!(tensor.dtype(), DType::F32, "fused kernels take f32 tensors");
    let (start, end) = tensor.layout().contiguous_offsets()?;
    Some(&mut tensor.try_storage_mut::<f32>()?[start..end])
}

/// The values of `tensor`, row-major, when it is an f32 ndarray tensor (`B` the ndarray
/// backend), copied in one piece as [`HostTensors::values`] does; any other tensor comes back
/// unchanged, for the caller's general path.
pub fn ndarray_f32_values<B: Backend>(tensor: FloatTensor<B>) -> Result<Vec<f32>, FloatTensor<B>> {
    let back =
        |any: Box<dyn Any>| -> FloatTensor<B> { *any.downcast().expect("the tensor's own type") };
    match (Box::new(tensor) as Box<dyn Any>).downcast::<NdArrayTensor>() {
        Ok(tensor) => copy_f32(*tensor).map_err(|tensor| back(Box::new(tensor))),
        Err(any) => Err(back(any)),
    }
}

/// An f32 ndarray tensor's values, row-major, copied in one piece; a tensor of another dtype
/// comes back unchanged. burn-ndarray's own `into_data` collects an array that another handle
/// shares (a module's weights, read at every call; a tensor autodiff keeps) one element at a
/// time through its n-dimensional iterator: three quarters of `prism evaluate`'s time on
/// ndarray went there, in the LPIPS network's convolutions.
fn copy_f32(tensor: NdArrayTensor) -> Result<Vec<f32>, NdArrayTensor> {
    let NdArrayTensor::F32(storage) = tensor else {
        return Err(tensor);
    };
    let array = storage.view();
    Ok(match array.as_slice() {
        Some(values) => values.to_vec(),
        None => array.as_standard_layout().iter().copied().collect(),
    })
}

impl HostTensors for NdArray {
    fn values(tensor: FloatTensor<Self>) -> HostValues {
        let values = copy_f32(tensor).unwrap_or_else(|tensor| {
            panic!("fused kernels take f32 tensors, got {:?}", tensor.dtype())
        });
        HostValues::Owned(values)
    }

    fn tensor(values: Vec<f32>, shape: Shape, device: &Self::Device) -> FloatTensor<Self> {
        Self::float_from_data(TensorData::new(values, shape), device)
    }
}
