//! The odometry's scale error (docs/method.md, "Scale"): how much longer or shorter than the
//! road an odometry measures its motion, estimated from the lanes and taken out of every later
//! step.
//!
//! The window is moved rigidly, so an odometry whose distances are off by a constant factor
//! gives it a shape no rotation and translation fits to the lanes (1 % over a 500 m window is
//! 5 m). After each accepted alignment, the kept pairs are asked what change of the window's
//! scale about its newest pose, with its position and heading free, fits the lanes best
//! ([`scale_evidence`]): a linear least-squares fit of the pairs' distances across their lanes,
//! weighted as the covariance weighs them ([`crate::confidence`]: the car's wander about the
//! centreline, and each 100 m stretch's lane offset shared by its pairs). A distance within the
//! robust method's lane band counts as none, so that a car driving beside the mapped centreline
//! of a curve does not read as a scale (a lateral offset on an arc is a scale about its centre).
//!
//! [`ScaleEstimate`] is a one-state Kalman filter on the factor the odometry's steps are
//! multiplied by: it starts at 1 with the preset's `scale_sigma`, drifts as a random walk per
//! metre, and takes each alignment's evidence by the share of the window that is new (as the
//! pose's covariance does). The change it accepts rescales the window about its newest pose, so
//! that the window's shape follows the estimate.
//!
//! Hand-written 4x4 least squares on nalgebra's fixed-size matrices: no crate models this.

use nalgebra::{Matrix4, RowVector4, Vector4};
use serde::{Deserialize, Serialize};

use crate::confidence::{
    kept_pairs_by_stretch, lane_sigma_m, Stretch, WANDER_CORRELATION_M, WANDER_SIGMA_M,
};
use crate::lane_map::LaneMap;
use crate::matching::Correspondence;
use crate::se2::Se2;

/// What one alignment says about the scale of its window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleEvidence {
    /// The relative change of scale about the center that fits the lanes best, with the
    /// window's position and heading free: `1 + scale_change` multiplies every distance to the
    /// center.
    pub scale_change: f64,
    /// The information (inverse variance) of `scale_change`, position and heading marginalised
    /// out.
    pub information: f64,
}

/// What the kept pairs, their window poses moved by `correction`, say about a change of the
/// window's scale about `center` (metres, map plane). A pair's distance across its lane counts
/// only beyond `band_m` (metres). `spacing_m[i]` is the path length from window pose `i` to the
/// next (metres). `None` when the pairs' geometry does not fix the scale (a straight road).
pub fn scale_evidence(
    map: &LaneMap,
    pairs: &[Correspondence],
    kept: &[u32],
    correction: &Se2,
    center: [f64; 2],
    spacing_m: &[f64],
    band_m: f64,
) -> Option<ScaleEvidence> {
    let wander_var = WANDER_SIGMA_M * WANDER_SIGMA_M;
    let mut information = Matrix4::zeros();
    let mut gradient = Vector4::zeros();
    let mut block = Stretch::<4>::default();
    for kept_pair in kept_pairs_by_stretch(map, pairs, kept, spacing_m) {
        if kept_pair.new_stretch {
            information += block.information();
            gradient += block.gradient();
            block = Stretch::default();
        }
        let (pair, direction) = (kept_pair.pair, kept_pair.direction);
        let sigma = lane_sigma_m(map.lane_info()[map.lane_of(pair.point)]);
        let normal = [-direction[1], direction[0]];
        let p = correction.apply(pair.source);
        let arm = [p[0] - center[0], p[1] - center[1]];
        // d(normal . p) / d(dx, dy, dyaw, dscale) for p moved about `center`.
        let j = RowVector4::new(
            normal[0],
            normal[1],
            -normal[0] * arm[1] + normal[1] * arm[0],
            normal[0] * arm[0] + normal[1] * arm[1],
        );
        let across = normal[0] * (pair.target[0] - p[0]) + normal[1] * (pair.target[1] - p[1]);
        let beyond_band = across.signum() * (across.abs() - band_m).max(0.0);
        let share = (spacing_m[pair.index] / WANDER_CORRELATION_M).clamp(1e-3, 1.0);
        let inv_a = share / wander_var;
        block.add(&j, inv_a, sigma * sigma);
        block.add_residual(&j, beyond_band, inv_a);
    }
    information += block.information();
    gradient += block.gradient();
    let covariance = information.try_inverse()?;
    let variance = covariance[(3, 3)];
    (variance.is_finite() && variance > 0.0).then(|| ScaleEvidence {
        scale_change: (covariance * gradient)[3],
        information: 1.0 / variance,
    })
}

