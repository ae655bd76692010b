//! The model file: round trips and rejection of damaged or foreign files.

use gsenc::field::{IndexFrame, Transform, ValueRange};
use gsenc::format::{read_model, write_model, BYTES_PER_PRIMITIVE};
use gsenc::model::{Model, ModelMeta};
use gsenc::rng::Rng;
use gsenc::Error;

fn model(n: usize) -> Model {
    let mut rng = Rng::new(1);
    Model {
        meta: ModelMeta {
            frame: IndexFrame { dims: [128, 64, 32], bmin: [-1.5, 0.25, 3.0], gamma: 42.5 },
            range: ValueRange::new(-3.0, 7.5, Transform::Log10).unwrap(),
            field: "density".into(),
            step: 17,
            schedule: "full".into(),
            iterations: 3000,
            points: 16384,
            seed_init: 0,
            seed_sample: 1,
        },
        params: (0..n).map(|_| std::array::from_fn(|_| rng.range(-5.0, 5.0) as f32)).collect(),
    }
}

#[test]
fn round_trip_is_exact_and_48_bytes_a_primitive() {
    let m = model(37);
    let a = write_model(&m).unwrap();
    let b = write_model(&model(38)).unwrap();
    assert_eq!(b.len() - a.len(), BYTES_PER_PRIMITIVE);
    assert_eq!(read_model(&a).unwrap(), m);
    let empty = model(0);
    assert_eq!(read_model(&write_model(&empty).unwrap()).unwrap(), empty);
}

#[test]
fn every_truncation_is_rejected() {
    let bytes = write_model(&model(5)).unwrap();
    for cut in 0..bytes.len() {
        let e = read_model(&bytes[..cut]).unwrap_err();
        assert!(matches!(e, Error::Format(_)), "cut at {cut}: {e}");
    }
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(read_model(&longer).is_err());
}

#[test]
fn every_corrupted_byte_is_detected() {
    let bytes = write_model(&model(3)).unwrap();
    for i in 0..bytes.len() {
        for flip in [0x01u8, 0x80] {
            let mut b = bytes.clone();
            b[i] ^= flip;
            assert!(read_model(&b).is_err(), "flipping bit {flip:#x} of byte {i} went unnoticed");
        }
    }
}

#[test]
fn foreign_and_newer_files_are_rejected_with_clear_errors() {
    let e = read_model(b"\x89HDF\r\n\x1a\n and more bytes of another format").unwrap_err().to_string();
    assert!(e.contains("not a gsenc model"), "{e}");
    let mut b = write_model(&model(2)).unwrap();
    b[8..10].copy_from_slice(&2u16.to_le_bytes());
    let n = b.len();
    let crc = crc32fast::hash(&b[..n - 4]);
    b[n - 4..].copy_from_slice(&crc.to_le_bytes());
    let e = read_model(&b).unwrap_err();
    assert!(matches!(e, Error::Version(_)) && e.to_string().contains("2.0 is newer"), "{e}");
}

#[test]
fn a_newer_minor_version_with_extra_header_fields_is_read() {
    let m = model(4);
    let b = write_model(&m).unwrap();
    let header_len = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    let mut out = b[..16 + header_len].to_vec();
    out[10..12].copy_from_slice(&3u16.to_le_bytes());
    out.extend_from_slice(b"future fields");
    out[12..16].copy_from_slice(&((header_len + 13) as u32).to_le_bytes());
    out.extend_from_slice(&b[16 + header_len..b.len() - 4]);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(read_model(&out).unwrap(), m);
}
