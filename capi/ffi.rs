//! What every C entry point shares: element types of caller arrays, the
//! caller's structs that start with their own size, strings, and copies
//! of strided arrays out of the caller's memory.

use crate::status::{fail, gsenc_status, Failure};
use std::os::raw::{c_char, c_void};

/// Element types of pushed arrays.
pub const GSENC_DTYPE_FLOAT32: i32 = 0;
pub const GSENC_DTYPE_FLOAT64: i32 = 1;

#[derive(Clone, Copy, Debug)]
pub(crate) enum DType {
    F32,
    F64,
}

impl DType {
    pub(crate) fn from_c(code: i32) -> Result<DType, Failure> {
        match code {
            GSENC_DTYPE_FLOAT32 => Ok(DType::F32),
            GSENC_DTYPE_FLOAT64 => Ok(DType::F64),
            d => fail(gsenc_status::InvalidArgument, format!("unknown dtype {d} (GSENC_DTYPE_FLOAT32 or _FLOAT64)")),
        }
    }

    /// Bytes of an element.
    pub(crate) fn size(self) -> usize {
        match self {
            DType::F32 => 4,
            DType::F64 => 8,
        }
    }

    /// Element `at` of an array of this type.
    ///
    /// # Safety
    /// `data` holds at least `at + 1` elements of this type.
    pub(crate) unsafe fn read(self, data: *const c_void, at: isize) -> f64 {
        // SAFETY: per the contract; unaligned reads tolerate any caller buffer.
        unsafe {
            match self {
                DType::F32 => data.cast::<f32>().offset(at).read_unaligned() as f64,
                DType::F64 => data.cast::<f64>().offset(at).read_unaligned(),
            }
        }
    }
}

/// A caller's NUL-terminated UTF-8 string.
///
/// # Safety
/// `s` is NULL or points to a NUL-terminated string.
pub(crate) unsafe fn c_str(s: *const c_char, what: &str) -> Result<String, Failure> {
    if s.is_null() {
        return fail(gsenc_status::NullPointer, format!("{what} is NULL"));
    }
    // SAFETY: per the contract.
    let c = unsafe { std::ffi::CStr::from_ptr(s) };
    c.to_str().map(str::to_owned).map_err(|_| Failure(gsenc_status::InvalidArgument, format!("{what} is not UTF-8")))
}

/// Grid extents as dims, each positive and their product bounded.
pub(crate) fn extents(e: [u64; 3]) -> Result<[usize; 3], Failure> {
    let dims = e.map(|d| usize::try_from(d).unwrap_or(usize::MAX));
    let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).filter(|&n| n > 0 && n <= 1 << 34);
    match n {
        Some(_) => Ok(dims),
        None => fail(gsenc_status::InvalidArgument, format!("extents {e:?} must be positive with at most 2^34 cells")),
    }
}

/// Checks that a caller's struct, which starts with `size_t struct_size`,
/// holds at least this version's fields. Reads the size only.
///
/// # Safety
/// `p` is NULL or points to such a struct.
pub(crate) unsafe fn check_sized<T>(p: *const T, what: &str) -> Result<(), Failure> {
    if p.is_null() {
        return fail(gsenc_status::NullPointer, format!("{what} is NULL"));
    }
    // SAFETY: per the contract, the first field is a usize.
    let size = unsafe { p.cast::<usize>().read_unaligned() };
    let want = std::mem::size_of::<T>();
    if size < want {
        return fail(gsenc_status::StructSize, format!("{what}: struct_size is {size}, this gsenc needs {want}"));
    }
    Ok(())
}

/// A copy of a caller's struct after [`check_sized`].
///
/// # Safety
/// As for [`check_sized`], and the struct is initialised.
pub(crate) unsafe fn read_sized<T: Copy>(p: *const T, what: &str) -> Result<T, Failure> {
    // SAFETY: per the contract; then it holds at least size_of::<T>() bytes.
    unsafe {
        check_sized(p, what)?;
        Ok(p.read_unaligned())
    }
}

/// Refuses strides that no array can have: the element that `reaches`
/// (counts, each with its stride in elements) name farthest from the start
/// must lie within `isize::MAX` bytes of it, as every array's elements do.
/// A field left unset (garbage) or a count and stride whose product
/// overflows would otherwise have the copy read at a wrapped address.
pub(crate) fn check_reach(what: &str, dtype: DType, reaches: &[(usize, i64)]) -> Result<(), Failure> {
    let far: i128 = reaches.iter().map(|&(n, s)| n.saturating_sub(1) as i128 * i128::from(s).abs()).sum();
    if far.saturating_mul(dtype.size() as i128) <= isize::MAX as i128 {
        return Ok(());
    }
    let strides: Vec<i64> = reaches.iter().map(|r| r.1).collect();
    fail(gsenc_status::InvalidArgument, format!("{what}: strides {strides:?} reach element {far} from the start, past the end of any array (a stride left unset?)"))
}

