//! How sure a correction is, and how much of it the map's evidence supports
//! (docs/method.md, "Confidence").
//!
//! The corrector carries the covariance of the error of its current corrected pose: planar
//! position (x, y, metres) and heading (yaw, radians), in the map plane, at the newest pose. Three
//! things move it:
//! - **Driving** adds the odometry's drift: a random walk of `drift_var_per_m` m^2 per metre in
//!   position and `yaw_drift_var_per_m` rad^2 per metre in heading, and a heading error turns
//!   every metre driven into position error.
//! - **An accepted alignment** adds the information the matched lanes give: each kept pair
//!   constrains the pose only across its lane (along a straight lane it says nothing), with the
//!   car's wander about the centreline as independent noise and the lane's own offset error
//!   ([`lane_sigma_m`]: tagged or inferred lanes, road class) shared by every pair on that lane.
//!   A sliding window sees the same lanes on many steps, so each step adds only the share of the
//!   window's information that is new: the distance driven since the last accepted step over the
//!   window's path length.
//! - **What is applied.** Of the correction ICP proposes, only the directions in which the
//!   window's information outweighs the current uncertainty by `min_evidence_ratio` are applied
//!   (a generalised eigenproblem of the information against the prior covariance). On a straight
//!   road the along-road direction carries no information, so the pose is not moved along the
//!   road; where the odometry is more certain than the map, it is kept.
//!
//! - **What is published** adds to that filter covariance the map's own error the pose inherits
//!   from the lanes it was last aligned to ([`Alignment::inherited_map_error`]): observations of the same
//!   lanes do not average it away. The filter's covariance alone measures how well the odometry
//!   and the map agree; the published one, how far the pose may be from the world.
//!
//! Hand-written 3x3 algebra on nalgebra's fixed-size matrices: no crate models this filter.

use nalgebra::{Matrix3, Matrix4, RowVector3, SMatrix, SVector, SymmetricEigen, Vector3};

use crate::lane_geometry::{LaneInfo, RoadClass};
use crate::lane_map::LaneMap;
use crate::matching::Correspondence;
use crate::params::Params;
use crate::pose::MAX_COORDINATE_M;
use crate::se2::Se2;
use crate::stall::Widening;

/// Covariance of a planar pose error (x and y in metres, yaw in radians), row-major, in the map
/// plane.
pub type Covariance = [[f64; 3]; 3];

/// The largest magnitude an entry of a covariance may have to be continued from (square metres,
/// metres times radians, square radians): a position sigma of 1e9 m, a hundred times the
/// farthest a pose may lie ([`crate::pose::MAX_COORDINATE_M`]) and beyond what driving
/// accumulates ([`MAX_DRIVEN_VARIANCES`]), while sums and products of a few entries stay finite.
pub const MAX_COVARIANCE_ENTRY: f64 = 1e18;

/// The largest variances the covariance of a driven pose reaches (square metres, square metres,
/// square radians): a position anywhere within the farthest a pose may lie
/// ([`crate::pose::MAX_COORDINATE_M`]) and a heading anywhere on the circle (a sigma of 180
/// degrees, [`crate::params::MAX_SIGMA_YAW_DEG`]). A larger variance says nothing more, and
/// driving grew it without end: the heading's with the distance, the position's with its cube,
/// past [`MAX_COVARIANCE_ENTRY`] after some 1400 km without a lane at the largest heading drift a
/// corrector may be set for (a restarted daemon then started the session afresh).
pub const MAX_DRIVEN_VARIANCES: [f64; 3] = [
    MAX_COORDINATE_M * MAX_COORDINATE_M,
    MAX_COORDINATE_M * MAX_COORDINATE_M,
    std::f64::consts::PI * std::f64::consts::PI,
];

/// Whether `matrix` is a covariance a filter can continue from (one restored from a saved
/// state): every entry finite and within [`MAX_COVARIANCE_ENTRY`], the variances non-negative,
/// and symmetric and positive semi-definite within rounding (1e-9, measured on the matrix of
/// correlations, so that a large variance does not hide a small one's errors). A matrix that
/// is not would turn the filter's variances negative or infinite. A 2x2 covariance is checked
/// as the upper left of a 3x3 one with zeros elsewhere.
pub fn is_covariance(matrix: &Covariance) -> bool {
    is_joint_covariance(matrix, [0.0; 3], 0.0)
}

