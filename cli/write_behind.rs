//! A decode's slabs written on a thread of their own, one slab behind the
//! decode: while the writer turns slab k into little-endian bytes and
//! hands them to the file (or standard output), the decode computes slab
//! k + 1. A large decode then takes about the longer of the two rather
//! than their sum: on the 2-core VM a 1024³ decode's 4 GiB took 3.5–11 s
//! to reach the disk, more than the host's whole share of a GPU decode
//! (docs/BENCHMARKS.md "A decode written behind").
//!
//! Two slab buffers go round between the threads (one being filled, one
//! being written), so a decode holds two slabs beside the decode's own (as
//! before: one in output units and one as bytes).
//! The writer's first error ends it: the next [`WriteBehind::send`] (or
//! [`WriteBehind::finish`]) returns that error, the decode stops there, and
//! the caller drops the sink uncommitted, which leaves what was under its
//! name before as it was.

use crate::output::Sink;
use gsenc::{Error, Result};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::JoinHandle;

/// Values turned into bytes and written at a time.
const WRITE_RUN: usize = 1 << 18;

pub struct WriteBehind {
    /// Slabs to the writer; a rendezvous, so a send waits until the writer
    /// has finished the slab before.
    to_writer: Option<SyncSender<Vec<f32>>>,
    /// Slabs the writer has written, to be filled again.
    spare: Receiver<Vec<f32>>,
    writer: Option<JoinHandle<Result<Sink>>>,
}

impl WriteBehind {
    /// Starts the writer thread, which owns `sink` until [`WriteBehind::finish`].
    pub fn new(mut sink: Sink) -> Result<WriteBehind> {
        let (to_writer, slabs) = sync_channel::<Vec<f32>>(0);
        let (give_back, spare) = sync_channel::<Vec<f32>>(2);
        let writer = std::thread::Builder::new()
            .name("gsenc-writer".into())
            .spawn(move || {
                // A megabyte of bytes at a time, written while in cache.
                let mut bytes = vec![0u8; 4 * WRITE_RUN];
                for slab in slabs {
                    for run in slab.chunks(WRITE_RUN) {
                        let bytes = &mut bytes[..4 * run.len()];
                        for (b, v) in bytes.chunks_exact_mut(4).zip(run) {
                            b.copy_from_slice(&v.to_le_bytes());
                        }
                        sink.write(bytes)?;
                    }
                    // At most two slabs go round; a full queue drops this one.
                    let _ = give_back.try_send(slab);
                }
                Ok(sink)
            })
            .map_err(|e| Error::io("the decode's writer thread", e))?;
        Ok(WriteBehind { to_writer: Some(to_writer), spare, writer: Some(writer) })
    }

    /// A buffer to fill with the next slab: one the writer has written, or
    /// a new one.
    pub fn buffer(&mut self) -> Vec<f32> {
        self.spare.try_recv().unwrap_or_default()
    }

    /// Hands `slab` to the writer, after it has written the slab before.
    /// Fails with the writer's error when it has stopped on one.
    pub fn send(&mut self, slab: Vec<f32>) -> Result<()> {
        let sent = self.to_writer.as_ref().map(|w| w.send(slab).is_ok());
        match sent {
            Some(true) => Ok(()),
            // The writer has ended: it failed (an i/o error it returns).
            _ => self.join().and_then(|_| Err(Error::arg("the decode's writer stopped early"))),
        }
    }

    /// Waits for the writer to write every slab sent, and gives the sink
    /// back (to append to, then commit); or the writer's error.
    pub fn finish(mut self) -> Result<Sink> {
        self.join()
    }

    fn join(&mut self) -> Result<Sink> {
        self.to_writer = None;
        match self.writer.take().map(JoinHandle::join) {
            Some(Ok(written)) => written,
            Some(Err(panic)) => std::panic::resume_unwind(panic),
            None => Err(Error::arg("the decode's writer has already ended")),
        }
    }
}

impl Drop for WriteBehind {
    /// Dropped before [`WriteBehind::finish`] (the decode failed): the
    /// writer ends with what it was given, and its sink is dropped there
    /// uncommitted.
    fn drop(&mut self) {
        self.to_writer = None;
        if let Some(w) = self.writer.take() {
            let _ = w.join();
        }
    }
}
