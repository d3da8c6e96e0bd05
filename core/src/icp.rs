//! Trimmed ICP on fixed correspondences (docs/algorithm.md, section 3, step 3).
//!
//! The pairs are not re-matched: each iteration keeps the `k` smallest residuals of the currently
//! transformed sources, fits a rigid transform to them and applies it to every source. Without a
//! tolerance band the fit is the closed-form 2D Kabsch, exactly the paper's. With a band the
//! objective (squared distance to the band's edge) has no closed form: each iteration takes a
//! damped Newton step on it, halved until the trimmed objective does not grow, and the trim ranks
//! the newest pairs as fitting ([`IcpParams::untrimmed_newest`]).

use crate::matching::Correspondence;
use crate::se2::{distance, Se2};

/// Trimmed ICP parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpParams {
    /// Fraction of pairs trimmed as outliers (rho); `k = max(2, floor((1 - rho) |C|))` are kept.
    pub trim_ratio: f64,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Stop when the mean kept residual changes by less than this (metres).
    pub tolerance_m: f64,
    /// Dead band around each target (metres): a source within this distance of its target has
    /// zero residual, one farther away is pulled only onto the band's edge. 0 is the paper's
    /// point-to-point ICP.
    pub tolerance_band_m: f64,
    /// With a band: how many of the last pairs (the newest matched poses) rank as fitting (zero
    /// residual) in the trim, whatever their residuals (see
    /// [`crate::params::Params::untrimmed_newest`]). Without a band the trim is the paper's.
    pub untrimmed_newest: usize,
}

/// The outcome of one trimmed ICP run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IcpResult {
    /// The correction `corrected_from_current` to apply to the sources (map plane).
    pub transform: Se2,
    /// Mean residual of the kept pairs after the last fit (metres).
    pub residual_m: f64,
    /// Iterations run.
    pub iterations: usize,
}

/// Reusable buffers so that a run allocates nothing once warm.
#[derive(Clone, Debug, Default)]
pub struct IcpScratch {
    sources: Vec<[f64; 2]>,
    targets: Vec<[f64; 2]>,
    residuals: Vec<f64>,
    sorted: Vec<u64>,
    kept: Vec<u32>,
    trial_sources: Vec<[f64; 2]>,
    trial_residuals: Vec<f64>,
    trial_kept: Vec<u32>,
    active: Vec<u32>,
    /// The last trim's cut (metres): where the next one is looked for first.
    last_cut: f64,
}

impl IcpScratch {
    /// The pairs the last run kept after its last trim (indices into its pairs, ascending).
    pub fn kept(&self) -> &[u32] {
        &self.kept
    }

    /// The last run's sources moved by its fit (metres, map plane), in pair order.
    pub fn fitted_sources(&self) -> &[[f64; 2]] {
        &self.sources
    }

    /// Readies the buffers for a run on up to `pairs` pairs ([`crate::headroom::make_room`]).
    pub(crate) fn make_room(&mut self, pairs: usize) {
        use crate::headroom::make_room;
        make_room(&mut self.sources, pairs);
        make_room(&mut self.targets, pairs);
        make_room(&mut self.residuals, pairs);
        make_room(&mut self.sorted, pairs);
        make_room(&mut self.kept, pairs);
        make_room(&mut self.trial_sources, pairs);
        make_room(&mut self.trial_residuals, pairs);
        make_room(&mut self.trial_kept, pairs);
        make_room(&mut self.active, pairs);
    }
}

/// How many pairs trimmed ICP keeps out of `pairs`.
pub fn kept_count(pairs: usize, trim_ratio: f64) -> usize {
    let k = ((1.0 - trim_ratio) * pairs as f64).floor() as usize;
    k.max(2).min(pairs)
}

