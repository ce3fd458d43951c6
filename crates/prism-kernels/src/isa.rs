//! Which of the host kernels' builds a CPU runs.
//!
//! The element-wise and row kernels of this crate and of prism-render (GELU, the norms,
//! attention's exponentials and rows, AdamW, the rasteriser's rows) are compiled with the
//! `multiversion` crate for AVX-512 (F, VL, DQ), for AVX2 with FMA and for the baseline, and
//! each picks the widest one the CPU has on its first call.
//!
//! By default `multiversion` takes its AVX-512 code only where the CPU also has the Ice Lake
//! extensions (VBMI, VBMI2, IFMA, BITALG, VPOPCNTDQ, VNNI, GFNI, VAES, VPCLMULQDQ), to spare
//! Skylake-SP and Cascade Lake Xeons the clock drop of 512-bit code. On those Xeons prism's
//! kernels then ran their AVX2 code, while `gemm`'s products (which check AVX-512F alone) ran
//! 512-bit multiply-adds and lowered the clock anyway. The workspace's `.cargo/config.toml`
//! sets `multiversion_allow_slow_avx512`, so that the AVX-512 code needs only the features it
//! is compiled for. On a 2-core Sapphire Rapids the AVX2 code took the backbone's forward
//! passes to 1.01x to 1.08x of their time (BENCHMARKS.md, issue 43's "The `multiversion`
//! variant on Cascade Lake").

use std::sync::OnceLock;

use multiversion::multiversion;
use multiversion::target::target_cfg_f;

/// The instruction set of the host kernels' code that this CPU runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HostIsa {
    /// AVX-512 F, VL and DQ.
    Avx512,
    /// AVX2 with FMA.
    Avx2,
    /// The target's baseline (SSE2 on x86-64).
    Baseline,
}

impl HostIsa {
    /// The code the kernels' dispatch picks on this CPU.
    pub fn detect() -> Self {
        selected().0
    }

    /// [`HostIsa::detect`], once per process. The first call on a CPU with AVX-512 that runs
    /// the AVX2 code says on stderr why: the build lacked `multiversion_allow_slow_avx512`.
    pub fn chosen() -> Self {
        static CHOSEN: OnceLock<HostIsa> = OnceLock::new();
        *CHOSEN.get_or_init(|| {
            let isa = Self::detect();
            if isa != Self::Avx512 && cpu_has_avx512() {
                eprintln!(
                    "prism: this CPU has AVX-512, but this build runs the host kernels' AVX2 \
                     code: it was built without `--cfg multiversion_allow_slow_avx512` (set in \
                     .cargo/config.toml; a RUSTFLAGS in the environment replaces it)"
                );
            }
            isa
        })
    }

    /// The name `prism bench` prints.
    pub fn name(self) -> &'static str {
        match self {
            Self::Avx512 => "AVX-512",
            Self::Avx2 => "AVX2",
            Self::Baseline => "baseline",
        }
    }
}

/// Whether the CPU has the AVX-512 features the kernels' AVX-512 code is compiled for.
fn cpu_has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512vl")
            && is_x86_feature_detected!("avx512dq")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The code the dispatch picks, with the kernels' own target list, and whether that code also
/// requires AVX512-VBMI (one of the Ice Lake extensions `multiversion` adds by default).
#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn selected() -> (HostIsa, bool) {
    let avx512 = target_cfg_f!(target_feature = "avx512f");
    let avx2 = target_cfg_f!(target_feature = "avx2");
    let isa = match (avx512, avx2) {
        (true, _) => HostIsa::Avx512,
        (false, true) => HostIsa::Avx2,
        (false, false) => HostIsa::Baseline,
    };
    (isa, target_cfg_f!(target_feature = "avx512vbmi"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX-512 code runs wherever the CPU has AVX-512 F, VL and DQ, and requires none of the
    /// Ice Lake extensions; otherwise AVX2 with FMA where the CPU has them.
    #[test]
    fn the_widest_code_the_cpu_has_runs() {
        let (isa, requires_vbmi) = selected();
        assert!(
            !requires_vbmi,
            "the kernels' AVX-512 code requires the Ice Lake extensions: the build lacks \
             `--cfg multiversion_allow_slow_avx512`"
        );
        #[cfg(target_arch = "x86_64")]
        let expected = if cpu_has_avx512() {
            HostIsa::Avx512
        } else if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            HostIsa::Avx2
        } else {
            HostIsa::Baseline
        };
        #[cfg(not(target_arch = "x86_64"))]
        let expected = HostIsa::Baseline;
        assert_eq!(isa, expected);
        assert_eq!(HostIsa::chosen(), expected);
    }
}
