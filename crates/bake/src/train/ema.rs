//! An exponential moving average of the trained texture and weights (Polyak averaging),
//! offered to the validation checks as a second candidate for the kept state.
//!
//! Training with one view per step is noisy: the state a check sees is one draw around the
//! point the optimiser hovers over, and the average of recent states may be a better
//! candidate where validation peaks while the learning rate is still high. The average never
//! feeds back into training; a check keeps it only when it scores higher on validation than
//! the current state and every earlier one. Measured at 300 s on the development set it did
//! not gain held out (docs/benchmarks.md), so `--ema` is off by default.

use rayon::prelude::*;

/// Steps between updates of the average (each update decays by `decay^EVERY`): an update
/// streams the whole texture, tens of megabytes on the balanced size, so it is not done
/// every step.
pub const EVERY: u64 = 4;

/// Elements per parallel chunk of an update.
const CHUNK: usize = 1 << 16;

/// The averaged tensors, in the trainer's order (texture levels, then network tensors).
#[derive(Clone, Debug)]
pub struct Ema {
    /// One average per tensor.
    pub tensors: Vec<Vec<f32>>,
    /// Updates folded in since the average started (from a copy of the state).
    pub updates: u64,
}

impl Ema {
    /// Starts an average at the current values.
    pub fn start(current: &[&[f32]]) -> Ema {
        Ema {
            tensors: current.iter().map(|t| t.to_vec()).collect(),
            updates: 0,
        }
    }

    /// Whether the average holds tensors of exactly these sizes.
    pub fn fits(&self, current: &[&[f32]]) -> bool {
        self.tensors.len() == current.len()
            && self
                .tensors
                .iter()
                .zip(current)
                .all(|(a, c)| a.len() == c.len())
    }

    /// Folds the current values in with weight `1 - keep`.
    pub fn update(&mut self, current: &[&[f32]], keep: f32) {
        let w = 1.0 - keep;
        for (avg, cur) in self.tensors.iter_mut().zip(current) {
            avg.par_chunks_mut(CHUNK)
                .zip(cur.par_chunks(CHUNK))
                .for_each(|(a, c)| {
                    for (a, &c) in a.iter_mut().zip(c) {
                        *a += w * (c - *a);
                    }
                });
        }
        self.updates += 1;
    }

    /// Steps the average spans (its time constant in steps), for a per-step `decay`.
    pub fn horizon(decay: f32) -> f64 {
        1.0 / (1.0 - f64::from(decay)).max(1e-9)
    }

    /// Whether enough updates have been folded in for the average to differ from the copy it
    /// started from by more than a few steps' worth (one time constant).
    pub fn warm(&self, decay: f32) -> bool {
        (self.updates * EVERY) as f64 >= Ema::horizon(decay)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn average_tracks_a_constant_and_weights_recent_values() {
        let a = vec![0.0f32; 3];
        let mut e = Ema::start(&[&a]);
        let one = vec![1.0f32; 3];
        for _ in 0..10 {
            e.update(&[&one], 0.5);
        }
        assert!((e.tensors[0][0] - (1.0 - 0.5f32.powi(10))).abs() < 1e-6);
        assert_eq!(e.updates, 10);
        assert!(e.fits(&[&one]));
        assert!(!e.fits(&[&one, &one]));
        assert!(!e.fits(&[&one[..2]]));
        // Horizon: 1 / (1 - decay) steps (0.99 is not exact in f32); warm after that many steps.
        assert!((Ema::horizon(0.99) - 100.0).abs() < 1e-3);
        assert!(!Ema::start(&[&a]).warm(0.99));
    }
}