/// The corrector's estimate of the odometry's scale error.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScaleEstimate {
    /// What the odometry's steps are multiplied by before they enter the window (a ratio; 1:
    /// the odometry's own scale).
    pub factor: f64,
    /// The variance of `factor` (a ratio squared).
    pub variance: f64,
}

impl ScaleEstimate {
    /// At the start: the odometry's own scale, off by `sigma` (a ratio, 1 sigma).
    pub fn new(sigma: f64) -> Self {
        ScaleEstimate {
            factor: 1.0,
            variance: sigma * sigma,
        }
    }

    /// The odometry drove `step_m` metres; its scale drifts by `var_per_m` (a ratio squared) per
    /// metre, up to [`MAX_DRIVEN_SCALE_VARIANCE`]. Returns the factor the estimate's standard
    /// deviation was brought down by to stay within it (1: not at all): the scale's covariance
    /// with the pose scales with it ([`crate::confidence::PoseUncertainty::scale_bounded`]).
    pub fn drive(&mut self, step_m: f64, var_per_m: f64) -> f64 {
        let variance = self.variance + var_per_m * step_m;
        if variance > MAX_DRIVEN_SCALE_VARIANCE {
            self.variance = MAX_DRIVEN_SCALE_VARIANCE;
            (MAX_DRIVEN_SCALE_VARIANCE / variance).sqrt()
        } else {
            self.variance = variance;
            1.0
        }
    }

    /// Folds in `evidence`, `share` of it new (the Kalman gain of its information against the
    /// variance), and returns the relative change of scale the window is to take (`1 +` it
    /// multiplies the window's distances to its newest pose). Evidence that would leave an
    /// estimate no corrector may continue from ([`ScaleEstimate::is_valid`]) is not taken (0 is
    /// returned): with a variance of a few (a drift set near its bound), a window's misfit read
    /// as a change of scale below -1 turned the factor negative, the odometry's steps backwards.
    pub fn update(&mut self, evidence: &ScaleEvidence, share: f64) -> f64 {
        let r = self.variance * evidence.information * share;
        let change = r / (1.0 + r) * evidence.scale_change;
        let updated = ScaleEstimate {
            factor: self.factor * (1.0 + change),
            variance: self.variance / (1.0 + r),
        };
        if !updated.is_valid() {
            return 0.0;
        }
        *self = updated;
        change
    }

    /// Whether the estimate is one a corrector can continue from (one restored from a saved
    /// state): the factor within [`MAX_SCALE_OFF`] times either way of 1, the variance
    /// non-negative and at most `MAX_SCALE_OFF` (both finite). Beyond, the scaled steps and the
    /// covariance overflowed into infinities.
    pub fn is_valid(&self) -> bool {
        (1.0 / MAX_SCALE_OFF..=MAX_SCALE_OFF).contains(&self.factor)
            && (0.0..=MAX_SCALE_OFF).contains(&self.variance)
    }
}

/// The largest random walk of the scale a corrector may be set for
/// ([`crate::params::Params::scale_drift_var_per_m`], a ratio squared per metre): the variance
/// of the largest `scale_sigma` (0.5) added in every metre driven. Beyond it the estimate is
/// noise, and its variance soon passed what a saved state may hold ([`MAX_SCALE_OFF`]; at 1e3
/// within the first kilometre of KITTI 07, so that the session's snapshot did not restore) and
/// then overflowed (at 1e100 the published covariances were NaN).
pub const MAX_SCALE_DRIFT_VAR_PER_M: f64 = 0.25;

/// The largest variance driving gives a scale estimate (a ratio squared): a scale off by its whole
/// self, one sigma. A larger one says nothing more, and at the largest drift
/// ([`MAX_SCALE_DRIFT_VAR_PER_M`]) it passed what a restore allows ([`MAX_SCALE_OFF`]) after
/// 4000 km without an alignment.
pub const MAX_DRIVEN_SCALE_VARIANCE: f64 = 1.0;

/// How far a scale estimate may be off to be continued from (a ratio; [`ScaleEstimate::is_valid`]):
/// a million times, far past any odometry lanes could correct, while a scaled step of the
/// farthest a pose may lie ([`crate::pose::MAX_COORDINATE_M`]) stays finite.
pub const MAX_SCALE_OFF: f64 = 1e6;

