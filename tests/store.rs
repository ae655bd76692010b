//! The HDF5 store (cargo feature `hdf5`): round trips of every payload,
//! refusals, one process writing and another reading, h5dump reading it
//! without gsenc, and the decoded series. Writers killed mid-append are in
//! `store_crash.rs`: its child processes would inherit this binary's open
//! HDF5 files, and their locks, from the tests running beside it.
#![cfg(feature = "hdf5")]

mod common;
use common::store_model as model;
use common::tmpdir;
use gsenc::backend::cpu::CpuBackend;
use gsenc::format::{write_model_as, Payload};
use gsenc::io::series::{write_decoded_series, xdmf_path, xdmf_text, Piece, SeriesOptions};
use gsenc::io::store::{EntryKey, Store, CACHE_BYTES};
use gsenc::field::Grid;
use gsenc::model::{Curve, Outside, Support, WarmRecord, WarmTaken};
use gsenc::format::packed::Precision;
use gsenc::format::quantize::CentreCoding;
use gsenc::Error;
use std::path::Path;
use std::process::Command;

#[test]
fn every_payload_round_trips_with_its_metadata() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("roundtrip");
    let path = dir.join("s.h5");
    let mut stored = Vec::new();
    {
        let mut s = Store::open_append(&path).unwrap();
        for (i, payload) in Payload::ALL.into_iter().enumerate() {
            for rank in 0..2 {
                let mut m = model("density", 10 + i as u64, rank, 1000 + 7 * i, 0.5);
                // A packed entry keeps the precision its encode measured.
                if payload == Payload::Packed {
                    m.meta.precision = Some(Precision { centre: [3 + rank as u8, 2, 4, 1], scale: 6, rotation: 7, value: 9, weight: 5 });
                }
                s.append(&m, payload).unwrap();
                stored.push((m, payload));
            }
        }
        // A second field beside the first, and an empty model.
        let mut empty = model("temperature", 10, 0, 0, 0.5);
        empty.meta.time = None;
        s.append(&empty, Payload::Bits8(CentreCoding::Fixed16)).unwrap();
        stored.push((empty, Payload::Bits8(CentreCoding::Fixed16)));
    }
    let s = Store::open_read(&path).unwrap();
    let entries = s.entries().unwrap();
    assert_eq!(entries.len(), stored.len());
    for (m, payload) in &stored {
        let key = EntryKey::of(&m.meta);
        let (back, back_payload) = s.read(&key).unwrap();
        assert_eq!(back_payload, *payload, "{}", key.path());
        assert_eq!(back.meta, m.meta, "{}", key.path());
        // Exactly what the .gsm file of that payload holds: one quantisation.
        assert_eq!(back.params, payload.round_trip(m).unwrap(), "{}", key.path());
        let info = entries.iter().find(|e| e.key == key).unwrap().content.as_ref().unwrap();
        assert_eq!(info.count, m.params.len() as u64);
    }
    // What the listing says each entry stores: the bytes of all its
    // datasets in the file (an 8-bit entry's two, centres and codes), as
    // HDF5 itself counts them.
    let f = hdf5::File::open(&path).unwrap();
    for e in &entries {
        let g = f.group(&e.key.path()).unwrap();
        let on_disk: u64 = g.datasets().unwrap().iter().map(|d| d.storage_size()).sum();
        assert_eq!(e.content.as_ref().unwrap().stored_bytes, on_disk, "{}", e.key.path());
    }
}

/// A support and its outside (layout 1.2) come back as stored; a zero
/// outside writes no attribute, and a damaged one is refused.
#[test]
fn supports_round_trip_with_their_outsides() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("support");
    let path = dir.join("s.h5");
    let mut m = model("density", 3, 0, 50, 0.5);
    let dims = m.meta.frame.dims;
    let half = Grid::new(dims, (0..dims.iter().product::<usize>()).map(|i| if i % dims[0] < 10 { 0.6 } else { 0.0 }).collect()).unwrap();
    let bare = Support::from_reference(&half).unwrap();
    m.support = Some(bare.clone().with_outside(Outside { offset: 0.0041, gain: 0.25 }).unwrap());
    let mut zero = model("density", 4, 0, 50, 0.5);
    zero.support = Some(bare);
    {
        let mut s = Store::open_append(&path).unwrap();
        s.append(&m, Payload::Float32).unwrap();
        s.append(&zero, Payload::Float32).unwrap();
    }
    {
        let s = Store::open_read(&path).unwrap();
        for want in [&m, &zero] {
            assert_eq!(s.read(&EntryKey::of(&want.meta)).unwrap().0.support, want.support);
        }
    }
    {
        let f = hdf5::File::open(&path).unwrap();
        assert!(f.dataset("density/4/rank_0/support").unwrap().attr("outside").is_err(), "a zero outside wrote an attribute");
    }
    {
        let f = hdf5::File::open_rw(&path).unwrap();
        let ds = f.dataset("density/3/rank_0/support").unwrap();
        replace_attr(&ds, "outside", &[0.1f32, 0.2, 0.3]);
    }
    let e = Store::open_read(&path).unwrap().read(&EntryKey::of(&m.meta)).unwrap_err();
    assert!(matches!(&e, Error::Format(w) if w.contains("outside")), "{e}");
}

