//! A stream of stamped poses judged as it comes (a daemon session's): its axes, its rate and
//! its speed, pose by pose.

use super::axes::AxisMotion;
use super::rate::{judged_rate_hz, rate_from_stamps};
use super::speed::{moving_step_m, pace_warning, SpeedChange, SpeedHistory, SpeedWatch};
use crate::pose::{AxisConvention, Pose3};

/// From how far (metres of path) into a stream a [`SourceWatch`] tells that its poses move
/// vertically more than [`MAX_VERTICAL_SHARE`](super::MAX_VERTICAL_SHARE) of the way. The
/// share of the path so far: on the 30 shared KITTI runs read in their own axes it stays below
/// 0.07 from here to [`AXIS_JUDGED_UNTIL_M`], but for the ground truth of 08, which rises 0.18 m
/// a pose while the car sets off (0.45 at 30 m, 0.30 at 60 m); read in the other axes it passes
/// 0.33 by 97 m on all of them but that one. The first metres alone cannot tell: a drive that
/// turns at once moves along an axis that is horizontal in both conventions.
pub const AXIS_JUDGED_FROM_M: f64 = 60.0;

/// How far (metres of path) a [`SourceWatch`] follows a stream's axes before it takes them as
/// right.
pub const AXIS_JUDGED_UNTIL_M: f64 = 300.0;

/// On how many steps that move a [`SourceWatch`] judges a stream's pace (its median speed
/// against `max_speed_mps`, as [`speed_warning`](super::speed_warning) judges a file's): five
/// seconds of driving at 10 Hz, however long the vehicle stood before.
pub const PACE_STEPS: usize = 50;

/// What a stream of stamped poses (a daemon session's) says of its source as the poses come,
/// as `correct` judges a file: whether they move as the set axis convention says (told once,
/// between [`AXIS_JUDGED_FROM_M`] and [`AXIS_JUDGED_UNTIL_M`] of path, as
/// [`axes_warning`](super::axes_warning) tells it), and else whether they stand upright over
/// their first [`AXIS_JUDGED_UNTIL_M`] (as it tells that too, told once); the rate its first
/// [`SourceWatch::STAMPS`] stamps say ([`rate_from_stamps`]), told once; its pace, the median
/// speed of its first [`PACE_STEPS`] steps that move at that rate, when it is beyond any
/// vehicle's (told once); and the changes of speed no car makes ([`SpeedWatch`]) judged at that
/// rate, or at the rate the corrector is set for where the stamps say none an odometry runs at
/// ([`judged_rate_hz`]). Until the stamps tell
/// the rate, it holds the positions, and then judges them. The changes wait for the pace to be
/// judged: a pace beyond any vehicle's (positions in centimetres, a wrong rate) explains them,
/// and they are not told.
#[derive(Clone, Debug)]
pub struct SourceWatch {
    /// The rate (Hz) the corrector is set for: the speed's when the stamps tell no rate.
    set_rate_hz: f64,
    /// The speed (m/s) beyond any vehicle's, for the pace.
    max_speed_mps: f64,
    /// The axis convention the poses are said to come in.
    convention: AxisConvention,
    /// The motion so far, until the axes are judged.
    axes: Option<AxisMotion>,
    /// The first stamps (seconds), until they tell the rate.
    stamps_s: Vec<f64>,
    /// The planar positions (metres) that came with them.
    held: Vec<[f64; 2]>,
    /// The watch and the rate (Hz) it judges at, once that is known.
    speed: Option<(SpeedWatch, f64)>,
    /// The pace, judged or still gathered.
    pace: Pace,
}

/// A stream's pace ([`SourceWatch`]): its median speed against `max_speed_mps`.
#[derive(Clone, Debug, PartialEq)]
pub enum Pace {
    /// Not judged yet.
    Gathering {
        /// The lengths (metres) of the steps that moved so far, at most [`PACE_STEPS`].
        steps_m: Vec<f64>,
        /// The last position (planar, metres), once there is one.
        last: Option<[f64; 2]>,
        /// The changes of speed no car makes found meanwhile, oldest first, told once the pace
        /// is judged a vehicle's.
        changes: Vec<SpeedChange>,
    },
    /// A vehicle's: the changes of speed are told as they come.
    Plausible,
    /// Beyond any vehicle's (told): the changes of speed are what that makes, and not told.
    TooFast,
}