/// The anchored odometry with its steps multiplied by the scale estimate (frame `scaled`, the
/// plane the corrector works in): each position is the last one's plus the step since, scaled.
/// Only positions change; headings are the odometry's.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScaledOdometry {
    /// The last position placed (metres, frame `anchored`).
    pub last_in_anchored: Option<[f64; 2]>,
    /// Where the last position lies in frame `scaled` relative to frame `anchored` (metres):
    /// `scaled = anchored + offset`.
    pub offset: [f64; 2],
}

impl ScaledOdometry {
    /// Where `position_in_anchored` (metres) lies in frame `scaled` when the steps are multiplied
    /// by `factor`, without placing it.
    pub fn predict(&self, position_in_anchored: [f64; 2], factor: f64) -> [f64; 2] {
        let offset = self.offset_at(position_in_anchored, factor);
        [
            position_in_anchored[0] + offset[0],
            position_in_anchored[1] + offset[1],
        ]
    }

    /// Places the next position (metres, frame `anchored`), its step since the last multiplied
    /// by `factor`: [`ScaledOdometry::scaled_from_anchored`] then holds for it.
    pub fn place(&mut self, position_in_anchored: [f64; 2], factor: f64) {
        self.offset = self.offset_at(position_in_anchored, factor);
        self.last_in_anchored = Some(position_in_anchored);
    }

    /// `scaled_from_anchored` at the last position placed: a translation.
    pub fn scaled_from_anchored(&self) -> Se2 {
        Se2::new(0.0, self.offset[0], self.offset[1])
    }