/// A target PSNR's curve (layout 1.5) comes back as stored and is in the
/// entry's checksum; a model without one writes no attribute, and one no
/// encode makes is refused.
#[test]
fn a_target_curve_round_trips_within_the_checksum() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("curve");
    let path = dir.join("s.h5");
    let mut m = model("density", 3, 0, 50, 0.5);
    m.meta.curve = Some(Curve { per_budget_doubling: 2.0625, per_iteration_doubling: 0.875 });
    let none = model("density", 4, 0, 50, 0.5);
    {
        let mut s = Store::open_append(&path).unwrap();
        s.append(&m, Payload::Packed).unwrap();
        s.append(&none, Payload::Float32).unwrap();
    }
    {
        let s = Store::open_read(&path).unwrap();
        for want in [&m, &none] {
            assert_eq!(s.read(&EntryKey::of(&want.meta)).unwrap().0.meta.curve, want.meta.curve);
        }
        assert!(hdf5::File::open(&path).unwrap().group("density/4/rank_0").unwrap().attr("target_curve").is_err(), "no curve wrote an attribute");
    }
    let rewrite = |v: [f64; 2], crc: bool| {
        let g = hdf5::File::open_rw(&path).unwrap().group("density/3/rank_0").unwrap();
        replace_attr(&g, "target_curve", &v);
        if !crc && g.attr("crc32").is_ok() {
            g.delete_attr("crc32").unwrap();
        }
        Store::open_read(&path).unwrap().read(&EntryKey::of(&m.meta)).map(|(back, _)| back.meta.curve)
    };
    let e = rewrite([2.0625, 0.75], true).unwrap_err();
    assert!(matches!(&e, Error::Format(w) if w.contains("fails its checksum")), "{e}");
    let e = rewrite([2.0625, f64::NAN], false).unwrap_err();
    assert!(matches!(&e, Error::Format(w) if w.contains("target curve")), "{e}");
    assert_eq!(rewrite([1.5, 0.25], false).unwrap(), Some(Curve { per_budget_doubling: 1.5, per_iteration_doubling: 0.25 }), "unchecked, as read");
}

#[test]
fn appends_never_rewrite_and_bad_input_is_refused() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("refuse");
    let path = dir.join("s.h5");
    let m = model("rho", 3, 0, 200, 0.5);
    let mut s = Store::open_append(&path).unwrap();
    s.append(&m, Payload::Float32).unwrap();
    // The same model again (a restarted run storing its steps again)
    // changes nothing and is no error; any other model of the key is
    // refused: other parameters, another time, another payload.
    s.append(&m, Payload::Float32).unwrap();
    let mut other = model("rho", 3, 0, 50, 0.5);
    let e = s.append(&other, Payload::Float32).unwrap_err();
    assert!(matches!(&e, Error::InvalidArgument(t) if t.contains("/rho/3/rank_0 already holds a model, another than this one")), "{e}");
    let mut later = m.clone();
    later.meta.time = Some(0.25);
    assert!(matches!(s.append(&later, Payload::Float32), Err(Error::InvalidArgument(_))));
    assert!(matches!(s.append(&m, Payload::Bits8(CentreCoding::Float16)), Err(Error::InvalidArgument(_))));
    other.meta.field = "a/b".into();
    assert!(matches!(s.append(&other, Payload::Float32), Err(Error::InvalidArgument(_))));
    other.meta.field = "ok".into();
    other.params[7][4] = f32::NAN;
    assert!(matches!(s.append(&other, Payload::Bits8(CentreCoding::Float16)), Err(Error::InvalidData(_))));
    drop(s);
    // The first model is untouched, and the refused ones left nothing behind.
    let s = Store::open_read(&path).unwrap();
    assert_eq!(s.entries().unwrap().len(), 1);
    assert_eq!(s.read(&EntryKey::of(&m.meta)).unwrap().0, m);
    assert!(matches!(s.read(&EntryKey { field: "rho".into(), step: 4, rank: 0 }), Err(Error::InvalidArgument(_))));

    // Foreign files: a model file, an HDF5 file that is no store, a newer store.
    let gsm = dir.join("m.gsm");
    std::fs::write(&gsm, write_model_as(&m, Payload::Float32).unwrap()).unwrap();
    assert!(matches!(Store::open_read(&gsm), Err(Error::Format(_))));
    assert!(matches!(Store::open_append(&gsm), Err(Error::Hdf5 { .. } | Error::Format(_))));
    let plain = dir.join("plain.h5");
    hdf5::File::create(&plain).unwrap().create_group("x").unwrap();
    assert!(matches!(Store::open_read(&plain), Err(Error::Format(_))));
    let newer = dir.join("newer.h5");
    drop(Store::open_append(&newer).unwrap());
    {
        let f = hdf5::File::open_rw(&newer).unwrap();
        replace_scalar(&f, "gsenc_store", "2.0".parse::<hdf5::types::VarLenUnicode>().unwrap());
    }
    assert!(matches!(Store::open_read(&newer), Err(Error::Version(_))));
    assert!(matches!(Store::open_read(dir.join("missing.h5")), Err(Error::Io { .. })));

    // A store made through a dangling symbolic link is made at its target,
    // and the link stays; a named pipe is refused, and stays a pipe.
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        std::os::unix::fs::symlink("linked.h5", dir.join("link.h5")).unwrap();
        Store::open_append(dir.join("link.h5")).unwrap().append(&m, Payload::Float32).unwrap();
        assert!(std::fs::symlink_metadata(dir.join("link.h5")).unwrap().file_type().is_symlink());
        assert_eq!(Store::open_read(dir.join("linked.h5")).unwrap().read(&EntryKey::of(&m.meta)).unwrap().0, m);
        let fifo = dir.join("pipe.h5");
        assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
        assert!(matches!(Store::open_append(&fifo), Err(Error::InvalidArgument(_))));
        assert!(matches!(Store::open_read(&fifo), Err(Error::InvalidArgument(_))));
        assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
    }

    // An `auto` step's record round-trips; a start the reader does not know
    // is refused with the entry's name.
    let warm = dir.join("warm.h5");
    let mut w = model("rho", 5, 0, 40, 0.5);
    w.meta.warm = Some(WarmRecord { taken: WarmTaken::Fresh, moved: 9 });
    Store::open_append(&warm).unwrap().append(&w, Payload::Float32).unwrap();
    assert_eq!(Store::open_read(&warm).unwrap().read(&EntryKey::of(&w.meta)).unwrap().0.meta.warm, w.meta.warm);
    {
        let f = hdf5::File::open_rw(&warm).unwrap();
        let g = f.group("rho/5/rank_0").unwrap();
        replace_scalar(&g, "warm_start", "sideways".parse::<hdf5::types::VarLenUnicode>().unwrap());
    }
    let e = Store::open_read(&warm).unwrap().read(&EntryKey::of(&w.meta)).unwrap_err();
    assert!(matches!(e, Error::Format(_)) && e.to_string().contains("rho/5/rank_0 has an unknown warm start 'sideways'"), "{e}");

    // An entry that declares 2^40 primitives in a chunked dataset it never
    // wrote (HDF5 would read its fill value: 52 TB) is refused unread.
    let huge = dir.join("huge.h5");
    Store::open_append(&huge).unwrap().append(&m, Payload::Float32).unwrap();
    {
        let f = hdf5::File::open_rw(&huge).unwrap();
        let g = f.group("rho/3/rank_0").unwrap();
        let n = 1usize << 40;
        g.unlink("params").unwrap();
        g.new_dataset::<f32>().shape([12, n]).chunk([12, 1024]).create("params").unwrap();
        replace_scalar(&g, "count", n as u64);
    }
    let e = Store::open_read(&huge).unwrap().read(&EntryKey::of(&m.meta)).unwrap_err();
    assert!(matches!(e, Error::Format(_)) && e.to_string().contains("dataset params declares 52776558133248 bytes"), "{e}");
    // A count beyond what the coded payloads (8-bit, packed) hold is
    // refused before anything is decoded: by the datasets' shapes, and by
    // what the packed payload's streams can hold.
    for payload in [Payload::Bits8(CentreCoding::Float16), Payload::Packed] {
        let claims = dir.join("claims.h5");
        let _ = std::fs::remove_file(&claims);
        Store::open_append(&claims).unwrap().append(&m, payload).unwrap();
        {
            let f = hdf5::File::open_rw(&claims).unwrap();
            let g = f.group("rho/3/rank_0").unwrap();
            replace_scalar(&g, "count", 1u64 << 40);
        }
        let e = Store::open_read(&claims).unwrap().read(&EntryKey::of(&m.meta)).unwrap_err();
        assert!(matches!(e, Error::Format(_)), "{payload:?}: {e}");
    }
}

