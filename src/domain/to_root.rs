//! An MPI run's models stored by rank 0: one store file for every rank's
//! models, written during the run (the exchange: cargo feature `mpi`), and
//! read back by rank 0 for every rank when a restarted run resumes.
//!
//! One process writes the store: the HDF5 most codes link (Debian's among
//! them) is the serial build, and the store's crash safety (an entry built unlinked,
//! then committed by one link) assumes a single writer. At a collective
//! call each rank sends rank 0 the models its worker finished since the
//! last one, one message a model, as a float32 model file (exact) followed
//! by the packed payload's measured precision, which that file does not
//! carry ([`to_wire`]). Rank 0 stores its own, then each rank's in rank
//! order, each rank's in the order it finished them, and answers each rank
//! with what became of each of its models (`Verdict`s). Rank 0 takes one
//! model at a time, so it never holds more than one other rank's model.
//!
//! What stores a model is the caller's (`store`): this layer knows MPI,
//! not files. Only the exchange needs MPI; what travels (the wire form of
//! a model, the verdicts) is built and tested in every build.

#[cfg(feature = "mpi")]
use super::mpi::Decomposition;
use crate::error::{Error, Result};
use crate::format::packed::{Precision, GROUPS};
use crate::format::{read_model, write_model_as, Payload};
use crate::model::Model;
#[cfg(feature = "mpi")]
use mpi::traits::*;

/// The tags of this exchange on the decomposition's own communicator.
#[cfg(feature = "mpi")]
const TAG_MODELS: i32 = 0x6773;
#[cfg(feature = "mpi")]
const TAG_VERDICTS: i32 = 0x6774;
#[cfg(feature = "mpi")]
const TAG_RESUME: i32 = 0x6775;

/// Reads rank `r`'s model of a stored step (on rank 0).
pub type ReadOne<'a> = &'a mut dyn FnMut(u32) -> Result<Model>;

/// Stores one model (on rank 0): where it went, or why it did not.
pub type StoreOne<'a> = &'a mut dyn FnMut(&Model) -> Result<String>;

#[cfg(feature = "mpi")]
impl Decomposition {
    /// Stores every rank's `mine` (the models its worker finished since
    /// the last call) with `store` on rank 0, rank after rank, and returns
    /// what became of each of `mine`, in order. Collective: every rank
    /// calls it at the same point, each with its own models (any number,
    /// none included). `store` is used on rank 0 only; without one there,
    /// every model fails with an error saying so (the ranks still answer
    /// each other, so none waits forever).
    pub fn store_on_root(&mut self, mine: &[Model], store: Option<StoreOne>) -> Result<Vec<Result<String>>> {
        self.check_thread()?;
        let comm = self.comm();
        let root = comm.process_at_rank(0);
        if self.rank() != 0 {
            root.send_with_tag(&(mine.len() as u64), TAG_MODELS);
            let mut unsent = Vec::with_capacity(mine.len());
            for m in mine {
                let wire = to_wire(m);
                root.send_with_tag(wire.as_deref().unwrap_or(&[]), TAG_MODELS);
                unsent.push(wire.err());
            }
            let (verdicts, _) = root.receive_vec_with_tag::<u8>(TAG_VERDICTS);
            let mut got = Verdict::read_all(&verdicts, mine.len())?;
            // A model this rank could not send keeps its own reason.
            for (g, why) in got.iter_mut().zip(unsent) {
                if let Some(e) = why {
                    *g = Err(e);
                }
            }
            return Ok(got);
        }
        let mut store = store;
        let mut put = |m: &Model| match store.as_mut() {
            Some(s) => s(m),
            None => Err(Error::arg("rank 0 was given no store for the ranks' models")),
        };
        let own = mine.iter().map(&mut put).collect();
        for r in 1..self.size() {
            let from = comm.process_at_rank(r as i32);
            let (n, _) = from.receive_with_tag::<u64>(TAG_MODELS);
            let mut verdicts = Vec::new();
            for _ in 0..n {
                let (wire, _) = from.receive_vec_with_tag::<u8>(TAG_MODELS);
                let stored = match wire.is_empty() {
                    true => Err(Error::Mpi(format!("rank {r} could not send its model (its own error says why)"))),
                    false => from_wire(&wire).and_then(|m| match m.meta.rank as usize == r {
                        true => put(&m),
                        false => Err(Error::Mpi(format!("rank {r} sent a model of rank {}; not stored", m.meta.rank))),
                    }),
                };
                Verdict::write(&mut verdicts, &stored);
            }
            from.send_with_tag(&verdicts[..], TAG_VERDICTS);
        }
        Ok(own)
    }
}

