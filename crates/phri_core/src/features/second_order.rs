//! What a feature reports for the Newton optimiser's second-order model of the cost: the segment's
//! second derivatives ([`SegmentHessian`]) and the hinge pieces that are off now but may turn on
//! within a step ([`Pieces`]).

/// Inactive hinge pieces for the optimiser's model. A piece is a term ½·c·max(0, f)² of the cost
/// whose argument f, at the point q(s) = q_{i-1} + s·(q_i − q_{i-1}) of a segment, is f0 ≤ 0 now
/// and varies as f0 + a·Δq(s) with a step Δ. The model adds it once a step would turn it on, so a
/// Newton step does not run blindly across a kink (e.g. back into a keep-out circle).
#[derive(Debug, Clone)]
pub struct Pieces {
    n: usize,
    segment: usize,
    pub(crate) list: Vec<Piece>,
    pub(crate) a: Vec<f64>,
}

/// One entry of [`Pieces`]: at waypoints (segment − 1, segment), parameter s; f0; curvature c.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Piece {
    pub(crate) segment: usize,
    pub(crate) s: f64,
    pub(crate) f0: f64,
    pub(crate) c: f64,
}

impl Pieces {
    /// Empty, for `n` joints.
    pub fn new(n: usize) -> Self {
        Pieces { n, segment: 0, list: Vec::new(), a: Vec::new() }
    }

    /// Number of joints n (each piece's a has n entries).
    pub fn dof(&self) -> usize {
        self.n
    }

    /// Number of pieces.
    pub fn len(&self) -> usize {
        self.list.len()
    }

    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    pub fn clear(&mut self) {
        self.list.clear();
        self.a.clear();
    }

    /// The segment (its end waypoint i) that following pushes belong to.
    pub(crate) fn set_segment(&mut self, i: usize) {
        self.segment = i;
    }

    /// Adds the piece ½·`c`·max(0, f)² with f = `f0` + Σ_j a(j)·Δq_j(s) at the point q(s).
    pub fn push(&mut self, s: f64, f0: f64, c: f64, a: impl Fn(usize) -> f64) {
        self.list.push(Piece { segment: self.segment, s, f0, c });
        self.a.extend((0..self.n).map(a));
    }
}

/// Second derivatives of one segment's cost with respect to (q_{i-1}, q_i): a symmetric 2n × 2n
/// matrix, row-major, q_{i-1} first. Features add to it with the helpers below; a quantity of the
/// point q(s) = q_{i-1} + s·(q_i − q_{i-1}) with derivative v and Hessian H in q maps to the segment
/// as [(1−s)v, s·v] and [[(1−s)²H, s(1−s)H], [s(1−s)H, s²H]]. Terms at the same s are summed in
/// an n × n buffer and mapped once.
#[derive(Debug, Clone)]
pub struct SegmentHessian {
    n: usize,
    /// Whether to include second derivatives of the kinematics (see [`SegmentHessian::kinematic`]).
    kinematic: bool,
    m: Vec<f64>,
    v: Vec<f64>,
    /// Pending n × n Hessian at the point `pending`.
    h: Vec<f64>,
    pending: Option<f64>,
    tmp: Vec<f64>,
    tmp2: Vec<f64>,
}

impl SegmentHessian {
    /// A zero matrix for `n` joints.
    pub fn new(n: usize) -> Self {
        SegmentHessian {
            n,
            kinematic: true,
            m: vec![0.0; 4 * n * n],
            v: vec![0.0; n],
            h: vec![0.0; n * n],
            pending: None,
            tmp: vec![0.0; n * n],
            tmp2: vec![0.0; n],
        }
    }

    /// Number of joints n (the matrix is 2n × 2n).
    pub fn dof(&self) -> usize {
        self.n
    }

    /// Whether the caller wants the terms with second derivatives of the kinematics (∂²p/∂q²,
    /// ∂²R/∂q²) of features that act at every waypoint (table, coffee, origin). True for the exact
    /// Hessian ([`FeatureSet::weighted_cost_curvature`]); the optimiser asks without them until
    /// its active set settles (`TrajoptParams::kinematic_curvature`): far from the optimum they
    /// make its model indefinite along the whole path and force heavy damping, while their
    /// Gauss–Newton part models these features well. Keep-out features keep them near their kink,
    /// where they decide the final convergence.
    pub fn kinematic(&self) -> bool {
        self.kinematic
    }

