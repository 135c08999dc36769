//! Distance constraints: stretch on edges, shear and bend between particles two edges
//! apart (the NvCloth cooker's classification), with hard stretch and compression limits.

use std::ops::Range;

use glam::{Vec3, Vec3A, Vec4};

use super::xpbd_delta;

/// What a distance constraint models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// A mesh edge.
    Stretch,
    /// Two edges apart around a corner (a quad's other diagonal).
    Shear,
    /// Two edges apart along a nearly straight path.
    Bend,
}

/// One distance constraint `C = |x_i - x_j| - rest`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distance {
    /// First particle.
    pub i: u32,
    /// Second particle.
    pub j: u32,
    /// Rest length (m).
    pub rest: f32,
    /// Compliance (m/N).
    pub compliance: f32,
    /// Shortest allowed length (m), enforced hard.
    pub min: f32,
    /// Longest allowed length (m), enforced hard.
    pub max: f32,
}

/// A distance constraint prepared for a fixed substep length and fixed masses: the XPBD
/// update of a constraint solved once per substep is `len' = len - k (len - rest)` with
/// `k = w / (w + alpha / h^2)`, `w = w_i + w_j`, clamped to `[min, max]`; particle i takes
/// the share `w_i / w` of the change and j the rest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prepared {
    /// First particle.
    pub i: u32,
    /// Second particle.
    pub j: u32,
    /// Rest length (m).
    pub rest: f32,
    /// Stiffness factor `w / (w + alpha / h^2)` in [0, 1].
    pub k: f32,
    /// Shortest allowed length (m).
    pub min: f32,
    /// Longest allowed length (m).
    pub max: f32,
    /// Share of particle i, `w_i / w` (0 if both particles are pinned).
    pub share_i: f32,
    /// Share of particle j.
    pub share_j: f32,
}

impl Prepared {
    /// Prepares `c` for inverse masses `wi`, `wj` and `1 / h^2 = inv_h2`.
    pub fn new(c: &Distance, wi: f32, wj: f32, inv_h2: f32) -> Self {
        let w = wi + wj;
        let (k, share_i, share_j) = if w == 0.0 {
            (0.0, 0.0, 0.0)
        } else {
            (w / (w + c.compliance * inv_h2), wi / w, wj / w)
        };
        Self {
            i: c.i,
            j: c.j,
            rest: c.rest,
            k,
            min: c.min,
            max: c.max,
            share_i,
            share_j,
        }
    }

    /// Corrections `(dx_i, dx_j)` at positions `xi`, `xj` (SIMD vectors: the solver's hot
    /// loop); the same as [`solve`].
    #[inline]
    pub fn solve(&self, xi: Vec3A, xj: Vec3A) -> (Vec3A, Vec3A) {
        let d = xi - xj;
        let len2 = d.length_squared();
        if len2 < 1e-24 {
            return (Vec3A::ZERO, Vec3A::ZERO);
        }
        let len = len2.sqrt();
        let target = (len - self.k * (len - self.rest)).clamp(self.min, self.max);
        let n = d * ((target - len) / len);
        (n * self.share_i, n * -self.share_j)
    }

    /// Solves the constraint once, moving its two particles in `x`.
    #[inline]
    pub fn apply(&self, x: &mut [Vec3A]) {
        let (i, j) = (self.i as usize, self.j as usize);
        let (di, dj) = self.solve(x[i], x[j]);
        x[i] += di;
        x[j] += dj;
    }
}

/// Four constraints of one colour (no particle in common), prepared to be solved together:
/// the lengths, square roots and divisions of the four in one SIMD vector each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Batch {
    /// First particles.
    pub i: [u32; 4],
    /// Second particles.
    pub j: [u32; 4],
    /// Rest lengths (m).
    pub rest: Vec4,
    /// Stiffness factors.
    pub k: Vec4,
    /// Shortest allowed lengths (m).
    pub min: Vec4,
    /// Longest allowed lengths (m).
    pub max: Vec4,
    /// Shares of the first particles.
    pub share_i: Vec4,
    /// Shares of the second particles.
    pub share_j: Vec4,
}