/// The bytes of a store of `entries` (field, step, payload; rank 0, 40
/// primitives each), written in a fresh `tmpdir(name)`, which is returned.
fn sound_store(name: &str, entries: &[(&str, u64, Payload)]) -> (common::TmpDir, Vec<u8>) {
    let dir = tmpdir(name);
    let path = dir.join("s.h5");
    let mut s = Store::open_append(&path).unwrap();
    for &(field, step, payload) in entries {
        s.append(&model(field, step, 0, 40, 0.5), payload).unwrap();
    }
    drop(s);
    let bytes = std::fs::read(&path).unwrap();
    (dir, bytes)
}

/// Appends a decomposed step: its pieces (float32), then its index.
fn append_step(s: &mut Store, index: &gsenc::format::StepIndex, pieces: &[gsenc::model::Model]) {
    for m in pieces {
        s.append(m, Payload::Float32).unwrap();
    }
    s.append_step_index(index).unwrap();
}

/// Replaces attribute `name` of `loc` by an array of `v` (a damage done through HDF5).
fn replace_attr<T: hdf5::H5Type>(loc: &hdf5::Location, name: &str, v: &[T]) {
    loc.delete_attr(name).unwrap();
    loc.new_attr::<T>().shape(v.len()).create(name).unwrap().write_raw(v).unwrap();
}

/// Replaces attribute `name` of `loc` by the scalar `v`.
fn replace_scalar<T: hdf5::H5Type>(loc: &hdf5::Location, name: &str, v: T) {
    loc.delete_attr(name).unwrap();
    loc.new_attr::<T>().create(name).unwrap().write_scalar(&v).unwrap();
}

/// An entry changed after it was written, without its checksum (as an
/// entry of a store before 1.4 has none), is refused by what is wrong in
/// it: never read as another model, and never a panic (unchecked, a `bmin`
/// or a map of too few values would be indexed past its end).
#[test]
fn an_entry_damaged_in_its_structure_is_refused_by_name() {
    let _serial = common::hdf5_serial();
    let (dir, sound) = sound_store("damaged", &[("rho", 0, Payload::Float32), ("rho", 1, Payload::Bits8(CentreCoding::Fixed16))]);
    // The sound store's entries: 40 primitives of a 24 x 16 x 12 lattice.
    let transposed = |g: &hdf5::Group| {
        let rows: Vec<f32> = g.dataset("params").unwrap().read_raw().unwrap();
        let columns: Vec<f32> = (0..40 * 12).map(|i| rows[(i % 12) * 40 + i / 12]).collect();
        g.unlink("params").unwrap();
        g.new_dataset::<f32>().shape([40, 12]).create("params").unwrap().write_raw(&columns).unwrap();
    };
    let nan = |g: &hdf5::Group| {
        let ds = g.dataset("params").unwrap();
        let mut rows: Vec<f32> = ds.read_raw().unwrap();
        rows[5 * 40 + 7] = f32::NAN;
        ds.write_raw(&rows).unwrap();
    };
    let cases: [(u64, &str, &dyn Fn(&hdf5::Group)); 10] = [
        (0, "has invalid dims [0, 16, 12]", &|g| replace_attr(g, "dims", &[0u64, 16, 12])),
        (0, "has invalid dims [4294967296, 16, 12]", &|g| replace_attr(g, "dims", &[1u64 << 32, 16, 12])),
        (0, "attribute bmin holds 2 values, not 3", &|g| replace_attr(g, "bmin", &[0.0f64, -1.0])),
        (0, "holds an invalid index frame", &|g| replace_scalar(g, "gamma", 0.0f64)),
        (0, "says it is /rho/0/rank_1", &|g| replace_scalar(g, "rank", 1u32)),
        (0, "dataset params has shape [40, 12], not [12, 40]", &transposed),
        (0, "holds non-finite parameters", &nan),
        (1, "centres attribute lo holds 2 values, not 3", &|g| replace_attr(&g.dataset("centres").unwrap(), "lo", &[0.0f32, 1.0])),
        (1, "codes attribute hi holds 8 values, not 9", &|g| replace_attr(&g.dataset("codes").unwrap(), "hi", &[1.0f32; 8])),
        (1, "dataset codes has shape [9, 39], not [9, 40]", &|g| {
            g.unlink("codes").unwrap();
            g.new_dataset::<u8>().shape([9, 39]).create("codes").unwrap().write_raw(&[7u8; 9 * 39]).unwrap();
        }),
    ];
    for (step, want, damage) in cases {
        let path = dir.join("d.h5");
        std::fs::write(&path, &sound).unwrap();
        {
            let f = hdf5::File::open_rw(&path).unwrap();
            let g = f.group(&format!("rho/{step}/rank_0")).unwrap();
            damage(&g);
            g.delete_attr("crc32").unwrap();
        }
        let key = EntryKey { field: "rho".into(), step, rank: 0 };
        match Store::open_read(&path).unwrap().read(&key) {
            Err(Error::Format(w)) => assert!(w.contains(&format!("rho/{step}/rank_0")) && w.contains(want), "{want}: {w}"),
            other => panic!("{want}: {:?}", other.map(|(m, _)| m.meta)),
        }
    }
}