#[cfg(feature = "mpi")]
impl Decomposition {
    /// The other way, for a restart: rank 0 reads every rank's model of a
    /// stored step with `read` (from the store it alone has open) and sends
    /// each rank its own; returns this rank's, or why rank 0 could not read
    /// or send it (with the error's kind: a missing entry is the same
    /// status on every rank). Collective; `read` is used on rank 0 only (a
    /// rank 0 without a store gives one that says so, for every rank).
    pub fn models_from_root(&mut self, read: ReadOne) -> Result<Model> {
        self.check_thread()?;
        let comm = self.comm();
        if self.rank() != 0 {
            let root = comm.process_at_rank(0);
            let (verdict, _) = root.receive_vec_with_tag::<u8>(TAG_RESUME);
            let read = Verdict::read_all(&verdict, 1)?.pop().unwrap_or_else(|| Err(Error::Mpi("rank 0 sent no answer".into())));
            read.map_err(|e| e.in_context("rank 0 reading this rank's model"))?;
            let (wire, _) = root.receive_vec_with_tag::<u8>(TAG_RESUME);
            return from_wire(&wire);
        }
        let own = read(0);
        for r in 1..self.size() {
            let to = comm.process_at_rank(r as i32);
            let (verdict, wire) = match read(r as u32).and_then(|m| to_wire(&m)) {
                Ok(wire) => (Ok(String::new()), Some(wire)),
                Err(e) => (Err(e), None),
            };
            let mut answer = Vec::new();
            Verdict::write(&mut answer, &verdict);
            to.send_with_tag(&answer[..], TAG_RESUME);
            if let Some(wire) = wire {
                to.send_with_tag(&wire[..], TAG_RESUME);
            }
        }
        own
    }
}

/// What travels for a model: its float32 model file, then, when its
/// packed precision was measured, the bits of each group of [`GROUPS`],
/// and last a byte saying whether they are there (1) or not (0). Fails for a model that has no float32 file (a
/// non-finite parameter) or one over MPI's 2^31 - 1 elements a message.
pub fn to_wire(model: &Model) -> Result<Vec<u8>> {
    let mut wire = write_model_as(model, Payload::Float32)?;
    match model.meta.precision {
        None => wire.push(0),
        Some(p) => {
            wire.extend((0..GROUPS.len()).map(|g| p.get(g)));
            wire.push(1);
        }
    }
    if i32::try_from(wire.len()).is_err() {
        return Err(Error::arg(format!(
            "field '{}' step {}: the model takes {} bytes, more than one MPI message carries to rank 0",
            model.meta.field,
            model.meta.step,
            wire.len()
        )));
    }
    Ok(wire)
}

/// The model [`to_wire`] sent, exactly.
pub fn from_wire(wire: &[u8]) -> Result<Model> {
    let bad = || Error::format("a model from another rank is cut short");
    let has = |k: usize| wire.len().checked_sub(k).ok_or_else(bad);
    let (file, precision) = match wire.last() {
        Some(0) => (&wire[..has(1)?], None),
        Some(1) => {
            let at = has(1 + GROUPS.len())?;
            let bits = &wire[at..wire.len() - 1];
            let p = (0..GROUPS.len()).fold(Precision::DEFAULT, |p, g| p.with(g, bits[g]));
            (&wire[..at], Some(p.check()?))
        }
        _ => return Err(bad()),
    };
    let mut model = read_model(file)?;
    model.meta.precision = precision;
    Ok(model)
}

/// What rank 0 answers for one model: stored (where), or failed (the
/// error's kind, so the C API gives the same status on every rank, and its
/// message).
#[cfg_attr(not(feature = "mpi"), allow(dead_code))]
struct Verdict;

