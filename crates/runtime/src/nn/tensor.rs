//! `Tensor`: a CHW planar f32 image (batch 1), the activation type of every layer.

use super::NnError;

/// Values per parallel task below which splitting costs more than it saves.
pub const PAR_MIN_VALUES: usize = 1 << 15;

/// Minimum number of `chunk`-sized items per rayon task so each task handles at least
/// [`PAR_MIN_VALUES`] values (use with `with_min_len`).
pub fn par_min_items(chunk: usize) -> usize {
    PAR_MIN_VALUES.div_ceil(chunk.max(1))
}

/// A C x H x W image stored plane after plane (`data[(c * h + y) * w + x]`).
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    /// Channels.
    pub c: usize,
    /// Rows.
    pub h: usize,
    /// Columns.
    pub w: usize,
    /// `c * h * w` values, CHW order.
    pub data: Vec<f32>,
}

impl Tensor {
    /// A tensor of zeros.
    pub fn zeros(c: usize, h: usize, w: usize) -> Self {
        Tensor {
            c,
            h,
            w,
            data: pool::zeroed(c * h * w),
        }
    }

    /// A tensor whose every value the caller overwrites before reading (storage from
    /// [`pool::scratch`]).
    pub fn scratch(c: usize, h: usize, w: usize) -> Self {
        Tensor {
            c,
            h,
            w,
            data: pool::scratch(c * h * w),
        }
    }

    /// Hands the storage back to [`pool`].
    pub fn recycle(self) {
        pool::recycle(self.data);
    }

    /// Wraps `data`, checking that it holds exactly `c * h * w` values.
    pub fn from_vec(c: usize, h: usize, w: usize, data: Vec<f32>) -> Result<Self, NnError> {
        let n = c.checked_mul(h).and_then(|v| v.checked_mul(w));
        if n != Some(data.len()) {
            return Err(NnError::Shape(format!(
                "tensor {c}x{h}x{w} needs {} values, got {}",
                n.map_or("overflowing".to_string(), |v| v.to_string()),
                data.len()
            )));
        }
        Ok(Tensor { c, h, w, data })
    }

    /// Pixels per plane (`h * w`).
    pub fn plane_len(&self) -> usize {
        self.h * self.w
    }

    /// Channel `c` as an H*W row-major slice.
    pub fn plane(&self, c: usize) -> &[f32] {
        let n = self.plane_len();
        &self.data[c * n..(c + 1) * n]
    }

    /// Channel `c`, mutable.
    pub fn plane_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.plane_len();
        &mut self.data[c * n..(c + 1) * n]
    }

    /// Value at (c, y, x).
    pub fn at(&self, c: usize, y: usize, x: usize) -> f32 {
        self.data[(c * self.h + y) * self.w + x]
    }

    /// Channels stacked: `self` first, then `other` (same H and W).
    pub fn concat(&self, other: &Tensor) -> Result<Tensor, NnError> {
        if self.h != other.h || self.w != other.w {
            return Err(NnError::Shape(format!(
                "concat of {}x{} with {}x{}",
                self.h, self.w, other.h, other.w
            )));
        }
        let mut data = Vec::with_capacity(self.data.len() + other.data.len());
        data.extend_from_slice(&self.data);
        data.extend_from_slice(&other.data);
        Ok(Tensor {
            c: self.c + other.c,
            h: self.h,
            w: self.w,
            data,
        })
    }

    /// The tensor grown to `h2 x w2` with zeros at the bottom and right (`h2 >= h`, `w2 >= w`).
    pub fn pad_bottom_right(&self, h2: usize, w2: usize) -> Tensor {
        assert!(h2 >= self.h && w2 >= self.w, "pad_bottom_right shrinks");
        if h2 == self.h && w2 == self.w {
            return self.clone();
        }
        let mut out = Tensor::zeros(self.c, h2, w2);
        for c in 0..self.c {
            for y in 0..self.h {
                let src = &self.data[(c * self.h + y) * self.w..][..self.w];
                out.data[(c * h2 + y) * w2..][..self.w].copy_from_slice(src);
            }
        }
        out
    }

    /// The top-left `h2 x w2` window (`h2 <= h`, `w2 <= w`).
    pub fn crop_top_left(&self, h2: usize, w2: usize) -> Tensor {
        assert!(h2 <= self.h && w2 <= self.w, "crop_top_left grows");
        if h2 == self.h && w2 == self.w {
            return self.clone();
        }
        let mut out = Tensor::zeros(self.c, h2, w2);
        for c in 0..self.c {
            for y in 0..h2 {
                let src = &self.data[(c * self.h + y) * self.w..][..w2];
                out.data[(c * h2 + y) * w2..][..w2].copy_from_slice(src);
            }
        }
        out
    }
}

/// A process-wide pool of large `f32` buffers. Layers take their scratch and output buffers
/// from it and callers hand dead ones back, so a training or render loop stops asking the OS
/// for fresh pages (page faults and zeroing were ~20% of a small U-Net's training step).
/// Contents never affect results: every buffer is either zero-filled or fully overwritten.
pub mod pool {
    use std::sync::Mutex;

    /// Buffers below this many values are not pooled (the allocator handles them well).
    const MIN_LEN: usize = 1 << 14;
    /// At most this many buffers are kept.
    const MAX_KEPT: usize = 96;

    static POOL: Mutex<Vec<Vec<f32>>> = Mutex::new(Vec::new());

    fn take(len: usize) -> Option<Vec<f32>> {
        if len < MIN_LEN {
            return None;
        }
        let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
        // Best fit: the smallest kept buffer that is large enough.
        let best = pool
            .iter()
            .enumerate()
            .filter(|(_, v)| v.capacity() >= len)
            .min_by_key(|(_, v)| v.capacity())
            .map(|(i, _)| i)?;
        Some(pool.swap_remove(best))
    }

    /// A buffer of `len` zeros.
    pub fn zeroed(len: usize) -> Vec<f32> {
        match take(len) {
            Some(mut v) => {
                v.clear();
                v.resize(len, 0.0);
                v
            }
            None => vec![0.0; len],
        }
    }

    /// A buffer of `len` values with unspecified (finite or not) contents, for callers that
    /// overwrite every value before reading it. Debug builds fill it with NaN so that a read
    /// before the write shows up in tests.
    pub fn scratch(len: usize) -> Vec<f32> {
        if cfg!(debug_assertions) {
            let mut v = zeroed(len);
            v.fill(f32::NAN);
            return v;
        }
        match take(len) {
            Some(mut v) => {
                if v.len() >= len {
                    v.truncate(len);
                } else {
                    v.resize(len, 0.0);
                }
                v
            }
            None => vec![0.0; len],
        }
    }

    /// Hands a dead buffer back.
    pub fn recycle(v: Vec<f32>) {
        if v.capacity() < MIN_LEN {
            return;
        }
        let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
        if pool.len() < MAX_KEPT {
            pool.push(v);
        } else if let Some((i, _)) = pool.iter().enumerate().min_by_key(|(_, b)| b.capacity()) {
            // Keep the larger buffers.
            if pool[i].capacity() < v.capacity() {
                pool[i] = v;
            }
        }
    }
}