    pub(super) fn set_kinematic(&mut self, on: bool) {
        self.kinematic = on;
    }

    /// Entry (r, c), r and c in 0..2n (terms still pending are not included; see `flush`).
    pub fn get(&self, r: usize, c: usize) -> f64 {
        self.m[r * 2 * self.n + c]
    }

    /// The 2n × 2n matrix, row-major, after [`SegmentHessian::flush`].
    pub fn matrix(&self) -> &[f64] {
        &self.m
    }

    /// Sets every entry to 0.
    pub fn clear(&mut self) {
        self.m.fill(0.0);
        self.h.fill(0.0);
        self.pending = None;
    }

    /// Adds `weight`·[[I, −I], [−I, I]] (the Hessian of weight·‖q_i − q_{i-1}‖²/2).
    pub fn add_difference(&mut self, weight: f64) {
        let (n, w) = (self.n, 2 * self.n);
        for j in 0..n {
            self.m[j * w + j] += weight;
            self.m[(n + j) * w + n + j] += weight;
            self.m[j * w + n + j] -= weight;
            self.m[(n + j) * w + j] -= weight;
        }
    }

    fn pending_at(&mut self, s: f64) {
        if self.pending != Some(s) {
            self.flush();
            self.pending = Some(s);
        }
    }

    /// Maps the pending n × n terms into the segment's matrix.
    pub fn flush(&mut self) {
        let Some(s) = self.pending.take() else { return };
        let (n, w) = (self.n, 2 * self.n);
        let (aa, ab, bb) = ((1.0 - s) * (1.0 - s), s * (1.0 - s), s * s);
        for r in 0..n {
            for c in 0..n {
                let x = self.h[r * n + c];
                if bb != 0.0 {
                    self.m[(n + r) * w + n + c] += bb * x;
                }
                if aa != 0.0 {
                    self.m[r * w + c] += aa * x;
                }
                if ab != 0.0 {
                    self.m[r * w + n + c] += ab * x;
                    self.m[(n + r) * w + c] += ab * x;
                }
            }
        }
        self.h.fill(0.0);
    }

    /// Adds `weight`·u·uᵀ with u = [(1−s)v, s·v] and v_j = `v(j)`, the derivative in q of a quantity
    /// at the point q(s) (a Gauss–Newton term).
    pub fn add_outer(&mut self, s: f64, weight: f64, v: impl Fn(usize) -> f64) {
        self.pending_at(s);
        let n = self.n;
        for j in 0..n {
            self.v[j] = v(j);
        }
        for r in 0..n {
            let vr = weight * self.v[r];
            if vr == 0.0 {
                continue;
            }
            for c in 0..n {
                self.h[r * n + c] += vr * self.v[c];
            }
        }
    }

    /// Adds `weight`·u·uᵀ with u = [a, b], a_j = `a(j)` the derivative in q_{i-1} and b_j = `b(j)`
    /// the derivative in q_i of a quantity of the whole segment (e.g. a step p(q_i) − p(q_{i-1})).
    pub fn add_outer_pair(&mut self, weight: f64, a: impl Fn(usize) -> f64, b: impl Fn(usize) -> f64) {
        let (n, w) = (self.n, 2 * self.n);
        for j in 0..n {
            self.v[j] = a(j);
            self.tmp2[j] = b(j);
        }
        for r in 0..2 * n {
            let ur = weight * if r < n { self.v[r] } else { self.tmp2[r - n] };
            if ur == 0.0 {
                continue;
            }
            for c in 0..2 * n {
                let uc = if c < n { self.v[c] } else { self.tmp2[c - n] };
                self.m[r * w + c] += ur * uc;
            }
        }
    }

    /// The n × n matrix the curvature helpers fill (exposed for custom features): fill it with a
    /// Hessian in q at a point, then call [`SegmentHessian::add_scratch_at`].
    pub fn scratch(&mut self) -> &mut [f64] {
        &mut self.tmp
    }

    /// Adds `weight`·(the scratch matrix) as the Hessian at the point q(s).
    pub fn add_scratch_at(&mut self, s: f64, weight: f64) {
        self.pending_at(s);
        for (h, t) in self.h.iter_mut().zip(&self.tmp) {
            *h += weight * t;
        }
    }
}