/// Whether the pose's `covariance`, its covariance with the odometry's scale error
/// (`scale_cross`, [`PoseUncertainty::scale_cross`]) and the scale's variance make one joint
/// covariance a filter can continue from (as [`is_covariance`], of the 4x4 matrix).
pub fn is_joint_covariance(
    covariance: &Covariance,
    scale_cross: [f64; 3],
    scale_variance: f64,
) -> bool {
    const ROUNDING: f64 = 1e-9;
    let joint = |r: usize, c: usize| match (r, c) {
        (3, 3) => scale_variance,
        (3, k) | (k, 3) => scale_cross[k],
        (r, c) => covariance[r][c],
    };
    let entries_valid = (0..4).all(|r| {
        (0..4).all(|c| {
            let v = joint(r, c);
            v.is_finite() && v.abs() <= MAX_COVARIANCE_ENTRY
        })
    });
    if !entries_valid || (0..4).any(|k| joint(k, k) < 0.0) {
        return false;
    }
    // Correlations: each entry over the product of its variances' square roots; an entry
    // beside a zero variance must be zero (within 1e-300, past which nothing is a variance).
    let sd: [f64; 4] = std::array::from_fn(|k| joint(k, k).sqrt());
    let mut correlation = Matrix4::zeros();
    for r in 0..4 {
        for c in 0..4 {
            let scale = sd[r] * sd[c];
            if scale > 1e-300 {
                correlation[(r, c)] = joint(r, c) / scale;
            } else if joint(r, c).abs() > 1e-300 {
                return false;
            }
        }
    }
    // Every eigenvalue at least -ROUNDING: the shifted matrix has a Cholesky factor (a tenth of
    // the cost of the eigenvalues, so that every update of the filter can be checked).
    (correlation - correlation.transpose()).amax() <= ROUNDING
        && (correlation + Matrix4::identity() * ROUNDING)
            .cholesky()
            .is_some()
}

/// How far a car wanders about the centreline of the lane it drives in, independently of the
/// map (metres, 1 sigma).
pub const WANDER_SIGMA_M: f64 = 0.3;

/// Over what stretch a car's wander stays correlated (metres): poses closer than this add less
/// than one independent observation each.
pub const WANDER_CORRELATION_M: f64 = 20.0;

/// How far the centreline of a lane may lie from where cars drive in it (metres, 1 sigma): the
/// lane's offset error, shared by every pose matched to it. Surveyed lanelets are trusted most,
/// OSM lanes whose count was tagged more than those inferred from the road class, unmarked
/// streets and lanes shared by both directions least (cars choose their line there).
pub fn lane_sigma_m(info: LaneInfo) -> f64 {
    if info.class == RoadClass::Lanelet {
        return 0.2;
    }
    if info.has(LaneInfo::SHARED) {
        return 1.0;
    }
    if info.has(LaneInfo::UNMARKED) {
        return 0.7;
    }
    if info.class == RoadClass::Unknown || info.has(LaneInfo::LANES_TAGGED) {
        0.5
    } else {
        0.7
    }
}

/// What an alignment says about the pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Alignment {
    /// The information (inverse covariance) about a small correction `(dx, dy, dyaw)` of the
    /// window taken at the center: each kept pair constrains the distance across its lane.
    pub information: Matrix3<f64>,
    /// The map's own error a pose aligned to the kept pairs inherits (2x2 covariance of x and
    /// y, metres, map plane): each pair's lane is off by its [`lane_sigma_m`] across its
    /// direction, and where the road curves by as much again as its segment's chord error
    /// ([`LaneMap::chord_error_m`]); the pose follows the lanes however often it sees them, so
    /// this does not shrink with more observations, unlike the filter's covariance. The average
    /// over the kept pairs of `MAP_ERROR_VAR_SCALE sigma^2 n n' + chord^2 n n'` (`n` the lane's
    /// normal); `None` without pairs.
    pub inherited_map_error: Option<[[f64; 2]; 2]>,
}