impl Batch {
    fn new(c: &[Prepared; 4]) -> Self {
        let lanes = |f: fn(&Prepared) -> f32| Vec4::from_array(c.each_ref().map(f));
        Self {
            i: c.each_ref().map(|c| c.i),
            j: c.each_ref().map(|c| c.j),
            rest: lanes(|c| c.rest),
            k: lanes(|c| c.k),
            min: lanes(|c| c.min),
            max: lanes(|c| c.max),
            share_i: lanes(|c| c.share_i),
            share_j: lanes(|c| c.share_j),
        }
    }

    /// The constraint of lane `l`.
    fn lane(&self, l: usize) -> Prepared {
        Prepared {
            i: self.i[l],
            j: self.j[l],
            rest: self.rest[l],
            k: self.k[l],
            min: self.min[l],
            max: self.max[l],
            share_i: self.share_i[l],
            share_j: self.share_j[l],
        }
    }
}

/// One Gauss-Seidel sweep over distance constraints in colour order, four constraints of a
/// colour at a time. Constraints of one colour share no particle, so the order inside a
/// colour does not matter: the sweep gives the same bits as solving the constraints one by
/// one with [`Prepared::solve`] (each lane does the same operations in the same order;
/// a batch with a near-zero length falls back to that scalar path).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Sweep {
    batches: Vec<Batch>,
    singles: Vec<Prepared>,
    /// Per colour: its batches, then its leftover constraints.
    colours: Vec<(Range<usize>, Range<usize>)>,
}

impl Sweep {
    /// Groups `prepared` (sorted by colour, `colours` its ranges of one colour each).
    ///
    /// # Panics
    /// If two constraints of one colour share a particle.
    pub fn new(prepared: &[Prepared], colours: &[Range<usize>]) -> Self {
        let mut sweep = Self::default();
        for range in colours {
            let group = &prepared[range.clone()];
            let mut seen = std::collections::HashSet::with_capacity(2 * group.len());
            for c in group {
                assert!(
                    seen.insert(c.i) && seen.insert(c.j),
                    "constraints of one colour share particle {} or {}",
                    c.i,
                    c.j
                );
            }
            let b0 = sweep.batches.len();
            let s0 = sweep.singles.len();
            let chunks = group.chunks_exact(4);
            sweep.singles.extend_from_slice(chunks.remainder());
            for chunk in chunks {
                sweep
                    .batches
                    .push(Batch::new(chunk.try_into().expect("chunks of four")));
            }
            sweep
                .colours
                .push((b0..sweep.batches.len(), s0..sweep.singles.len()));
        }
        sweep
    }

    /// Number of constraints.
    pub fn len(&self) -> usize {
        4 * self.batches.len() + self.singles.len()
    }

    /// True if there are no constraints.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Solves every constraint once, in colour order, moving `x`.
    pub fn run(&self, x: &mut [Vec3A]) {
        for (batches, singles) in &self.colours {
            for b in &self.batches[batches.clone()] {
                solve_batch(b, x);
            }
            for c in &self.singles[singles.clone()] {
                c.apply(x);
            }
        }
    }
}

/// The particles in two halves, each in a block of its own in a buffer that the solve
/// stage works on: half 0 at the start, half 1 from `split` (a multiple of four particles,
/// 64 bytes, so at most one cache line straddles the two), each in increasing particle
/// order. The halves are
/// the particles either side of the median of the rest shape along its longest extent, so
/// few constraints join them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Halves {
    /// Per buffer slot: its particle (`u32::MAX` for the padding between the halves).
    order: Vec<u32>,
    /// Per particle: its buffer slot.
    slot: Vec<u32>,
    /// Where half 1 starts in the buffer.
    split: usize,
}

impl Halves {
    /// Splits the particles at `rest`.
    pub fn new(rest: &[Vec3]) -> Self {
        let n = rest.len();
        let (lo, hi) = crate::mesh::bounds(rest).unwrap_or_default();
        let extent = hi - lo;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let mut by_axis: Vec<u32> = (0..n as u32).collect();
        by_axis.sort_by(|&a, &b| {
            rest[a as usize][axis]
                .total_cmp(&rest[b as usize][axis])
                .then(a.cmp(&b))
        });
        let mut half = vec![false; n];
        for &p in &by_axis[n / 2..] {
            half[p as usize] = true;
        }
        let first: Vec<u32> = (0..n as u32).filter(|&p| !half[p as usize]).collect();
        let split = first.len().div_ceil(4) * 4;
        let mut order = first;
        order.resize(split, u32::MAX);
        order.extend((0..n as u32).filter(|&p| half[p as usize]));
        let mut slot = vec![0; n];
        for (k, &p) in order.iter().enumerate() {
            if p != u32::MAX {
                slot[p as usize] = k as u32;
            }
        }
        Self { order, slot, split }
    }