/// A store kept open for a long run, as an in-situ encoder keeps its own,
/// holds HDF5's metadata cache within its size: the cache that never
/// evicted held every entry ever appended (about 9 KB of cache each, 5.5 MB
/// for these 600), and each flush walked it, so appends slowed as the run
/// went on. Every entry still reads back.
#[test]
fn a_long_run_keeps_the_metadata_cache_within_its_size() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("long");
    let path = dir.join("s.h5");
    let mut s = Store::open_append(&path).unwrap();
    let mut most = 0;
    for step in 0..600 {
        s.append(&model("rho", step, 0, 20, 0.5), Payload::Float32).unwrap();
        most = most.max(s.cache_size().0);
    }
    assert!(most < CACHE_BYTES + CACHE_BYTES / 4, "the cache grew to {most} bytes");
    drop(s);
    let s = Store::open_read(&path).unwrap();
    assert_eq!(s.entries().unwrap().len(), 600);
    for step in [0, 299, 599] {
        let want = model("rho", step, 0, 20, 0.5);
        assert_eq!(s.read(&EntryKey::of(&want.meta)).unwrap().0, want, "step {step}");
    }
}

/// A store whose global heap (where HDF5 keeps its string attributes,
/// without a checksum) was corrupted is refused by name before HDF5 reads
/// it: one changed byte in an object's size made HDF5 1.10 copy past its
/// buffer (a segmentation fault of the reader), a zero size loop forever.
/// The sound store opens.
#[test]
fn a_corrupted_global_heap_is_refused_before_hdf5_reads_it() {
    let _serial = common::hdf5_serial();
    let (dir, sound) = sound_store("heap", &[("rho", 0, Payload::Float32), ("rho", 1, Payload::Float32), ("rho", 2, Payload::Float32)]);
    let heap = sound.windows(8).position(|w| w == b"GCOL\x01\x00\x00\x00").expect("a store keeps its strings in a global heap");
    let open = |bytes: &[u8]| {
        let p = dir.join("c.h5");
        std::fs::write(&p, bytes).unwrap();
        Store::open_read(&p).and_then(|s| s.entries().map(|e| e.len()))
    };
    assert_eq!(open(&sound).unwrap(), 3);
    for (what, at, byte) in [("an object's size", heap + 16 + 9, 0x2d), ("an object's size", heap + 16 + 11, 0xf5), ("the collection's size", heap + 9, 0x80), ("a zero size", heap + 16 + 8, 0)] {
        let mut bad = sound.clone();
        bad[at] = byte;
        if what == "a zero size" {
            bad[at..at + 8].fill(0);
            bad[heap + 16..heap + 18].fill(0); // as the free space (index 0)
        }
        match open(&bad) {
            Err(Error::Format(m)) => assert!(m.contains(&format!("global heap collection at byte {heap}")), "{what}: {m}"),
            other => panic!("{what}: {:?}", other.map(|_| ())),
        }
    }
}

/// An entry's checksum (layout 1.4): one value changed through HDF5 itself
/// (a change the file's structure cannot see), a float32 parameter or an
/// 8-bit code, fails the read by name; without its `crc32` attribute (an
/// entry written before 1.4) the entry reads unchecked, as it is now.
#[test]
fn an_entry_changed_after_it_was_written_fails_its_checksum() {
    let _serial = common::hdf5_serial();
    for (payload, dataset) in [(Payload::Float32, "params"), (Payload::Bits8(CentreCoding::Float16), "codes")] {
        let (dir, _) = sound_store("crc", &[("rho", 0, payload)]);
        let path = dir.join("s.h5");
        let key = EntryKey { field: "rho".into(), step: 0, rank: 0 };
        let (sound, _) = Store::open_read(&path).unwrap().read(&key).unwrap();
        {
            let f = hdf5::File::open_rw(&path).unwrap();
            let ds = f.group("rho/0/rank_0").unwrap().dataset(dataset).unwrap();
            if payload == Payload::Float32 {
                let mut v: Vec<f32> = ds.read_raw().unwrap();
                v[17] = f32::from_bits(v[17].to_bits() ^ 1);
                ds.write_raw(&v).unwrap();
            } else {
                let mut v: Vec<u8> = ds.read_raw().unwrap();
                v[17] ^= 1;
                ds.write_raw(&v).unwrap();
            }
        }
        let e = Store::open_read(&path).unwrap().read(&key).unwrap_err();
        assert!(matches!(e, gsenc::Error::Format(_)) && e.to_string().contains("rho/0/rank_0 fails its checksum"), "{payload:?}: {e}");
        hdf5::File::open_rw(&path).unwrap().group("rho/0/rank_0").unwrap().delete_attr("crc32").unwrap();
        let (changed, _) = Store::open_read(&path).unwrap().read(&key).unwrap();
        assert!(changed.meta == sound.meta && changed.params != sound.params, "{payload:?}");
    }
    // A sound entry whose time and PSNR are NaNs of other bits than Rust's
    // f64::NAN (x86's 0.0 / 0.0 is negative): it reads them as unknown, and
    // its checksum, summed as a reader gets them, holds.
    let dir = tmpdir("crc-nan");
    let mut m = model("rho", 0, 0, 40, 0.5);
    (m.meta.time, m.meta.encode_psnr) = (Some(f64::from_bits(0xfff8_0000_0000_0000)), Some(f64::from_bits(0x7ff0_0000_0000_0001)));
    Store::open_append(dir.join("s.h5")).unwrap().append(&m, Payload::Float32).unwrap();
    let (back, _) = Store::open_read(dir.join("s.h5")).unwrap().read(&EntryKey::of(&m.meta)).unwrap();
    assert_eq!((back.meta.time, back.meta.encode_psnr), (None, None));
}