/// What the alignment of the kept pairs' sources after the fit says about a small correction of
/// the window taken at `center` (metres, map plane), and the map error it leaves the pose with.
///
/// `spacing_m[i]` is the path length from window pose `i` to the next (metres; 0 for the newest):
/// a pose stands for that stretch of wander out of [`WANDER_CORRELATION_M`].
pub fn alignment_information(
    map: &LaneMap,
    pairs: &[Correspondence],
    kept: &[u32],
    fitted_sources: &[[f64; 2]],
    center: [f64; 2],
    spacing_m: &[f64],
) -> Alignment {
    let wander_var = WANDER_SIGMA_M * WANDER_SIGMA_M;
    let mut inherited = [[0.0; 2]; 2];
    let mut inherited_count = 0usize;
    let mut information = Matrix3::zeros();
    // Pairs of one stretch of the window share its map offset error ([`Stretch`]).
    let mut block = Stretch::<3>::default();
    for KeptPair {
        k,
        pair,
        direction,
        new_stretch,
    } in kept_pairs_by_stretch(map, pairs, kept, spacing_m)
    {
        if new_stretch {
            information += block.information();
            block = Stretch::default();
        }
        let sigma = lane_sigma_m(map.lane_info()[map.lane_of(pair.point)]);
        let normal = [-direction[1], direction[0]];
        let chord = map.chord_error_m(pair.point);
        let inherited_var = MAP_ERROR_VAR_SCALE * sigma * sigma + chord * chord;
        for (r, row) in inherited.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v += inherited_var * normal[r] * normal[c];
            }
        }
        inherited_count += 1;
        let p = fitted_sources[k];
        let arm = [p[0] - center[0], p[1] - center[1]];
        // d(normal . p) / d(dx, dy, dyaw) for p moved by a rotation about `center`.
        let j = RowVector3::new(
            normal[0],
            normal[1],
            -normal[0] * arm[1] + normal[1] * arm[0],
        );
        let share = (spacing_m[pair.index] / WANDER_CORRELATION_M).clamp(1e-3, 1.0);
        block.add(&j, share / wander_var, sigma * sigma);
    }
    Alignment {
        information: information + block.information(),
        inherited_map_error: (inherited_count > 0)
            .then(|| inherited.map(|row| row.map(|v| v / inherited_count as f64))),
    }
}

/// A kept pair whose lane has a direction, as [`kept_pairs_by_stretch`] yields it.
pub(crate) struct KeptPair<'a> {
    /// Its index into the pairs.
    pub k: usize,
    /// The pair.
    pub pair: &'a Correspondence,
    /// The unit direction of its lane segment (map plane).
    pub direction: [f64; 2],
    /// Whether it begins a new stretch of [`MAP_CORRELATION_M`] of road (the first pair does).
    pub new_stretch: bool,
}

/// The kept pairs (indices into `pairs`, ascending) whose lane has a direction, in window order,
/// each marked where a new stretch of [`MAP_CORRELATION_M`] of road begins: the pairs of one
/// stretch share its map offset error. `spacing_m[i]` is the path length from window pose `i`
/// to the next (metres).
pub(crate) fn kept_pairs_by_stretch<'a>(
    map: &'a LaneMap,
    pairs: &'a [Correspondence],
    kept: &'a [u32],
    spacing_m: &'a [f64],
) -> impl Iterator<Item = KeptPair<'a>> + 'a {
    let mut stretch_start = f64::NEG_INFINITY;
    let mut along = 0.0;
    let mut last_index: Option<usize> = None;
    kept.iter().filter_map(move |&k| {
        let pair = &pairs[k as usize];
        let direction = map.direction_of(pair.point)?;
        if let Some(last) = last_index {
            // Kept pairs are mostly neighbours: one spacing, which its sum equals exactly.
            along += if pair.index == last + 1 {
                spacing_m[last]
            } else {
                spacing_m[last..pair.index].iter().sum::<f64>()
            };
        }
        last_index = Some(pair.index);
        let new_stretch = along - stretch_start >= MAP_CORRELATION_M;
        if new_stretch {
            stretch_start = along;
        }
        Some(KeptPair {
            k: k as usize,
            pair,
            direction,
            new_stretch,
        })
    })
}

/// How much larger than its lanes' sigmas ([`lane_sigma_m`], as variances) the offset error a
/// corrected pose inherits is taken to be. Measured on the shared KITTI runs (docs/method.md,
/// "Confidence"): OSM lanes there are off by up to 1.5-2 m over kilometres (lidar 09), more and
/// longer than the sigmas say. With the curves' chord error beside it, 1, 1.5, 2 and 3 put 10,
/// 12, 11 and 10 of the 20 sequences in the 0.85-0.99 coverage band (without the chord error 2
/// put 10, against 5 without either term).
pub const MAP_ERROR_VAR_SCALE: f64 = 1.5;

/// Over what stretch of road the map's offset error stays the same (metres): OSM ways are
/// traced from the same imagery by the same mappers, so neighbouring lanes are off together.
pub const MAP_CORRELATION_M: f64 = 100.0;

