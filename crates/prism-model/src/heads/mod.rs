//! The heads on `T_out` (paper Sec. 3.2, Stage III): the NVS decoder ([`nvs`]: target tokens
//! to `I_t`) and the 3DGS head ([`gaussian`]: source tokens to Gaussians and their render
//! `I_gs`).

pub(crate) mod gaussian;
pub(crate) mod nvs;