/// A string attribute whose bytes are not UTF-8 (a damaged or foreign
/// store) is refused by name: the field of an entry, and the root's layout
/// version. Before, the reader made a `String` of them unchecked, which
/// broke what every `str` operation relies on (formatting the entry's
/// metadata panicked).
#[test]
fn a_string_attribute_that_is_not_utf8_is_refused() {
    let _serial = common::hdf5_serial();
    let (dir, sound) = sound_store("utf8", &[("fieldzq", 0, Payload::Float32)]);
    let heap = sound.windows(8).position(|w| w == b"GCOL\x01\x00\x00\x00").expect("a store keeps its strings in a global heap");
    let read = |bytes: &[u8]| {
        let p = dir.join("c.h5");
        std::fs::write(&p, bytes).unwrap();
        let s = Store::open_read(&p)?;
        let key = s.entries()?.into_iter().next().expect("the entry").key;
        s.read(&key).map(|(m, _)| format!("{:?}", m.meta))
    };
    assert!(read(&sound).unwrap().contains("fieldzq"));
    // The attribute's copy of the name, in the heap (the link's is elsewhere).
    let at = heap + sound[heap..].windows(7).position(|w| w == b"fieldzq").expect("the field attribute in the heap");
    let mut bad = sound.clone();
    bad[at + 5] = 0xff;
    match read(&bad) {
        Err(gsenc::Error::Format(m)) => assert!(m.contains("attribute field is not UTF-8 text"), "{m}"),
        other => panic!("{other:?}"),
    }
    let version = gsenc::io::store::STORE_VERSION.as_bytes();
    let at = heap + sound[heap..].windows(version.len()).position(|w| w == version).expect("the layout version in the heap");
    let mut bad = sound.clone();
    bad[at + 1] = 0xc0;
    match read(&bad) {
        Err(gsenc::Error::Format(m)) => assert!(m.contains("gsenc_store attribute is not UTF-8 text"), "{m}"),
        other => panic!("{other:?}"),
    }
}

/// Stores with random bytes changed (1,500 of them, seeded) open, list and
/// read each entry or fail with an error: none crashes the reader or hangs
/// it, and every entry read, alone or through its step's index, is the
/// sound store's (each entry's checksum, layout 1.4). Before the global
/// heap was checked, 5 in 3,000 such stores killed `gsenc info`; before
/// the checksum, 319 of the 4,868 entries read here had changed, unseen
/// (docs/FORMAT.md).
#[test]
fn stores_with_random_bytes_changed_give_errors_not_crashes() {
    let _serial = common::hdf5_serial();
    let (dir, _) = sound_store("corrupt", &[("rho", 0, Payload::ALL[0]), ("rho", 1, Payload::ALL[1]), ("temp", 0, Payload::ALL[0])]);
    // And a decomposed step with its index (layout 1.3), read through it.
    {
        let mut s = Store::open_append(dir.join("s.h5")).unwrap();
        let (index, pieces) = common::decomposed_step("rho", 4);
        append_step(&mut s, &index, &pieces);
    }
    let sound = std::fs::read(dir.join("s.h5")).unwrap();
    let (truth, truth_step) = {
        let s = Store::open_read(dir.join("s.h5")).unwrap();
        let entries: Vec<_> = s.entries().unwrap().into_iter().map(|e| (e.key.clone(), s.read(&e.key).unwrap())).collect();
        (entries, s.read_step("rho", 4).unwrap())
    };
    let mut rng = gsenc::math::rng::Rng::new(17);
    let (mut refused, mut read, mut steps) = (0, 0, 0);
    for _ in 0..1500 {
        let mut bad = sound.clone();
        for _ in 0..1 + rng.below(3) {
            // Mostly in the first 8 KiB, where the metadata and the heap are.
            let span = if rng.below(3) == 0 { bad.len() } else { 8192.min(bad.len()) };
            bad[rng.below(span as u64) as usize] = rng.below(256) as u8;
        }
        let p = dir.join("c.h5");
        std::fs::write(&p, &bad).unwrap();
        match Store::open_read(&p) {
            Err(_) => refused += 1,
            Ok(s) => {
                for e in s.entries().unwrap_or_default() {
                    if let Ok(got) = s.read(&e.key) {
                        read += 1;
                        let (_, want) = truth.iter().find(|(k, _)| *k == e.key).expect("a listed entry is one of the sound store's");
                        assert!(got == *want, "{:?} read back changed", e.key);
                    }
                }
                if let Ok(got) = s.read_step("rho", 4) {
                    steps += 1;
                    assert!(got == truth_step, "the indexed step read back changed");
                }
            }
        }
    }
    eprintln!("1500 corrupted stores: {refused} refused at open, {read} entries read, {steps} indexed steps read");
    assert!(refused > 0 && read > 0 && steps > 0, "the corruptions should both be refused and leave entries readable");
}

