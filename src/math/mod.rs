//! The one mathematical definition of the method (METHOD.md "Representation"
//! and "Objective"): a primitive, its truncated kernel and analytic gradient
//! ([`kernel`]), the four loss terms and their gradients ([`loss`]), Adam with
//! cosine decay ([`optim`]), and the seeded random stream everything draws
//! from ([`rng`]); `simd` picks which build of a hot loop runs. Every
//! backend evaluates exactly this.

pub mod kernel;
pub mod loss;
pub mod optim;
pub mod rng;
pub mod simd;

/// Primitives per parallel task in a pass over every primitive (frames,
/// binning, the gradient's reduction, the regularisers, Adam): at least
/// `MIN`, and at most `MAX_TASKS` tasks, so that a small model still
/// spreads over every core and a large one pays for few tasks. The split
/// depends only on the count, never on the thread count.
///
/// The passes hand rayon these tasks one at a time (`with_max_len(1)`):
/// left to itself, rayon runs a pass's tasks in runs of several that no
/// other thread can take once started, and on two threads a pass then
/// ended with one thread running the last run alone for up to half a
/// millisecond an iteration (`benches/timeline.sh`, docs/BENCHMARKS.md
/// "Where an iteration loses time on p threads"). Binning keeps rayon's
/// runs: its tasks, each filling a list of its own, took twice as long
/// handed out one at a time.
pub fn primitives_per_task(n: usize) -> usize {
    const MIN: usize = 256;
    const MAX_TASKS: usize = 64;
    n.div_ceil(MAX_TASKS).max(MIN)
}