/// The kept pairs of one stretch of the window, summed: each pair's row `J` of the derivative of
/// its distance across its lane, with its own variance `a` (the car's wander) and the stretch's
/// shared map offset variance `b` (the mean of the pairs'). By Sherman-Morrison the stretch's
/// information is `sum(J'J / a) - c (sum J / a)'(sum J / a)` and, given the pairs' residuals `r`
/// ([`Stretch::add_residual`]), its gradient `sum(J' r / a) - c (sum J / a)' (sum r / a)`, with
/// `c = b / (1 + b sum(1 / a))`. `N` is the number of unknowns: 3 for the pose
/// ([`alignment_information`]), 4 with the scale ([`crate::scale::scale_evidence`]).
pub(crate) struct Stretch<const N: usize> {
    sum_jj: SMatrix<f64, N, N>,
    sum_j: SMatrix<f64, 1, N>,
    sum_jr: SVector<f64, N>,
    sum_r: f64,
    sum_inv_a: f64,
    sum_b: f64,
    count: usize,
}

impl<const N: usize> Default for Stretch<N> {
    fn default() -> Self {
        Stretch {
            sum_jj: SMatrix::zeros(),
            sum_j: SMatrix::zeros(),
            sum_jr: SVector::zeros(),
            sum_r: 0.0,
            sum_inv_a: 0.0,
            sum_b: 0.0,
            count: 0,
        }
    }
}

impl<const N: usize> Stretch<N> {
    /// Adds a pair's row `j`, its inverse variance `inv_a` and its lane's offset variance `b`.
    pub(crate) fn add(&mut self, j: &SMatrix<f64, 1, N>, inv_a: f64, b: f64) {
        // `j' j inv_a`, element by element as the matrix product forms it, its upper triangle
        // only: the pairs of a window are summed on every accepted step.
        for r in 0..N {
            for c in r..N {
                self.sum_jj[(r, c)] += j[r] * j[c] * inv_a;
            }
        }
        self.sum_j += j * inv_a;
        self.sum_inv_a += inv_a;
        self.sum_b += b;
        self.count += 1;
    }

    /// Adds the residual of the pair last added (its row `j`, inverse variance `inv_a`), for the
    /// gradient.
    pub(crate) fn add_residual(&mut self, j: &SMatrix<f64, 1, N>, residual: f64, inv_a: f64) {
        self.sum_jr += j.transpose() * (residual * inv_a);
        self.sum_r += residual * inv_a;
    }

    /// `c` of the stretch's shared offset (zero for an empty stretch).
    fn shared(&self) -> f64 {
        if self.count == 0 {
            return 0.0;
        }
        let b = self.sum_b / self.count as f64;
        b / (1.0 + b * self.sum_inv_a)
    }

    /// The stretch's information (zero for an empty stretch).
    pub(crate) fn information(&self) -> SMatrix<f64, N, N> {
        if self.count == 0 {
            return SMatrix::zeros();
        }
        let mut sum_jj = self.sum_jj;
        for r in 0..N {
            for c in 0..r {
                sum_jj[(r, c)] = sum_jj[(c, r)];
            }
        }
        sum_jj - self.sum_j.transpose() * self.sum_j * self.shared()
    }

    /// The stretch's gradient (zero for an empty stretch or one without residuals).
    pub(crate) fn gradient(&self) -> SVector<f64, N> {
        if self.count == 0 {
            return SVector::zeros();
        }
        self.sum_jr - self.sum_j.transpose() * (self.sum_r * self.shared())
    }
}

/// `covariance` with the position's variance grown along `offset` (metres, map plane) by its
/// square: the pose may lie `offset` away (one sigma), where no measurement can tell.
pub fn widened_by(covariance: &Covariance, offset: [f64; 2]) -> Covariance {
    let mut widened = *covariance;
    for r in 0..2 {
        for c in 0..2 {
            widened[r][c] += offset[r] * offset[c];
        }
    }
    widened
}

/// A correction `corrected_from_current` as `(dx, dy, dyaw)` about `center`: the move of
/// `center` (metres) and the rotation (radians).
pub fn correction_at(correction: &Se2, center: [f64; 2]) -> Vector3<f64> {
    let moved = correction.apply(center);
    Vector3::new(moved[0] - center[0], moved[1] - center[1], correction.yaw())
}

/// The rigid transform that moves `center` by `(dx, dy)` and rotates about it by `dyaw`.
pub fn correction_from(xi: &Vector3<f64>, center: [f64; 2]) -> Se2 {
    let (sin, cos) = xi[2].sin_cos();
    let rotated = [
        cos * center[0] - sin * center[1],
        sin * center[0] + cos * center[1],
    ];
    Se2::from_rotation(
        cos,
        sin,
        center[0] + xi[0] - rotated[0],
        center[1] + xi[1] - rotated[1],
    )
}

