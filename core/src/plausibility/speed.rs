//! Changes of an odometry's speed that no car makes: where it lost track.

use std::collections::VecDeque;

use super::{first_few, plural, rate_text};
use crate::pose::{AxisConvention, Pose3};

/// The most a car's speed changes per second (m/s^2): about 1 g, what its tyres give at most
/// when it brakes. Measured as [`SpeedWatch`] does, the speed of the 30 shared KITTI runs
/// (ground truth, LiDAR and visual odometry) changes by at most 5.5 m/s^2, but for the visual
/// odometry of sequence 01, which falls from 19 to 1 m/s within 0.6 s on the highway while the
/// car drives on at 22 m/s (docs/method.md, "Confidence").
pub const MAX_ACCELERATION_MPS2: f64 = 10.0;

/// How long (seconds) a stretch of poses the speed check measures a speed over: the median of
/// its steps' speeds, so that one long step (poses missing from the input, a jump) or one noisy
/// step does not count as a change of speed.
pub const SPEED_SPAN_S: f64 = 0.5;

/// A change of the odometry's speed faster than [`MAX_ACCELERATION_MPS2`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedChange {
    /// The pose (0-based) between the stretch before the change and the one after it.
    pub pose: usize,
    /// The speed before (m/s): the median over the [`SPEED_SPAN_S`] before `pose`.
    pub from_mps: f64,
    /// The speed after (m/s): the median over the [`SPEED_SPAN_S`] after `pose`.
    pub to_mps: f64,
    /// The time (seconds) from one stretch's middle to the other's: [`SPEED_SPAN_S`] in whole
    /// poses, at least one.
    pub over_s: f64,
}

impl SpeedChange {
    /// The acceleration (m/s^2, negative when braking) from one stretch's middle to the other's.
    pub fn acceleration_mps2(&self) -> f64 {
        (self.to_mps - self.from_mps) / self.over_s
    }
}

/// What a [`SpeedWatch`] has seen ([`SpeedWatch::history`]): enough to continue exactly where
/// it was (a daemon's snapshot of a session).
#[derive(Clone, Debug, PartialEq)]
pub struct SpeedHistory {
    /// Poses observed.
    pub seen: usize,
    /// The last pose it took (planar, metres).
    pub last: Option<[f64; 2]>,
    /// Poses in a row it took exactly where the last one was (at most [`MAX_REPEATS`]).
    pub repeats: usize,
    /// The last steps' speeds (m/s), oldest first: at most two spans of them.
    pub speeds: Vec<f64>,
    /// The pose (0-based) each of them ended at; as many as `speeds`.
    pub ends: Vec<usize>,
    /// The steepest change of the ones under way, and the pose of the last one as steep.
    pub open: Option<(SpeedChange, usize)>,
}

/// How many poses in a row exactly where the last one was are no new estimate of the odometry
/// (one that publishes up to three times faster than it updates); more stand still or are frozen.
pub const MAX_REPEATS: usize = 2;

/// The most steps the speed check takes the median of: at a higher rate it looks at every few
/// poses only, so that a pose costs it a median of a few numbers at any rate.
const MAX_SPAN_STEPS: usize = 8;

/// Watches an odometry's speed, pose by pose, for changes faster than a car's can be
/// ([`MAX_ACCELERATION_MPS2`]): the speed is the median of the steps' over [`SPEED_SPAN_S`],
/// compared with the one over the [`SPEED_SPAN_S`] after it, so that one long step (poses missing
/// from the input, a jump) or one noisy step is no change. A pose exactly where the last one was
/// is no new estimate while at most [`MAX_REPEATS`] of them come in a row (an odometry that
/// publishes every estimate twice keeps its speed: the next step's is taken over the time since
/// the last estimate); beyond that it stands or is frozen, and each is a step of no speed.
/// Above 16 Hz it takes every few poses (at most eight steps to a span). Of the changes next to
/// one another, the steepest stands for them all, told when they end.
#[derive(Clone, Debug)]
pub struct SpeedWatch {
    /// The rate (Hz) of the poses it takes.
    rate_hz: f64,
    /// It takes every `every`-th pose.
    every: usize,
    /// Steps to a span.
    span: usize,
    /// Poses observed.
    seen: usize,
    /// The last pose taken (planar, metres).
    last: Option<[f64; 2]>,
    /// Poses in a row taken exactly where the last one was, while at most [`MAX_REPEATS`].
    repeats: usize,
    /// The last `2 span` steps' speeds (m/s), oldest first, each with the pose (0-based) it
    /// ended at.
    steps: VecDeque<(f64, usize)>,
    scratch: Vec<f64>,
    /// The steepest change of the ones under way, and the pose of the last one as steep.
    open: Option<(SpeedChange, usize)>,
}