    fn offset_at(&self, position_in_anchored: [f64; 2], factor: f64) -> [f64; 2] {
        match self.last_in_anchored {
            Some(last) if factor != 1.0 => {
                let excess = factor - 1.0;
                [
                    self.offset[0] + excess * (position_in_anchored[0] - last[0]),
                    self.offset[1] + excess * (position_in_anchored[1] - last[1]),
                ]
            }
            _ => self.offset,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;

    /// A U of lanes, a point every 3 m: east along y = 0 to x = 300, north from there to
    /// y = 201, and west back along y = 201.
    fn u_map() -> LaneMap {
        let east: Vec<[f64; 2]> = (0..=100).map(|i| [i as f64 * 3.0, 0.0]).collect();
        let north: Vec<[f64; 2]> = (0..=67).map(|i| [300.0, i as f64 * 3.0]).collect();
        let west: Vec<[f64; 2]> = (0..=100).map(|i| [300.0 - i as f64 * 3.0, 201.0]).collect();
        LaneMap::new(&[Lane::new(1, east), Lane::new(2, north), Lane::new(3, west)]).unwrap()
    }

    /// The U driven every 2 m (`legs` of it: 1 east, 2 also north, 3 also west), each pose
    /// paired with its true place on its lane's segment, then scaled by `factor` about the
    /// drive's end (the center returned).
    fn pairs_of_u(factor: f64, legs: usize, map: &LaneMap) -> (Vec<Correspondence>, [f64; 2]) {
        let offsets = map.lane_offsets();
        let segment = |lane: usize, along_m: f64| offsets[lane] + (along_m / 3.0) as u32;
        let mut truth: Vec<([f64; 2], u32)> = (0..150)
            .map(|i| ([i as f64 * 2.0, 0.0], segment(0, i as f64 * 2.0)))
            .collect();
        if legs >= 2 {
            truth.extend((1..100).map(|i| ([300.0, i as f64 * 2.0], segment(1, i as f64 * 2.0))));
        }
        if legs >= 3 {
            truth.extend(
                (1..150).map(|i| ([300.0 - i as f64 * 2.0, 201.0], segment(2, i as f64 * 2.0))),
            );
        }
        let end = truth[truth.len() - 1].0;
        let pairs = truth
            .iter()
            .enumerate()
            .map(|(index, &(t, point))| Correspondence {
                index,
                source: [
                    end[0] + factor * (t[0] - end[0]),
                    end[1] + factor * (t[1] - end[1]),
                ],
                target: t,
                point,
            })
            .collect();
        (pairs, end)
    }

    fn evidence_of(factor: f64, legs: usize, band_m: f64) -> Option<ScaleEvidence> {
        let map = u_map();
        let (pairs, end) = pairs_of_u(factor, legs, &map);
        let kept: Vec<u32> = (0..pairs.len() as u32).collect();
        let spacing = vec![2.0; pairs.len()];
        scale_evidence(&map, &pairs, &kept, &Se2::IDENTITY, end, &spacing, band_m)
    }

    #[test]
    fn a_u_drive_scaled_about_its_end_is_measured_so() {
        for factor in [0.97, 1.0, 1.02] {
            let evidence = evidence_of(factor, 3, 0.0).unwrap();
            // Scaled back by 1 / factor, the drive lies on its lanes again.
            let wanted = 1.0 / factor - 1.0;
            assert!(
                (evidence.scale_change - wanted).abs() < 1e-9,
                "factor {factor}: {evidence:?}, wanted {wanted}"
            );
            assert!(evidence.information > 1e4, "{evidence:?}");
        }
        // Within the band the lanes see nothing amiss: 3 % of the 200 m between the two long
        // legs is 6 m, beyond a 1 m band; 0.3 % is 0.6 m, within it.
        let banded = evidence_of(1.03, 3, 1.0).unwrap();
        assert!(banded.scale_change < -0.015, "{banded:?}");
        assert_eq!(evidence_of(1.003, 3, 1.0).unwrap().scale_change, 0.0);
    }

    #[test]
    fn a_straight_drive_or_a_single_turn_says_nothing_of_scale() {
        // Along one line, or two at an angle, a scale about the end is a move along the road
        // and across the first leg: what the window's position takes anyway.
        for legs in [1, 2] {
            let evidence = evidence_of(1.02, legs, 0.0);
            assert!(
                evidence.is_none_or(|e| e.information < 1e-3),
                "{legs} legs: {evidence:?}"
            );
        }
    }

    #[test]
    fn the_estimate_moves_by_its_gain_and_grows_uncertain_as_it_drives() {
        let mut estimate = ScaleEstimate::new(0.02);
        assert_eq!(estimate.drive(1000.0, 1e-7), 1.0);
        assert!((estimate.variance - (4e-4 + 1e-4)).abs() < 1e-15);
        let evidence = ScaleEvidence {
            scale_change: -0.03,
            information: 1.0 / 5e-4,
        };
        let change = estimate.update(&evidence, 1.0);
        assert!((change + 0.015).abs() < 1e-12, "{change}");
        assert!((estimate.factor - 0.985).abs() < 1e-12);
        assert!((estimate.variance - 2.5e-4).abs() < 1e-15);
    }

    /// Evidence that would turn the factor negative (a change below -1, which a window's
    /// misfit gives once the variance is a few) is not taken: the estimate stays as it was.
    #[test]
    fn evidence_that_would_turn_the_steps_backwards_is_not_taken() {
        let mut estimate = ScaleEstimate {
            factor: 1.0,
            variance: 4.0,
        };
        let evidence = ScaleEvidence {
            scale_change: -1.5,
            information: 10.0,
        };
        assert_eq!(estimate.update(&evidence, 1.0), 0.0);
        assert_eq!(
            estimate,
            ScaleEstimate {
                factor: 1.0,
                variance: 4.0
            }
        );
    }

    #[test]
    fn the_scaled_odometry_multiplies_each_step_by_the_factor_in_force() {
        let close =
            |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12;
        let mut scaled = ScaledOdometry::default();
        // The first position has no step before it: it stays where the anchor put it.
        scaled.place([10.0, 0.0], 1.1);
        assert_eq!(scaled.scaled_from_anchored(), Se2::IDENTITY);
        // The step (10, 5) becomes (11, 5.5); predicting it places nothing.
        let predicted = scaled.predict([20.0, 5.0], 1.1);
        assert!(close(predicted, [21.0, 5.5]), "{predicted:?}");
        assert!(close(scaled.predict([20.0, 5.0], 1.1), predicted));
        scaled.place([20.0, 5.0], 1.1);
        assert!(close(
            scaled.scaled_from_anchored().apply([20.0, 5.0]),
            predicted
        ));
        // The next step with another factor: (0, 10) becomes (0, 9), from where the last was.
        scaled.place([20.0, 15.0], 0.9);
        let now = scaled.scaled_from_anchored().apply([20.0, 15.0]);
        assert!(close(now, [21.0, 14.5]), "{now:?}");
        // A factor of 1 leaves the offset as it is.
        scaled.place([30.0, 15.0], 1.0);
        assert!(close(
            scaled.scaled_from_anchored().apply([30.0, 15.0]),
            [31.0, 14.5]
        ));
    }
}
