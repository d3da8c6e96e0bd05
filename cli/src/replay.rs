//! Streaming a recorded trajectory through the daemon and collecting every answer.

use std::time::{Duration, Instant};

use lanealign_client::connection::ConnectionEvents;
use lanealign_client::{Connection, PublishError, ReceiveError};
use lanealign_core::plausibility::plural;
use lanealign_core::pose::Pose3;
use lanealign_wire::clock::{deadline_after, monotonic_ns, time_left};
use lanealign_wire::payload::{CorrectedPose, ReasonCode, StatusCode};

/// How fast to publish.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rate {
    /// Poses per second ([`Rate::SLOWEST_HZ`] to [`Rate::FASTEST_HZ`] when read from text).
    Hz(f64),
    /// As fast as the daemon answers, with at most this many poses in flight.
    Max(usize),
}

impl Rate {
    /// The slowest rate a replay is asked for in text (Hz): a pose every 1000 s, the slowest
    /// `odometry_rate_hz` a corrector takes. Slower, the time a pose is due overflowed (a rate
    /// of 1e-300 Hz panicked at the second pose).
    pub const SLOWEST_HZ: f64 = lanealign_core::params::MIN_ODOMETRY_RATE_HZ;
    /// The fastest (Hz): the corrector's `odometry_rate_hz` bound; beyond it, use `max`.
    pub const FASTEST_HZ: f64 = lanealign_core::params::MAX_ODOMETRY_RATE_HZ;
}

impl std::str::FromStr for Rate {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "max" {
            return Ok(Rate::Max(64));
        }
        match s.parse::<f64>() {
            Ok(hz) if (Rate::SLOWEST_HZ..=Rate::FASTEST_HZ).contains(&hz) => Ok(Rate::Hz(hz)),
            _ => Err(format!(
                "rate '{}': expected {} to {} Hz, or 'max'",
                lanealign_core::input::quote(s),
                Rate::SLOWEST_HZ,
                Rate::FASTEST_HZ
            )),
        }
    }
}

/// A replay that did not complete.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// Publishing failed.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// Receiving failed.
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    /// No daemon serves the source.
    #[error("no daemon is serving source '{name}' (waited {waited:?}): {why}")]
    NoDaemon {
        /// The source's name.
        name: String,
        /// How long the replay waited for a daemon.
        waited: Duration,
        /// What the namespace holds instead ([`Connection::why_unserved`]).
        why: String,
    },
    /// Some poses never came back: which, and everything that did.
    #[error("{} of {sent} poses were not answered within {timeout:?} of the last answer (sequence numbers {}){}", missing.len(), summarize(missing), if *unopened { NOT_OPENED } else { "" })]
    Lost {
        /// The poses not answered.
        missing: Vec<u64>,
        /// True when a living daemon served the source but had not opened the session when
        /// the replay gave up ([`Connection::session_opened`]).
        unopened: bool,
        /// How many were published.
        sent: usize,
        /// How long the replay waited without progress.
        timeout: Duration,
        /// What did come back.
        partial: Box<Replay>,
    },
}

impl ReplayError {
    /// What came back of a replay that lost poses ([`ReplayError::Lost`]).
    pub fn partial(&self) -> Option<&Replay> {
        match self {
            ReplayError::Lost { partial, .. } => Some(partial),
            _ => None,
        }
    }
}

/// What a lost replay adds when the daemon never opened its session.
const NOT_OPENED: &str = "; the daemon never opened this session: its log says why (`cannot answer a session`, e.g. no room in /dev/shm)";

/// The first few of a list of sequence numbers.
fn summarize(seqs: &[u64]) -> String {
    let shown: Vec<String> = seqs.iter().take(10).map(u64::to_string).collect();
    let more = seqs.len().saturating_sub(10);
    if more > 0 {
        format!("{}, and {more} more", shown.join(", "))
    } else {
        shown.join(", ")
    }
}

/// A warning when some of `answers` came back uncorrected because their session waited for a
/// place among the source's `max_sessions` (`pass_through`, reason `sessions_full`): another
/// client of the source held every place while they were sent.
pub fn waited_for_place_warning(answers: &[CorrectedPose]) -> Option<String> {
    let waited: Vec<u64> = answers
        .iter()
        .filter(|a| {
            a.status() == Some(StatusCode::PassThrough)
                && a.reason == ReasonCode::SessionsFull as u32
        })
        .map(|a| a.seq)
        .collect();
    let (first, last) = (waited.first()?, waited.last()?);
    Some(format!(
        "{} pose{} (sequence numbers {first} to {last}) came back uncorrected: the source's \
         sessions were all in use by other clients streaming at the same time, and this one \
         waited for a place (status pass_through, reason sessions_full); raise max_sessions in \
         lanealignd's configuration, or stop the other clients",
        waited.len(),
        plural(waited.len()),
    ))
}

