//! One worker thread per source: it owns the source's iceoryx2 node, ports and corrector, waits
//! (without polling) for poses, corrects them and publishes the results.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::identifiers::UniquePublisherId;
use iceoryx2::prelude::*;
use lanealign_client::connection::{
    event_service, monotonic_ns, pubsub_service, service_names, ConnectionError,
};
use lanealign_client::wire::{pose_from_wire, pose_to_wire, CorrectedPose, OdomPose, WireStatus};
use lanealign_core::corrector::{RejectReason, Status, StepTiming};
use lanealign_core::geo::MapPlane;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::offline::{Source, SourceCorrector};

use crate::config::ResolvedSource;
use crate::metrics::SourceMetrics;

/// How long a worker waits for a pose before it checks for shutdown.
const WAKE_UP: Duration = Duration::from_millis(100);

/// A worker that could not start.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// Its services or ports could not be set up.
    #[error("source {name}: {error}")]
    Transport {
        /// The source.
        name: String,
        /// What failed.
        error: ConnectionError,
    },
}

/// What a worker did over its life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WorkerSummary {
    /// Poses received.
    pub received: u64,
    /// Corrected poses published.
    pub published: u64,
}

/// Sequence-number bookkeeping: per publisher, so that a restarted client starts afresh.
#[derive(Default)]
struct Sequences {
    last: Vec<(UniquePublisherId, u64)>,
}

impl Sequences {
    /// `None` when `seq` is new for this publisher, else why it is not.
    fn check(&mut self, publisher: UniquePublisherId, seq: u64) -> Option<WireStatus> {
        match self.last.iter_mut().find(|(p, _)| *p == publisher) {
            Some((_, last)) if seq == *last => Some(WireStatus::DuplicateSeq),
            Some((_, last)) if seq < *last => Some(WireStatus::OutOfOrderSeq),
            Some((_, last)) => {
                *last = seq;
                None
            }
            None => {
                self.last.push((publisher, seq));
                None
            }
        }
    }
}

fn reason_code(r: RejectReason) -> u32 {
    match r {
        RejectReason::TooFewMatches => 1,
        RejectReason::ResidualTooLarge => 2,
    }
}

/// Corrects one input: the answer and the step's timing.
fn process(
    corrector: &mut SourceCorrector,
    sequences: &mut Sequences,
    origin: UniquePublisherId,
    input: &OdomPose,
    pass_through: bool,
    received_mono_ns: u64,
) -> (CorrectedPose, StepTiming) {
    let mut out = CorrectedPose {
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
        status: WireStatus::PassThrough as u32,
        reason: 0,
        reserved: 0,
    };
    if pass_through {
        return (out, StepTiming::default());
    }
    if let Some(flag) = sequences.check(origin, input.seq) {
        out.status = flag as u32;
        return (out, StepTiming::default());
    }
    let (record, timing) = corrector.correct(&pose_from_wire(&input.pose));
    let [x, y] = record.map_from_odom.translation();
    out.map_from_odom = [x, y, record.map_from_odom.yaw()];
    out.pose = pose_to_wire(&record.pose);
    let (status, reason, residual_m, match_ratio, window_len) = match record.status {
        Status::WarmingUp { window_len } => {
            (WireStatus::WarmingUp, 0, f64::NAN, f64::NAN, window_len)
        }
        Status::Accepted {
            residual_m,
            match_ratio,
            window_len,
        } => (WireStatus::Accepted, 0, residual_m, match_ratio, window_len),
        Status::Rejected {
            reason,
            residual_m,
            match_ratio,
            window_len,
        } => (
            WireStatus::Rejected,
            reason_code(reason),
            residual_m,
            match_ratio,
            window_len,
        ),
        Status::Reset {
            reason,
            residual_m,
            match_ratio,
            window_len,
        } => (
            WireStatus::Reset,
            reason_code(reason),
            residual_m,
            match_ratio,
            window_len,
        ),
        Status::InvalidInput => (WireStatus::InvalidInput, 0, f64::NAN, f64::NAN, 0),
    };
    out.status = status as u32;
    out.reason = reason;
    out.residual_m = residual_m;
    out.match_ratio = match_ratio;
    out.window_len = window_len as u32;
    (out, timing)
}

