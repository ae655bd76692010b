//! Any text given to the step-index reader gives an index or an error, never
//! a panic, a hang or a huge allocation: the lattice, the range, the halo and
//! the pieces' boxes a file claims must be checked before a decode trusts
//! them. An index it accepts is then decoded as `gsenc decode` decodes a
//! step, with a one-Gaussian model made for each piece it names, onto a
//! lattice of at most 6 voxels an axis: the blend across the halos must give
//! a finite value at every voxel.
#![no_main]

use gsenc::backend::cpu::CpuBackend;
use gsenc::domain::global::GlobalField;
use gsenc::field::{IndexBox, Transform, ValueRange};
use gsenc::format::StepIndex;
use gsenc::math::kernel::isotropic;
use gsenc::model::{Model, ModelMeta};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(index) = StepIndex::from_json(text) else { return };
    // What the reader accepted is a layout a decode can use.
    let transform = Transform::from_name(&index.range.transform).expect("an accepted index names a known transform");
    let range = ValueRange::new(index.range.vmin, index.range.vmax, transform).expect("an accepted index has a valid range");
    let (global, boxes) = index.layout();
    let pieces: Vec<Model> = boxes
        .iter()
        .enumerate()
        .map(|(rank, b)| {
            let frame = global.sub_frame(b);
            let mut meta = ModelMeta::new(frame, range);
            (meta.field, meta.step, meta.rank) = (index.field.clone(), index.step, rank as u32);
            let mu = frame.dims.map(|d| (d as f32 - 1.0) / 2.0);
            Model { meta, params: vec![isotropic(mu, 1.0, 0.5, 0.5)], support: None }
        })
        .collect();
    // Frames at extreme corners or voxel sizes may not round-trip through
    // world units; such pieces are refused, which is an answer too.
    if index.check_pieces(&pieces).is_err() {
        return;
    }
    let Ok(field) = GlobalField::of_step(index, pieces) else { return };
    let dims = global.dims.map(|d| d.min(6));
    if let Ok(values) = field.decode(&mut CpuBackend::new(), dims, IndexBox::whole(dims), false) {
        assert_eq!(values.len(), dims.iter().product::<usize>());
        assert!(values.iter().all(|v| v.is_finite()), "a blend gave a value that is not finite");
    }
});