/// Every answer, in sequence order (`answers[i]` has `seq = i + 1`), and how the connection
/// fared.
#[derive(Debug, Clone)]
pub struct Replay {
    /// The answers (for a complete replay, one per pose).
    pub answers: Vec<CorrectedPose>,
    /// Round-trip latency per answer (its last send to its receipt), nanoseconds.
    pub round_trip_ns: Vec<u64>,
    /// Restarts, re-sent poses, gaps, fresh starts.
    pub events: ConnectionEvents,
}

/// Publishes `poses` (with `stamps_ns`, or their index) as the session's poses 1, 2, ... and
/// collects every answer. Waits up to `wait_for_daemon` for a daemon at the start, and fails
/// naming the missing poses when no answer arrives for `stall` (a daemon restarting in between
/// is fine: the connection sends again what it did not answer).
pub fn replay(
    conn: &mut Connection,
    source: &str,
    poses: &[Pose3],
    stamps_ns: &[i64],
    rate: Rate,
    wait_for_daemon: Duration,
    stall: Duration,
) -> Result<Replay, ReplayError> {
    let until = deadline_after(wait_for_daemon);
    while !conn.daemon_connected() {
        if time_left(until).is_zero() {
            return Err(ReplayError::NoDaemon {
                name: source.to_string(),
                waited: wait_for_daemon,
                why: conn.why_unserved(),
            });
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let n = poses.len();
    let first_seq = conn.next_seq();
    let mut answers: Vec<Option<CorrectedPose>> = vec![None; n];
    let mut round_trip_ns = vec![0u64; n];
    let mut received = 0usize;
    let mut last_progress = Instant::now();
    let mut take = |answer: CorrectedPose, received: &mut usize, last_progress: &mut Instant| {
        let i = answer.seq.wrapping_sub(first_seq) as usize;
        if i < n && answers[i].is_none() {
            round_trip_ns[i] = monotonic_ns().saturating_sub(answer.sent_mono_ns);
            answers[i] = Some(answer);
            *received += 1;
            *last_progress = Instant::now();
        }
    };
    let start = Instant::now();
    for (i, pose) in poses.iter().enumerate() {
        if let Rate::Hz(hz) = rate {
            let due = start + Duration::from_secs_f64(i as f64 / hz);
            while let Some(left) = due.checked_duration_since(Instant::now()) {
                match conn.recv(left)? {
                    Some(a) => take(a, &mut received, &mut last_progress),
                    None => break,
                }
            }
        }
        let stamp = stamps_ns.get(i).copied().unwrap_or(i as i64);
        loop {
            let limit = match rate {
                Rate::Max(k) => k,
                Rate::Hz(_) => usize::MAX,
            };
            let full = i - received >= limit;
            if !full {
                match conn.publish(stamp, &pose.to_row_major()) {
                    Ok(_) => break,
                    Err(PublishError::Full { .. }) => {}
                    Err(e) => return Err(e.into()),
                }
            }
            match conn.recv(Duration::from_millis(100))? {
                Some(a) => take(a, &mut received, &mut last_progress),
                None if last_progress.elapsed() > stall => {
                    return Err(lost(&answers, first_seq, &round_trip_ns, conn, stall));
                }
                None => {}
            }
        }
        while let Some(a) = conn.try_recv()? {
            take(a, &mut received, &mut last_progress);
        }
    }
    while received < n {
        match conn.recv(Duration::from_millis(100))? {
            Some(a) => take(a, &mut received, &mut last_progress),
            None if last_progress.elapsed() > stall => {
                return Err(lost(&answers, first_seq, &round_trip_ns, conn, stall));
            }
            None => {}
        }
    }
    Ok(Replay {
        answers: answers.into_iter().flatten().collect(),
        round_trip_ns,
        events: conn.events(),
    })
}

fn lost(
    answers: &[Option<CorrectedPose>],
    first_seq: u64,
    round_trip_ns: &[u64],
    conn: &mut Connection,
    timeout: Duration,
) -> ReplayError {
    let missing = answers
        .iter()
        .enumerate()
        .filter(|(_, a)| a.is_none())
        .map(|(i, _)| first_seq + i as u64)
        .collect();
    ReplayError::Lost {
        missing,
        unopened: conn.daemon_connected() && !conn.session_opened(),
        sent: answers.len(),
        timeout,
        partial: Box::new(Replay {
            answers: answers.iter().flatten().copied().collect(),
            round_trip_ns: round_trip_ns.to_vec(),
            events: conn.events(),
        }),
    }
}
