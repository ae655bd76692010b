//! HDF5's automatic error printing, as the host set it.
//!
//! HDF5 prints an error stack to stderr when a call fails, unless the
//! program turned that off (`H5Eset_auto2`); a simulation that writes its
//! own HDF5 output relies on the one or the other. The `hdf5` crate turns
//! it off for good on every thread it is first used on (and for the whole
//! process where HDF5 is the serial build, whose error stack is global),
//! so that its own failed calls (a dataset looked for) stay quiet. The
//! store is written on the host's thread (`gsenc_wait`, `gsenc_poll`,
//! destroy), so that would change the host's HDF5 for the rest of the run.
//! Instead each of the store's calls holds a [`Quiet`]: printing off while
//! it runs, and as it was before once it returns.

use std::ffi::c_void;

use hdf5_sys::h5e::{H5E_auto2_t, H5Eget_auto2, H5Eset_auto2, H5E_DEFAULT};

/// While held, HDF5 prints no error stack on this thread; dropped, it
/// prints as it did when this was made.
pub(crate) struct Quiet {
    func: H5E_auto2_t,
    data: *mut c_void,
}

/// Makes a [`Quiet`]: reads the printing as it is, then turns it off.
pub(crate) fn quiet() -> Quiet {
    let (mut func, mut data): (H5E_auto2_t, *mut c_void) = (None, std::ptr::null_mut());
    let _lock = hdf5_sys::LOCK.lock();
    // SAFETY: HDF5's lock is held; the first calls the `hdf5` crate would
    // make (H5dont_atexit fails harmlessly once the library is open), then
    // the current printing read into two out-parameters.
    unsafe {
        hdf5_sys::h5::H5dont_atexit();
        if H5Eget_auto2(H5E_DEFAULT, &mut func, &mut data) < 0 {
            (func, data) = (None, std::ptr::null_mut());
        }
    }
    // The crate's own first use on this thread (which turns printing off),
    // then off while the store works.
    hdf5::sync::sync(|| unsafe { H5Eset_auto2(H5E_DEFAULT, None, std::ptr::null_mut()) });
    Quiet { func, data }
}

impl Drop for Quiet {
    fn drop(&mut self) {
        // SAFETY: the function and data HDF5 gave, on the same thread.
        hdf5::sync::sync(|| unsafe { H5Eset_auto2(H5E_DEFAULT, self.func, self.data) });
    }
}