impl Default for Pace {
    /// Nothing gathered yet.
    fn default() -> Self {
        Pace::Gathering {
            steps_m: Vec::new(),
            last: None,
            changes: Vec::new(),
        }
    }
}

/// What a [`SourceWatch`] has seen, to continue from later (a daemon's snapshot of a session):
/// with the rate the source's corrector is set for and the axis convention, all it needs.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceWatchState {
    /// The motion so far, while the axes are still followed.
    pub axes: Option<AxisMotion>,
    /// The first stamps (seconds, any number a client sent), while they have not told the
    /// rate yet; empty once they have.
    pub stamps_s: Vec<f64>,
    /// The planar positions (metres) that came with them.
    pub held: Vec<[f64; 2]>,
    /// The rate (Hz) the speed is judged at and what the speed watch has seen, once the stamps
    /// have told it.
    pub speed: Option<(f64, SpeedHistory)>,
    /// The pace, judged or still gathered.
    pub pace: Pace,
}

/// What one pose told a [`SourceWatch`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SourceNews {
    /// The rate (Hz) the stamps say, with the pose that completed the first
    /// [`SourceWatch::STAMPS`] of them (never again, nor when they say none).
    pub rate_hz: Option<f64>,
    /// A warning when the poses move or stand as no vehicle does in the set axis convention,
    /// with the pose that judged them (or where the stream ends).
    pub axis_warning: Option<String>,
    /// A warning when the poses move faster than any vehicle ([`PACE_STEPS`]), with the pose
    /// that judged their pace (or where the stream ends).
    pub pace_warning: Option<String>,
    /// The changes of speed no car makes that ended with this pose (or, with the pose that
    /// told the rate, among the poses held until then), oldest first.
    pub speed_changes: Vec<SpeedChange>,
}

impl SourceWatch {
    /// Stamps gathered before the rate is told.
    pub const STAMPS: usize = 64;

    /// A watch for a source whose corrector is set for `set_rate_hz` and `max_speed_mps` and
    /// whose poses are said to come in `convention`.
    pub fn new(set_rate_hz: f64, max_speed_mps: f64, convention: AxisConvention) -> Self {
        SourceWatch {
            set_rate_hz,
            max_speed_mps,
            convention,
            axes: Some(AxisMotion::default()),
            stamps_s: Vec::with_capacity(Self::STAMPS),
            held: Vec::with_capacity(Self::STAMPS),
            speed: None,
            pace: Pace::default(),
        }
    }

    /// A watch for a source whose corrector is set for `set_rate_hz` and `max_speed_mps` and
    /// whose poses are said to come in `convention` that continues from `state`, exactly as the
    /// one it was saved from ([`SourceWatch::state`]) would.
    pub fn restore(
        set_rate_hz: f64,
        max_speed_mps: f64,
        convention: AxisConvention,
        state: SourceWatchState,
    ) -> Self {
        SourceWatch {
            set_rate_hz,
            max_speed_mps,
            convention,
            axes: state.axes,
            stamps_s: state.stamps_s,
            held: state.held,
            speed: state
                .speed
                .map(|(rate_hz, history)| (SpeedWatch::resume(rate_hz, history), rate_hz)),
            pace: state.pace,
        }
    }

    /// What the watch has seen (see [`SourceWatch::restore`]).
    pub fn state(&self) -> SourceWatchState {
        SourceWatchState {
            axes: self.axes.clone(),
            stamps_s: self.stamps_s.clone(),
            held: self.held.clone(),
            speed: self
                .speed
                .as_ref()
                .map(|(watch, rate_hz)| (*rate_hz, watch.history())),
            pace: self.pace.clone(),
        }
    }

