//! phri's two hand-written banded kernels against faer, the maintained library the project would
//! otherwise use, on the same matrices in one run: a kernel is hand-written only where it is
//! measurably faster.
//!
//! - The Newton optimiser's system: a symmetric positive definite block-tridiagonal matrix of
//!   N − 2 blocks of 7 × 7 (N = 31 and 100 waypoints). phri: `BlockCholesky` (block Thomas),
//!   factor + solve. faer: sparse LLᵀ with the symbolic analysis done once and only the numeric
//!   factorisation + solve timed; and faer's dense LLᵀ of the same matrix.
//! - The deformation's norm R = AᵀA for a 10,000-waypoint window (pentadiagonal 6, −4, 1): the
//!   shape H = R⁻¹e₁. phri factors once in double-double arithmetic and applies μ·H·u_H per
//!   correction; faer factors R once in f64 and solves per correction. Printed with the timings:
//!   each H's relative error against the closed form H[k] ∝ (k+1)(m−k)(m+1−k) — in f64 the
//!   factorisation of this κ ~ m⁴ matrix loses four digits, which is why phri does not use it.
//!
//! `cargo bench -p phri_benches --bench linalg`

use std::hint::black_box;

use criterion::{criterion_group, BenchmarkId, Criterion};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};
use phri_core::deform::{DeformParams, Deformation};
use phri_core::trajopt::block_tridiagonal::{BlockCholesky, BlockTridiagonal, Damping};

const NQ: usize = 7;

/// A random diagonally dominant SPD block-tridiagonal matrix with `blocks` blocks of 7 × 7, as
/// (phri's form, its lower triangle as faer triplets).
fn system(blocks: usize) -> (BlockTridiagonal, Vec<Triplet<usize, usize, f64>>) {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let (mut diag, mut off) = (vec![0.0; blocks * NQ * NQ], vec![0.0; blocks * NQ * NQ]);
    for b in 0..blocks {
        for r in 0..NQ {
            for c in 0..=r {
                let v = uniform();
                diag[(b * NQ + r) * NQ + c] = v;
                diag[(b * NQ + c) * NQ + r] = v;
            }
            diag[(b * NQ + r) * NQ + r] += 4.0 * NQ as f64;
        }
        if b + 1 < blocks {
            for k in 0..NQ * NQ {
                off[b * NQ * NQ + k] = uniform();
            }
        }
    }
    let mut h = BlockTridiagonal::new(NQ, blocks);
    let mut triplets = Vec::new();
    for b in 0..blocks {
        for r in 0..NQ {
            for c in 0..NQ {
                let (row, col) = (b * NQ + r, b * NQ + c);
                h.add(row, col, diag[(b * NQ + r) * NQ + c]);
                if row >= col {
                    triplets.push(Triplet::new(row, col, diag[(b * NQ + r) * NQ + c]));
                }
                if b + 1 < blocks {
                    // Block (b, b+1): rows of waypoint b, columns of waypoint b+1.
                    let v = off[b * NQ * NQ + r * NQ + c];
                    h.add(row, (b + 1) * NQ + c, v);
                    triplets.push(Triplet::new((b + 1) * NQ + c, row, v));
                }
            }
        }
    }
    (h, triplets)
}