/// The position block of `covariance` expressed in another plane: `frame_from_map`'s rotation
/// `R` gives `R S R'` (metres^2).
pub fn position_covariance_in(frame_from_map: &Se2, covariance: &Covariance) -> [[f64; 2]; 2] {
    let (c, s) = frame_from_map.rotation();
    let r = [[c, -s], [s, c]];
    let p = [
        [covariance[0][0], covariance[0][1]],
        [covariance[1][0], covariance[1][1]],
    ];
    std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            (0..2)
                .map(|k| (0..2).map(|l| r[i][k] * p[k][l] * r[j][l]).sum::<f64>())
                .sum()
        })
    })
}

/// The uncertainty of a corrector's current pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseUncertainty {
    covariance: Matrix3<f64>,
    /// The covariance of the pose error with the odometry's scale error (metres, metres,
    /// radians; see [`crate::scale`]): a scale error turns every metre driven into position
    /// error along the motion, so the two grow together.
    scale_cross: Vector3<f64>,
}

/// What [`PoseUncertainty::supported`] kept of a proposed correction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Supported {
    /// The correction to apply, `(dx, dy, dyaw)` about the same center (metres, radians).
    pub correction: Vector3<f64>,
    /// How many of the three directions the evidence supports (3: the whole proposal).
    pub directions: usize,
}

impl PoseUncertainty {
    /// The uncertainty at the start: the anchor's (`initial_sigma_m` in x and y,
    /// `initial_sigma_yaw_deg` in yaw).
    pub fn new(params: &Params) -> Self {
        let s = params.initial_sigma_m;
        let y = params.initial_sigma_yaw_deg.to_radians();
        PoseUncertainty {
            covariance: Matrix3::from_diagonal(&Vector3::new(s * s, s * s, y * y)),
            scale_cross: Vector3::zeros(),
        }
    }

    /// A saved uncertainty (see [`PoseUncertainty::covariance`]).
    pub fn from_covariance(covariance: &Covariance) -> Self {
        PoseUncertainty {
            covariance: Matrix3::from_fn(|r, c| covariance[r][c]),
            scale_cross: Vector3::zeros(),
        }
    }

    /// A saved uncertainty with its covariance with the odometry's scale error (see
    /// [`PoseUncertainty::scale_cross`]).
    pub fn from_parts(covariance: &Covariance, scale_cross: [f64; 3]) -> Self {
        PoseUncertainty {
            scale_cross: Vector3::from(scale_cross),
            ..Self::from_covariance(covariance)
        }
    }

    /// The covariance of the pose error with the odometry's scale error (metres, metres,
    /// radians; zero where the scale is not estimated).
    pub fn scale_cross(&self) -> [f64; 3] {
        self.scale_cross.into()
    }

    /// The covariance (map plane; x, y in metres, yaw in radians).
    pub fn covariance(&self) -> Covariance {
        let c = &self.covariance;
        std::array::from_fn(|r| std::array::from_fn(|k| c[(r, k)]))
    }

    /// The pose moved by `motion` (metres, map plane): the heading error turns the motion into
    /// position error, and the odometry drifts by its rate per metre.
    pub fn drive(&mut self, motion: [f64; 2], params: &Params) {
        self.drive_scaled(motion, params, 0.0);
    }

    /// [`PoseUncertainty::drive`] for an odometry whose scale is uncertain by `scale_variance`
    /// (a ratio squared; 0 when the scale is not estimated): the motion's scale error adds to
    /// the position error along it, correlated over every metre driven.
    pub fn drive_scaled(&mut self, motion: [f64; 2], params: &Params, scale_variance: f64) {
        let step = motion[0].hypot(motion[1]);
        if step == 0.0 {
            return;
        }
        let f = moved_by(motion);
        let q = Vector3::new(
            params.drift_var_per_m * step,
            params.drift_var_per_m * step,
            params.yaw_drift_var_per_m * step,
        );
        self.covariance = f * self.covariance * f.transpose() + Matrix3::from_diagonal(&q);
        if scale_variance > 0.0 {
            let m = Vector3::new(motion[0], motion[1], 0.0);
            let fc = f * self.scale_cross;
            self.covariance +=
                fc * m.transpose() + m * fc.transpose() + m * m.transpose() * scale_variance;
            self.scale_cross = fc + m * scale_variance;
        }
        self.symmetrize();
        self.bound();
    }

    /// The scale error's standard deviation was brought down by `factor`
    /// ([`crate::scale::ScaleEstimate::drive`]): its covariance with the pose scales with it, so
    /// that pose and scale stay one covariance.
    pub fn scale_bounded(&mut self, factor: f64) {
        self.scale_cross *= factor;
    }

