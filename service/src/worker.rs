//! One worker thread per source: it owns the source's iceoryx2 node, ports and one corrector per
//! client session, waits (without polling) for poses, corrects them and publishes the answers.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Sender;
use std::sync::Arc;
use std::time::{Duration, Instant};

use lanealign_core::corrector::{RejectReason, Status, StepTiming};
use lanealign_core::geo::MapPlane;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::pose::Pose3;
use lanealign_core::source_corrector::{Placement, SourceCorrector};
use lanealign_wire::clock::monotonic_ns;
use lanealign_wire::payload::{CorrectedPose, OdomPose, ReasonCode, StatusCode};
use lanealign_wire::service::{
    Namespace, NodeCreateError, PortCreateError, ServiceOpenError, SourceServices,
};

use crate::config::ResolvedSource;
use crate::metrics::{Outcome, SourceMetrics};

/// How long a worker waits for a pose before it checks for shutdown.
const WAKE_UP: Duration = Duration::from_millis(100);

/// A worker that could not start.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// Its node could not be created.
    #[error("source {name}")]
    Node {
        /// The source.
        name: String,
        /// What failed.
        #[source]
        source: NodeCreateError,
    },
    /// Its services could not be opened.
    #[error("source {name}")]
    Service {
        /// The source.
        name: String,
        /// What failed.
        #[source]
        source: ServiceOpenError,
    },
    /// A port could not be created.
    #[error("source {name}")]
    Port {
        /// The source.
        name: String,
        /// What failed.
        #[source]
        source: PortCreateError,
    },
}

/// What a worker did over its life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WorkerSummary {
    /// Poses received.
    pub received: u64,
    /// Answers published.
    pub published: u64,
}

/// The wire's status and reason for a corrector status: the one conversion between the two
/// models.
pub fn wire_status(status: &Status) -> (StatusCode, ReasonCode) {
    let code = match status {
        Status::WarmingUp { .. } => StatusCode::WarmingUp,
        Status::Accepted { .. } => StatusCode::Accepted,
        Status::Rejected { .. } => StatusCode::Rejected,
        Status::Reset { .. } => StatusCode::Reset,
        Status::InvalidInput => StatusCode::InvalidInput,
    };
    let reason = match status.reason() {
        None => ReasonCode::None,
        Some(RejectReason::TooFewMatches) => ReasonCode::TooFewMatches,
        Some(RejectReason::ResidualTooLarge) => ReasonCode::ResidualTooLarge,
    };
    (code, reason)
}

/// One client session's corrector and sequence bookkeeping.
struct Session {
    corrector: SourceCorrector,
    last_seq: Option<u64>,
}

/// Everything a source's worker keeps between poses.
struct SourceState {
    source: ResolvedSource,
    map: Arc<LaneMap>,
    placement: Placement,
    sessions: HashMap<u64, Session>,
}

impl SourceState {
    /// Answers one input: the answer, what happened, and the step's timing.
    fn process(
        &mut self,
        input: &OdomPose,
        received_mono_ns: u64,
    ) -> (CorrectedPose, Outcome, StepTiming) {
        let mut out = CorrectedPose {
            session: input.session,
            seq: input.seq,
            stamp_ns: input.stamp_ns,
            sent_mono_ns: input.sent_mono_ns,
            received_mono_ns,
            published_mono_ns: 0,
            pose: input.pose,
            map_from_odom: [f64::NAN; 3],
            residual_m: f64::NAN,
            match_ratio: f64::NAN,
            window_len: 0,
            status: StatusCode::PassThrough as u32,
            reason: ReasonCode::None as u32,
            reserved: 0,
        };
        if self.source.pass_through {
            return (out, Outcome::PassThrough, StepTiming::default());
        }
        let (map, params, mode, placement) = (
            &self.map,
            self.source.params,
            self.source.corrector.match_mode,
            self.placement,
        );
        let session = self
            .sessions
            .entry(input.session)
            .or_insert_with(|| Session {
                corrector: SourceCorrector::new(map.clone(), params, mode, placement),
                last_seq: None,
            });
        let flag = match session.last_seq {
            Some(last) if input.seq == last => Some(StatusCode::DuplicateSeq),
            Some(last) if input.seq < last => Some(StatusCode::OutOfOrderSeq),
            _ => None,
        };
        if let Some(flag) = flag {
            out.status = flag as u32;
            return (out, Outcome::Flagged, StepTiming::default());
        }
        session.last_seq = Some(input.seq);
        let (record, timing) = session
            .corrector
            .correct(&Pose3::from_row_major(&input.pose));
        let [x, y] = record.map_from_odom.translation();
        out.map_from_odom = [x, y, record.map_from_odom.yaw()];
        out.pose = record.pose.to_row_major();
        let (status, reason) = wire_status(&record.status);
        out.status = status as u32;
        out.reason = reason as u32;
        out.residual_m = record.status.residual_m().unwrap_or(f64::NAN);
        out.match_ratio = record.status.match_ratio().unwrap_or(f64::NAN);
        out.window_len = record.status.window_len() as u32;
        let outcome = match record.status {
            Status::InvalidInput => Outcome::Flagged,
            status => Outcome::Corrected(status),
        };
        (out, outcome, timing)
    }
}

