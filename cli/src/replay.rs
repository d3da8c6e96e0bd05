//! Streaming a recorded trajectory through the daemon and collecting every answer.

use std::time::{Duration, Instant};

use lanealign_client::{Connection, PublishError, ReceiveError};
use lanealign_core::pose::Pose3;
use lanealign_wire::clock::monotonic_ns;
use lanealign_wire::payload::CorrectedPose;

/// How fast to publish.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rate {
    /// Poses per second.
    Hz(f64),
    /// As fast as the daemon answers, with at most this many poses in flight.
    Max(usize),
}

impl std::str::FromStr for Rate {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "max" {
            return Ok(Rate::Max(64));
        }
        match s.parse::<f64>() {
            Ok(hz) if hz.is_finite() && hz > 0.0 => Ok(Rate::Hz(hz)),
            _ => Err(format!(
                "rate '{s}': expected a positive number of Hz or 'max'"
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
    /// No daemon subscribed to the source in time.
    #[error("no daemon is serving source '{0}' (waited {1:?})")]
    NoDaemon(String, Duration),
    /// Some poses never came back.
    #[error("{missing} of {sent} poses did not come back within {timeout:?} (first missing: seq {first})")]
    Lost {
        /// How many are missing.
        missing: usize,
        /// How many were sent.
        sent: usize,
        /// The first missing sequence number.
        first: u64,
        /// How long the replay waited after the last pose.
        timeout: Duration,
    },
}

/// Every answer, in sequence order (`answers[i]` has `seq = first_seq + i`).
#[derive(Debug, Clone)]
pub struct Replay {
    /// The corrected poses.
    pub answers: Vec<CorrectedPose>,
    /// Round-trip latency per pose (client send to client receive), nanoseconds.
    pub round_trip_ns: Vec<u64>,
}

/// Publishes `poses` as `seq = first_seq..` with the given stamps (nanoseconds) and collects
/// every answer; an answer to a sequence number this replay did not send is ignored.
pub fn replay(
    conn: &Connection,
    source: &str,
    poses: &[Pose3],
    stamps_ns: &[i64],
    first_seq: u64,
    rate: Rate,
    wait_for_daemon: Duration,
) -> Result<Replay, ReplayError> {
    let until = Instant::now() + wait_for_daemon;
    while !conn.daemon_connected() {
        if Instant::now() > until {
            return Err(ReplayError::NoDaemon(source.to_string(), wait_for_daemon));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let n = poses.len();
    let mut answers: Vec<Option<CorrectedPose>> = vec![None; n];
    let mut round_trip_ns = vec![0u64; n];
    let mut received = 0usize;
    let mut take = |answer: CorrectedPose, received: &mut usize| {
        let now = monotonic_ns();
        let Some(i) = answer
            .seq
            .checked_sub(first_seq)
            .map(|i| i as usize)
            .filter(|&i| i < n)
        else {
            return;
        };
        if answers[i].is_none() {
            round_trip_ns[i] = now.saturating_sub(answer.sent_mono_ns);
            answers[i] = Some(answer);
            *received += 1;
        }
    };
    let start = Instant::now();
    for (i, pose) in poses.iter().enumerate() {
        match rate {
            Rate::Hz(hz) => {
                let due = start + Duration::from_secs_f64(i as f64 / hz);
                while let Some(left) = due.checked_duration_since(Instant::now()) {
                    match conn.recv(left)? {
                        Some(a) => take(a, &mut received),
                        None => break,
                    }
                }
            }
            Rate::Max(in_flight) => {
                while i - received >= in_flight {
                    match conn.recv(Duration::from_secs(5))? {
                        Some(a) => take(a, &mut received),
                        None => break,
                    }
                }
            }
        }
        let stamp_ns = stamps_ns.get(i).copied().unwrap_or(i as i64);
        conn.publish(first_seq + i as u64, stamp_ns, &pose.to_row_major())?;
        while let Some(a) = conn.try_recv()? {
            take(a, &mut received);
        }
    }
    let timeout = Duration::from_secs(10);
    let until = Instant::now() + timeout;
    while received < n && Instant::now() < until {
        if let Some(a) = conn.recv(Duration::from_millis(100))? {
            take(a, &mut received);
        }
    }
    if received < n {
        let first = answers.iter().position(Option::is_none).unwrap_or(0) as u64 + first_seq;
        return Err(ReplayError::Lost {
            missing: n - received,
            sent: n,
            first,
            timeout,
        });
    }
    Ok(Replay {
        answers: answers.into_iter().flatten().collect(),
        round_trip_ns,
    })
}