    /// The pose moved by `widening`'s missed road (its direction in the map plane) that the
    /// odometry did not see (it stalled, [`crate::stall`]), which no alignment has seen either:
    /// the position's variance along that direction and the heading's grow by the widening's,
    /// and then the heading error turns the motion into position error as in
    /// [`PoseUncertainty::drive`]. The odometry's drift and scale take no part: it measured none
    /// of that motion.
    pub fn drive_unseen(&mut self, widening: &Widening) {
        let Widening {
            direction,
            missed_m,
            along_variance_m2,
            yaw_variance_rad2,
            ..
        } = *widening;
        for r in 0..2 {
            for c in 0..2 {
                self.covariance[(r, c)] += along_variance_m2 * direction[r] * direction[c];
            }
        }
        self.covariance[(2, 2)] += yaw_variance_rad2;
        let f = moved_by([missed_m * direction[0], missed_m * direction[1]]);
        self.covariance = f * self.covariance * f.transpose();
        self.scale_cross = f * self.scale_cross;
        self.symmetrize();
        self.bound();
    }

    /// The part of `proposed` (a correction about the same center as `information`) the
    /// evidence supports. In the eigen-directions of the window's `information` against the
    /// current covariance, one whose ratio is at least `min_ratio` is applied whole; in the others
    /// the Kalman gain of the new share (`share` of the information) applies.
    pub fn supported(
        &self,
        information: &Matrix3<f64>,
        proposed: &Vector3<f64>,
        min_ratio: f64,
        share: f64,
    ) -> Supported {
        let whole = Supported {
            correction: *proposed,
            directions: 3,
        };
        let Some(cholesky) = self.covariance.cholesky() else {
            return whole;
        };
        let l = cholesky.l();
        let whitened = SymmetricEigen::new(l.transpose() * information * l);
        let Some(y) = l.solve_lower_triangular(proposed) else {
            return whole;
        };
        let mut kept = Vector3::zeros();
        let mut directions = 0;
        for (k, &ratio) in whitened.eigenvalues.iter().enumerate() {
            let v = whitened.eigenvectors.column(k);
            let gain = if ratio >= min_ratio {
                directions += 1;
                1.0
            } else {
                let r = (ratio * share).max(0.0);
                r / (1.0 + r)
            };
            kept += v * (gain * v.dot(&y));
        }
        Supported {
            correction: l * kept,
            directions,
        }
    }

    /// Adds `information` (about a correction at the current pose), scaled by `share`: the part
    /// of it that is new since the last update.
    pub fn update(&mut self, information: &Matrix3<f64>, share: f64) {
        self.update_scaled(information, share, 0.0);
    }