impl SpeedWatch {
    /// A watch for poses coming at `rate_hz` (a rate that is no rate, zero or not finite, is
    /// taken as the presets' 10 Hz).
    pub fn new(rate_hz: f64) -> Self {
        let rate_hz = if rate_hz.is_finite() && rate_hz > 0.0 {
            rate_hz
        } else {
            crate::params::PRESET_RATE_HZ
        };
        let steps = SPEED_SPAN_S * rate_hz;
        let every = ((steps / MAX_SPAN_STEPS as f64).ceil() as usize).max(1);
        let rate_hz = rate_hz / every as f64;
        // At most MAX_SPAN_STEPS already, but for rates beyond what `every` can count.
        let span = ((SPEED_SPAN_S * rate_hz).round() as usize).clamp(1, MAX_SPAN_STEPS);
        SpeedWatch {
            rate_hz,
            every,
            span,
            seen: 0,
            last: None,
            repeats: 0,
            steps: VecDeque::with_capacity(2 * span),
            scratch: Vec::with_capacity(span),
            open: None,
        }
    }

    /// Takes the next pose's position (planar, metres, any fixed frame); returns a change of
    /// speed no car makes when one has ended with this pose.
    pub fn observe(&mut self, position: [f64; 2]) -> Option<SpeedChange> {
        let index = self.seen;
        self.seen += 1;
        if !index.is_multiple_of(self.every) {
            return None;
        }
        let last = self.last.replace(position)?;
        let periods = if position == last {
            if self.repeats < MAX_REPEATS {
                self.repeats += 1;
                return None;
            }
            1
        } else {
            std::mem::take(&mut self.repeats) + 1
        };
        let moved = (position[0] - last[0]).hypot(position[1] - last[1]);
        if self.steps.len() == 2 * self.span {
            self.steps.pop_front();
        }
        self.steps
            .push_back((moved * self.rate_hz / periods as f64, index));
        if self.steps.len() < 2 * self.span {
            return None;
        }
        let change = SpeedChange {
            // Where the span after the change begins: the end of the span before it.
            pose: self.steps[self.span - 1].1,
            from_mps: self.median(0),
            to_mps: self.median(self.span),
            over_s: self.span as f64 / self.rate_hz,
        };
        // NaN compares false: a span without a speed is no change.
        let steepness = change.acceleration_mps2().abs();
        if steepness > MAX_ACCELERATION_MPS2 {
            match &mut self.open {
                Some((steepest, last_as_steep)) => {
                    let steepest_so_far = steepest.acceleration_mps2().abs();
                    if steepness > steepest_so_far {
                        (*steepest, *last_as_steep) = (change, change.pose);
                    } else if steepness == steepest_so_far {
                        *last_as_steep = change.pose;
                    }
                }
                None => self.open = Some((change, change.pose)),
            }
            return None;
        }
        self.finish()
    }

    /// What the watch has seen, to continue from later ([`SpeedWatch::resume`]).
    pub fn history(&self) -> SpeedHistory {
        SpeedHistory {
            seen: self.seen,
            last: self.last,
            repeats: self.repeats,
            speeds: self.steps.iter().map(|s| s.0).collect(),
            ends: self.steps.iter().map(|s| s.1).collect(),
            open: self.open,
        }
    }

