//! The exchange of models with rank 0 (`gsenc::domain::to_root`), every
//! outcome of it: run under `mpirun -n N` (tests/mpi.sh, N = 1, 2, 4).
//!
//! To rank 0's store: rank 0 hands in a model of its own; every other rank
//! r a model of its own (stored, exactly, in rank order), one that says it
//! is another rank's (refused by rank 0, by name) and one with a
//! non-finite parameter (which has no wire form: refused on rank r with
//! its own error). Then the same with no store on rank 0: every model is
//! refused, saying so. Back from rank 0, for a restart: rank 0 reads each
//! rank's model and rank r gets exactly its own, but the last rank (of
//! several), whose read fails: it gets that error, of its kind, said to
//! be rank 0's. Rank 0 prints "exchange: N ranks ok"; a failed check
//! panics and aborts every rank, and mpirun fails.
//!
//! ```text
//! mpirun -n 2 target/release/examples/mpi_exchange
//! ```

use gsenc::domain::mpi::{Decomposition, DecompositionConfig};
use gsenc::field::{IndexFrame, Transform, ValueRange};
use gsenc::format::packed::Precision;
use gsenc::model::{Model, ModelMeta};
use gsenc::series::SeriesRange;
use gsenc::Error;
use mpi::traits::*;

/// Rank `rank`'s model, the same wherever it is made.
fn model_of(rank: u32) -> Model {
    let mut meta = ModelMeta::new(
        IndexFrame { dims: [8, 6, 5], bmin: [rank as f64, 0.0, 0.0], gamma: 4.0 },
        ValueRange::new(-1.0, 2.0, Transform::Linear).unwrap(),
    );
    (meta.field, meta.step, meta.rank, meta.time) = ("rho".into(), 3, rank, Some(0.5));
    meta.precision = Some(Precision { value: 7 + rank as u8 % 4, ..Precision::DEFAULT });
    let params = (0..10 + rank as usize).map(|i| std::array::from_fn(|k| (i * 12 + k) as f32 * 0.01 + rank as f32)).collect();
    Model { meta, params, support: None }
}

fn main() {
    let (universe, _) = mpi::initialize_with_threading(mpi::Threading::Funneled).expect("MPI initialises");
    // A failed check ends every rank (the others would wait for it).
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        report(info);
        mpi::topology::SimpleCommunicator::world().abort(1);
    }));
    let world = universe.world();
    let (rank, n) = (world.rank() as u32, world.size() as u32);
    let cfg = DecompositionConfig { dims: [8, 6, 5], bounds: None, halo: 0, range: SeriesRange::FirstStep(Transform::Linear) };
    let mut ranks = Decomposition::new(&world, cfg).unwrap();

    let mut mine = vec![model_of(rank)];
    let mut no_wire = None;
    if rank > 0 {
        let mut other = model_of(rank);
        other.meta.rank = rank + 100;
        let mut nan = model_of(rank);
        nan.params[2][4] = f32::NAN;
        no_wire = Some(gsenc::domain::to_root::to_wire(&nan).unwrap_err().to_string());
        mine.extend([other, nan]);
    }
    // What rank r is told of each of its models (`stored`: with a store).
    let check = |verdicts: Vec<gsenc::Result<String>>, stored: bool| {
        let text: Vec<String> = verdicts.into_iter().map(|v| v.unwrap_or_else(|e| e.to_string())).collect();
        let kept = match stored {
            true => format!("stored rho/3 of rank {rank}"),
            false => "invalid argument: rank 0 was given no store for the ranks' models".to_string(),
        };
        let mut want = vec![kept];
        if rank > 0 {
            want.push(format!("MPI: rank 0 could not store this rank's model: rank {rank} sent a model of rank {}; not stored", rank + 100));
            want.push(no_wire.clone().unwrap());
        }
        assert_eq!(text, want, "rank {rank}, stored {stored}");
    };

    let mut got = Vec::new();
    let mut store = |m: &Model| {
        got.push(m.clone());
        Ok(format!("stored {}/{} of rank {}", m.meta.field, m.meta.step, m.meta.rank))
    };
    check(ranks.store_on_root(&mine, Some(&mut store)).unwrap(), true);
    if rank == 0 {
        // Every rank's own model, exactly, in rank order, and nothing else.
        assert_eq!(got, (0..n).map(model_of).collect::<Vec<_>>());
    }
    check(ranks.store_on_root(&mine, None).unwrap(), false);

    let mut read = |r: u32| match r == n - 1 && n > 1 {
        true => Err(Error::arg(format!("no model of rank {r}"))),
        false => Ok(model_of(r)),
    };
    match ranks.models_from_root(&mut read) {
        Ok(m) => {
            assert!(rank < n - 1 || n == 1, "rank {rank} got a model");
            assert_eq!(m, model_of(rank), "rank {rank}");
        }
        Err(Error::InvalidArgument(m)) => {
            assert!(rank == n - 1 && n > 1, "rank {rank}: {m}");
            assert_eq!(m, format!("rank 0 reading this rank's model: no model of rank {rank}"));
        }
        Err(e) => panic!("rank {rank}: {e}"),
    }
    if rank == 0 {
        println!("exchange: {n} ranks ok");
    }
}