/// Runs a source until `shutdown` is set: receive, correct, publish, report. Tells `ready`
/// once its ports exist (or why they could not be made) before serving.
pub fn run(
    source: ResolvedSource,
    namespace: Namespace,
    map: Arc<LaneMap>,
    plane: MapPlane,
    metrics_interval: Duration,
    shutdown: Arc<AtomicBool>,
    ready: Sender<Result<(), WorkerError>>,
) -> WorkerSummary {
    let name = source.name.to_string();
    let setup = || -> Result<_, WorkerError> {
        let node = namespace.node().map_err(|e| WorkerError::Node {
            name: name.clone(),
            source: e,
        })?;
        let services =
            SourceServices::open(&node, &source.name).map_err(|e| WorkerError::Service {
                name: name.clone(),
                source: e,
            })?;
        let port = |e| WorkerError::Port {
            name: name.clone(),
            source: e,
        };
        let subscriber = services.odom_subscriber().map_err(port)?;
        let listener = services.odom_listener().map_err(port)?;
        let notifier = services.corrected_notifier().map_err(port)?;
        // Created last: clients take its existence as the sign that the worker is ready.
        let publisher = services.corrected_publisher().map_err(port)?;
        Ok((node, subscriber, listener, notifier, publisher))
    };
    let (_node, subscriber, listener, notifier, publisher) = match setup() {
        Ok(ports) => ports,
        Err(e) => {
            // The daemon is waiting for this; if it is gone, there is no one left to tell.
            let _ = ready.send(Err(e));
            return WorkerSummary::default();
        }
    };
    let _ = ready.send(Ok(()));
    let placement = Placement {
        convention: source.convention,
        anchored_from_odom: source.anchor.anchored_from_odom(&plane),
        smoothing: source.corrector.smoothing(),
    };
    tracing::info!(source = %name, method = source.corrector.method.name(), preset = source.corrector.preset.name(), pass_through = source.pass_through, "worker started");
    let mut state = SourceState {
        source,
        map,
        placement,
        sessions: HashMap::new(),
    };
    let mut metrics = SourceMetrics::default();
    let mut summary = WorkerSummary::default();
    let mut next_report = Instant::now() + metrics_interval;
    loop {
        // On shutdown, answer what is already queued once more, then stop.
        let stopping = shutdown.load(Ordering::Relaxed);
        if !stopping {
            // An interrupted wait (a signal) is a wake-up like any other.
            let _ = listener.timed_wait(|_| {}, WAKE_UP);
        }
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(sample)) => sample,
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!(source = %name, error = %e, "receive failed");
                    break;
                }
            };
            let received = monotonic_ns();
            summary.received += 1;
            let input = *sample;
            drop(sample);
            let (mut out, outcome, timing) = state.process(&input, received);
            out.published_mono_ns = monotonic_ns();
            let in_daemon_ns = out.published_mono_ns.saturating_sub(received);
            tracing::debug!(source = %name, session = input.session, seq = input.seq, status = StatusCode::from_code(out.status).map_or("", StatusCode::name), in_daemon_us = in_daemon_ns as f64 / 1e3, "pose");
            if let Err(e) = publisher.send_copy(out) {
                tracing::warn!(source = %name, seq = out.seq, error = %e, "publish failed");
                continue;
            }
            if let Err(e) = notifier.notify() {
                tracing::warn!(source = %name, error = %e, "notify failed");
            }
            summary.published += 1;
            metrics.record(
                &outcome,
                out.published_mono_ns.saturating_sub(input.sent_mono_ns),
                in_daemon_ns,
                &timing,
            );
        }
        if stopping {
            break;
        }
        if Instant::now() >= next_report {
            metrics.report(&name);
            next_report += metrics_interval;
        }
    }
    metrics.report(&name);
    tracing::info!(source = %name, received = summary.received, published = summary.published, "worker stopped");
    summary
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_statuses_carry_the_correctors_names() {
        let statuses = [
            Status::WarmingUp { window_len: 3 },
            Status::Accepted {
                residual_m: 0.1,
                match_ratio: 0.9,
                window_len: 200,
            },
            Status::Rejected {
                reason: RejectReason::TooFewMatches,
                residual_m: f64::INFINITY,
                match_ratio: 0.1,
                window_len: 199,
            },
            Status::Reset {
                reason: RejectReason::ResidualTooLarge,
                residual_m: 3.0,
                match_ratio: 0.8,
                window_len: 149,
            },
            Status::InvalidInput,
        ];
        assert_eq!(statuses.len(), Status::NAMES.len());
        for s in statuses {
            let (code, reason) = wire_status(&s);
            assert_eq!(code.name(), s.name());
            assert_eq!(reason.name(), s.reason().map_or("", RejectReason::name));
        }
    }
}