/// Runs a source until `shutdown` is set: receive, correct, publish, report.
pub fn run(
    source: ResolvedSource,
    map: Arc<LaneMap>,
    plane: MapPlane,
    metrics_interval: Duration,
    shutdown: Arc<AtomicBool>,
) -> Result<WorkerSummary, WorkerError> {
    let transport = |error| WorkerError::Transport {
        name: source.name.clone(),
        error,
    };
    let node = NodeBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| transport(ConnectionError::Node(format!("{e:?}"))))?;
    let (odom, corrected) = service_names(&source.name);
    let port_error = |port: &'static str, service: &str, e: &dyn std::fmt::Debug| {
        transport(ConnectionError::Port {
            port,
            service: service.to_string(),
            message: format!("{e:?}"),
        })
    };
    let subscriber = pubsub_service::<OdomPose>(&node, &odom, &source.name)
        .map_err(transport)?
        .subscriber_builder()
        .create()
        .map_err(|e| port_error("subscriber", &odom, &e))?;
    let listener = event_service(&node, &odom, &source.name)
        .map_err(transport)?
        .listener_builder()
        .create()
        .map_err(|e| port_error("listener", &odom, &e))?;
    let notifier = event_service(&node, &corrected, &source.name)
        .map_err(transport)?
        .notifier_builder()
        .create()
        .map_err(|e| port_error("notifier", &corrected, &e))?;
    // Created last: clients take its existence as the sign that the worker is ready.
    let publisher = pubsub_service::<CorrectedPose>(&node, &corrected, &source.name)
        .map_err(transport)?
        .publisher_builder()
        .create()
        .map_err(|e| port_error("publisher", &corrected, &e))?;

    let placement = Source {
        convention: source.convention,
        plane_from_odom: source.anchor.plane_from_odom_in(&plane),
        smoothing: source.smoothing,
    };
    let mut corrector = SourceCorrector::new(map, source.params, source.match_mode, placement);
    let mut sequences = Sequences::default();
    let mut metrics = SourceMetrics::default();
    let mut summary = WorkerSummary::default();
    let mut next_report = Instant::now() + metrics_interval;
    tracing::info!(source = %source.name, preset_window = source.params.max_window, pass_through = source.pass_through, "worker started");
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
                    tracing::warn!(source = %source.name, error = ?e, "receive failed");
                    break;
                }
            };
            let received = monotonic_ns();
            summary.received += 1;
            let input = *sample;
            let origin = sample.origin();
            drop(sample);
            let span = tracing::debug_span!("pose", source = %source.name, seq = input.seq, in_daemon_us = tracing::field::Empty).entered();
            let (mut out, timing) = process(
                &mut corrector,
                &mut sequences,
                origin,
                &input,
                source.pass_through,
                received,
            );
            out.published_mono_ns = monotonic_ns();
            span.record(
                "in_daemon_us",
                (out.published_mono_ns - received) as f64 / 1e3,
            );
            drop(span);
            match WireStatus::from_code(out.status) {
                Some(WireStatus::Accepted) => metrics.accepted += 1,
                Some(WireStatus::Rejected | WireStatus::Reset) => metrics.rejected += 1,
                Some(
                    WireStatus::InvalidInput | WireStatus::DuplicateSeq | WireStatus::OutOfOrderSeq,
                ) => metrics.flagged += 1,
                _ => {}
            }
            if let Err(e) = publisher.send_copy(out) {
                tracing::warn!(source = %source.name, seq = out.seq, error = ?e, "publish failed");
                continue;
            }
            if let Err(e) = notifier.notify() {
                tracing::warn!(source = %source.name, error = ?e, "notify failed");
            }
            summary.published += 1;
            metrics.record(
                out.published_mono_ns.saturating_sub(input.sent_mono_ns),
                out.published_mono_ns - received,
                timing.matching.as_nanos() as u64,
                timing.icp.as_nanos() as u64,
                timing
                    .total
                    .saturating_sub(timing.matching + timing.icp)
                    .as_nanos() as u64,
            );
        }
        if stopping {
            break;
        }
        if Instant::now() >= next_report {
            metrics.report(&source.name);
            next_report += metrics_interval;
        }
    }
    metrics.report(&source.name);
    tracing::info!(source = %source.name, received = summary.received, published = summary.published, "worker stopped");
    Ok(summary)
}