    /// Length of the buffer.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// Where half 1 starts in the buffer.
    pub fn split(&self) -> usize {
        self.split
    }

    /// True if there are no particles.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Copies the particles' positions `x` into the buffer, given as its two parts `a`
    /// (before [`Halves::split`]) and `b`.
    pub fn gather(&self, x: &[Vec3A], a: &mut [Vec3A], b: &mut [Vec3A]) {
        let (oa, ob) = self.order.split_at(self.split);
        for (dst, order) in [(a, oa), (b, ob)] {
            for (d, &p) in dst.iter_mut().zip(order) {
                if p != u32::MAX {
                    *d = x[p as usize];
                }
            }
        }
    }

    /// Copies the buffer's two parts `a` and `b` back to the particles' positions `x`.
    pub fn scatter(&self, a: &[Vec3A], b: &[Vec3A], x: &mut [Vec3A]) {
        let split = self.split as u32;
        for (p, &k) in x.iter_mut().zip(&self.slot) {
            *p = if k < split {
                a[k as usize]
            } else {
                b[(k - split) as usize]
            };
        }
    }
}

/// A sweep split for two threads: the constraints inside each half (numbered from the
/// half's start in the buffer of [`Halves`]), which can run at the same time, then those
/// that join the halves (numbered in the buffer). Each group keeps the colour order. The
/// halves share no particle, so the result does not depend on whether they run one after
/// the other or at once: the same bits on one thread or two.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SplitSweep {
    halves: [Sweep; 2],
    joins: Vec<Prepared>,
    split: u32,
}

impl SplitSweep {
    /// Groups `prepared` (particle indices; sorted by colour, `colours` its ranges of one
    /// colour each) for `halves`.
    pub fn new(prepared: &[Prepared], colours: &[Range<usize>], halves: &Halves) -> Self {
        let mut inside: [(Vec<Prepared>, Vec<Range<usize>>); 2] = Default::default();
        let mut joins = Vec::new();
        let split = halves.split as u32;
        for range in colours {
            let starts = inside.each_ref().map(|g| g.0.len());
            for c in &prepared[range.clone()] {
                let (i, j) = (halves.slot[c.i as usize], halves.slot[c.j as usize]);
                match (i < split, j < split) {
                    (true, true) => inside[0].0.push(Prepared { i, j, ..*c }),
                    (false, false) => inside[1].0.push(Prepared {
                        i: i - split,
                        j: j - split,
                        ..*c
                    }),
                    _ => joins.push(Prepared { i, j, ..*c }),
                }
            }
            for (g, start) in inside.iter_mut().zip(starts) {
                let end = g.0.len();
                g.1.push(start..end);
            }
        }
        Self {
            halves: inside.map(|(p, c)| Sweep::new(&p, &c)),
            joins,
            split,
        }
    }

    /// Number of constraints: inside the halves, and joining them.
    pub fn len(&self) -> (usize, usize) {
        (
            self.halves[0].len() + self.halves[1].len(),
            self.joins.len(),
        )
    }

    /// True if there are no constraints.
    pub fn is_empty(&self) -> bool {
        self.len() == (0, 0)
    }

    /// Solves the constraints inside half `h` (0 or 1) once, moving `x` (that half's part
    /// of the buffer).
    pub fn run_half(&self, h: usize, x: &mut [Vec3A]) {
        self.halves[h].run(x);
    }

    /// Solves the constraints that join the halves once, in colour order, moving `a` and
    /// `b` (the halves' parts of the buffer).
    pub fn run_joins(&self, a: &mut [Vec3A], b: &mut [Vec3A]) {
        let split = self.split;
        for c in &self.joins {
            let get = |k: u32, a: &[Vec3A], b: &[Vec3A]| {
                if k < split {
                    a[k as usize]
                } else {
                    b[(k - split) as usize]
                }
            };
            let (di, dj) = c.solve(get(c.i, a, b), get(c.j, a, b));
            for (k, d) in [(c.i, di), (c.j, dj)] {
                if k < split {
                    a[k as usize] += d;
                } else {
                    b[(k - split) as usize] += d;
                }
            }
        }
    }