/// The least-squares rigid transform `target_from_source` for paired points (closed-form 2D
/// Kabsch: the rotation maximising the trace, always proper, det = +1).
pub fn fit_rigid(sources: &[[f64; 2]], targets: &[[f64; 2]], kept: &[u32]) -> Se2 {
    let n = kept.len() as f64;
    let (mut cs, mut cd) = ([0.0; 2], [0.0; 2]);
    for &i in kept {
        let (s, d) = (sources[i as usize], targets[i as usize]);
        cs = [cs[0] + s[0], cs[1] + s[1]];
        cd = [cd[0] + d[0], cd[1] + d[1]];
    }
    cs = [cs[0] / n, cs[1] / n];
    cd = [cd[0] / n, cd[1] / n];
    let (mut dot, mut crs) = (0.0, 0.0);
    for &i in kept {
        let s = sources[i as usize];
        let d = targets[i as usize];
        let (sx, sy) = (s[0] - cs[0], s[1] - cs[1]);
        let (dx, dy) = (d[0] - cd[0], d[1] - cd[1]);
        dot += sx * dx + sy * dy;
        crs += sx * dy - sy * dx;
    }
    let h = (dot * dot + crs * crs).sqrt();
    let (c, s) = if h > 0.0 {
        (dot / h, crs / h)
    } else {
        (1.0, 0.0)
    };
    let t = [
        cd[0] - (c * cs[0] - s * cs[1]),
        cd[1] - (s * cs[0] + c * cs[1]),
    ];
    Se2::from_rotation(c, s, t[0], t[1])
}

/// The residual of `source` against the disc of radius `band` around `target` (metres).
#[inline]
fn band_residual(source: [f64; 2], target: [f64; 2], band: f64) -> f64 {
    (distance(source, target) - band).max(0.0)
}

/// Sums over a trim's kept pairs, in the order the kept set lists them (ascending index): of
/// their residuals (metres; over `k`, the mean the iterations stop on) and of the residuals'
/// squares (m^2, the trimmed objective). Summed while the set is built, so that the iterations
/// do not walk it again. With the trim's cut, the largest residual ranked as kept (metres).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct KeptSums {
    residuals: f64,
    squares: f64,
    cut: f64,
}

impl KeptSums {
    #[inline]
    fn add(&mut self, r: f64) {
        self.residuals += r;
        self.squares += r.powi(2);
    }
}

/// How far from a guessed cut (relative) [`keep_smallest`] looks for the cut before it selects
/// among every residual. On KITTI 00 (LiDAR, kiss-icp) 98 % of the trims find it there, among 13
/// residuals on average instead of the 100-200 outside the band (1/16: 96 %, 7 residuals).
const CUT_BRACKET: f64 = 0.125;

/// The indices of the `k` smallest residuals (finite, never negative), in index order, ties at
/// the cut going to the lowest indices: the set a stable sort by residual would keep. Residuals
/// from index `fitting_from` on rank as zero (their sums are of their own residuals). Linear
/// time.
///
/// `guess` is where the cut is expected (metres; the last trim's, whose residuals differ by one
/// small step): when the cut lies within [`CUT_BRACKET`] of it, the selection runs on the few
/// residuals there instead of all. Only the time depends on it, not the result.
fn keep_smallest(
    residuals: &[f64],
    k: usize,
    fitting_from: usize,
    guess: f64,
    sorted: &mut Vec<u64>,
    kept: &mut Vec<u32>,
) -> KeptSums {
    kept.clear();
    let mut sums = KeptSums::default();
    let n = residuals.len();
    if k >= n {
        kept.extend(0..n as u32);
        residuals.iter().for_each(|&r| sums.add(r));
        return sums;
    }
    let from = fitting_from.min(n);
    let ranked = &residuals[..from];
    // Residuals are never negative, and with a tolerance band most are zero (poses inside it):
    // the cut is looked for among the others only.
    let zeros = count_where(ranked, |r| r == 0.0) + (n - from);
    let (cut, below) = if zeros >= k {
        (0.0, 0)
    } else {
        // `k < n`, so fewer than `k - zeros` of the ranked residuals are positive.
        let (cut, smaller) = select_cut(ranked, k - zeros, guess, sorted);
        (cut, zeros + smaller)
    };
    sums.cut = cut;
    let mut ties_kept = k - below;
    for (i, &r) in ranked.iter().enumerate() {
        if r < cut {
            kept.push(i as u32);
            sums.add(r);
        } else if r == cut && ties_kept > 0 {
            kept.push(i as u32);
            sums.add(r);
            ties_kept -= 1;
        }
    }
    // The fitting tail ranks as zero: all of it lies below a positive cut; at a zero cut it
    // ties, and the ties left go to its lowest indices.
    let tail_kept = if cut > 0.0 { n - from } else { ties_kept };
    for (i, &r) in residuals.iter().enumerate().skip(from).take(tail_kept) {
        kept.push(i as u32);
        sums.add(r);
    }
    sums
}