/// h5dump, from HDF5's own tools, reads the store without gsenc.
#[test]
fn h5dump_reads_the_store() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("h5dump");
    let path = dir.join("s.h5");
    let mut m = model("rho", 9, 2, 5, 0.5);
    for (i, p) in m.params.iter_mut().enumerate() {
        p[10] = i as f32 * 0.25 - 1.0; // values h5dump prints exactly
    }
    Store::open_append(&path).unwrap().append(&m, Payload::Float32).unwrap();
    let out = Command::new("h5dump")
        .args(["-a", "/rho/9/rank_2/count", "-d", "/rho/9/rank_2/params"])
        .arg(&path)
        .output()
        .expect("h5dump (apt hdf5-tools) is needed by this test");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("(0): 5"), "{text}");
    // Row k of params is parameter k of every primitive: row 10 is alpha.
    let row = text.lines().find(|l| l.trim_start().starts_with("(10,0)")).unwrap_or_else(|| panic!("{text}"));
    assert_eq!(row.trim(), "(10,0): -1, -0.75, -0.5, -0.25, 0,", "{text}");
}

fn read_f32_dataset(path: &Path, name: &str) -> (Vec<usize>, Vec<f32>) {
    let f = hdf5::File::open(path).unwrap();
    let ds = f.dataset(name).unwrap();
    (ds.shape(), ds.read_raw::<f32>().unwrap())
}

#[test]
fn decoded_series_matches_each_model_and_xdmf_points_at_it() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("series");
    let path = dir.join("s.h5");
    let mut models = Vec::new();
    {
        let mut s = Store::open_append(&path).unwrap();
        for step in [2u64, 4] {
            for rank in 0..2 {
                let m = model("rho", step, rank, 40, -0.5);
                s.append(&m, Payload::Float32).unwrap();
                models.push(m);
            }
        }
        s.append(&model("other", 1, 0, 10, -0.5), Payload::Float32).unwrap();
    }
    let s = Store::open_read(&path).unwrap();
    let out = dir.join("series.h5");
    let mut opts = SeriesOptions { field: None, scale: 0.5, normalized: false, slab_voxels: 24 * 16 };
    let mut cpu = CpuBackend::new();
    assert!(matches!(write_decoded_series(&s, &out, &opts, &mut cpu), Err(Error::InvalidArgument(_))), "two fields, none chosen");
    opts.field = Some("rho");
    let summary = write_decoded_series(&s, &out, &opts, &mut cpu).unwrap();
    assert_eq!(summary.pieces.len(), 4);
    assert!(summary.skipped.is_empty());
    let xdmf = std::fs::read_to_string(xdmf_path(&out)).unwrap();
    for m in &models {
        let key = EntryKey::of(&m.meta);
        let want_dims = [12, 8, 6];
        let want = m.decode(&mut cpu, Some(want_dims)).unwrap();
        let (shape, got) = read_f32_dataset(&out, &key.path());
        assert_eq!(shape, [6, 8, 12]);
        for (g, w) in got.iter().zip(&want.values) {
            let w = m.meta.range.denormalize(*w) as f32;
            assert!((g - w).abs() <= 1e-5 * w.abs().max(1.0), "{}: {g} vs {w}", key.path());
        }
        assert!(xdmf.contains(&format!("series.h5:{}</DataItem>", key.path())), "{xdmf}");
    }
    // Two time steps with the models' own times, two ranks each.
    assert_eq!(xdmf.matches("<Time Value=").count(), 2);
    assert!(xdmf.contains("<Time Value=\"5e-1\"/>") && xdmf.contains("<Time Value=\"1e0\"/>"), "{xdmf}");
    assert_eq!(xdmf.matches("Dimensions=\"6 8 12\"").count(), 8);
    // Rank 1's box starts 2 world units further in x: origin = bmin + half a voxel.
    let spacing = 24.0 / 12.0 / 12.0;
    assert!(xdmf.contains(&format!("{:e} {:e} {:e}</DataItem>", 0.5 + spacing / 2.0, -1.0 + spacing / 2.0, 2.0 + spacing / 2.0)), "{xdmf}");
    // A scale whose lattice the decode refuses is refused by name before
    // HDF5 is asked for it (which failed with "unknown library error"), and
    // the series already written stays, with no temporary file beside it.
    let before = std::fs::read(&out).unwrap();
    opts.scale = 1e10;
    let e = write_decoded_series(&s, &out, &opts, &mut cpu).unwrap_err();
    assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("are too large")), "{e}");
    assert_eq!(std::fs::read(&out).unwrap(), before);
    let mut names: Vec<String> = std::fs::read_dir(&*dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["s.h5", "series.h5", "series.xmf"]);
}