    /// A watch for poses coming at `rate_hz` that continues from `history` (what one for the
    /// same rate had seen), exactly as that one would. Speeds pair with the poses they ended at
    /// in order (one without its pair is dropped); those beyond what a watch for this rate keeps
    /// are dropped, the oldest first.
    pub fn resume(rate_hz: f64, history: SpeedHistory) -> Self {
        let mut watch = SpeedWatch::new(rate_hz);
        let steps: Vec<(f64, usize)> = history.speeds.into_iter().zip(history.ends).collect();
        let keep = steps.len().min(2 * watch.span);
        watch.steps.extend(&steps[steps.len() - keep..]);
        watch.seen = history.seen;
        watch.last = history.last;
        watch.repeats = history.repeats.min(MAX_REPEATS);
        watch.open = history.open;
        watch
    }

    /// How many poses `change` (told by this watch) lies before the last pose observed.
    pub fn poses_since(&self, change: &SpeedChange) -> usize {
        self.seen.saturating_sub(1 + change.pose)
    }

    /// The change under way when the poses end, if one is.
    pub fn finish(&mut self) -> Option<SpeedChange> {
        let (mut steepest, last_as_steep) = self.open.take()?;
        // Spans that see the same change from a few poses apart are as steep (a change within
        // a step, medians of the same speeds): it lies in their middle.
        steepest.pose = steepest.pose.midpoint(last_as_steep);
        Some(steepest)
    }

    /// The median speed (m/s) of the span of steps from `first`; NaN when half of them or more
    /// are not finite.
    fn median(&mut self, first: usize) -> f64 {
        self.scratch.clear();
        let span = self.steps.range(first..first + self.span);
        self.scratch
            .extend(span.map(|s| s.0).filter(|s| s.is_finite()));
        if self.scratch.len() * 2 <= self.span {
            return f64::NAN;
        }
        let mid = self.scratch.len() / 2;
        *self.scratch.select_nth_unstable_by(mid, f64::total_cmp).1
    }
}

/// The changes of speed faster than [`MAX_ACCELERATION_MPS2`] along `positions` (planar, metres,
/// any fixed frame) coming at `rate_hz`, as a [`SpeedWatch`] tells them.
pub fn speed_changes(positions: &[[f64; 2]], rate_hz: f64) -> Vec<SpeedChange> {
    let mut watch = SpeedWatch::new(rate_hz);
    let mut changes: Vec<SpeedChange> =
        positions.iter().filter_map(|&p| watch.observe(p)).collect();
    changes.extend(watch.finish());
    changes
}

/// A warning when the odometry's speed (the planar positions of `poses`, given in `convention`,
/// at `rate_hz`) changes faster than a car's can ([`speed_changes`]): where, and what it means
/// for the corrected poses.
pub fn speed_change_warning(
    poses: &[Pose3],
    convention: AxisConvention,
    rate_hz: f64,
) -> Option<String> {
    change_warning(&planar_positions(poses, convention), rate_hz)
}

/// A warning when the odometry's median speed over the steps that move is beyond any vehicle's
/// (`max_speed_mps`: positions in other units than metres, or poses slower than `rate_hz`),
/// else when it changes faster than a car's can
/// ([`speed_change_warning`], whose changes the first explains), from one pass over `poses`
/// (given in `convention`, at `rate_hz`).
pub fn speed_warning(
    poses: &[Pose3],
    convention: AxisConvention,
    rate_hz: f64,
    max_speed_mps: f64,
) -> Option<String> {
    let positions = planar_positions(poses, convention);
    median_speed_warning(&positions, rate_hz, max_speed_mps)
        .or_else(|| change_warning(&positions, rate_hz))
}

/// The planar positions (metres) of `poses`, given in `convention`.
fn planar_positions(poses: &[Pose3], convention: AxisConvention) -> Vec<[f64; 2]> {
    poses
        .iter()
        .map(|p| convention.to_planar(p).planar_position())
        .collect()
}

