//! An odometry that loses track: the road it may have missed, as uncertainty along the road.
//!
//! A visual odometry that sees too little stalls: its speed falls faster than a car can brake
//! while the vehicle drives on. The road it misses lies along the direction of travel, where a
//! straight road's lanes cannot show it, so the corrector's covariance, built for an odometry
//! that drifts a little with every metre, said a few metres where the corrected pose was off by
//! a hundred (the shared visual odometry of KITTI 01, docs/method.md, "Confidence").
//!
//! [`StallWatch`] watches the odometry's speed as the warning does ([`SpeedWatch`], at the rate
//! the stamps say). From a fall faster than [`MAX_ACCELERATION_MPS2`] until the
//! odometry has found its track again (its speed rises as fast, or one step is as long as the
//! speed before the fall covers) it counts the distance the odometry fell short of its speed before the
//! fall: the vehicle is taken to have driven on at that speed. The pose's uncertainty along the
//! direction the vehicle was heading widens by that distance squared: all of it was missed in
//! one direction, so it adds up as one error, not as independent ones. The heading's widens too:
//! over the road missed the vehicle may have turned, by about [`TURN_ACCELERATION_SD_MPS2`] over
//! its speed squared per metre, and the uncertainty drives that road unseen, so that the heading
//! error it had and the one it gains turn into position error across the road as the vehicle
//! drives on. Alignments take it away as they do any other uncertainty, where the lanes show the
//! position along that direction (a curve, a crossing road) and the heading.
//!
//! Frames: positions and headings are in any fixed planar frame (the source corrector's
//! `scaled`, [`crate::source_corrector`]); a [`Widening`]'s direction is in the same frame.

use crate::plausibility::{
    judged_rate_hz, rate_from_stamps, SourceWatch, SpeedChange, SpeedHistory, SpeedWatch,
    MAX_ACCELERATION_MPS2,
};

/// How fast a car turns (m/s^2, one standard deviation of its mean lateral acceleration over a
/// few seconds): while the odometry misses `d` metres of road at `v` m/s the vehicle may have
/// turned by about this times `d / v^2` radians. KITTI's ground truth (every sequence, wherever
/// the car drives faster than 5 m/s, over 1, 3 and 6 s) turns at mean lateral accelerations
/// whose 95th percentile is 0.03-4.6 m/s^2 by sequence and whose largest is 5.4 m/s^2 (the
/// ramps of 01's highway): two standard deviations cover all but the sharpest turns.
pub const TURN_ACCELERATION_SD_MPS2: f64 = 2.0;

/// The standard deviation (radians) of a heading known not at all, spread evenly over the
/// circle: `pi / sqrt(3)`. A stall widens the heading no further (after 58 m missed at 8 m/s).
pub const UNKNOWN_HEADING_SD_RAD: f64 = 1.813_799_364_234_217_8;

/// A stall under way: the odometry's speed fell faster than a car can brake.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stall {
    /// The odometry's speed before the fall (m/s): the vehicle is taken to drive on at it.
    pub before_mps: f64,
    /// The direction the vehicle was heading when the fall was told (a unit vector).
    pub heading: [f64; 2],
    /// The distance the odometry fell short of `before_mps` so far (metres).
    pub missed_m: f64,
}

/// How much a pose widens the uncertainty: the road the odometry missed with it, along
/// `direction` (a unit vector, the frame of the positions observed), and what the vehicle may
/// have turned on it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Widening {
    /// The direction the vehicle was heading when the odometry stalled.
    pub direction: [f64; 2],
    /// The road missed with this pose (metres, along `direction`).
    pub missed_m: f64,
    /// The position's variance added along `direction` (metres squared).
    pub along_variance_m2: f64,
    /// The heading's variance added (radians squared).
    pub yaw_variance_rad2: f64,
    /// Whether the stall was told with this pose (it began some poses before).
    pub began: bool,
}

impl Widening {
    /// Adds `later`'s widening of the same stall to this one.
    fn add(&mut self, later: &Widening) {
        self.missed_m += later.missed_m;
        self.along_variance_m2 += later.along_variance_m2;
        self.yaw_variance_rad2 += later.yaw_variance_rad2;
    }
}

/// What a [`StallWatch`] has seen, to continue from later (a daemon's snapshot of a session).
#[derive(Clone, Debug, PartialEq)]
pub struct StallState {
    /// The first poses (stamp in seconds, x, y in metres, heading in radians) while their stamps
    /// have not told the rate yet; empty once they have.
    pub held: Vec<[f64; 4]>,
    /// The rate (Hz) the speed is judged at and what the speed watch has seen, once the stamps
    /// have told it.
    pub judged: Option<(f64, SpeedHistory)>,
    /// The last position taken (metres).
    pub last: Option<[f64; 2]>,
    /// The stall under way, if one is.
    pub open: Option<Stall>,
}