    /// Solves every constraint once on this thread, moving `buf` (the buffer of
    /// [`Halves`]): half 0, half 1, then the joins.
    pub fn run(&self, buf: &mut [Vec3A]) {
        let (a, b) = buf.split_at_mut(self.split as usize);
        self.run_half(0, a);
        self.run_half(1, b);
        self.run_joins(a, b);
    }
}

#[inline]
fn solve_batch(b: &Batch, x: &mut [Vec3A]) {
    let d: [Vec3A; 4] = std::array::from_fn(|l| x[b.i[l] as usize] - x[b.j[l] as usize]);
    let len2 = Vec4::from_array(d.map(|d| d.length_squared()));
    if len2.cmplt(Vec4::splat(1e-24)).any() {
        // As `Prepared::solve`: no correction for a constraint of zero length.
        for l in 0..4 {
            b.lane(l).apply(x);
        }
        return;
    }
    let len = len2.sqrt();
    let target = (len - b.k * (len - b.rest)).max(b.min).min(b.max);
    let s = ((target - len) / len).to_array();
    let (si, sj) = (b.share_i.to_array(), b.share_j.to_array());
    for l in 0..4 {
        let n = d[l] * s[l];
        x[b.i[l] as usize] += n * si[l];
        x[b.j[l] as usize] += n * -sj[l];
    }
}