/// [`speed_change_warning`] of planar `positions`.
fn change_warning(positions: &[[f64; 2]], rate_hz: f64) -> Option<String> {
    let changes = speed_changes(positions, rate_hz);
    if changes.is_empty() {
        return None;
    }
    let shown = changes
        .iter()
        .map(|c| format!("pose {} ({:.1} -> {:.1} m/s)", c.pose, c.from_mps, c.to_mps));
    Some(format!(
        "the odometry's speed changes faster than a car's can (more than {MAX_ACCELERATION_MPS2} \
         m/s^2 over {SPEED_SPAN_S} s) at {} place{}: {}; it probably lost track there (a \
         visual odometry stalls where it sees too little), and where the lanes run straight the \
         corrector cannot tell how far the vehicle went meanwhile, so the corrected poses after \
         it may be off along the road; the corrector takes the vehicle to have driven on at the \
         speed before a fall, restarts its window and widens the covariance along the road by \
         the distance that misses and the heading by what a car may turn there (watch_stalls) \
         (this takes the poses to come at {} Hz: \
         where they do not, give their stamps or odometry_rate_hz)",
        changes.len(),
        plural(changes.len()),
        first_few(shown, changes.len()),
        rate_text(rate_hz),
    ))
}

/// A warning when the odometry's median speed (planar `positions` at `rate_hz`, over the steps
/// that move) is beyond `max_speed_mps` ([`pace_warning`]).
fn median_speed_warning(
    positions: &[[f64; 2]],
    rate_hz: f64,
    max_speed_mps: f64,
) -> Option<String> {
    let mut steps_m: Vec<f64> = positions
        .windows(2)
        .filter_map(|w| moving_step_m(w[0], w[1]))
        .collect();
    pace_warning(&mut steps_m, rate_hz, max_speed_mps)
}

/// The length (metres) of the step from planar position `from` to `to`, where it moves (a
/// finite length above zero).
pub(super) fn moving_step_m(from: [f64; 2], to: [f64; 2]) -> Option<f64> {
    let length_m = (to[0] - from[0]).hypot(to[1] - from[1]);
    (length_m.is_finite() && length_m > 0.0).then_some(length_m)
}