    /// Takes the next pose (`odom_from_body` in the set convention) and its stamp (seconds).
    pub fn observe(&mut self, stamp_s: f64, pose: &Pose3) -> SourceNews {
        let axis_warning = self.follow_axes(pose);
        let position = self.convention.to_planar(pose).planar_position();
        if let Pace::Gathering { steps_m, last, .. } = &mut self.pace {
            let from = last.replace(position);
            if steps_m.len() < PACE_STEPS {
                steps_m.extend(from.and_then(|from| moving_step_m(from, position)));
            }
        }
        let mut news = match &mut self.speed {
            Some((speed, _)) => SourceNews {
                speed_changes: speed.observe(position).into_iter().collect(),
                ..SourceNews::default()
            },
            None => {
                self.stamps_s.push(stamp_s);
                self.held.push(position);
                if self.stamps_s.len() < Self::STAMPS {
                    SourceNews::default()
                } else {
                    self.judge_held()
                }
            }
        };
        news.axis_warning = axis_warning;
        self.pass_on_changes(&mut news, false);
        news
    }

    /// Where the stream ends: a change of speed still under way, for a stream shorter than
    /// [`SourceWatch::STAMPS`] poses what its stamps and positions say at all, and for one shorter
    /// than [`AXIS_JUDGED_UNTIL_M`] its tilt (a stream shorter than [`AXIS_JUDGED_FROM_M`] is
    /// not judged for its axes).
    pub fn finish(&mut self) -> SourceNews {
        let mut news = match self.speed {
            Some(_) => SourceNews::default(),
            None => self.judge_held(),
        };
        news.axis_warning = self
            .axes
            .take()
            .filter(|motion| motion.path_m() >= AXIS_JUDGED_FROM_M)
            .and_then(|motion| motion.tilt_warning(self.convention));
        news.speed_changes
            .extend(self.speed.as_mut().and_then(|(s, _)| s.finish()));
        self.pass_on_changes(&mut news, true);
        news
    }

    /// Passes the changes of speed in `news` on as the pace says: told once it is a vehicle's,
    /// held while it is gathered, and dropped when it is beyond any vehicle's. Judges the pace
    /// once the rate is known and [`PACE_STEPS`] steps have moved, or where the stream `ends`.
    fn pass_on_changes(&mut self, news: &mut SourceNews, ends: bool) {
        let rate_hz = self.speed_rate_hz();
        match &mut self.pace {
            Pace::Plausible => {}
            Pace::TooFast => news.speed_changes.clear(),
            Pace::Gathering {
                steps_m, changes, ..
            } => {
                changes.append(&mut news.speed_changes);
                let Some(rate_hz) = rate_hz.filter(|_| ends || steps_m.len() >= PACE_STEPS) else {
                    return;
                };
                news.pace_warning = pace_warning(steps_m, rate_hz, self.max_speed_mps);
                self.pace = match news.pace_warning {
                    Some(_) => Pace::TooFast,
                    None => {
                        news.speed_changes = std::mem::take(changes);
                        Pace::Plausible
                    }
                };
            }
        }
    }

    /// Follows the motion until its axes are told wrong (from [`AXIS_JUDGED_FROM_M`] of path on)
    /// or [`AXIS_JUDGED_UNTIL_M`] of path have not told them so; then tells whether the poses
    /// were tilted as no vehicle drives ([`axes_warning`](super::axes_warning)). Poses in the
    /// other convention are tilted too, so the tilt waits for the axes to be judged right.
    fn follow_axes(&mut self, pose: &Pose3) -> Option<String> {
        let motion = self.axes.as_mut()?;
        motion.observe(pose);
        let path_m = motion.path_m();
        if path_m < AXIS_JUDGED_FROM_M {
            return None;
        }
        let judged = path_m >= AXIS_JUDGED_UNTIL_M;
        let warning = motion.warning(self.convention).or_else(|| {
            judged
                .then(|| motion.tilt_warning(self.convention))
                .flatten()
        });
        if warning.is_some() || judged {
            self.axes = None;
        }
        warning
    }

    /// Judges the held positions' speed at the rate their stamps say (or the set rate), at
    /// which it watches on.
    fn judge_held(&mut self) -> SourceNews {
        let rate_hz = rate_from_stamps(&self.stamps_s);
        let judged_hz = judged_rate_hz(rate_hz, self.set_rate_hz);
        let mut speed = SpeedWatch::new(judged_hz);
        let speed_changes = self.held.iter().filter_map(|&p| speed.observe(p)).collect();
        self.speed = Some((speed, judged_hz));
        (self.stamps_s, self.held) = (Vec::new(), Vec::new());
        SourceNews {
            rate_hz,
            speed_changes,
            ..SourceNews::default()
        }
    }