    /// [`PoseUncertainty::update`] with the scale error's variance `scale_variance` beside the
    /// pose's (0 when the scale is not estimated): the alignment also tells the part of the
    /// scale error that is correlated with the pose's.
    pub fn update_scaled(&mut self, information: &Matrix3<f64>, share: f64, scale_variance: f64) {
        if scale_variance > 0.0 {
            let mut joint = Matrix4::zeros();
            joint
                .fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&self.covariance);
            joint
                .fixed_view_mut::<3, 1>(0, 3)
                .copy_from(&self.scale_cross);
            joint
                .fixed_view_mut::<1, 3>(3, 0)
                .copy_from(&self.scale_cross.transpose());
            joint[(3, 3)] = scale_variance;
            let Some(mut joint_information) = joint.try_inverse() else {
                return;
            };
            let mut pose = joint_information.fixed_view_mut::<3, 3>(0, 0);
            pose += information * share;
            if let Some(updated) = joint_information.try_inverse() {
                self.take(
                    updated.fixed_view::<3, 3>(0, 0).into_owned(),
                    updated.fixed_view::<3, 1>(0, 3).into_owned(),
                    scale_variance,
                );
            }
            return;
        }
        let Some(prior_information) = self.covariance.try_inverse() else {
            return;
        };
        if let Some(covariance) = (prior_information + information * share).try_inverse() {
            self.take(covariance, self.scale_cross, 0.0);
        }
    }

    /// Takes an update's `covariance` and `scale_cross` (symmetrised), unless the arithmetic
    /// could not carry it: the inverses of a covariance whose variances lie many orders of
    /// magnitude apart (a position sigma of 1e6 m beside a heading sigma of 180 degrees and no
    /// drift, all allowed) lose their digits, and the result was no covariance. The pose then
    /// keeps the wider covariance it had, which is what a consumer may be given.
    fn take(&mut self, covariance: Matrix3<f64>, scale_cross: Vector3<f64>, scale_variance: f64) {
        let updated = PoseUncertainty {
            covariance: symmetric(&covariance),
            scale_cross,
        };
        if is_joint_covariance(&updated.covariance(), updated.scale_cross(), scale_variance) {
            *self = updated;
        }
    }

    /// The scale's own update ([`crate::scale::ScaleEstimate::update`]: evidence on the scale
    /// alone, its pose free) took its variance from `before` to `after` (a ratio squared): the
    /// Kalman update of the joint covariance by that measurement. The covariance with the scale
    /// shrinks by `after / before`, and the pose's by what the scale's error explained of it, so
    /// that pose and scale stay one covariance (without it, the covariance with the scale was
    /// kept while the scale's variance fell, and with `scale_sigma` 0.5 their correlation passed
    /// 2 at the first alignment on KITTI 01).
    pub fn scale_measured(&mut self, before: f64, after: f64) {
        if !(before > 0.0 && after < before) {
            return;
        }
        let kept = after / before;
        let c = self.scale_cross;
        self.covariance -= c * c.transpose() * ((1.0 - kept) / before);
        self.scale_cross = c * kept;
        self.symmetrize();
    }

    fn symmetrize(&mut self) {
        self.covariance = symmetric(&self.covariance);
    }

    /// Brings each variance beyond its [`MAX_DRIVEN_VARIANCES`] down to it, its row and column
    /// (and its covariance with the scale) scaled with it: the correlations stay, and so does a
    /// positive semi-definite covariance.
    fn bound(&mut self) {
        let d = Vector3::from_fn(|i, _| {
            let v = self.covariance[(i, i)];
            if v > MAX_DRIVEN_VARIANCES[i] {
                (MAX_DRIVEN_VARIANCES[i] / v).sqrt()
            } else {
                1.0
            }
        });
        if d != Vector3::repeat(1.0) {
            let d = Matrix3::from_diagonal(&d);
            self.covariance = symmetric(&(d * self.covariance * d));
            self.scale_cross = d * self.scale_cross;
        }
    }
}

/// The symmetric part of `m`: what rounding took out of a covariance's symmetry put back.
fn symmetric(m: &Matrix3<f64>) -> Matrix3<f64> {
    (m + m.transpose()) * 0.5
}