/// Watches an odometry's speed for stalls and says how much each pose widens the uncertainty
/// along the road (see the module's documentation). The speed is judged at the rate the
/// first [`SourceWatch::STAMPS`] stamps say, or at the rate the corrector is set for where they
/// say none (no stamps: a file in KITTI's format) or none an odometry runs at
/// ([`judged_rate_hz`]), as the daemon's warning judges it; until
/// then the poses are held.
#[derive(Clone, Debug)]
pub struct StallWatch {
    set_rate_hz: f64,
    held: Vec<[f64; 4]>,
    judged: Option<(f64, SpeedWatch)>,
    last: Option<[f64; 2]>,
    open: Option<Stall>,
}

impl StallWatch {
    /// A watch for a source whose corrector is set for `set_rate_hz`.
    pub fn new(set_rate_hz: f64) -> Self {
        StallWatch {
            set_rate_hz,
            held: Vec::with_capacity(SourceWatch::STAMPS),
            judged: None,
            last: None,
            open: None,
        }
    }

    /// A watch for a source whose corrector is set for `set_rate_hz` that continues from
    /// `state`, exactly as the one it was saved from would.
    pub fn restore(set_rate_hz: f64, state: StallState) -> Self {
        StallWatch {
            set_rate_hz,
            held: state.held,
            judged: state
                .judged
                .map(|(rate_hz, history)| (rate_hz, SpeedWatch::resume(rate_hz, history))),
            last: state.last,
            open: state.open,
        }
    }

    /// What the watch has seen (see [`StallWatch::restore`]).
    pub fn state(&self) -> StallState {
        StallState {
            held: self.held.clone(),
            judged: self
                .judged
                .as_ref()
                .map(|(rate_hz, watch)| (*rate_hz, watch.history())),
            last: self.last,
            open: self.open,
        }
    }

    /// The stall under way, if one is.
    pub fn stall(&self) -> Option<&Stall> {
        self.open.as_ref()
    }

    /// Takes the next pose's position (metres), heading (radians, from the frame's x axis
    /// towards its y axis) and stamp (seconds; NaN without one); hands `widen` what it widens
    /// the uncertainty by (the poses held until the stamps told the rate are judged with the
    /// one that completed them, and each stall among them widens it once).
    pub fn observe(
        &mut self,
        position: [f64; 2],
        heading: f64,
        stamp_s: f64,
        mut widen: impl FnMut(Widening),
    ) {
        if self.judged.is_some() {
            if let Some(widening) = self.take(position, heading) {
                widen(widening);
            }
            return;
        }
        self.held.push([stamp_s, position[0], position[1], heading]);
        if self.held.len() < SourceWatch::STAMPS {
            return;
        }
        let stamps: Vec<f64> = self.held.iter().map(|h| h[0]).collect();
        let rate_hz = judged_rate_hz(rate_from_stamps(&stamps), self.set_rate_hz);
        self.judged = Some((rate_hz, SpeedWatch::new(rate_hz)));
        let mut pending: Option<Widening> = None;
        for [_, x, y, heading] in std::mem::take(&mut self.held) {
            let Some(widening) = self.take([x, y], heading) else {
                continue;
            };
            match &mut pending {
                Some(p) if !widening.began => p.add(&widening),
                _ => {
                    if let Some(p) = pending.replace(widening) {
                        widen(p);
                    }
                }
            }
        }
        if let Some(p) = pending {
            widen(p);
        }
    }

    /// The next pose at the judged rate: the stall it tells, ends or falls short in.
    fn take(&mut self, position: [f64; 2], heading: f64) -> Option<Widening> {
        let (rate_hz, speed) = self.judged.as_mut()?;
        let rate_hz = *rate_hz;
        let step = self.last.replace(position).map_or(0.0, |last| {
            (position[0] - last[0]).hypot(position[1] - last[1])
        });
        let missed_before = self.open.map_or(0.0, |s| s.missed_m);
        let was_open = self.open.is_some();
        match speed.observe(position) {
            Some(change) if change.acceleration_mps2() < -MAX_ACCELERATION_MPS2 => {
                if self.open.is_none() {
                    let since_s = speed.poses_since(&change) as f64 / rate_hz;
                    self.open = Some(opened(&change, heading, since_s));
                } else {
                    self.fall_short(step, rate_hz);
                }
            }
            Some(change) if change.acceleration_mps2() > MAX_ACCELERATION_MPS2 => {
                self.open = None;
            }
            _ => self.fall_short(step, rate_hz),
        }
        let stall = self.open?;
        let missed_m = stall.missed_m - missed_before;
        (missed_m > 0.0).then(|| {
            // The heading's standard deviation grows with the road missed, as a car's turn
            // does: by the lateral acceleration over the speed squared per metre (a stall's
            // speed before is at least the fall it was told by, MAX_ACCELERATION_MPS2 times a
            // span), up to a heading known not at all.
            let turn_per_m = TURN_ACCELERATION_SD_MPS2 / stall.before_mps.powi(2);
            let heading_sd = |missed_m: f64| (turn_per_m * missed_m).min(UNKNOWN_HEADING_SD_RAD);
            Widening {
                direction: stall.heading,
                missed_m,
                along_variance_m2: stall.missed_m.powi(2) - missed_before.powi(2),
                yaw_variance_rad2: heading_sd(stall.missed_m).powi(2)
                    - heading_sd(missed_before).powi(2),
                began: !was_open,
            }
        })
    }