fn block_tridiagonal(c: &mut Criterion) {
    let mut group = c.benchmark_group("newton_system_factor_and_solve");
    for waypoints in [31usize, 100] {
        let blocks = waypoints - 2;
        let dim = blocks * NQ;
        let (h, triplets) = system(blocks);
        let rhs: Vec<f64> = (0..dim).map(|k| (k as f64 * 0.37).sin()).collect();
        let fixed = vec![false; dim];
        // phri, and the residual of its solution (computed densely, once).
        let mut chol = BlockCholesky::new(NQ, blocks);
        let mut x = rhs.clone();
        assert!(chol.factor_from(&h, 0, Damping::identity(0.0), &fixed, 0));
        chol.solve(&mut x, 0);
        let dense = Mat::<f64>::from_fn(dim, dim, |r, c| h.get(r, c));
        let residual = (0..dim).map(|r| ((0..dim).map(|c| dense[(r, c)] * x[c]).sum::<f64>() - rhs[r]).abs()).fold(0.0, f64::max);
        eprintln!("N = {waypoints}: phri's block Cholesky residual {residual:.1e}");
        group.bench_function(BenchmarkId::new("phri_block_cholesky", waypoints), |b| {
            b.iter(|| {
                let mut x = rhs.clone();
                chol.factor_from(black_box(&h), 0, Damping::identity(0.0), &fixed, 0);
                chol.solve(&mut x, 0);
                x
            })
        });
        let sparse = SparseColMat::<usize, f64>::try_new_from_triplets(dim, dim, &triplets).expect("valid triplets");
        let symbolic = SymbolicLlt::try_new(sparse.symbolic(), Side::Lower).expect("symbolic LLT");
        group.bench_function(BenchmarkId::new("faer_sparse_llt", waypoints), |b| {
            b.iter(|| {
                let llt = Llt::try_new_with_symbolic(symbolic.clone(), black_box(sparse.as_ref()), Side::Lower)
                    .expect("positive definite");
                let mut x = Mat::<f64>::from_fn(dim, 1, |r, _| rhs[r]);
                llt.solve_in_place(x.as_mut());
                x
            })
        });
        group.bench_function(BenchmarkId::new("faer_dense_llt", waypoints), |b| {
            b.iter(|| {
                let llt = black_box(&dense).llt(Side::Lower).expect("positive definite");
                let mut x = Mat::<f64>::from_fn(dim, 1, |r, _| rhs[r]);
                llt.solve_in_place(x.as_mut());
                x
            })
        });
    }
    group.finish();
}

/// The closed-form acceleration shape of an m-window, scaled to ‖H‖ = √m.
fn closed_form(m: usize) -> Vec<f64> {
    let raw: Vec<f64> = (0..m).map(|k| ((k + 1) * (m - k) * (m + 1 - k)) as f64).collect();
    let norm = raw.iter().map(|v| v * v).sum::<f64>().sqrt();
    raw.iter().map(|v| v * (m as f64).sqrt() / norm).collect()
}

fn max_rel_err(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| ((x - y) / y).abs()).fold(0.0, f64::max)
}

fn deformation(c: &mut Criterion) {
    let m = 10_000;
    let exact = closed_form(m);
    let mut group = c.benchmark_group("deformation_window_10000");
    // phri: one correction of a 7-joint trajectory (μ = 1, unit push on joint 0 reads H back).
    let d = Deformation::new(DeformParams { window: m, mu: 1.0, ..Default::default() }).expect("valid window");
    let mut traj = vec![0.0; (m + 2) * NQ];
    let mut push = [0.0; NQ];
    push[0] = 1.0;
    d.deform_in_place(&mut traj, NQ, 0, &push).expect("valid push");
    let h_phri: Vec<f64> = (0..m).map(|k| traj[(k + 1) * NQ]).collect();
    group.bench_function("phri_deform", |b| {
        b.iter(|| {
            traj.fill(0.0);
            d.deform_in_place(black_box(&mut traj), NQ, 0, &push).expect("valid push")
        })
    });
    // faer: R factored once in f64, H = R⁻¹e₁ solved and normalised per correction.
    let mut triplets = Vec::new();
    for i in 0..m {
        triplets.push(Triplet::new(i, i, 6.0));
        if i + 1 < m {
            triplets.push(Triplet::new(i + 1, i, -4.0));
        }
        if i + 2 < m {
            triplets.push(Triplet::new(i + 2, i, 1.0));
        }
    }
    let r = SparseColMat::<usize, f64>::try_new_from_triplets(m, m, &triplets).expect("valid triplets");
    let symbolic = SymbolicLlt::try_new(r.symbolic(), Side::Lower).expect("symbolic LLT");
    let llt = Llt::try_new_with_symbolic(symbolic, r.as_ref(), Side::Lower).expect("positive definite");
    let solve = || {
        let mut e1 = Mat::<f64>::zeros(m, 1);
        e1[(0, 0)] = 1.0;
        llt.solve_in_place(e1.as_mut());
        let norm = (0..m).map(|k| e1[(k, 0)] * e1[(k, 0)]).sum::<f64>().sqrt();
        (0..m).map(|k| e1[(k, 0)] * (m as f64).sqrt() / norm).collect::<Vec<f64>>()
    };
    let h_faer = solve();
    eprintln!(
        "window {m}: H relative error against the closed form: phri {:.1e}, faer f64 LLT {:.1e}",
        max_rel_err(&h_phri, &exact),
        max_rel_err(&h_faer, &exact)
    );
    group.bench_function("faer_sparse_llt_solve", |b| b.iter(solve));
    group.finish();
}

criterion_group!(benches, block_tridiagonal, deformation);

fn main() {
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
}