#[cfg_attr(not(feature = "mpi"), allow(dead_code))]
impl Verdict {
    const STORED: u8 = 0;
    const ARGUMENT: u8 = 1;
    const DATA: u8 = 2;
    const FORMAT: u8 = 3;
    const VERSION: u8 = 4;
    const FILE: u8 = 5;
    const OTHER: u8 = 6;

    fn write(out: &mut Vec<u8>, stored: &Result<String>) {
        let (kind, text) = match stored {
            Ok(at) => (Verdict::STORED, at.clone()),
            Err(Error::InvalidArgument(m)) => (Verdict::ARGUMENT, m.clone()),
            Err(Error::InvalidData(m)) => (Verdict::DATA, m.clone()),
            Err(Error::Format(m)) => (Verdict::FORMAT, m.clone()),
            Err(Error::Version(m)) => (Verdict::VERSION, m.clone()),
            Err(e @ (Error::Io { .. } | Error::Hdf5 { .. })) => (Verdict::FILE, e.to_string()),
            // Read back as an MPI error, which says "MPI:" itself; another
            // kind (a device's) keeps its own prefix.
            Err(Error::Mpi(m)) => (Verdict::OTHER, m.clone()),
            Err(e) => (Verdict::OTHER, e.to_string()),
        };
        out.push(kind);
        out.extend_from_slice(&(text.len() as u64).to_le_bytes());
        out.extend_from_slice(text.as_bytes());
    }

