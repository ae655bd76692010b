//! Any bytes given to the model reader give a model or an error, never a
//! panic, a hang or a huge allocation. The checksum would reject almost every
//! mutation at once, so half the inputs get a valid checksum appended: the
//! fuzzer then reaches the header, payload and zstd parsing behind it.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = gsenc::format::read_model_file(data);
    if let Some((&flag, rest)) = data.split_first() {
        if flag & 1 == 1 {
            let mut with_crc = rest.to_vec();
            with_crc.extend_from_slice(&crc32(rest).to_le_bytes());
            if let Ok(file) = gsenc::format::read_model_file(&with_crc) {
                // What was read can be written again with its own payload.
                let _ = gsenc::format::write_model_as(&file.model, file.payload);
            }
        }
    }
});

/// CRC-32 (IEEE), bit by bit: the fuzz target needs no extra dependency.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 == 1 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
    }
    !c
}