#[test]
fn a_decomposed_steps_index_gives_back_its_pieces_and_leaves_the_listing_as_it_was() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("step-index");
    let path = dir.join("s.h5");
    let (index, pieces) = common::decomposed_step("rho", 4);
    {
        let mut s = Store::open_append(&path).unwrap();
        // The index may come first: it makes the step's group.
        s.append_step_index(&index).unwrap();
        for m in &pieces {
            s.append(m, Payload::Float32).unwrap();
        }
        // The same index again changes nothing; another index of the step
        // is refused, as another model is.
        s.append_step_index(&index).unwrap();
        let moved = gsenc::format::StepIndex { time: Some(9.0), ..index.clone() };
        let e = s.append_step_index(&moved).unwrap_err();
        assert!(matches!(e, Error::InvalidArgument(_)) && e.to_string().contains("already holds a step index, another than this one"), "{e}");
        // And one step without an index.
        s.append(&model("rho", 5, 0, 30, 0.5), Payload::Float32).unwrap();
    }
    let s = Store::open_read(&path).unwrap();
    let (back, models) = s.read_step("rho", 4).unwrap();
    assert_eq!(models, pieces);
    assert_eq!((back.halo, back.dims, back.pieces.len()), (index.halo, index.dims, 2));
    // The models are named by their entries.
    assert_eq!(back.pieces.iter().map(|p| p.model.as_str()).collect::<Vec<_>>(), ["rank_0", "rank_1"]);
    // The listing holds the models only, as a reader before 1.3 sees it.
    let keys: Vec<String> = s.entries().unwrap().iter().map(|e| e.key.path()).collect();
    assert_eq!(keys, ["/rho/4/rank_0", "/rho/4/rank_1", "/rho/5/rank_0"]);
    assert!(s.step_index("rho", 5).unwrap().is_none());
    assert!(s.step_index("temp", 4).unwrap().is_none());
    assert!(matches!(s.read_step("rho", 5), Err(Error::InvalidArgument(_))));
    drop(s);
    // A changed byte of the index fails its checksum (the halo 2 made 3
    // would read, and blend the step otherwise).
    let mut bytes = std::fs::read(&path).unwrap();
    let at = bytes.windows(10).position(|w| w == b"\"halo\": 2,").expect("the index is stored as its text");
    bytes[at + 8] = b'3';
    let changed = dir.join("changed.h5");
    std::fs::write(&changed, &bytes).unwrap();
    let e = Store::open_read(&changed).unwrap().read_step("rho", 4).unwrap_err();
    assert!(matches!(e, Error::Format(_)) && e.to_string().contains("dataset index"), "{e}");
    // An index whose rank the store lacks, or whose box is not its model's.
    {
        let mut s = Store::open_append(&path).unwrap();
        let (mut index, pieces) = common::decomposed_step("temp", 4);
        index.pieces[0].hi[0] = 13;
        append_step(&mut s, &index, &pieces);
    }
    let s = Store::open_read(&path).unwrap();
    let e = s.read_step("temp", 4).unwrap_err();
    assert!(e.to_string().contains("covers voxels"), "{e}");
    drop(s);
    {
        let mut s = Store::open_append(&path).unwrap();
        let (index, pieces) = common::decomposed_step("v", 4);
        s.append(&pieces[1], Payload::Float32).unwrap();
        s.append_step_index(&index).unwrap();
    }
    let e = Store::open_read(&path).unwrap().read_step("v", 4).unwrap_err();
    assert!(matches!(e, Error::InvalidData(_)) && e.to_string().contains("names rank 0"), "{e}");
}

/// The listing and `verify` (`gsenc store verify`): entries in the order of
/// field, step and rank as numbers (HDF5 lists its names as text, "10"
/// before "9"), members that are no entry's skipped; each step's group
/// carries its step and time (NaN unknown); `verify` gives every entry one
/// verdict, with or without its checksum, then every step index one, and a
/// step without an index none. An index linked under another step is
/// refused by what it is.
#[test]
fn the_listing_and_verify_give_each_entry_and_index_once_in_order() {
    use gsenc::io::store::Verified;
    let _serial = common::hdf5_serial();
    let dir = tmpdir("listing");
    let path = dir.join("s.h5");
    let (index, pieces) = common::decomposed_step("rho", 4);
    {
        let mut s = Store::open_append(&path).unwrap();
        append_step(&mut s, &index, &pieces);
        for (field, step, rank) in [("rho", 10, 0), ("rho", 9, 10), ("rho", 9, 2), ("a", 100, 0)] {
            s.append(&model(field, step, rank, 20, 0.5), Payload::Float32).unwrap();
        }
        let mut untimed = model("rho", 11, 0, 20, 0.5);
        untimed.meta.time = None;
        s.append(&untimed, Payload::Float32).unwrap();
    }
    {
        // What a store's reader must pass over, and an entry without its checksum.
        let f = hdf5::File::open_rw(&path).unwrap();
        f.create_group("rho/notastep").unwrap().create_group("rank_0").unwrap();
        f.group("rho/9").unwrap().create_group("ranks").unwrap();
        f.new_dataset::<u8>().shape(3).create("notes").unwrap().write_raw(&[1u8, 2, 3]).unwrap();
        f.group("rho/9/rank_2").unwrap().delete_attr("crc32").unwrap();
        for (step, time) in [(4, index.time.unwrap()), (10, 2.5), (11, f64::NAN)] {
            let g = f.group(&format!("rho/{step}")).unwrap();
            assert_eq!(g.attr("step").unwrap().read_scalar::<u64>().unwrap(), step);
            let t = g.attr("time").unwrap().read_scalar::<f64>().unwrap();
            assert!(t == time || (t.is_nan() && time.is_nan()), "step {step}: time {t}, not {time}");
        }
    }
    let s = Store::open_read(&path).unwrap();
    let keys: Vec<String> = s.entries().unwrap().iter().map(|e| e.key.path()).collect();
    let want = ["/a/100/rank_0", "/rho/4/rank_0", "/rho/4/rank_1", "/rho/9/rank_2", "/rho/9/rank_10", "/rho/10/rank_0", "/rho/11/rank_0"];
    assert_eq!(keys, want);
    let verdicts: Vec<(String, Verified)> = s.verify().unwrap().into_iter().map(|(k, v)| (k, v.unwrap())).collect();
    let mut expected: Vec<(String, Verified)> =
        want.iter().map(|k| (k.to_string(), if *k == "/rho/9/rank_2" { Verified::NoChecksum } else { Verified::Checksum })).collect();
    expected.push(("/rho/4/index".into(), Verified::StepIndex));
    assert_eq!(verdicts, expected);
    drop(s);
    hdf5::File::open_rw(&path).unwrap().link_hard("rho/4/index", "rho/10/index").unwrap();
    let e = Store::open_read(&path).unwrap().step_index("rho", 10).unwrap_err();
    assert!(matches!(&e, Error::Format(w) if w.contains("/rho/10/index is the index of field 'rho' step 4")), "{e}");
}