/// `n` tuples of three from a caller's array `what` (strides in elements,
/// 0 = default), refusing strides no array can have ([`check_reach`]).
///
/// # Safety
/// `ptr` holds every element the count and strides name.
pub(crate) unsafe fn read_tuples(what: &str, dtype: DType, ptr: *const c_void, n: usize, stride: i64, component: i64) -> Result<Vec<[f64; 3]>, Failure> {
    let (ts, cs) = (if stride == 0 { 3 } else { stride }, if component == 0 { 1 } else { component });
    check_reach(what, dtype, &[(n, ts), (3, cs)])?;
    // SAFETY: per the contract; every offset fits (checked just above).
    Ok((0..n as i64).map(|i| std::array::from_fn(|c| unsafe { dtype.read(ptr, (i * ts + c as i64 * cs) as isize) })).collect())
}

/// `n` scalars from a caller's array `what` (stride in elements, 0 = 1),
/// refusing a stride no array can have ([`check_reach`]).
///
/// # Safety
/// `ptr` holds every element the count and stride name.
pub(crate) unsafe fn read_scalars(what: &str, dtype: DType, ptr: *const c_void, n: usize, stride: i64) -> Result<Vec<f64>, Failure> {
    let s = if stride == 0 { 1 } else { stride };
    check_reach(what, dtype, &[(n, s)])?;
    // SAFETY: per the contract; every offset fits (checked just above).
    Ok((0..n as i64).map(|i| unsafe { dtype.read(ptr, (i * s) as isize) }).collect())
}

/// The values of a strided grid, x fastest, as float32, into `values`
/// (a recycled buffer: no page faults for a fresh allocation), and whether
/// every one is finite. Rows with unit stride are copied as slices (a 128^3
/// float push is a few memcpy-speed milliseconds, the solver's only wait);
/// other layouts element by element. Each row is checked as float32 (a
/// finite double can overflow) right after its copy, while it is in cache:
/// a check of the whole copy afterwards read it back from memory, 1 ms of
/// a 3.5 ms push of 128^3 on the 2-core VM.
///
/// # Safety
/// `ptr` holds every element that `dims` and `strides` name.
pub(crate) unsafe fn copy_grid(dtype: DType, ptr: *const c_void, dims: [usize; 3], strides: [i64; 3], mut values: Vec<f32>) -> (Vec<f32>, bool) {
    values.clear();
    values.reserve(dims.iter().product());
    // Slices need aligned data; a misaligned caller buffer takes the slow path.
    let unit = match dtype {
        DType::F32 if ptr.cast::<f32>().is_aligned() => strides[0] == 1,
        DType::F64 if ptr.cast::<f64>().is_aligned() => strides[0] == 1,
        _ => false,
    };
    let mut finite = true;
    for k in 0..dims[2] as i64 {
        for j in 0..dims[1] as i64 {
            let row = j * strides[1] + k * strides[2];
            let start = values.len();
            // SAFETY (all three arms): per the contract, the row's elements exist.
            match (dtype, unit) {
                (DType::F32, true) => values.extend_from_slice(unsafe {
                    std::slice::from_raw_parts(ptr.cast::<f32>().offset(row as isize), dims[0])
                }),
                (DType::F64, true) => values.extend(
                    unsafe { std::slice::from_raw_parts(ptr.cast::<f64>().offset(row as isize), dims[0]) }.iter().map(|&v| v as f32),
                ),
                _ => values.extend((0..dims[0] as i64).map(|i| unsafe { dtype.read(ptr, (row + i * strides[0]) as isize) } as f32)),
            }
            finite &= gsenc::field::all_finite(&values[start..]);
        }
    }
    (values, finite)
}

/// A count of items (particles, cells, points): 1..2^40, or from 0 where
/// `none_ok` (a rank of an MPI encoder may hold none).
pub(crate) fn item_count(count: u64, what: &str, none_ok: bool) -> Result<usize, Failure> {
    let least = usize::from(!none_ok);
    usize::try_from(count)
        .ok()
        .filter(|&n| n >= least && n <= 1 << 40)
        .ok_or_else(|| Failure(gsenc_status::InvalidArgument, format!("{what} count {count} must be {least}..2^40")))
}