    /// `n` verdicts from `bytes`.
    fn read_all(mut bytes: &[u8], n: usize) -> Result<Vec<Result<String>>> {
        let bad = || Error::Mpi("rank 0's answer about this rank's models is cut short".into());
        let mut all = Vec::with_capacity(n);
        for _ in 0..n {
            let (&kind, rest) = bytes.split_first().ok_or_else(bad)?;
            let len = rest.get(..8).ok_or_else(bad)?;
            let len = u64::from_le_bytes(len.try_into().unwrap()) as usize;
            let text = rest.get(8..8usize.saturating_add(len)).ok_or_else(bad)?;
            let text = String::from_utf8_lossy(text).into_owned();
            bytes = &rest[8 + len..];
            all.push(match kind {
                Verdict::STORED => Ok(text),
                Verdict::ARGUMENT => Err(Error::InvalidArgument(text)),
                Verdict::DATA => Err(Error::InvalidData(text)),
                Verdict::FORMAT => Err(Error::Format(text)),
                Verdict::VERSION => Err(Error::Version(text)),
                Verdict::FILE => Err(Error::Hdf5 { path: "rank 0's store".into(), message: text }),
                _ => Err(Error::Mpi(format!("rank 0 could not store this rank's model: {text}"))),
            });
        }
        if !bytes.is_empty() {
            return Err(Error::Mpi("rank 0 answered for more models than this rank sent".into()));
        }
        Ok(all)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::{IndexFrame, Transform, ValueRange};
    use crate::model::ModelMeta;

    fn model(precision: Option<Precision>) -> Model {
        let frame = IndexFrame { dims: [8, 6, 4], bmin: [0.5, -1.0, 2.0], gamma: 4.0 };
        let mut meta = ModelMeta::new(frame, ValueRange::new(-2.0, 3.0, Transform::Linear).unwrap());
        meta.field = "rho".into();
        meta.step = 7;
        meta.rank = 3;
        meta.time = Some(0.25);
        meta.encode_psnr = Some(41.5);
        meta.precision = precision;
        let params = (0..5).map(|i| std::array::from_fn(|k| (i * 12 + k) as f32 * 0.013 - 0.2)).collect();
        Model { meta, params, support: None }
    }

    #[test]
    fn a_model_crosses_exactly_with_or_without_its_precision() {
        for p in [None, Some(Precision::DEFAULT.with(2, 8).with(5, 3))] {
            let m = model(p);
            assert_eq!(from_wire(&to_wire(&m).unwrap()).unwrap(), m);
        }
        // One of 4,000 primitives (192 kB: no small bound on a message).
        let mut big = model(None);
        big.params = (0..4000).map(|i| std::array::from_fn(|k| ((i * 12 + k) % 97) as f32 * 0.01)).collect();
        assert_eq!(from_wire(&to_wire(&big).unwrap()).unwrap(), big);
    }

    #[test]
    fn a_cut_or_changed_wire_is_refused() {
        let wire = to_wire(&model(Some(Precision::FINEST))).unwrap();
        for cut in [0, 1, 5, wire.len() - 1] {
            assert!(from_wire(&wire[..cut]).is_err(), "cut at {cut}");
        }
        let mut bits = wire.clone();
        let weight = bits.len() - 2;
        bits[weight] = 40; // weight bits out of range
        let mut flag = wire.clone();
        flag.push(9);
        assert!(from_wire(&bits).is_err() && from_wire(&flag).is_err());
    }

    #[test]
    fn verdicts_keep_their_kind_and_message() {
        let sent: Vec<Result<String>> = vec![
            Ok("run.h5:/rho/7/rank_3".into()),
            Err(Error::arg("/rho/7/rank_3 already holds a model")),
            Err(Error::Hdf5 { path: "run.h5".into(), message: "no space left".into() }),
            Err(Error::Device("lost".into())),
            Err(Error::Mpi("rank 1 sent a model of rank 101; not stored".into())),
        ];
        let mut bytes = Vec::new();
        sent.iter().for_each(|s| Verdict::write(&mut bytes, s));
        let got = Verdict::read_all(&bytes, 5).unwrap();
        assert_eq!(got[0].as_ref().unwrap(), "run.h5:/rho/7/rank_3");
        assert!(matches!(&got[1], Err(Error::InvalidArgument(m)) if m.contains("already holds")));
        assert!(matches!(&got[2], Err(Error::Hdf5 { message, .. }) if message.contains("run.h5") && message.contains("no space left")));
        // Another kind says both kinds; an MPI error says "MPI:" once.
        let text = |i: usize| got[i].as_ref().unwrap_err().to_string();
        assert_eq!(text(3), "MPI: rank 0 could not store this rank's model: GPU: lost");
        assert!(matches!(&got[3], Err(Error::Mpi(_))));
        assert_eq!(text(4), "MPI: rank 0 could not store this rank's model: rank 1 sent a model of rank 101; not stored");
        assert!(Verdict::read_all(&bytes[..bytes.len() - 1], 5).is_err());
        assert!(Verdict::read_all(&bytes, 4).is_err());
    }

    /// Every kind of error crosses as its own kind (the C API's status on
    /// the sending rank), with its message; a file error as a store error
    /// that keeps the path and the cause; anything else as an MPI error.
    #[test]
    fn every_kind_of_error_crosses_as_itself() {
        let io = std::io::Error::new(std::io::ErrorKind::StorageFull, "disk full");
        let sent: Vec<Result<String>> = vec![
            Err(Error::data("NaN at 4")),
            Err(Error::format("not a model")),
            Err(Error::Version("2.0".into())),
            Err(Error::Io { path: "run.h5".into(), source: io }),
            Err(Error::Cancelled("stopped".into())),
            Ok(String::new()),
        ];
        let mut bytes = Vec::new();
        sent.iter().for_each(|s| Verdict::write(&mut bytes, s));
        let got = Verdict::read_all(&bytes, sent.len()).unwrap();
        assert!(matches!(&got[0], Err(Error::InvalidData(m)) if m == "NaN at 4"), "{:?}", got[0]);
        assert!(matches!(&got[1], Err(Error::Format(m)) if m == "not a model"), "{:?}", got[1]);
        assert!(matches!(&got[2], Err(Error::Version(m)) if m == "2.0"), "{:?}", got[2]);
        assert!(matches!(&got[3], Err(Error::Hdf5 { message, .. }) if message.contains("run.h5") && message.contains("disk full")), "{:?}", got[3]);
        assert!(matches!(&got[4], Err(Error::Mpi(m)) if m.contains("stopped")), "{:?}", got[4]);
        assert_eq!(got[5].as_ref().unwrap(), "");
    }
}