/// Corrections `(dx_i, dx_j)` of one distance constraint at positions `xi`, `xj`.
#[inline]
pub fn solve(c: &Distance, xi: Vec3, xj: Vec3, wi: f32, wj: f32, inv_h2: f32) -> (Vec3, Vec3) {
    let w = wi + wj;
    if w == 0.0 {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    let d = xi - xj;
    let len = d.length();
    if len < 1e-12 {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    let n = d / len;
    // Soft part, then the hard limits on the softly corrected length.
    let dl = xpbd_delta(len - c.rest, w, c.compliance * inv_h2);
    let soft = len + w * dl;
    let target = soft.clamp(c.min, c.max);
    let total = (target - len) / w;
    (n * (wi * total), n * (-wj * total))
}

/// Classifies the pair `(a, c)` reached from `a` through `b`: the NvCloth cooker's ratio
/// `|(a - b) x (c - b)| / |c - a|^2` is 0 on a straight path and 0.5 at a right angle.
/// Bend below 0.1; shear from 0.35 to 0.6 (around a quad's right-angled corner, where
/// NvCloth's shear score peaks at 0.45); otherwise neither (NvCloth also sums its scores over
/// all paths between a pair; here the first path that classifies decides).
pub fn classify(a: Vec3, b: Vec3, c: Vec3) -> Option<Kind> {
    let ac = (c - a).length_squared();
    if ac < 1e-20 {
        return None;
    }
    let ratio = (a - b).cross(c - b).length() / ac;
    if ratio < 0.1 {
        Some(Kind::Bend)
    } else if (0.35..=0.6).contains(&ratio) {
        Some(Kind::Shear)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stiff_constraint_restores_length_and_keeps_the_centre_of_mass() {
        let c = Distance {
            i: 0,
            j: 1,
            rest: 1.0,
            compliance: 0.0,
            min: 0.0,
            max: f32::MAX,
        };
        let (xi, xj) = (Vec3::ZERO, Vec3::new(1.5, 0.0, 0.0));
        let (di, dj) = solve(&c, xi, xj, 1.0, 3.0, 1e4);
        assert!(((xi + di).distance(xj + dj) - 1.0).abs() < 1e-6);
        assert!(
            (di * 1.0 + dj * (1.0 / 3.0)).length() < 1e-6,
            "momentum kept with masses 1 and 1/3"
        );
    }

    #[test]
    fn soft_constraint_yields_and_limits_hold() {
        let soft = Distance {
            i: 0,
            j: 1,
            rest: 1.0,
            compliance: 1.0,
            min: 0.0,
            max: f32::MAX,
        };
        let (di, dj) = solve(&soft, Vec3::ZERO, Vec3::X * 2.0, 1.0, 1.0, 1.0);
        let len = (Vec3::X * 2.0 + dj - di).length();
        // w = 2, alpha~ = 1: the length moves 2/3 of the way, to 2 - 2/3.
        assert!((len - (2.0 - 2.0 / 3.0)).abs() < 1e-5, "{len}");
        let limited = Distance { max: 1.1, ..soft };
        let (di, dj) = solve(&limited, Vec3::ZERO, Vec3::X * 2.0, 1.0, 1.0, 1.0);
        assert!(((Vec3::X * 2.0 + dj - di).length() - 1.1).abs() < 1e-5);
    }

    #[test]
    fn prepared_form_matches_the_direct_update() {
        let c = Distance {
            i: 0,
            j: 1,
            rest: 1.0,
            compliance: 0.3,
            min: 0.8,
            max: 1.05,
        };
        let cases = [
            (Vec3::new(1.3, 0.2, 0.0), 1.0, 2.0),
            (Vec3::new(0.5, 0.0, 0.1), 0.0, 1.0),
            (Vec3::new(1.02, 0.0, 0.0), 3.0, 0.5),
        ];
        for (xj, wi, wj) in cases {
            let (a, b) = solve(&c, Vec3::ZERO, xj, wi, wj, 10.0);
            let (p, q) = Prepared::new(&c, wi, wj, 10.0).solve(Vec3A::ZERO, xj.into());
            let (p, q) = (Vec3::from(p), Vec3::from(q));
            assert!(
                a.distance(p) < 1e-6 && b.distance(q) < 1e-6,
                "{a} {p} / {b} {q}"
            );
        }
    }

    #[test]
    fn sweep_gives_the_bits_of_one_constraint_at_a_time() {
        // A chain of 21 particles: colour 0 the even links (10, so two batches of four and
        // two left over), colour 1 the odd ones (10); one particle pinned, two coincident.
        let mut x: Vec<Vec3A> = (0..21)
            .map(|k| {
                let t = k as f32;
                Vec3A::new(
                    0.011 * t + 0.003 * (t * 1.7).sin(),
                    0.002 * (t * 2.3).cos(),
                    0.0,
                )
            })
            .collect();
        x[7] = x[6];
        let w: Vec<f32> = (0..21)
            .map(|k| if k == 0 { 0.0 } else { 1.0 + 0.1 * k as f32 })
            .collect();
        let mut prepared = Vec::new();
        for parity in [0, 1] {
            for a in (parity..20).step_by(2) {
                let c = Distance {
                    i: a as u32,
                    j: a as u32 + 1,
                    rest: 0.01,
                    compliance: 1e-7 * a as f32,
                    min: 0.008,
                    max: 0.0105,
                };
                prepared.push(Prepared::new(&c, w[a], w[a + 1], 3.6e5));
            }
        }
        let colours = [0..10, 10..20];
        let sweep = Sweep::new(&prepared, &colours);
        assert_eq!(sweep.len(), 20);
        let start = x.clone();
        let mut expected = x.clone();
        for c in &prepared {
            let (i, j) = (c.i as usize, c.j as usize);
            let (di, dj) = c.solve(expected[i], expected[j]);
            expected[i] += di;
            expected[j] += dj;
        }
        sweep.run(&mut x);
        for (a, b) in x.iter().zip(&expected) {
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits)
            );
        }
        // It did something: every particle but the pinned one moved.
        let moved = x.iter().zip(&start).filter(|(a, b)| a != b).count();
        assert_eq!(moved, 20);
    }

    #[test]
    #[should_panic(expected = "share particle")]
    fn a_colour_whose_constraints_share_a_particle_is_refused() {
        let c = |i, j| {
            Prepared::new(
                &Distance {
                    i,
                    j,
                    rest: 1.0,
                    compliance: 0.0,
                    min: 0.0,
                    max: 2.0,
                },
                1.0,
                1.0,
                1.0,
            )
        };
        Sweep::new(&[c(0, 1), c(1, 2)], std::slice::from_ref(&(0..2)));
    }

    #[test]
    fn classification_follows_the_path_shape() {
        let b = Vec3::ZERO;
        assert_eq!(classify(-Vec3::X, b, Vec3::X), Some(Kind::Bend));
        assert_eq!(classify(-Vec3::X, b, Vec3::Y), Some(Kind::Shear));
        // Equilateral corner (120 degrees): neither.
        let c = Vec3::new(0.5, 3f32.sqrt() / 2.0, 0.0);
        assert_eq!(classify(-Vec3::X, b, c), None);
        // A sharp corner (60 degrees, ratio 0.87): neither.
        let sharp = Vec3::new(-0.5, 3f32.sqrt() / 2.0, 0.0);
        assert_eq!(classify(-Vec3::X, b, sharp), None);
    }
}