/// A caller's time: NaN (or any non-finite value) means unknown.
pub(crate) fn time_of(time: f64) -> Option<f64> {
    time.is_finite().then_some(time)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Negative strides walk their axes backwards from the first element:
    /// the copy of a view reversed along every axis, and along y alone, is
    /// the values gathered by hand, for both types and both copy paths
    /// (unit x stride and not).
    #[test]
    fn negative_strides_copy_reversed_views() {
        let dims = [4usize, 3, 2];
        let n: usize = dims.iter().product();
        let src: Vec<f64> = (0..n).map(|i| i as f64 * 0.5 - 1.0).collect();
        let f32s: Vec<f32> = src.iter().map(|&x| x as f32).collect();
        let at = |i: usize, j: usize, k: usize| i + dims[0] * (j + dims[1] * k);
        // (flip x, flip y, flip z)
        for flip in [[true, true, true], [false, true, false], [true, false, false]] {
            let mut strides = [1i64, dims[0] as i64, (dims[0] * dims[1]) as i64];
            let mut first = 0usize;
            for a in 0..3 {
                if flip[a] {
                    first += (dims[a] - 1) * strides[a] as usize;
                    strides[a] = -strides[a];
                }
            }
            let want: Vec<f32> = (0..n)
                .map(|v| {
                    let (i, j, k) = (v % dims[0], v / dims[0] % dims[1], v / (dims[0] * dims[1]));
                    let r = |c: usize, a: usize| if flip[a] { dims[a] - 1 - c } else { c };
                    f32s[at(r(i, 0), r(j, 1), r(k, 2))]
                })
                .collect();
            for dtype in [DType::F32, DType::F64] {
                let ptr: *const c_void = match dtype {
                    // SAFETY: `first` is an element of each array.
                    DType::F32 => unsafe { f32s.as_ptr().add(first) }.cast(),
                    DType::F64 => unsafe { src.as_ptr().add(first) }.cast(),
                };
                assert!(check_reach("a", dtype, &[(dims[0], strides[0]), (dims[1], strides[1]), (dims[2], strides[2])]).is_ok());
                // SAFETY: every element the dims and strides name is in the array.
                let (out, finite) = unsafe { copy_grid(dtype, ptr, dims, strides, Vec::new()) };
                assert!(finite);
                assert_eq!(out, want, "{dtype:?} flipped {flip:?}");
            }
        }
    }

    /// The farthest element may lie `isize::MAX` bytes from the start, no
    /// further, counted over every axis, negative strides by their size.
    #[test]
    fn strides_reach_no_further_than_an_array_can() {
        let most = isize::MAX as i64;
        assert!(check_reach("a", DType::F32, &[(2, most / 4)]).is_ok());
        assert!(check_reach("a", DType::F32, &[(2, most / 4 + 1)]).is_err());
        assert!(check_reach("a", DType::F64, &[(2, most / 8 + 1)]).is_err());
        assert!(check_reach("a", DType::F64, &[(2, most / 8)]).is_ok());
        assert!(check_reach("a", DType::F64, &[(2, most / 8), (2, 1)]).is_err(), "axes add up");
        assert!(check_reach("a", DType::F64, &[(2, -(most / 8 + 1))]).is_err(), "a negative stride counts by its size");
        assert!(check_reach("a", DType::F64, &[(1, i64::MIN), (1, i64::MAX)]).is_ok(), "one element reaches nothing");
        let e = check_reach("gsenc_push_cells: edges", DType::F32, &[(1 << 20, 1 << 50), (3, 1)]).unwrap_err();
        assert!(e.1.contains("gsenc_push_cells: edges") && e.1.contains("past the end"), "{}", e.1);
    }

    /// The copy's finite flag against a check of the whole copy: grids of
    /// float32 and float64 with unit stride and with a strided x (the three
    /// ways a row is copied), all finite, then with one NaN, infinity, or
    /// float64 too large for float32 at the first, a middle and the last
    /// element; the values are the caller's either way.
    #[test]
    fn the_copy_finds_what_a_whole_check_finds() {
        let dims = [5usize, 4, 3];
        let n: usize = dims.iter().product();
        for (stride, dtype) in [(1i64, DType::F32), (1, DType::F64), (2, DType::F32), (2, DType::F64)] {
            let strides = [stride, stride * dims[0] as i64, stride * (dims[0] * dims[1]) as i64];
            for (at, bad) in [(None, 0.0), (Some(0), f64::NAN), (Some(n / 2), f64::INFINITY), (Some(n - 1), f64::NEG_INFINITY), (Some(7), 1e300)] {
                let mut v: Vec<f64> = (0..n).map(|i| i as f64 * 0.25 - 3.0).collect();
                if let Some(at) = at {
                    v[at] = bad;
                }
                let src: Vec<f64> = v.iter().flat_map(|&x| std::iter::once(x).chain((1..stride).map(|_| f64::NAN))).collect();
                let f32s: Vec<f32> = src.iter().map(|&x| x as f32).collect();
                let ptr: *const c_void = match dtype {
                    DType::F32 => f32s.as_ptr().cast(),
                    DType::F64 => src.as_ptr().cast(),
                };
                // SAFETY: the array holds every element the dims and strides name.
                let (out, finite) = unsafe { copy_grid(dtype, ptr, dims, strides, vec![f32::NAN; 3]) };
                let want: Vec<f32> = v.iter().map(|&x| x as f32).collect();
                assert_eq!(out.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), want.iter().map(|x| x.to_bits()).collect::<Vec<_>>());
                assert_eq!(finite, gsenc::field::check_finite_serial(&want).is_ok(), "stride {stride}, {bad} at {at:?}");
                assert_eq!(finite, at.is_none(), "stride {stride}, {bad} at {at:?}");
            }
        }
    }
}