/// The `m`-th smallest (from 1) positive value of `ranked`, and how many positive values are
/// smaller; at least `m` must be positive. Positive floats order as their bits do, so
/// the selection compares integers; it runs on the values within [`CUT_BRACKET`] of `guess`
/// when the answer lies there, else on every positive value.
fn select_cut(ranked: &[f64], m: usize, guess: f64, sorted: &mut Vec<u64>) -> (f64, usize) {
    if guess > 0.0 && guess.is_finite() {
        let (lo, hi) = (guess * (1.0 - CUT_BRACKET), guess * (1.0 + CUT_BRACKET));
        sorted.clear();
        let under = count_where(ranked, |r| r != 0.0 && r < lo);
        sorted.extend(
            ranked
                .iter()
                .filter(|&&r| r >= lo && r <= hi)
                .map(|r| r.to_bits()),
        );
        if under < m && m <= under + sorted.len() {
            return select_in(sorted, m - under - 1, under);
        }
    }
    sorted.clear();
    sorted.extend(ranked.iter().filter(|&&r| r != 0.0).map(|r| r.to_bits()));
    select_in(sorted, m - 1, 0)
}

/// The value at sorted position `nth` of `bits` (positive floats' bits), and how many values
/// are smaller, plus `under` (values known smaller that `bits` does not hold).
fn select_in(bits: &mut [u64], nth: usize, under: usize) -> (f64, usize) {
    let (left, &mut cut, _) = bits.select_nth_unstable(nth);
    let smaller = under + count_where(left, |r| r < cut);
    (f64::from_bits(cut), smaller)
}

/// How many of `values` pass `test`. The count is at most `values.len()`, so it is summed
/// without overflow checks: the checked sum `Iterator::count` compiles to in a build that checks
/// overflow (the release profile does) keeps the loop from being vectorised, and the trim runs
/// it over every residual of the window at every ICP iteration.
fn count_where<T: Copy>(values: &[T], test: impl Fn(T) -> bool) -> usize {
    values
        .iter()
        .fold(0, |n: usize, &v| n.wrapping_add(usize::from(test(v))))
}

/// Runs trimmed ICP on fixed pairs. Needs at least two pairs (the caller checks the match ratio
/// first); with fewer it returns the identity and an infinite residual.
///
/// With a tolerance band `b > 0` it minimises the trimmed sum of squared band residuals (see
/// `band_newton_step`); with `b = 0` it is exactly the paper's (docs/algorithm.md, section 3).
pub fn trimmed_icp(
    pairs: &[Correspondence],
    params: &IcpParams,
    scratch: &mut IcpScratch,
) -> IcpResult {
    let n = pairs.len();
    if n < 2 {
        return IcpResult {
            transform: Se2::IDENTITY,
            residual_m: f64::INFINITY,
            iterations: 0,
        };
    }
    let band = params.tolerance_band_m;
    scratch.sources.clear();
    scratch.sources.extend(pairs.iter().map(|c| c.source));
    scratch.targets.clear();
    scratch.targets.extend(pairs.iter().map(|c| c.target));
    fill_band_residuals(
        &scratch.sources,
        &scratch.targets,
        band,
        &mut scratch.residuals,
    );
    if band > 0.0 {
        banded_icp(n, params, scratch)
    } else {
        paper_icp(n, params, scratch)
    }
}

