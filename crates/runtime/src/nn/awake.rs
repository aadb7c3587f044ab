//! Keeping the pool's workers awake through a burst of small parallel kernels.
//!
//! A U-Net step forks ~150 kernels, many of them tens of microseconds long. Between two of
//! them an idle rayon worker spins only briefly, then sleeps on a futex, and the next fork
//! wakes it: a system call for the waker and, in a virtual machine, an inter-processor
//! interrupt that exits to the hypervisor. Measured on a 2-core KVM guest (Intel, AVX-512):
//! about 150 sleeps per CPU-sized training step at 256, and 8% of the step's samples in the
//! kernel's wake-up and schedule paths. [`with_workers_awake`] keeps the other workers polling
//! for work instead, for the length of one call.

use rayon::Yield;
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, Ordering};

/// Runs `f` on a worker of the current rayon pool while every other worker polls the pool for
/// jobs (executing them as they appear) instead of going to sleep, until `f` returns or
/// panics. Results do not change: the same jobs run, only sooner. With one thread this is
/// `rayon::scope(|_| f())`.
///
/// Meant for short bursts of fine-grained parallel work (a training step, a frame); the
/// pollers occupy their cores for the whole call.
pub fn with_workers_awake<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    let done = AtomicBool::new(false);
    rayon::scope(|s| {
        for _ in 1..rayon::current_num_threads() {
            let done = &done;
            s.spawn(move |_| poll_until(done));
        }
        // Cleared on return and on unwinding alike: the scope waits for the pollers.
        let _body = Body::enter(&done);
        f()
    })
}

thread_local! {
    /// Bodies of [`with_workers_awake`] running on this thread (nested or suspended ones
    /// included).
    static BODIES: Cell<u32> = const { Cell::new(0) };
}

/// A body of [`with_workers_awake`] running on this thread; sets the pollers' flag when it
/// ends.
struct Body<'a>(&'a AtomicBool);

impl<'a> Body<'a> {
    fn enter(done: &'a AtomicBool) -> Self {
        BODIES.with(|b| b.set(b.get() + 1));
        Body(done)
    }
}

impl Drop for Body<'_> {
    fn drop(&mut self) {
        BODIES.with(|b| b.set(b.get() - 1));
        self.0.store(true, Ordering::Release);
    }
}

/// Executes the pool's pending jobs until `done`. Returns at once on a thread that is running
/// a body: a worker waiting inside a body can pick up a poller (its own or another caller's),
/// and polling there would hold the body under it until the poller's own body ends, which
/// can wait on this one (two concurrent callers would deadlock).
fn poll_until(done: &AtomicBool) {
    if BODIES.with(Cell::get) > 0 {
        return;
    }
    let mut idle = 0u32;
    while !done.load(Ordering::Acquire) {
        match rayon::yield_now() {
            Some(Yield::Executed) => idle = 0,
            _ => {
                idle = idle.wrapping_add(1);
                // Mostly a pause; now and then a yield to the OS, so that a thread that
                // shares this core (another program, or a test runner's thread) gets it.
                if idle.is_multiple_of(64) {
                    std::thread::yield_now();
                } else {
                    std::hint::spin_loop();
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn returns_f_and_runs_nested_work() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let sum = pool.install(|| {
            with_workers_awake(|| {
                (0..200)
                    .map(|i| (0..1000u64).into_par_iter().map(|x| x * i).sum::<u64>())
                    .sum::<u64>()
            })
        });
        assert_eq!(sum, (0..200u64).sum::<u64>() * (0..1000u64).sum::<u64>());
    }

    #[test]
    fn concurrent_callers_finish() {
        // Four callers on one 2-thread pool: a worker waiting inside one body steals the
        // other's poller; both must still finish (without the body check in `poll_until`
        // this deadlocks).
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        std::thread::scope(|ts| {
            for k in 0..4u64 {
                let pool = &pool;
                ts.spawn(move || {
                    for _ in 0..20 {
                        let s = pool.install(|| {
                            with_workers_awake(|| (0..10_000u64).into_par_iter().sum::<u64>())
                        });
                        assert_eq!(s, 49_995_000, "caller {k}");
                    }
                });
            }
        });
    }

    #[test]
    fn callers_inside_parallel_work_finish() {
        // Bodies running side by side on the pool's workers, each forking work of its own.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        for _ in 0..50 {
            let sums: Vec<u64> = pool.install(|| {
                (0..8u64)
                    .into_par_iter()
                    .map(|i| {
                        with_workers_awake(|| (0..5_000u64).into_par_iter().map(|x| x + i).sum())
                    })
                    .collect()
            });
            for (i, s) in sums.iter().enumerate() {
                assert_eq!(*s, 12_497_500 + 5_000 * i as u64);
            }
        }
    }

    #[test]
    fn a_body_that_picks_up_a_poller_finishes() {
        // The other worker is kept busy (it steals the join's older half first), so the
        // body's own `yield_now` pops its poller from the local queue. Polling there would
        // wait for the body under it forever: run it on a thread with a deadline.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap();
            let r = pool.install(|| {
                rayon::join(
                    || {
                        with_workers_awake(|| {
                            rayon::yield_now();
                            7
                        })
                    },
                    || std::thread::sleep(std::time::Duration::from_millis(50)),
                )
                .0
            });
            let _ = tx.send(r);
        });
        let r = rx.recv_timeout(std::time::Duration::from_secs(20));
        assert_eq!(r, Ok(7), "with_workers_awake deadlocked");
    }

    #[test]
    fn a_panic_stops_the_pollers() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            pool.install(|| with_workers_awake(|| panic!("inside")))
        }));
        assert!(r.is_err());
        // The pool still works (no poller left spinning forever).
        assert_eq!(pool.install(|| (0..10u32).into_par_iter().sum::<u32>()), 45);
    }
}