    /// Counts what a step of `step_m` metres fell short of the speed before the stall under
    /// way at `rate_hz`; a step as long as that speed covers in a period ends it.
    fn fall_short(&mut self, step_m: f64, rate_hz: f64) {
        let Some(stall) = &mut self.open else {
            return;
        };
        let expected_m = stall.before_mps / rate_hz;
        if step_m >= expected_m {
            self.open = None;
        } else {
            stall.missed_m += expected_m - step_m;
        }
    }
}

/// A stall told by `change`, `since_s` seconds ago: it fell short of the speed before it by the
/// speed after it since, heading as the vehicle heads now.
fn opened(change: &SpeedChange, heading: f64, since_s: f64) -> Stall {
    Stall {
        before_mps: change.from_mps,
        heading: [heading.cos(), heading.sin()],
        missed_m: (change.from_mps - change.to_mps).max(0.0) * since_s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight drive along x at `rate_hz` with the odometry's speed (m/s) at each time (s).
    fn drive(seconds: f64, rate_hz: f64, speed: impl Fn(f64) -> f64) -> Vec<[f64; 2]> {
        let mut x = 0.0;
        (0..(seconds * rate_hz) as usize)
            .map(|i| {
                x += speed(i as f64 / rate_hz) / rate_hz;
                [x, 0.0]
            })
            .collect()
    }

    /// The widenings of `drive`'s poses, with the pose that told each, stamped at `stamp_hz`
    /// (no stamps: 0).
    fn widen(watch: &mut StallWatch, drive: &[[f64; 2]], stamp_hz: f64) -> Vec<(usize, Widening)> {
        let mut out = Vec::new();
        for (i, &p) in drive.iter().enumerate() {
            let stamp = if stamp_hz > 0.0 {
                i as f64 / stamp_hz
            } else {
                f64::NAN
            };
            watch.observe(p, 0.0, stamp, |w| out.push((i, w)));
        }
        out
    }

    /// 20 m/s, 0.2 m/s from 10 s to 13 s, then 20 m/s again.
    fn stall(t: f64) -> f64 {
        if (10.0..13.0).contains(&t) {
            0.2
        } else {
            20.0
        }
    }

    #[test]
    fn a_stall_widens_along_the_road_by_the_distance_missed() {
        let poses = drive(20.0, 10.0, stall);
        let mut watch = StallWatch::new(10.0);
        let widenings = widen(&mut watch, &poses, 0.0);
        let added: f64 = widenings.iter().map(|(_, w)| w.along_variance_m2).sum();
        // The vehicle drove on at 20 m/s: 3 s of 19.8 m/s missed.
        let missed = 3.0 * 19.8;
        assert!(
            (added.sqrt() - missed).abs() < 0.1 * missed,
            "{} m against {missed} m",
            added.sqrt()
        );
        assert!(widenings.iter().all(|(_, w)| w.direction == [1.0, 0.0]));
        // Told within a second of the fall, once, and over once the speed is back.
        let (first, w) = widenings[0];
        assert!(
            (100..112).contains(&first) && w.began,
            "first widening at {first}"
        );
        assert!(widenings[1..].iter().all(|(_, w)| !w.began));
        assert!(watch.stall().is_none());
        assert!(widenings.iter().all(|&(i, _)| i < 140));
    }

    #[test]
    fn a_stall_widens_the_heading_by_what_a_car_may_turn_on_the_road_missed() {
        let poses = drive(20.0, 10.0, stall);
        let widenings = widen(&mut StallWatch::new(10.0), &poses, 0.0);
        let missed: f64 = widenings.iter().map(|(_, w)| w.missed_m).sum();
        let along: f64 = widenings.iter().map(|(_, w)| w.along_variance_m2).sum();
        let yaw: f64 = widenings.iter().map(|(_, w)| w.yaw_variance_rad2).sum();
        // The road missed is the along-road sd, and 2 m/s^2 over (20 m/s)^2 per metre of it
        // in heading: 0.005 rad/m over 59 m, 17 degrees.
        assert!(
            (missed - along.sqrt()).abs() < 1e-9,
            "{missed} against {along}"
        );
        assert!(
            (yaw.sqrt() - 0.005 * missed).abs() < 1e-9,
            "{} rad over {missed} m",
            yaw.sqrt()
        );
    }

    #[test]
    fn braking_as_a_car_can_widens_nothing() {
        // 20 m/s, braking at 8 m/s^2 to a stand, standing, and off again at 3 m/s^2.
        let speed = |t: f64| match t {
            t if t < 10.0 => 20.0,
            t if t < 12.5 => 20.0 - 8.0 * (t - 10.0),
            t if t < 20.0 => 0.0,
            t => (3.0 * (t - 20.0)).min(20.0),
        };
        let mut watch = StallWatch::new(10.0);
        assert_eq!(widen(&mut watch, &drive(40.0, 10.0, speed), 0.0), []);
    }

    #[test]
    fn an_odometry_that_never_finds_its_track_again_keeps_widening() {
        let poses = drive(30.0, 10.0, |t| if t < 10.0 { 15.0 } else { 0.0 });
        let mut watch = StallWatch::new(10.0);
        let added: f64 = widen(&mut watch, &poses, 0.0)
            .iter()
            .map(|(_, w)| w.along_variance_m2)
            .sum();
        assert!(watch.stall().is_some());
        // 20 s of 15 m/s.
        assert!((added.sqrt() - 300.0).abs() < 15.0, "{}", added.sqrt());
        // The heading's sd grows by 2 m/s^2 / (15 m/s)^2 per metre, to a heading known not at
        // all after 204 m, and no further.
        let yaw: f64 = widen(&mut StallWatch::new(10.0), &poses, 0.0)
            .iter()
            .map(|(_, w)| w.yaw_variance_rad2)
            .sum();
        assert!(
            (yaw.sqrt() - UNKNOWN_HEADING_SD_RAD).abs() < 1e-9,
            "{} rad",
            yaw.sqrt()
        );
    }

    #[test]
    fn the_speed_is_judged_at_the_rate_the_stamps_say() {
        // At 100 Hz, stamped, for a corrector set for 10 Hz: braking as a car can is no stall,
        // and a stall is measured in seconds, not in the set rate's periods.
        let braking = drive(30.0, 100.0, |t| (20.0 - 8.0 * (t - 10.0).max(0.0)).max(0.0));
        assert_eq!(widen(&mut StallWatch::new(10.0), &braking, 100.0), []);
        let stalled = drive(20.0, 100.0, stall);
        let added: f64 = widen(&mut StallWatch::new(10.0), &stalled, 100.0)
            .iter()
            .map(|(_, w)| w.along_variance_m2)
            .sum();
        assert!((added.sqrt() - 3.0 * 19.8).abs() < 6.0, "{}", added.sqrt());
        // Without stamps the poses are taken at the set rate: ten times too slow, so the same
        // stall is a fall of 2 m/s, which a car can brake.
        assert_eq!(widen(&mut StallWatch::new(10.0), &stalled, 0.0), []);
    }

    #[test]
    fn a_stall_among_the_poses_held_for_the_rate_widens_once() {
        // The stall at 3 s, before the 64 stamps (6.4 s) have told the rate.
        let poses = drive(
            12.0,
            10.0,
            |t| if (3.0..4.5).contains(&t) { 0.1 } else { 20.0 },
        );
        let widenings = widen(&mut StallWatch::new(10.0), &poses, 10.0);
        assert_eq!(widenings.len(), 1, "{widenings:?}");
        let (told, w) = widenings[0];
        assert_eq!(told, SourceWatch::STAMPS - 1);
        assert!(
            w.began && (w.along_variance_m2.sqrt() - 1.5 * 19.9).abs() < 3.0,
            "{w:?}"
        );
    }

    #[test]
    fn a_restored_watch_goes_on_as_the_one_it_was_saved_from() {
        let poses = drive(20.0, 10.0, stall);
        let mut whole = StallWatch::new(10.0);
        let expected = widen(&mut whole, &poses, 10.0);
        for cut in [30, 64, 103, 106, 115, 131, 135] {
            let mut first = StallWatch::new(10.0);
            let mut got = widen(&mut first, &poses[..cut], 10.0);
            let mut restored = StallWatch::restore(10.0, first.state());
            let rest = widen(&mut restored, &poses[cut..], 10.0);
            got.extend(rest.into_iter().map(|(i, w)| (i + cut, w)));
            assert_eq!(got, expected, "cut at {cut}");
        }
    }
}
