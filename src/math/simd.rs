//! Which build of a hot loop runs: the CPU backend's lane loops, its
//! passes over every primitive (frames, the reduction with the chain rule)
//! and its decode's rows, and the regularisers with Adam. The AVX-512 (32 vector registers), AVX2
//! and baseline builds execute the same IEEE operations in the same order
//! (Rust never fuses multiply-adds on its own, `sqrt` and `/` are exact
//! whatever the width, and `exp` is the same libm call), so they return
//! identical bits; `GSENC_SIMD=avx2|baseline` caps the level (for
//! benchmarks and for testing that claim; the encode output's `simd` names
//! the build that ran).

use crate::error::{by_name, Result};

#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(dead_code)] // the x86 levels exist only there
pub(crate) enum Simd {
    Baseline,
    Avx2,
    Avx512,
}

impl Simd {
    const ALL: [Simd; 3] = [Simd::Avx512, Simd::Avx2, Simd::Baseline];

    fn name(self) -> &'static str {
        match self {
            Simd::Baseline => "baseline",
            Simd::Avx2 => "avx2",
            Simd::Avx512 => "avx512",
        }
    }
}

/// The level `GSENC_SIMD` caps the loops at, when it is set and not empty.
fn cap_from_env() -> Result<Option<Simd>> {
    match std::env::var("GSENC_SIMD") {
        Ok(s) if !s.trim().is_empty() => {
            by_name(&Simd::ALL, Simd::name, s.trim(), "build").map(Some).map_err(|e| e.in_context("GSENC_SIMD"))
        }
        _ => Ok(None),
    }
}

/// An error when `GSENC_SIMD` names no build: checked where a backend
/// opens (`BackendChoice::open`), as `GSENC_BACKEND` is, so that a misspelt
/// cap fails a benchmark instead of timing another build.
pub fn check_env() -> Result<()> {
    cap_from_env().map(|_| ())
}

/// The build of the CPU backend's loops that runs on this CPU ("avx512",
/// "avx2" or "baseline"; the encode output's `simd`).
pub fn build() -> &'static str {
    simd_level().name()
}

pub(crate) fn simd_level() -> Simd {
    static LEVEL: std::sync::OnceLock<Simd> = std::sync::OnceLock::new();
    *LEVEL.get_or_init(|| {
        // A bad value is refused where a backend opens (`check_env`).
        let cap = cap_from_env().ok().flatten().unwrap_or(Simd::Avx512);
        #[cfg(target_arch = "x86_64")]
        let found = if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512vl") {
            Simd::Avx512
        } else if std::arch::is_x86_feature_detected!("avx2") {
            Simd::Avx2
        } else {
            Simd::Baseline
        };
        #[cfg(not(target_arch = "x86_64"))]
        let found = Simd::Baseline;
        let rank = |s: Simd| s as u8;
        if rank(cap) < rank(found) { cap } else { found }
    })
}

/// `simd_dispatch!(fn name(args) -> T => inner);` defines `name`, which runs
/// `inner(args)` compiled for the best level [`simd_level`] allows. `inner`
/// must be `#[inline(always)]`, so that each level's wrapper holds its own
/// copy of the loops built with that level's instructions.
macro_rules! simd_dispatch {
    ($(#[$m:meta])* fn $name:ident($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty => $inner:path) => {
        $(#[$m])*
        fn $name($($arg: $ty),*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx512f,avx512vl,avx2")]
            unsafe fn avx512($($arg: $ty),*) -> $ret {
                $inner($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2")]
            unsafe fn avx2($($arg: $ty),*) -> $ret {
                $inner($($arg),*)
            }
            match $crate::math::simd::simd_level() {
                // SAFETY: the CPU supports the instructions (`simd_level` checked).
                #[cfg(target_arch = "x86_64")]
                $crate::math::simd::Simd::Avx512 => unsafe { avx512($($arg),*) },
                #[cfg(target_arch = "x86_64")]
                $crate::math::simd::Simd::Avx2 => unsafe { avx2($($arg),*) },
                _ => $inner($($arg),*),
            }
        }
    };
}
pub(crate) use simd_dispatch;