    /// How many poses `change` (told by this watch) lies before the last pose observed.
    pub fn poses_since(&self, change: &SpeedChange) -> usize {
        self.speed
            .as_ref()
            .map_or(0, |(s, _)| s.poses_since(change))
    }

    /// The rate (Hz) the speed is judged at: the stamps', or the set rate where they tell none;
    /// `None` while the stamps are still gathered.
    pub fn speed_rate_hz(&self) -> Option<f64> {
        self.speed.as_ref().map(|&(_, rate_hz)| rate_hz)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plausibility::speed::speed_changes;
    use crate::plausibility::speed::tests::{drive, drive_at};

    /// A source at 2 Hz set for 10 Hz: its speed is judged at the rate its stamps say, the
    /// positions held until they say it included, so that braking is not read as five times
    /// faster and five times steeper. A stall is told at that rate, where it lies, before and
    /// after the stamps have told.
    #[test]
    fn a_session_is_judged_at_the_rate_of_its_stamps() {
        let stamps: Vec<f64> = (0..200).map(|i| 100.0 + 0.5 * i as f64).collect();
        // Braking at 4 m/s^2 from 20 m/s to 4 m/s and speeding up as hard again, from pose 20
        // (held) and from pose 120.
        let braking = drive_at(2.0, 199, |k| match k % 100 {
            k @ 0..50 => (20.0 - 2.0 * k.saturating_sub(20) as f64).max(4.0),
            k => (4.0 + 2.0 * (k - 50) as f64).min(20.0),
        });
        assert!(
            !speed_changes(&braking, 10.0).is_empty(),
            "read at the set 10 Hz, the braking is 25 times steeper"
        );
        let mut watch = SourceWatch::new(10.0, 70.0, AxisConvention::Flu);
        let news: Vec<SourceNews> = stamps
            .iter()
            .zip(&along_x(&braking))
            .map(|(&s, p)| watch.observe(s, p))
            .collect();
        let rates: Vec<f64> = news.iter().filter_map(|n| n.rate_hz).collect();
        assert_eq!(rates.len(), 1);
        assert!((rates[0] - 2.0).abs() < 1e-9, "{rates:?}");
        assert!(news[SourceWatch::STAMPS - 1].rate_hz.is_some());
        assert_eq!(watch.speed_rate_hz(), Some(2.0));
        let told: Vec<&SpeedChange> = news.iter().flat_map(|n| &n.speed_changes).collect();
        assert!(told.is_empty(), "{told:?}");
        // A stall from 20 to 0.5 m/s in one step at pose 30 (held), its recovery at 100 and the
        // same stall at 130.
        let stalled = along_x(&drive_at(
            2.0,
            199,
            |k| {
                if k % 100 < 30 {
                    20.0
                } else {
                    0.5
                }
            },
        ));
        let mut watch = SourceWatch::new(10.0, 70.0, AxisConvention::Flu);
        let mut told = Vec::new();
        for (i, (&s, p)) in stamps.iter().zip(&stalled).enumerate() {
            for change in watch.observe(s, p).speed_changes {
                told.push(i - watch.poses_since(&change));
            }
        }
        assert_eq!(told.len(), 3, "{told:?}");
        for (at, pose) in [30, 100, 130].into_iter().zip(told) {
            assert!((at - 1..=at + 2).contains(&pose), "{pose} for {at}");
        }
        // A stream that ends in a stall, or before its stamps have told the rate, is told when
        // it ends.
        for poses in [32, 132] {
            let mut watch = SourceWatch::new(10.0, 70.0, AxisConvention::Flu);
            let during: usize = stamps
                .iter()
                .zip(&stalled[..poses])
                .map(|(&s, p)| watch.observe(s, p).speed_changes.len())
                .sum();
            assert_eq!(during, if poses < 100 { 0 } else { 2 });
            let end = watch.finish();
            assert_eq!(end.speed_changes.len(), 1, "{poses}: {end:?}");
            let pose = poses - 1 - watch.poses_since(&end.speed_changes[0]);
            assert!((poses - 11..poses).contains(&pose), "{pose} of {poses}");
            assert_eq!(end.rate_hz.is_some(), poses < SourceWatch::STAMPS);
        }
        // Stamps that tell no rate leave it at the set rate.
        let mut watch = SourceWatch::new(10.0, 70.0, AxisConvention::Flu);
        let news: Vec<SourceNews> = stalled.iter().map(|p| watch.observe(0.0, p)).collect();
        assert!(news.iter().all(|n| n.rate_hz.is_none()));
        assert_eq!(watch.speed_rate_hz(), Some(10.0));
    }

    /// A watch saved at any pose and restored tells from there on exactly what the one that
    /// went on tells: the rate (held stamps and positions included), the axes (poses that climb
    /// as far as they drive), the stalls and their recoveries, and a stall under way at the end;
    /// or, for the same poses ten times as far apart, their pace and none of their changes.
    #[test]
    fn a_restored_watch_goes_on_as_if_never_stopped() {
        let stamps: Vec<f64> = (0..300).map(|i| 100.0 + 0.5 * i as f64).collect();
        for scale in [1.0, 10.0] {
            // Climbing as steeply as it drives (half the path vertical: axes no vehicle moves in).
            let speed = |k: usize| scale * if k % 100 < 30 { 20.0 } else { 0.5 };
            let poses: Vec<Pose3> = drive_at(2.0, 231, speed)
                .iter()
                .map(|&[x, y]| Pose3::planar(x, y, 0.0, x))
                .collect();
            let told = |news: &SourceNews| {
                news.rate_hz.is_some()
                    || news.axis_warning.is_some()
                    || news.pace_warning.is_some()
                    || !news.speed_changes.is_empty()
            };
            let mut whole = SourceWatch::new(10.0, 70.0, AxisConvention::Flu);
            let expected: Vec<(usize, SourceNews)> = (0..poses.len())
                .map(|i| (i, whole.observe(stamps[i], &poses[i])))
                .filter(|(_, n)| told(n))
                .collect();
            let expected_end = whole.finish();
            assert!(expected.iter().any(|(_, n)| n.rate_hz.is_some()));
            assert!(expected.iter().any(|(_, n)| n.axis_warning.is_some()));
            let count =
                |told: fn(&SourceNews) -> bool| expected.iter().filter(|(_, n)| told(n)).count();
            let (changes, paces) = (
                count(|n| !n.speed_changes.is_empty()),
                count(|n| n.pace_warning.is_some()),
            );
            let ended_in_a_stall = expected_end.speed_changes.len();
            if scale == 1.0 {
                assert!(
                    changes >= 4 && paces == 0 && ended_in_a_stall == 1,
                    "{expected:?}"
                );
            } else {
                assert!(
                    changes == 0 && paces == 1 && ended_in_a_stall == 0,
                    "{expected:?}"
                );
            }
            for saved_at in (0..poses.len()).step_by(7).chain([63, 64, 65]) {
                let mut before = SourceWatch::new(10.0, 70.0, AxisConvention::Flu);
                let mut got: Vec<(usize, SourceNews)> = (0..saved_at)
                    .map(|i| (i, before.observe(stamps[i], &poses[i])))
                    .collect();
                let mut after =
                    SourceWatch::restore(10.0, 70.0, AxisConvention::Flu, before.state());
                assert_eq!(after.state(), before.state());
                got.extend(
                    (saved_at..poses.len()).map(|i| (i, after.observe(stamps[i], &poses[i]))),
                );
                got.retain(|(_, n)| told(n));
                assert_eq!(got, expected, "saved at pose {saved_at}");
                assert_eq!(after.finish(), expected_end, "saved at pose {saved_at}");
            }
        }
    }

    /// A session whose positions are in centimetres moves faster than any vehicle: told once,
    /// where its first [`PACE_STEPS`] steps that move are judged (after 100 poses standing, or
    /// where the stamps tell the rate, whichever is later), or where a shorter stream ends; its
    /// braking, 100 times steeper, is not told as changes of speed. In metres nothing is told of
    /// its pace, and a stall while the pace is gathered is told once it is judged, where it lay.
    #[test]
    fn a_session_in_centimetres_is_told_its_pace_not_its_changes_of_speed() {
        // Standing 100 poses, then speeding up at 4 m/s^2 to 12 m/s, braking at 6 m/s^2 to a
        // stop at pose 220 for 4 s, and off again.
        let speed = |k: usize| match k {
            0..100 => 0.0,
            100..200 => (0.4 * (k - 99) as f64).min(12.0),
            200..220 => 12.0 - 0.6 * (k - 199) as f64,
            220..260 => 0.0,
            _ => (0.4 * (k - 259) as f64).min(12.0),
        };
        let metres = drive(399, speed);
        let centimetres: Vec<[f64; 2]> = metres.iter().map(|&[x, y]| [100.0 * x, y]).collect();
        let watched = |positions: &[[f64; 2]]| {
            let mut watch = SourceWatch::new(10.0, 70.0, AxisConvention::Flu);
            let news: Vec<SourceNews> = along_x(positions)
                .iter()
                .enumerate()
                .map(|(i, p)| watch.observe(0.1 * i as f64, p))
                .collect();
            (news, watch.finish())
        };
        let paces = |news: &[SourceNews]| -> Vec<(usize, String)> {
            let told = news.iter().enumerate();
            told.filter_map(|(i, n)| Some((i, n.pace_warning.clone()?)))
                .collect()
        };
        let changes = |news: &[SourceNews], end: &SourceNews| {
            news.iter()
                .chain([end])
                .map(|n| n.speed_changes.len())
                .sum::<usize>()
        };
        let (news, end) = watched(&metres);
        assert_eq!(paces(&news), vec![]);
        assert_eq!((changes(&news, &end), end.pace_warning), (0, None));
        let (news, end) = watched(&centimetres);
        let told = paces(&news);
        assert_eq!(told.len(), 1, "{told:?}");
        // Pose 101 ends the first step that moves.
        assert_eq!(told[0].0, 100 + PACE_STEPS);
        // The median of 30 steps speeding up and 20 at 12 m/s: the 26th, 10.4 m/s.
        assert!(told[0].1.contains("moves at 1040 m/s"), "{told:?}");
        assert!(
            told[0].1.contains("are its positions in metres"),
            "{told:?}"
        );
        assert_eq!((changes(&news, &end), end.pace_warning), (0, None));
        assert!(
            !speed_changes(&centimetres, 10.0).is_empty(),
            "in centimetres the stop is 100 times steeper than a car brakes"
        );
        // Moving from the first pose, the pace waits for the stamps to tell the rate.
        let (news, _) = watched(&centimetres[100..]);
        assert_eq!(paces(&news).len(), 1);
        assert_eq!(paces(&news)[0].0, SourceWatch::STAMPS - 1);
        let (news, end) = watched(&centimetres[100..130]);
        assert_eq!(paces(&news), vec![]);
        assert!(end
            .pace_warning
            .is_some_and(|w| w.contains("moves at 600 m/s")));
        // A stall at 12 m/s after 40 steps that move, told with the pace judged 10 poses on.
        let stalled = drive(399, |k| match k {
            0..100 => 0.0,
            100..140 => (0.4 * (k - 99) as f64).min(12.0),
            140..180 => 0.2,
            _ => (0.2 + 0.4 * (k - 179) as f64).min(12.0),
        });
        let (news, _) = watched(&stalled);
        let told: Vec<(usize, usize)> = news
            .iter()
            .enumerate()
            .flat_map(|(i, n)| n.speed_changes.iter().map(move |c| (i, c.pose)))
            .collect();
        assert_eq!(told.len(), 1, "{told:?}");
        assert_eq!(told[0].0, 100 + PACE_STEPS, "{told:?}");
        assert!((139..=142).contains(&told[0].1), "{told:?}");
    }

    /// Poses along x (planar `flu`, heading along x) at `positions`.
    fn along_x(positions: &[[f64; 2]]) -> Vec<Pose3> {
        positions
            .iter()
            .map(|&[x, y]| Pose3::planar(x, y, 0.0, 0.0))
            .collect()
    }

    /// A session's poses are checked for their axes from 60 m of path on: a camera's poses
    /// watched as `flu` are told once, with the convention that fits, also after standing still
    /// for longer than the rate takes to tell; watched as what they are, they are not. A drive
    /// that turns at once is told where its vertical share passes a third.
    #[test]
    fn a_session_in_the_wrong_axes_is_told_once() {
        let camera_of = |flu: &[Pose3]| -> Vec<Pose3> {
            flu.iter()
                .map(|p| AxisConvention::KittiCamera.from_planar(p))
                .collect()
        };
        let camera = camera_of(&along_x(&drive(399, |_| 10.0)));
        let parked_first: Vec<Pose3> = std::iter::repeat_n(camera[0], 100)
            .chain(camera.iter().copied())
            .collect();
        // 40 m along its start's right-hand axis (horizontal either way), then ahead.
        let turning = camera_of(
            &(0..400)
                .map(|i| {
                    let (x, y) = if i < 40 {
                        (0.0, -(i as f64))
                    } else {
                        ((i - 40) as f64, -40.0)
                    };
                    Pose3::planar(x, y, 0.0, 0.0)
                })
                .collect::<Vec<_>>(),
        );
        // The metres driven when the share of the path along the camera's forward axis (up,
        // read as `flu`) first passes a third: 60 for the straight drives, 60 for the turning
        // one (20 of 60 m).
        for (poses, told_at_m) in [(&camera, 60), (&parked_first, 60), (&turning, 60)] {
            for (convention, told) in [(AxisConvention::Flu, 1), (AxisConvention::KittiCamera, 0)] {
                let mut watch = SourceWatch::new(10.0, 70.0, convention);
                let warnings: Vec<(usize, String)> = poses
                    .iter()
                    .enumerate()
                    .filter_map(|(i, p)| Some((i, watch.observe(0.1 * i as f64, p).axis_warning?)))
                    .collect();
                assert_eq!(warnings.len(), told, "{convention:?}: {warnings:?}");
                if let Some((i, w)) = warnings.first() {
                    assert!(w.contains("--frame kitti-camera"), "{w}");
                    assert_eq!(poses.len() - i, 400 - told_at_m, "after {told_at_m} m");
                }
                assert_eq!(watch.finish().axis_warning, None);
            }
        }
    }

    /// A session's rotations read from quaternions written scalar first (`qw qx qy qz`) put the
    /// vehicle upside down: told once, when its first 300 m are judged in the right axes, or
    /// where a shorter stream ends; upright poses never are, and a camera's poses watched as
    /// `flu` (tilted too) are told their axes only.
    #[test]
    fn a_session_whose_poses_stand_as_no_vehicle_does_is_told_once() {
        let upright = along_x(&drive(499, |_| 10.0));
        let scalar_first: Vec<Pose3> = upright
            .iter()
            .map(crate::plausibility::axes::tests::scalar_first)
            .collect();
        let camera: Vec<Pose3> = upright
            .iter()
            .map(|p| AxisConvention::KittiCamera.from_planar(p))
            .collect();
        let told = |poses: &[Pose3]| {
            let mut watch = SourceWatch::new(10.0, 70.0, AxisConvention::Flu);
            let during: Vec<(usize, String)> = poses
                .iter()
                .enumerate()
                .filter_map(|(i, p)| Some((i, watch.observe(0.1 * i as f64, p).axis_warning?)))
                .collect();
            (during, watch.finish().axis_warning)
        };
        let (during, end) = told(&scalar_first);
        assert_eq!(during.len(), 1, "{during:?}");
        assert_eq!(during[0].0, 300, "at 300 m");
        assert!(
            during[0].1.contains("were these written qw qx qy qz?"),
            "{during:?}"
        );
        assert_eq!(end, None);
        assert_eq!(told(&upright), (vec![], None));
        let (during, end) = told(&scalar_first[..101]);
        assert!(during.is_empty(), "{during:?}");
        assert!(end.is_some_and(|w| w.contains("100% of their path")));
        let (during, end) = told(&camera);
        assert_eq!(during.len(), 1, "{during:?}");
        assert!(during[0].1.contains("--frame kitti-camera"), "{during:?}");
        assert_eq!(end, None);
    }
}
