//! The one place CPU work fans out (pbrt's `ParallelFor`): every launch is
//! labelled, and results never depend on the thread count because each index
//! is computed independently and written to its own slot. Each launch also
//! feeds [`meter`] (progress for long renders; off unless enabled).

pub mod meter;

use rayon::prelude::*;

/// Fills `out[i] = f(i)` in parallel over chunks of `grain` items.
pub fn par_map_into<T: Send>(
    label: &'static str,
    out: &mut [T],
    grain: usize,
    f: impl Fn(usize) -> T + Sync,
) {
    let _span = tracing::debug_span!("par_for", label, n = out.len()).entered();
    let launch = meter::GLOBAL.open(label, out.len());
    out.par_chunks_mut(grain.max(1))
        .enumerate()
        .for_each(|(c, chunk)| {
            let base = c * grain.max(1);
            for (k, slot) in chunk.iter_mut().enumerate() {
                *slot = f(base + k);
            }
            launch.advance(chunk.len());
        });
}

/// Runs `f(chunk_index, chunk)` over `grain`-sized chunks of `out` in parallel.
pub fn par_chunks<T: Send>(
    label: &'static str,
    out: &mut [T],
    grain: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let _span = tracing::debug_span!("par_chunks", label, n = out.len()).entered();
    let launch = meter::GLOBAL.open(label, out.len());
    out.par_chunks_mut(grain.max(1))
        .enumerate()
        .for_each(|(c, chunk)| {
            let n = chunk.len();
            f(c, chunk);
            launch.advance(n);
        });
}

/// [`par_chunks`] over two slices cut into the same chunks: `f(c, a_c,
/// b_c)` with `grain_a` elements of `a` and `grain_b` of `b` per chunk.
pub fn par_chunks2<A: Send, B: Send>(
    label: &'static str,
    (a, grain_a): (&mut [A], usize),
    (b, grain_b): (&mut [B], usize),
    f: impl Fn(usize, &mut [A], &mut [B]) + Sync,
) {
    let _span = tracing::debug_span!("par_chunks2", label, n = a.len()).entered();
    let launch = meter::GLOBAL.open(label, a.len());
    a.par_chunks_mut(grain_a.max(1))
        .zip(b.par_chunks_mut(grain_b.max(1)))
        .enumerate()
        .for_each(|(c, (ca, cb))| {
            let n = ca.len();
            f(c, ca, cb);
            launch.advance(n);
        });
}

/// Maps `0..n` to a vector in parallel (index order is kept).
pub fn par_collect<T: Send>(
    label: &'static str,
    n: usize,
    f: impl Fn(usize) -> T + Sync + Send,
) -> Vec<T> {
    let _span = tracing::debug_span!("par_collect", label, n).entered();
    let launch = meter::GLOBAL.open(label, n);
    (0..n)
        .into_par_iter()
        .map(|i| {
            let v = f(i);
            launch.advance(1);
            v
        })
        .collect()
}

/// Runs `f` on a pool of `threads` threads (0 = rayon's default).
pub fn with_threads<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
        Ok(pool) => pool.install(f),
        Err(_) => f(),
    }
}

/// Runs `f(i, item)` for every item in parallel. Items carry disjoint
/// mutable borrows (tiles of an output), so each writes only its own slots.
pub fn par_each<T: Send>(label: &'static str, items: Vec<T>, f: impl Fn(usize, T) + Sync + Send) {
    let _span = tracing::debug_span!("par_each", label, n = items.len()).entered();
    let launch = meter::GLOBAL.open(label, items.len());
    items.into_par_iter().enumerate().for_each(|(i, t)| {
        f(i, t);
        launch.advance(1);
    });
}

/// Sorts `v` in parallel (unstable: equal elements are indistinguishable).
pub fn par_sort<T: Ord + Send>(label: &'static str, v: &mut [T]) {
    let _span = tracing::debug_span!("par_sort", label, n = v.len()).entered();
    v.par_sort_unstable();
}