/// How a pose error (x, y, yaw) changes when the pose moves by `motion` (metres, map plane): the
/// heading error turns the motion into position error across it.
fn moved_by(motion: [f64; 2]) -> Matrix3<f64> {
    Matrix3::new(
        1.0, 0.0, -motion[1], //
        0.0, 1.0, motion[0], //
        0.0, 0.0, 1.0,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scale's own update is the Kalman update of the joint covariance of pose and scale by
    /// a measurement of the scale alone: what `scale_measured` leaves equals that update of the
    /// 4x4 matrix, whose scale variance is the estimate's new one.
    #[test]
    fn a_scale_measurement_is_the_kalman_update_of_the_joint_covariance() {
        let params = crate::params::Preset::OrbSlam3.robust_params();
        let (before, after) = (0.04, 0.01);
        let mut u = PoseUncertainty::from_covariance(&[
            [1.0, 0.2, 0.0],
            [0.2, 2.0, 0.01],
            [0.0, 0.01, 0.01],
        ]);
        for motion in [[30.0, 5.0], [10.0, -20.0]] {
            u.drive_scaled(motion, &params, before);
        }
        let (covariance, cross) = (u.covariance(), u.scale_cross());
        let joint = Matrix4::from_fn(|r, c| match (r, c) {
            (3, 3) => before,
            (3, k) | (k, 3) => cross[k],
            (r, c) => covariance[r][c],
        });
        // The measurement's noise that takes the scale's variance from `before` to `after`.
        let noise = before * after / (before - after);
        let gain = joint.column(3) / (before + noise);
        let updated = joint - gain * joint.row(3);
        assert!((updated[(3, 3)] - after).abs() < 1e-15);
        u.scale_measured(before, after);
        for r in 0..3 {
            assert!(
                (u.scale_cross()[r] - updated[(r, 3)]).abs() < 1e-12,
                "{u:?}"
            );
            for c in 0..3 {
                assert!(
                    (u.covariance()[r][c] - updated[(r, c)]).abs() < 1e-12,
                    "{u:?}"
                );
            }
        }
        assert!(is_joint_covariance(&u.covariance(), u.scale_cross(), after));
    }

    #[test]
    fn road_driven_unseen_turns_the_heading_error_into_position_error_across_it() {
        // 1 m in x and y, 0.1 rad in heading; 10 m missed northwards, 10 m sd along it, and
        // 0.2 rad more in heading.
        let mut u =
            PoseUncertainty::from_covariance(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.01]]);
        u.drive_unseen(&Widening {
            direction: [0.0, 1.0],
            missed_m: 10.0,
            along_variance_m2: 100.0,
            yaw_variance_rad2: 0.04,
            began: true,
        });
        let c = u.covariance();
        let expected = [
            // Across the road (x) the heading's 0.05 rad^2 over 10 m.
            [1.0 + 100.0 * 0.05, 0.0, -10.0 * 0.05],
            [0.0, 1.0 + 100.0, 0.0],
            [-10.0 * 0.05, 0.0, 0.05],
        ];
        for r in 0..3 {
            for k in 0..3 {
                assert!((c[r][k] - expected[r][k]).abs() < 1e-12, "{c:?}");
            }
        }
    }

    /// 5000 km without an alignment, the drifts at their bounds and the scale estimated (as the
    /// corrector drives it): the variances stay within [`MAX_DRIVEN_VARIANCES`] and
    /// [`crate::scale::MAX_DRIVEN_SCALE_VARIANCE`], and pose and scale one covariance a snapshot
    /// holds. Unbounded, the position's variance passed [`MAX_COVARIANCE_ENTRY`] after 1446 km
    /// and the scale's passed what a restore allows after 4000 km.
    #[test]
    fn a_drive_without_lanes_keeps_a_covariance_a_snapshot_holds() {
        use crate::scale::{ScaleEstimate, MAX_DRIVEN_SCALE_VARIANCE, MAX_SCALE_DRIFT_VAR_PER_M};
        let mut params = crate::params::Preset::OrbSlam3.robust_params();
        params.yaw_drift_var_per_m = crate::params::MAX_YAW_DRIFT_VAR_PER_M;
        params.drift_var_per_m = 999_999.0;
        let mut u = PoseUncertainty::new(&params);
        let mut scale = ScaleEstimate::new(0.5);
        let mut c = u.covariance();
        for km in 1..=5000 {
            let heading = 0.1 * (km as f64).sin();
            u.scale_bounded(scale.drive(1000.0, MAX_SCALE_DRIFT_VAR_PER_M));
            let motion = [1000.0 * heading.cos(), 1000.0 * heading.sin()];
            u.drive_scaled(motion, &params, scale.variance);
            c = u.covariance();
            assert!(
                scale.is_valid() && is_joint_covariance(&c, u.scale_cross(), scale.variance),
                "{km} km: {c:?}, {:?}, {scale:?}",
                u.scale_cross()
            );
            for k in 0..3 {
                assert!(
                    c[k][k] <= MAX_DRIVEN_VARIANCES[k] * (1.0 + 1e-12),
                    "{km} km: {c:?}"
                );
            }
        }
        // The heading's variance met its bound after 10 m, the scale's after 3 m; the
        // position's grew to some 5e12 m^2.
        assert!(c[2][2] > MAX_DRIVEN_VARIANCES[2] * 0.99, "{c:?}");
        assert_eq!(scale.variance, MAX_DRIVEN_SCALE_VARIANCE);
        assert!(c[0][0] > 1e12 && c[1][1] > 1e12, "{c:?}");
    }

    #[test]
    fn a_covariance_to_continue_from_is_symmetric_positive_semi_definite_and_bounded() {
        let good = [
            [4.5, 0.003, 1e-4],
            [0.003, 1.09, 0.007],
            [1e-4, 0.007, 3e-4],
        ];
        assert!(is_covariance(&good));
        assert!(is_covariance(&[[0.0; 3]; 3]));
        // Rounding: an asymmetry or a negative eigenvalue of 1e-12 of the largest entry.
        let mut rounded = good;
        rounded[0][1] += 4.5e-12;
        assert!(is_covariance(&rounded));
        let map_error = [[0.375, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]];
        assert!(is_covariance(&map_error));
        let mut bad = Vec::new();
        for (r, c, v) in [
            (1, 1, -1.0),     // a negative variance
            (0, 1, 0.5),      // asymmetric
            (2, 2, f64::NAN), // not a number
            (0, 0, 1.3e19),   // beyond MAX_COVARIANCE_ENTRY
        ] {
            let mut m = good;
            m[r][c] = v;
            bad.push(m);
        }
        // Every entry fine alone, the whole indefinite: a correlation above 1.
        bad.push([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        for m in bad {
            assert!(!is_covariance(&m), "{m:?}");
        }
    }
}
