//! The store leaves HDF5's automatic error printing as the host set it
//! (`src/io/store/host_errors.rs`). A binary of its own: Debian's HDF5 is
//! the serial build, whose error printing is one setting for the whole
//! process, which the store tests running beside it would change under
//! this one.
#![cfg(feature = "hdf5")]

mod common;
use common::store_model as model;
use common::tmpdir;
use gsenc::format::Payload;
use gsenc::io::store::{EntryKey, Store};
use hdf5_sys::h5e::{H5E_auto2_t, H5Eget_auto2, H5Eset_auto2, H5E_DEFAULT};
use hdf5_sys::h5i::hid_t;
use std::ffi::c_void;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Times the host's handler was called.
static CALLS: AtomicUsize = AtomicUsize::new(0);
/// The host's client data, which must come back with its handler.
const DATA: usize = 0x6773_6e63;

extern "C" fn host_handler(_stack: hid_t, data: *mut c_void) -> hdf5_sys::h5::herr_t {
    assert_eq!(data as usize, DATA);
    CALLS.fetch_add(1, Ordering::SeqCst);
    0
}

/// HDF5's current handler and data on this thread.
fn printing() -> (H5E_auto2_t, usize) {
    let (mut f, mut d): (H5E_auto2_t, *mut c_void) = (None, std::ptr::null_mut());
    let _lock = hdf5_sys::LOCK.lock();
    // SAFETY: two out-parameters, under HDF5's lock.
    assert!(unsafe { H5Eget_auto2(H5E_DEFAULT, &mut f, &mut d) } >= 0);
    (f, d as usize)
}

#[track_caller]
fn hosts_printing_in_place(after: &str) {
    let (f, d) = printing();
    assert!(f.is_some_and(|f| f as usize == host_handler as *const () as usize) && d == DATA, "after {after}: HDF5's error printing is no longer the host's");
    assert_eq!(CALLS.load(Ordering::SeqCst), 0, "after {after}: the store's own HDF5 errors reached the host's handler");
}

#[test]
fn the_hosts_hdf5_error_printing_is_left_as_it_set_it() {
    {
        let _lock = hdf5_sys::LOCK.lock();
        // SAFETY: a handler of HDF5's type and data it only hands back.
        unsafe { H5Eset_auto2(H5E_DEFAULT, Some(host_handler), DATA as *mut c_void) };
    }
    let dir = tmpdir("store-host-errors");
    let path = dir.join("s.h5");
    let (a, b) = (model("rho", 0, 0, 30, 2.0), model("rho", 0, 0, 31, 2.0));

    // Creating, appending, appending the same again, refusing another model
    // at its place, and reading an entry it does not hold: the last two
    // fail inside HDF5 as well as in gsenc.
    let mut store = Store::open_append(&path).unwrap();
    hosts_printing_in_place("creating a store");
    store.append(&a, Payload::Float32).unwrap();
    store.append(&a, Payload::Float32).unwrap();
    hosts_printing_in_place("appending");
    assert!(store.append(&b, Payload::Float32).is_err());
    let missing = EntryKey { field: "rho".into(), step: 7, rank: 3 };
    assert!(store.read(&missing).is_err());
    assert!(store.step_index("rho", 0).unwrap().is_none());
    hosts_printing_in_place("refused and missing entries");
    drop(store);
    hosts_printing_in_place("closing the store");

    let store = Store::open_read(&path).unwrap();
    assert_eq!(store.entries().unwrap().len(), 1);
    assert!(store.verify().unwrap().iter().all(|(_, v)| v.is_ok()));
    assert_eq!(store.read(&EntryKey::of(&a.meta)).unwrap().0, a);
    drop(store);
    hosts_printing_in_place("reading and verifying");
}