/// `decode-series` of a store holding a decomposed step's index: that step
/// is one grid, its global field as the pieces blend it; a step without an
/// index stays a grid per rank, and so does one whose index names a rank
/// the store lacks (said in the summary).
#[test]
fn a_decoded_series_blends_a_step_that_has_its_index() {
    use gsenc::domain::global::GlobalField;
    use gsenc::field::IndexBox;
    let _serial = common::hdf5_serial();
    let dir = tmpdir("series-global");
    let path = dir.join("s.h5");
    let (index, pieces) = common::decomposed_step("rho", 4);
    {
        let mut s = Store::open_append(&path).unwrap();
        append_step(&mut s, &index, &pieces);
        for rank in 0..2 {
            s.append(&model("rho", 6, rank, 30, -0.5), Payload::Float32).unwrap();
        }
        let (index, pieces) = common::decomposed_step("rho", 8);
        s.append(&pieces[0], Payload::Float32).unwrap();
        s.append_step_index(&index).unwrap();
    }
    let s = Store::open_read(&path).unwrap();
    let out = dir.join("series.h5");
    let opts = SeriesOptions { field: Some("rho"), scale: 1.0, normalized: false, slab_voxels: 24 * 16 * 5 };
    let mut cpu = CpuBackend::new();
    let summary = write_decoded_series(&s, &out, &opts, &mut cpu).unwrap();
    let names: Vec<String> = summary.pieces.iter().map(|p| p.path()).collect();
    assert_eq!(names, ["/rho/4/global", "/rho/6/rank_0", "/rho/6/rank_1", "/rho/8/rank_0"]);
    assert_eq!(summary.unblended.len(), 1);
    assert!(summary.unblended[0].0 == 8 && summary.unblended[0].1.contains("names rank 1"), "{:?}", summary.unblended);
    // The global grid is the blend, on the global lattice.
    let g = GlobalField::of_step(index.clone(), pieces).unwrap();
    let range = g.merged().meta.range;
    let want: Vec<f32> = g.decode(&mut cpu, index.dims, IndexBox::whole(index.dims), false).unwrap().iter().map(|&v| range.denormalize(v) as f32).collect();
    let (shape, got) = read_f32_dataset(&out, "/rho/4/global");
    assert_eq!(shape, [12, 16, 24]);
    assert_eq!(got, want);
    let xdmf = std::fs::read_to_string(xdmf_path(&out)).unwrap();
    assert!(xdmf.contains("<Grid Name=\"global\"") && xdmf.contains("series.h5:/rho/4/global</DataItem>"), "{xdmf}");
    assert_eq!(xdmf.matches("<Grid Name=\"rank_").count(), 3);
}

/// Each decoded grid carries its origin, spacing and time as attributes
/// (NaN for a model without a time, whose step in the XDMF takes its step
/// number as time); `normalized` keeps the decode's own values; a scale
/// that is not a positive number, and a store without models, are refused
/// by name.
#[test]
fn decoded_grids_carry_their_geometry_and_time_and_bad_requests_are_refused() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("series-attributes");
    let path = dir.join("s.h5");
    let timed = model("rho", 3, 1, 40, -0.5);
    let mut untimed = model("rho", 5, 0, 40, -0.5);
    untimed.meta.time = None;
    {
        let mut s = Store::open_append(&path).unwrap();
        s.append(&timed, Payload::Float32).unwrap();
        s.append(&untimed, Payload::Float32).unwrap();
    }
    drop(Store::open_append(dir.join("empty.h5")).unwrap());
    let s = Store::open_read(&path).unwrap();
    let out = dir.join("series.h5");
    let mut cpu = CpuBackend::new();
    let mut opts = SeriesOptions { field: None, scale: 0.5, normalized: true, slab_voxels: 24 * 16 };
    for scale in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
        opts.scale = scale;
        let e = write_decoded_series(&s, &out, &opts, &mut cpu).unwrap_err();
        assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("scale must be positive")), "scale {scale}: {e}");
    }
    opts.scale = 0.5;
    let e = write_decoded_series(&Store::open_read(dir.join("empty.h5")).unwrap(), &out, &opts, &mut cpu).unwrap_err();
    assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("holds no models")), "{e}");

    write_decoded_series(&s, &out, &opts, &mut cpu).unwrap();
    let file = hdf5::File::open(&out).unwrap();
    for (m, time) in [(&timed, 0.75), (&untimed, f64::NAN)] {
        let key = EntryKey::of(&m.meta);
        let (_, got) = read_f32_dataset(&out, &key.path());
        assert!(got == m.decode(&mut cpu, Some([12, 8, 6])).unwrap().values, "{}: not the normalised decode", key.path());
        let ds = file.dataset(&key.path()).unwrap();
        let attr = |name: &str| ds.attr(name).unwrap().read_raw::<f64>().unwrap();
        // The model's 24 x 16 x 12 voxels of 1/12 world unit, decoded on half as many a side.
        let spacing = 2.0 / 12.0;
        assert_eq!(attr("spacing"), [spacing; 3]);
        assert_eq!(attr("origin"), [0, 1, 2].map(|a| m.meta.frame.bmin[a] + spacing / 2.0));
        let stored = attr("time");
        assert!(stored.len() == 1 && (stored[0] == time || time.is_nan() && stored[0].is_nan()), "{}: time {stored:?}", key.path());
    }
    let xdmf = std::fs::read_to_string(xdmf_path(&out)).unwrap();
    assert!(xdmf.contains("<Time Value=\"7.5e-1\"/>") && xdmf.contains("<Time Value=\"5e0\"/>"), "{xdmf}");
}

/// Names an XML reader would misread are escaped in the XDMF: the
/// field's (grid names, the attribute, dataset paths) and the HDF5 file's.
#[test]
fn the_xdmf_escapes_field_and_file_names() {
    let field = "a<b&\"c\"";
    let piece = Piece { key: EntryKey { field: field.into(), step: 2, rank: 1 }, global: false, time: None, dims: [4, 3, 2], origin: [0.0; 3], spacing: [1.0; 3] };
    let x = xdmf_text(field, "run&<1>.h5", &[piece]);
    let escaped = "a&lt;b&amp;&quot;c&quot;";
    assert!(x.contains(&format!("<Attribute Name=\"{escaped}\"")), "{x}");
    assert!(x.contains(&format!(">run&amp;&lt;1&gt;.h5:/{escaped}/2/rank_1</DataItem>")), "{x}");
    assert!(!x.contains(field) && !x.contains("run&<1>"), "{x}");
}