/// A warning when the median of `steps_m` (the lengths of steps that move, metres, reordered),
/// the poses taken to come at `rate_hz`, is a speed beyond `max_speed_mps`: positions in other
/// units than metres, or poses that come slower than `rate_hz`. On the shared KITTI
/// trajectories the median is at most 25.3 m/s (the highway of 01); centimetres read as metres
/// make 00's 849 m/s. No steps, no warning.
pub(super) fn pace_warning(
    steps_m: &mut [f64],
    rate_hz: f64,
    max_speed_mps: f64,
) -> Option<String> {
    if steps_m.is_empty() {
        return None;
    }
    let middle = steps_m.len() / 2;
    let (_, &mut median_m, _) = steps_m.select_nth_unstable_by(middle, f64::total_cmp);
    let median = median_m * rate_hz;
    (median > max_speed_mps).then(|| {
        let rate_hz = rate_text(rate_hz);
        format!(
            "the odometry moves at {median:.0} m/s (the median over the steps that move, the \
             poses taken to come at {rate_hz} Hz), faster than max_speed_mps ({max_speed_mps} \
             m/s) lets any vehicle: are its positions in metres (centimetres read as metres are \
             100 times too fast), and does it come at {rate_hz} Hz (where not, give its stamps \
             or odometry_rate_hz)?"
        )
    })
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    #[test]
    fn an_odometry_in_centimetres_is_told_by_its_speed() {
        let metres: Vec<Pose3> = drive(300, |k| if k < 100 { 0.0 } else { 12.0 })
            .iter()
            .map(|&[x, y]| Pose3::planar(x, y, 0.0, 0.0))
            .collect();
        let centimetres: Vec<Pose3> = metres
            .iter()
            .map(|p| Pose3 {
                translation: p.translation * 100.0,
                ..*p
            })
            .collect();
        let flu = AxisConvention::Flu;
        assert_eq!(
            median_speed_warning(&planar_positions(&metres, flu), 10.0, 70.0),
            None
        );
        let w = median_speed_warning(&planar_positions(&centimetres, flu), 10.0, 70.0)
            .unwrap_or_default();
        assert!(w.starts_with("the odometry moves at 1200 m/s"), "{w}");
        // Read as coming at 1 Hz, it drives at 120 m/s: the rate is named too.
        let w = median_speed_warning(&planar_positions(&centimetres, flu), 1.0, 70.0)
            .unwrap_or_default();
        assert!(
            w.contains("at 120 m/s") && w.contains("come at 1.0 Hz"),
            "{w}"
        );
        assert_eq!(
            median_speed_warning(&planar_positions(&metres[..100], flu), 10.0, 70.0),
            None
        );
    }

    /// A drive along x at 10 Hz whose speed (m/s) at each step `speed(step)` gives.
    pub(in crate::plausibility) fn drive(
        steps: usize,
        speed: impl Fn(usize) -> f64,
    ) -> Vec<[f64; 2]> {
        drive_at(10.0, steps, speed)
    }

    /// A drive along x at `rate_hz` whose speed (m/s) at each step `speed(step)` gives.
    pub(in crate::plausibility) fn drive_at(
        rate_hz: f64,
        steps: usize,
        speed: impl Fn(usize) -> f64,
    ) -> Vec<[f64; 2]> {
        let mut x = 0.0;
        let mut out = vec![[x, 0.0]];
        for k in 0..steps {
            x += speed(k) / rate_hz;
            out.push([x, 0.0]);
        }
        out
    }

    #[test]
    fn an_odometry_that_stalls_at_speed_is_noticed_and_hard_braking_is_not() {
        // 20 m/s for 10 s, then braking at 8 m/s^2 (0.8 g) to a stop: a car can.
        let braking = drive(200, |k| {
            if k < 100 {
                20.0
            } else {
                (20.0 - 0.8 * (k - 100) as f64).max(0.0)
            }
        });
        assert_eq!(speed_changes(&braking, 10.0), []);
        // The odometry falls from 20 m/s to 1 m/s in 0.4 s and stays there: no car can.
        let stalled = drive(200, |k| match k {
            0..100 => 20.0,
            100..104 => 20.0 - 4.75 * (k - 99) as f64,
            _ => 1.0,
        });
        let changes = speed_changes(&stalled, 10.0);
        assert_eq!(changes.len(), 1, "{changes:?}");
        let stall = changes[0];
        assert!((99..=105).contains(&stall.pose), "{stall:?}");
        assert!(stall.from_mps >= 15.0 && stall.to_mps <= 5.0, "{stall:?}");
        assert!(stall.acceleration_mps2() < -MAX_ACCELERATION_MPS2);
        let poses: Vec<Pose3> = stalled
            .iter()
            .map(|&[x, y]| Pose3::planar(x, y, 0.0, 0.0))
            .collect();
        let w = speed_change_warning(&poses, AxisConvention::Flu, 10.0).unwrap();
        assert!(
            w.contains(&format!("at 1 place: pose {}", stall.pose)),
            "{w}"
        );
        assert!(speed_change_warning(&poses[..100], AxisConvention::Flu, 10.0).is_none());
    }

    #[test]
    fn every_estimate_published_twice_is_no_change_but_a_frozen_odometry_is() {
        // 20 m/s braking to 10 m/s at 4 m/s^2, every pose published twice at the rate set for
        // once: a step, then none.
        let once: Vec<[f64; 2]> = (0..300)
            .scan(0.0, |x, i| {
                let t = i as f64 / 10.0;
                *x += (20.0 - 4.0 * (t - 10.0).clamp(0.0, 2.5)) / 10.0;
                Some([*x, 3.0])
            })
            .collect();
        let twice: Vec<[f64; 2]> = once.iter().flat_map(|&p| [p, p]).collect();
        assert_eq!(speed_changes(&twice, 10.0), []);
        let thrice: Vec<[f64; 2]> = once.iter().flat_map(|&p| [p, p, p]).collect();
        assert_eq!(speed_changes(&thrice, 10.0), []);
        // An odometry that freezes (repeats its last pose) for 3 s at 20 m/s, then goes on.
        let frozen: Vec<[f64; 2]> = (0..300)
            .map(|i| once[if (100..130).contains(&i) { 99 } else { i }])
            .collect();
        let changes = speed_changes(&frozen, 10.0);
        assert!(
            changes
                .iter()
                .any(|c| c.acceleration_mps2() < -MAX_ACCELERATION_MPS2
                    && (99..110).contains(&c.pose)),
            "{changes:?}"
        );
    }

    #[test]
    fn a_stall_is_noticed_at_any_rate_and_one_under_way_at_the_end_too() {
        for rate_hz in [1.0, 4.0, 25.0, 100.0, 1000.0] {
            // 20 m/s for 30 s, then 1 m/s, the change within one step.
            let n = (60.0 * rate_hz) as usize;
            let positions: Vec<[f64; 2]> = (0..n)
                .map(|i| {
                    let t = i as f64 / rate_hz;
                    [20.0 * t.min(30.0) + (t - 30.0).max(0.0), 0.0]
                })
                .collect();
            let changes = speed_changes(&positions, rate_hz);
            assert_eq!(changes.len(), 1, "{rate_hz} Hz: {changes:?}");
            let full = changes[0];
            let at_s = full.pose as f64 / rate_hz;
            assert!(
                (at_s - 30.0).abs() <= full.over_s / 2.0,
                "{rate_hz} Hz: {full:?}"
            );
            // Cut where the span after the change ends: it is still under way, and is told
            // when the poses end.
            let end = full.pose + (full.over_s * rate_hz).round() as usize + 1;
            let mut watch = SpeedWatch::new(rate_hz);
            assert!(positions[..end].iter().all(|&p| watch.observe(p).is_none()));
            let cut = watch.finish().unwrap();
            assert_eq!((cut.from_mps, cut.to_mps), (full.from_mps, full.to_mps));
            assert!((cut.pose as f64 - full.pose as f64).abs() <= full.over_s * rate_hz);
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 256, rng_seed: proptest::test_runner::RngSeed::Fixed(31), ..Default::default() })]

        /// Any positions (NaN, infinite, 1e308 m) at any rate: changes name poses of the input,
        /// with speeds that are numbers, one at most for every two spans.
        #[test]
        fn any_positions_give_changes_within_the_input(
            positions in proptest::collection::vec(
                (proptest::num::f64::ANY, proptest::num::f64::ANY), 0..300),
            rate_hz in proptest::prop_oneof![0.1f64..2000.0, proptest::num::f64::ANY],
        ) {
            let positions: Vec<[f64; 2]> = positions.into_iter().map(|(x, y)| [x, y]).collect();
            let changes = speed_changes(&positions, rate_hz);
            for c in &changes {
                proptest::prop_assert!(c.pose < positions.len(), "{c:?}");
                proptest::prop_assert!(!c.from_mps.is_nan() && !c.to_mps.is_nan(), "{c:?}");
            }
            proptest::prop_assert!(changes.len() <= positions.len() / 2 + 1);
        }
    }

    #[test]
    fn poses_missing_noise_and_bad_positions_are_no_change_of_speed() {
        // One step over five missing poses.
        let gap = drive(100, |k| if k == 50 { 120.0 } else { 20.0 });
        assert_eq!(speed_changes(&gap, 10.0), []);
        // 100 Hz with every position off by up to 2 cm (per-step speeds off by up to 4 m/s).
        let mut rng = crate::rng::Lcg(7);
        let noisy: Vec<[f64; 2]> = (0..2000)
            .map(|i| [0.2 * i as f64 + 0.04 * (rng.uniform() - 0.5), 0.0])
            .collect();
        assert_eq!(speed_changes(&noisy, 100.0), []);
        // A stretch of non-finite positions tells no speed.
        let mut holed = drive(100, |_| 20.0);
        holed[40..46].fill([f64::NAN, 0.0]);
        assert_eq!(speed_changes(&holed, 10.0), []);
        let stalled = drive(100, |k| if k < 50 { 20.0 } else { 0.0 });
        assert_eq!(speed_changes(&stalled, 10.0).len(), 1);
        // A rate that is no rate is taken as the presets'.
        assert_eq!(speed_changes(&stalled, 0.0), speed_changes(&stalled, 10.0));
        assert_eq!(
            speed_changes(&stalled, f64::NAN),
            speed_changes(&stalled, 10.0)
        );
    }
}