/// The paper's iteration: trim, Kabsch on the kept pairs, apply to every source.
fn paper_icp(n: usize, params: &IcpParams, scratch: &mut IcpScratch) -> IcpResult {
    let k = kept_count(n, params.trim_ratio);
    let IcpScratch {
        sources,
        targets,
        residuals,
        sorted,
        kept,
        last_cut,
        ..
    } = scratch;
    let mut transform = Se2::IDENTITY;
    let mut previous = f64::INFINITY;
    let mut residual_m = f64::INFINITY;
    let mut iterations = 0;
    while iterations < params.max_iterations {
        iterations += 1;
        *last_cut = keep_smallest(residuals, k, usize::MAX, *last_cut, sorted, kept).cut;
        let step = fit_rigid(sources, targets, kept);
        for (s, (r, &q)) in sources
            .iter_mut()
            .zip(residuals.iter_mut().zip(targets.iter()))
        {
            *s = step.apply(*s);
            *r = distance(*s, q);
        }
        transform = step * transform;
        residual_m = mean_kept(residuals, kept, k);
        if (previous - residual_m).abs() < params.tolerance_m {
            break;
        }
        previous = residual_m;
    }
    IcpResult {
        transform,
        residual_m,
        iterations,
    }
}

/// Halvings of a Newton step before the iteration gives up on it.
const MAX_HALVINGS: u32 = 12;

/// The banded iteration: trim, a Newton step on the kept pairs outside the band, halved until the
/// trimmed sum of squares does not grow, apply to every source. Stops when the mean kept residual
/// changes by less than the tolerance or no step reduces the objective.
fn banded_icp(n: usize, params: &IcpParams, scratch: &mut IcpScratch) -> IcpResult {
    let k = kept_count(n, params.trim_ratio);
    let fitting_from = n.saturating_sub(params.untrimmed_newest);
    let band = params.tolerance_band_m;
    let IcpScratch {
        sources,
        targets,
        residuals,
        sorted,
        kept,
        trial_sources,
        trial_residuals,
        trial_kept,
        active,
        last_cut,
    } = scratch;
    let sums = keep_smallest(residuals, k, fitting_from, *last_cut, sorted, kept);
    *last_cut = sums.cut;
    let mut cost = sums.squares;
    let mut residual_m = sums.residuals / k as f64;
    let mut transform = Se2::IDENTITY;
    let mut iterations = 0;
    while iterations < params.max_iterations && cost > 0.0 {
        iterations += 1;
        let Some(full) = band_newton_step(sources, targets, residuals, kept, active) else {
            break;
        };
        let mut accepted = None;
        let mut scale = 1.0;
        for _ in 0..=MAX_HALVINGS {
            let step = full.scaled(scale).transform();
            move_sources(
                &step,
                sources,
                targets,
                band,
                trial_sources,
                trial_residuals,
            );
            let sums = keep_smallest(
                trial_residuals,
                k,
                fitting_from,
                *last_cut,
                sorted,
                trial_kept,
            );
            *last_cut = sums.cut;
            if sums.squares <= cost {
                accepted = Some((step, sums));
                break;
            }
            scale *= 0.5;
        }
        let Some((step, sums)) = accepted else {
            break;
        };
        std::mem::swap(sources, trial_sources);
        std::mem::swap(residuals, trial_residuals);
        std::mem::swap(kept, trial_kept);
        transform = step * transform;
        cost = sums.squares;
        let previous = residual_m;
        residual_m = sums.residuals / k as f64;
        if (previous - residual_m).abs() < params.tolerance_m {
            break;
        }
    }
    IcpResult {
        transform,
        residual_m,
        iterations,
    }
}

/// `out[i]` = the band residual of pair `i` (metres).
fn fill_band_residuals(sources: &[[f64; 2]], targets: &[[f64; 2]], band: f64, out: &mut Vec<f64>) {
    out.clear();
    out.extend(
        sources
            .iter()
            .zip(targets)
            .map(|(&s, &q)| band_residual(s, q, band)),
    );
}

/// `moved[i]` = `sources[i]` moved by `step`, and `residuals[i]` its band residual against
/// `targets[i]` (metres), in one pass.
fn move_sources(
    step: &Se2,
    sources: &[[f64; 2]],
    targets: &[[f64; 2]],
    band: f64,
    moved: &mut Vec<[f64; 2]>,
    residuals: &mut Vec<f64>,
) {
    let n = sources.len();
    moved.resize(n, [0.0; 2]);
    residuals.resize(n, 0.0);
    for ((m, r), (&s, &q)) in moved
        .iter_mut()
        .zip(residuals.iter_mut())
        .zip(sources.iter().zip(targets))
    {
        *m = step.apply(s);
        *r = band_residual(*m, q, band);
    }
}

