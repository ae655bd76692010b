//! Any bytes given to the `.vti` reader give a grid or an error, never a
//! panic, a hang or a huge allocation: the sizes a file claims (its extent,
//! offsets, block headers, zlib streams) must be checked against what it holds.
//! The first byte picks the array by name half the time, so that the search
//! for a named array is fuzzed as well as the default choice.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&flag, rest)) = data.split_first() else { return };
    let array = if flag & 1 == 1 { Some("v") } else { None };
    if let Ok(v) = gsenc::io::vti::parse_vti(rest, array) {
        // What was read is a whole grid: its values fill its dims.
        assert_eq!(v.grid.values.len(), v.grid.dims.iter().product::<usize>());
    }
});
