//! When an `auto` warm-started step stops (METHOD.md "Warm start"): its
//! iterations follow the validation PSNR instead of a fixed count.
//!
//! The learning rate follows the usual cosine over the cap until the
//! validation PSNR has not risen by `MIN_RISE` dB for `PATIENCE` checks.
//! Then the step anneals: the rate falls from where it is to the schedule's
//! floor by a half cosine over `max(2 checks, ANNEAL_SHARE x iterations
//! done)` iterations (never past the cap), and the step ends. A calm step
//! (a model that already fits) stops after about `PATIENCE + 2` checks; a
//! step whose PSNR keeps rising runs to the cap like a fixed schedule. The
//! encode keeps the best-scoring parameters of its checks (`refine.rs`),
//! so a step never ends below where it started.

use crate::math::optim::{cosine_lr, FINAL_LR_FRACTION};

/// Checks without a rise of `MIN_RISE` before the step anneals.
pub const PATIENCE: usize = 4;
/// A rise of the validation PSNR smaller than this (dB) is no rise.
pub const MIN_RISE: f64 = 0.02;
/// The anneal's length as a share of the iterations done when it starts.
pub const ANNEAL_SHARE: f64 = 0.25;

/// The stopping rule of one step.
#[derive(Clone, Debug)]
pub struct Plateau {
    cap: usize,
    every: usize,
    /// The PSNR of the last rise and the iteration it was scored at.
    level: f64,
    rose_at: usize,
    /// The anneal: its first iteration, its length and the rate it starts from.
    anneal: Option<(usize, usize, f32)>,
}

impl Plateau {
    /// A step of at most `cap` iterations scored every `every`.
    pub fn new(cap: usize, every: usize) -> Plateau {
        Plateau { cap, every: every.max(1), level: f64::NEG_INFINITY, rose_at: 0, anneal: None }
    }

    /// The learning rate of iteration `t` for a base rate `lr0`.
    pub fn lr(&self, lr0: f32, t: usize) -> f32 {
        match self.anneal {
            None => cosine_lr(lr0, t, self.cap),
            Some((start, len, from)) => {
                let x = ((t - start) as f64 / len as f64).min(1.0);
                let floor = (lr0 * FINAL_LR_FRACTION) as f64;
                (floor + (from as f64 - floor) * 0.5 * (1.0 + (std::f64::consts::PI * x).cos())) as f32
            }
        }
    }

    /// Takes the validation PSNR scored before iteration `t` (`lr0`: the
    /// base rate, to know where an anneal starts from).
    pub fn score(&mut self, t: usize, psnr: f64, lr0: f32) {
        if psnr > self.level + MIN_RISE {
            self.level = psnr;
            self.rose_at = t;
        } else if self.anneal.is_none() && t >= self.rose_at + PATIENCE * self.every {
            let len = (2 * self.every).max((ANNEAL_SHARE * t as f64).round() as usize);
            self.anneal = Some((t, len.min(self.cap.saturating_sub(t)).max(1), self.lr(lr0, t)));
        }
    }

    /// The iterations the step runs, as far as it is known before
    /// iteration `t`: the cap, or where the anneal ends.
    pub fn end(&self) -> usize {
        self.anneal.map_or(self.cap, |(start, len, _)| (start + len).min(self.cap))
    }

    /// True once the step anneals.
    pub fn annealing(&self) -> bool {
        self.anneal.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rising_score_runs_the_whole_cosine() {
        let mut p = Plateau::new(1000, 50);
        for (c, t) in (0..1000).step_by(50).enumerate() {
            p.score(t, 30.0 + c as f64, 0.01);
            assert_eq!(p.lr(0.01, t), cosine_lr(0.01, t, 1000));
        }
        assert_eq!(p.end(), 1000);
        assert!(!p.annealing());
    }

    #[test]
    fn a_flat_score_anneals_after_the_patience_and_stops() {
        let mut p = Plateau::new(3000, 50);
        let mut t = 0;
        // Scores that wander by less than MIN_RISE.
        while !p.annealing() && t < 3000 {
            p.score(t, 40.0 + 0.015 * ((t / 50) % 2) as f64, 0.01);
            t += 50;
        }
        // The first score is a rise; four more checks without one.
        assert_eq!(t - 50, PATIENCE * 50);
        let start = t - 50;
        let len = 100usize.max((ANNEAL_SHARE * start as f64).round() as usize);
        assert_eq!(p.end(), start + len);
        // The rate falls from where the cosine was to the floor, monotonically.
        let from = cosine_lr(0.01, start, 3000);
        assert!((p.lr(0.01, start) - from).abs() < 1e-9);
        let mut last = from;
        for s in start..p.end() {
            assert!(p.lr(0.01, s) <= last + 1e-12);
            last = p.lr(0.01, s);
        }
        assert!((p.lr(0.01, p.end()) - 0.01 * FINAL_LR_FRACTION).abs() < 1e-9);
        // Later scores change nothing.
        let end = p.end();
        p.score(p.end(), 10.0, 0.01);
        assert_eq!(p.end(), end);
    }

    #[test]
    fn the_anneal_never_runs_past_the_cap() {
        let mut p = Plateau::new(260, 50);
        for t in (0..=250).step_by(50) {
            p.score(t, 40.0, 0.01);
        }
        assert!(p.annealing());
        assert_eq!(p.end(), 260);
    }
}