/// The mean residual of the `k` kept pairs (metres).
fn mean_kept(residuals: &[f64], kept: &[u32], k: usize) -> f64 {
    kept.iter().map(|&i| residuals[i as usize]).sum::<f64>() / k as f64
}

/// A small rigid motion: rotation by `yaw` (radians) about `center` (metres, map plane), then a
/// translation (metres).
#[derive(Clone, Copy, Debug)]
struct LocalStep {
    yaw: f64,
    translation: [f64; 2],
    center: [f64; 2],
}

impl LocalStep {
    fn scaled(&self, f: f64) -> LocalStep {
        LocalStep {
            yaw: self.yaw * f,
            translation: [self.translation[0] * f, self.translation[1] * f],
            center: self.center,
        }
    }

    /// The motion as a transform: `x -> R (x - c) + c + t`.
    fn transform(&self) -> Se2 {
        let rotation = Se2::new(self.yaw, 0.0, 0.0);
        let r = rotation.apply(self.center);
        let (cos, sin) = rotation.rotation();
        Se2::from_rotation(
            cos,
            sin,
            self.center[0] + self.translation[0] - r[0],
            self.center[1] + self.translation[1] - r[1],
        )
    }
}

/// One Newton step on `F = 1/2 sum (|x_i - q_i| - b)^2` over the kept pairs outside the band
/// (those inside have zero residual and zero gradient), parametrised by a rotation about their
/// centroid and a translation. The Hessian keeps each residual's full curvature in the point
/// (`u u^T` across the disc's edge plus `(rho / d) (I - u u^T)` along it) and drops only the
/// rotation's own second derivative, so it is positive semi-definite; a relative damping of
/// 1e-9 of its trace makes it definite where the pairs leave a direction free (a straight road),
/// and there the gradient has no component, so the step does not move along it. `None` when no
/// kept pair lies outside the band. `residuals` are the band residuals of `sources`; `active`
/// is scratch for the indices of the pairs outside the band, so that the sums visit only those
/// (a third of the kept pairs on KITTI) and take no square root for the others.
fn band_newton_step(
    sources: &[[f64; 2]],
    targets: &[[f64; 2]],
    residuals: &[f64],
    kept: &[u32],
    active: &mut Vec<u32>,
) -> Option<LocalStep> {
    // A pair is outside the band exactly when its band residual is positive (`d - band > 0`
    // if and only if `d > band`): those are the pairs the step sums over, in kept order.
    active.clear();
    active.extend(
        kept.iter()
            .copied()
            .filter(|&i| residuals[i as usize] > 0.0),
    );
    if active.is_empty() {
        return None;
    }
    let mut center = [0.0; 2];
    for &i in active.iter() {
        let s = sources[i as usize];
        center = [center[0] + s[0], center[1] + s[1]];
    }
    let count = active.len() as f64;
    center = [center[0] / count, center[1] / count];
    let mut h = nalgebra::Matrix3::<f64>::zeros();
    let mut g = nalgebra::Vector3::<f64>::zeros();
    for &i in active.iter() {
        let (s, q) = (sources[i as usize], targets[i as usize]);
        let d = distance(s, q);
        let rho = residuals[i as usize];
        let u = [(s[0] - q[0]) / d, (s[1] - q[1]) / d];
        let w = [-(s[1] - center[1]), s[0] - center[0]];
        // M = u u^T + (rho / d) (I - u u^T), the point's curvature.
        let f = rho / d;
        let m = [
            [u[0] * u[0] * (1.0 - f) + f, u[0] * u[1] * (1.0 - f)],
            [u[0] * u[1] * (1.0 - f), u[1] * u[1] * (1.0 - f) + f],
        ];
        let mw = [
            m[0][0] * w[0] + m[0][1] * w[1],
            m[1][0] * w[0] + m[1][1] * w[1],
        ];
        h[(0, 0)] += w[0] * mw[0] + w[1] * mw[1];
        h[(0, 1)] += mw[0];
        h[(0, 2)] += mw[1];
        h[(1, 1)] += m[0][0];
        h[(1, 2)] += m[0][1];
        h[(2, 2)] += m[1][1];
        g[0] += rho * (u[0] * w[0] + u[1] * w[1]);
        g[1] += rho * u[0];
        g[2] += rho * u[1];
    }
    h[(1, 0)] = h[(0, 1)];
    h[(2, 0)] = h[(0, 2)];
    h[(2, 1)] = h[(1, 2)];
    let damping = 1e-9 * h.trace().max(f64::MIN_POSITIVE);
    for j in 0..3 {
        h[(j, j)] += damping;
    }
    let delta = h.cholesky()?.solve(&-g);
    delta.iter().all(|v| v.is_finite()).then_some(LocalStep {
        yaw: delta[0],
        translation: [delta[1], delta[2]],
        center,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Lcg;

    #[test]
    fn recovers_a_known_transform_with_ten_percent_outliers() {
        let mut rng = Lcg(42);
        let truth = Se2::new(0.05, 2.0, -1.5);
        let mut pairs = Vec::new();
        for i in 0..200 {
            let s = [rng.uniform() * 100.0, rng.uniform() * 40.0];
            let mut q = truth.apply(s);
            if i % 10 == 3 {
                // Gross outliers: 5-20 m off.
                q = [
                    q[0] + 5.0 + 15.0 * rng.uniform(),
                    q[1] - 5.0 - 15.0 * rng.uniform(),
                ];
            }
            pairs.push(Correspondence {
                index: i,
                source: s,
                target: q,
                point: 0,
            });
        }
        let params = IcpParams {
            trim_ratio: 0.1,
            max_iterations: 50,
            tolerance_m: 1e-8,
            tolerance_band_m: 0.0,
            untrimmed_newest: 0,
        };
        let r = trimmed_icp(&pairs, &params, &mut IcpScratch::default());
        assert!(r.residual_m < 1e-9, "residual {}", r.residual_m);
        assert!((r.transform.yaw() - truth.yaw()).abs() < 1e-12);
        let [x, y] = r.transform.translation();
        assert!((x - 2.0).abs() < 1e-9 && (y + 1.5).abs() < 1e-9);
    }

    #[test]
    fn a_tolerance_band_pulls_only_onto_its_edge() {
        // Sources 0.5 m and 2.5 m beside a line of targets: with a 1 m band the close ones are
        // already fine, so the fit moves the set until the far ones reach the band's edge.
        let pairs: Vec<Correspondence> = (0..100)
            .map(|i| {
                let x = (i / 2) as f64;
                let offset = if i % 2 == 0 { 0.5 } else { 2.5 };
                Correspondence {
                    index: i,
                    source: [x, offset],
                    target: [x, 0.0],
                    point: 0,
                }
            })
            .collect();
        let params = |band| IcpParams {
            trim_ratio: 0.0,
            max_iterations: 50,
            tolerance_m: 1e-12,
            tolerance_band_m: band,
            untrimmed_newest: 0,
        };
        let paper = trimmed_icp(&pairs, &params(0.0), &mut IcpScratch::default());
        assert!(
            (paper.transform.translation()[1] + 1.5).abs() < 1e-9,
            "to the mean"
        );
        let banded = trimmed_icp(&pairs, &params(1.0), &mut IcpScratch::default());
        let dy = banded.transform.translation()[1];
        assert!(
            (dy + 1.5).abs() < 1e-6,
            "far ones onto the edge at 1 m: {dy}"
        );
        assert!(banded.residual_m < 1e-6, "{}", banded.residual_m);
        assert!(banded.transform.yaw().abs() < 1e-9);
    }

    #[test]
    fn kabsch_never_reflects() {
        // Mirror-image targets: a reflection would fit them exactly. The fit must instead be
        // the best proper rotation: orientation kept, and no rotation angle fits better.
        let src = [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [2.0, 1.0]];
        let dst: Vec<[f64; 2]> = src.iter().map(|p| [p[0], -p[1]]).collect();
        let t = fit_rigid(&src, &dst, &[0, 1, 2, 3, 4]);
        let cost = |t: &Se2| -> f64 {
            src.iter()
                .zip(&dst)
                .map(|(s, d)| {
                    let p = t.apply(*s);
                    (p[0] - d[0]).powi(2) + (p[1] - d[1]).powi(2)
                })
                .sum()
        };
        let area = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        };
        let (a, b, c) = (src[0], src[1], src[4]);
        assert!(area(t.apply(a), t.apply(b), t.apply(c)) * area(a, b, c) > 0.0);
        let centroid = |v: &[[f64; 2]]| {
            let n = v.len() as f64;
            [
                v.iter().map(|p| p[0]).sum::<f64>() / n,
                v.iter().map(|p| p[1]).sum::<f64>() / n,
            ]
        };
        let (cs, cd) = (centroid(&src), centroid(&dst));
        let best = (0..3600)
            .map(|k| {
                let yaw = k as f64 * std::f64::consts::TAU / 3600.0;
                let r = Se2::new(yaw, 0.0, 0.0).apply(cs);
                cost(&Se2::new(yaw, cd[0] - r[0], cd[1] - r[1]))
            })
            .fold(f64::INFINITY, f64::min);
        assert!(cost(&t) <= best + 1e-9, "{} vs {best}", cost(&t));
        // The reflection would have cost 0: a proper fit cannot reach it.
        assert!(cost(&t) > 1.0, "{}", cost(&t));
    }

    #[test]
    fn keeps_the_smallest_with_ties_to_the_lowest_index() {
        let (mut sorted, mut kept) = (Vec::new(), Vec::new());
        keep_smallest(
            &[3.0, 1.0, 2.0, 1.0, 2.0, 2.0, 0.5],
            4,
            usize::MAX,
            0.0,
            &mut sorted,
            &mut kept,
        );
        assert_eq!(kept, vec![1, 2, 3, 6]);
        keep_smallest(&[1.0, 1.0, 1.0], 2, usize::MAX, 0.0, &mut sorted, &mut kept);
        assert_eq!(kept, vec![0, 1]);
        // Zeros (inside a tolerance band) decide alone, or with the smallest of the rest.
        keep_smallest(
            &[0.0, 2.0, 0.0, 1.0, 0.0],
            2,
            usize::MAX,
            0.0,
            &mut sorted,
            &mut kept,
        );
        assert_eq!(kept, vec![0, 2]);
        keep_smallest(
            &[0.0, 2.0, 0.0, 1.0, 1.0],
            3,
            usize::MAX,
            0.0,
            &mut sorted,
            &mut kept,
        );
        assert_eq!(kept, vec![0, 2, 3]);
        // A guessed cut changes where the cut is looked for, not what is kept: 2.0 holds it
        // (three smaller, three ties), 1.0 does not (the cut lies above its bracket).
        for guess in [2.0, 1.0, 0.5, 10.0] {
            let residuals = [3.0, 1.0, 2.0, 1.0, 2.0, 2.0, 0.5];
            let sums = keep_smallest(&residuals, 4, usize::MAX, guess, &mut sorted, &mut kept);
            assert_eq!(kept, vec![1, 2, 3, 6]);
            assert_eq!(sums.cut, 2.0);
        }
    }

    #[test]
    fn the_newest_rank_as_fitting() {
        let (mut sorted, mut kept) = (Vec::new(), Vec::new());
        // The two largest residuals are the newest: ranked as zero, they are kept and the cut
        // falls among the others.
        let residuals = [0.0, 0.5, 0.0, 0.3, 0.0, 2.0, 3.0];
        keep_smallest(&residuals, 6, usize::MAX, 0.0, &mut sorted, &mut kept);
        assert_eq!(kept, vec![0, 1, 2, 3, 4, 5]);
        let sums = keep_smallest(&residuals, 6, 5, 0.0, &mut sorted, &mut kept);
        assert_eq!(kept, vec![0, 2, 3, 4, 5, 6]);
        // The sums are of the kept pairs' own residuals, the newest ones' too.
        assert_eq!(sums.residuals, 0.3 + 2.0 + 3.0);
        assert_eq!(sums.squares, 0.3f64.powi(2) + 4.0 + 9.0);
        // Where the others fit, the newest do not make the fit run: ties at zero go to the lowest
        // indices, so the kept set is the older zeros.
        let residuals = [0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 3.0];
        keep_smallest(&residuals, 5, 5, 0.0, &mut sorted, &mut kept);
        assert_eq!(kept, vec![0, 1, 2, 3, 4]);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 256, rng_seed: proptest::test_runner::RngSeed::Fixed(5), ..Default::default() })]
        /// Residuals on a coarse grid (many ties and zeros), any `k`, fitting tail and guessed
        /// cut: the kept set is what a stable sort by rank keeps, and the sums are of the kept
        /// residuals.
        #[test]
        fn the_trim_keeps_what_a_stable_sort_keeps(
            steps in proptest::collection::vec(0u8..8, 1..80),
            k_frac in 0.0f64..1.0,
            tail in 0usize..5,
            guess in 0.0f64..2.5,
        ) {
            let residuals: Vec<f64> = steps.iter().map(|&s| f64::from(s) * 0.25).collect();
            let n = residuals.len();
            let k = 1 + (k_frac * n as f64) as usize % n;
            let fitting_from = n.saturating_sub(tail);
            let (mut sorted, mut kept) = (Vec::new(), Vec::new());
            let sums = keep_smallest(&residuals, k, fitting_from, guess, &mut sorted, &mut kept);
            let rank = |i: usize| if i >= fitting_from { 0.0 } else { residuals[i] };
            let mut want: Vec<u32> = (0..n as u32).collect();
            want.sort_by(|&a, &b| rank(a as usize).total_cmp(&rank(b as usize)));
            want.truncate(k);
            want.sort_unstable();
            proptest::prop_assert_eq!(&kept, &want);
            let kept_residuals = || want.iter().map(|&i| residuals[i as usize]);
            proptest::prop_assert_eq!(sums.residuals, kept_residuals().sum::<f64>());
            proptest::prop_assert_eq!(sums.squares, kept_residuals().map(|r| r.powi(2)).sum::<f64>());
        }
    }

    /// A straight lane along x; the older 40 poses of 50 lie inside the band, 6 beyond it by a
    /// drift of `0.5 m` and the newest 4 by twice that. With a 10 % trim the newest are the
    /// outliers the paper's trim drops; ranked as fitting they pull the fit with the others.
    #[test]
    fn untrimmed_newest_matches_pull_the_fit() {
        let pairs: Vec<Correspondence> = (0..50)
            .map(|i| {
                let lateral = match i {
                    0..40 => 0.5,
                    40..46 => 1.5,
                    _ => 2.0,
                };
                let x = i as f64;
                Correspondence {
                    index: i,
                    source: [x, lateral],
                    target: [x, 0.0],
                    point: 0,
                }
            })
            .collect();
        let fit = |untrimmed_newest| {
            let params = IcpParams {
                trim_ratio: 0.1,
                max_iterations: 50,
                tolerance_m: 1e-12,
                tolerance_band_m: 1.0,
                untrimmed_newest,
            };
            trimmed_icp(&pairs, &params, &mut IcpScratch::default())
        };
        let trimmed = fit(0);
        let kept = fit(4);
        // Where the newest pose ends up across the lane (metres). Trimmed: the fit pulls the 6
        // onto the band's edge and leaves the newest 1 m beyond it; kept, they pull too and the
        // newest ends up nearer the lane.
        let newest = |r: &IcpResult| r.transform.apply(pairs[49].source)[1];
        assert!(
            (newest(&trimmed) - 1.5).abs() < 1e-6,
            "{}",
            newest(&trimmed)
        );
        assert!(newest(&kept) < 1.4, "{}", newest(&kept));
    }

    #[test]
    fn kept_count_follows_the_spec() {
        assert_eq!(kept_count(100, 0.1), 90);
        assert_eq!(kept_count(2, 0.1), 2);
        assert_eq!(kept_count(25, 0.1), 22);
    }
}
