//! How often the daemon's log tells something a session's odometry may do again and again: jump
//! (each answered with status `odometry_jump` and raised in the session's answers,
//! `Warning::Jumped`), or take a step the corrector takes for poses missing (each published with a
//! covariance that covers a glitch). The log, read by people, tells the first and then at most
//! one every [`TOLD_EVERY`], with how many it did not tell since. An odometry that glitches on
//! every other pose at 100 Hz wrote 50 WARN lines a second before, one per jump.

use std::time::{Duration, Instant};

/// The shortest time between two repeats of a session that the log tells.
pub const TOLD_EVERY: Duration = Duration::from_secs(10);

/// The repeats of a session the log has not told, by sequence number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Untold {
    /// How many.
    pub count: u64,
    /// The first one's sequence number.
    pub first_seq: u64,
    /// The last one's sequence number.
    pub last_seq: u64,
}

/// A repeat the log tells.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Told {
    /// The repeats before it that the log did not tell.
    pub untold_before: Option<Untold>,
}

/// What the log has told of one thing a session's odometry repeats.
#[derive(Clone, Debug, Default)]
pub struct RepeatLog {
    /// When the last repeat told was.
    told_at: Option<Instant>,
    /// The repeats since, untold.
    untold: Option<Untold>,
}

impl RepeatLog {
    /// Takes a repeat at sequence number `seq` (at `now`); `Some` when the log tells it, `None`
    /// when it is left untold.
    pub fn repeated(&mut self, seq: u64, now: Instant) -> Option<Told> {
        let due = self
            .told_at
            .is_none_or(|at| now.saturating_duration_since(at) >= TOLD_EVERY);
        if due {
            self.told_at = Some(now);
            return Some(Told {
                untold_before: self.untold.take(),
            });
        }
        self.untold = Some(match self.untold {
            Some(u) => Untold {
                count: u.count.saturating_add(1),
                last_seq: seq,
                ..u
            },
            None => Untold {
                count: 1,
                first_seq: seq,
                last_seq: seq,
            },
        });
        None
    }

    /// The repeats left untold where the session ends.
    pub fn finish(&mut self) -> Option<Untold> {
        self.untold.take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_jump_is_told_then_one_in_ten_seconds_with_those_between() {
        let start = Instant::now();
        let at = |ms: u64| start + Duration::from_millis(ms);
        let mut log = RepeatLog::default();
        let told = |untold_before| Some(Told { untold_before });
        assert_eq!(log.repeated(100, at(0)), told(None));
        // Every other pose at 100 Hz: 499 more within the 10 s, untold.
        for k in 1..500 {
            assert_eq!(log.repeated(100 + 2 * k, at(20 * k)), None, "jump {k}");
        }
        let between = Untold {
            count: 499,
            first_seq: 102,
            last_seq: 1098,
        };
        assert_eq!(log.repeated(1100, at(10_000)), told(Some(between)));
        assert_eq!(log.repeated(1102, at(10_020)), None);
        assert_eq!(
            log.finish(),
            Some(Untold {
                count: 1,
                first_seq: 1102,
                last_seq: 1102
            })
        );
        assert_eq!(log.finish(), None);
        // A jump long after the last told is told, with none untold before it.
        assert_eq!(log.repeated(5000, at(60_000)), told(None));
    }
}
