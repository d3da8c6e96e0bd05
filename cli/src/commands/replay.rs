//! `lanealign replay`: streams a trajectory through a running lanealignd.

use lanealign_wire::wait::WaitStrategy;
use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use lanealign_cli::replay::{replay, waited_for_place_warning, Rate};
use lanealign_cli::status_file;
use lanealign_client::Connection;
use lanealign_core::input;
use lanealign_core::plausibility::{first_few, plural, refusals_warning};
use lanealign_core::pose::Pose3;
use lanealign_core::trajectory::{self, Format, Trajectory};
use lanealign_wire::payload::{
    from_upper_triangle, CorrectedPose, ReasonCode, StatusCode, Warning,
};
use lanealign_wire::service::{Namespace, SourceName};

use super::percentile_us;

/// The `lanealign replay` arguments.
#[derive(Args)]
pub struct ReplayArgs {
    /// The source name configured in lanealignd.
    #[arg(long)]
    source: SourceName,
    /// The daemon's namespace (its config's `namespace`).
    #[arg(long, default_value = "default")]
    namespace: Namespace,
    /// Poses per second, or max (flow-controlled, 64 in flight).
    #[arg(long, default_value = "max")]
    rate: Rate,
    /// How to wait for answers: event (sleep until notified), busy-spin[:CORE] (poll; a core
    /// pins this process's receiving thread) or spin-then-block:SPIN_US.
    #[arg(long, default_value = "event")]
    wait: WaitStrategy,
    /// Seconds to wait for a daemon to serve the source at the start.
    #[arg(long, default_value_t = 10.0)]
    wait_for_daemon: f64,
    /// File format: kitti or tum.
    #[arg(long, default_value = "kitti")]
    format: Format,
    /// The trajectory to stream (in the source's axis convention).
    input: PathBuf,
    /// Where to write the corrected trajectory.
    #[arg(short, long)]
    output: PathBuf,
    /// Also write the status CSV of `lanealign correct --status` from the daemon's answers: what
    /// the corrector did, `map_from_odom` and the covariance of each pose.
    #[arg(long)]
    status: Option<PathBuf>,
}

/// The status CSV ([`status_file`]) of the daemon's answers.
fn status_csv(answers: &[CorrectedPose]) -> String {
    status_file::format(answers.iter().map(|a| status_file::Row {
        status: a.status().map_or("unknown", StatusCode::name),
        reason: ReasonCode::from_code(a.reason).map_or("unknown", ReasonCode::name),
        residual_m: a.residual_m,
        match_ratio: a.match_ratio,
        window_len: a.window_len as usize,
        map_from_odom: a.map_from_odom,
        applied_directions: a.applied_directions.min(3) as u8,
        covariance: from_upper_triangle(&a.covariance),
        anchor_yaw: a.anchor_yaw,
        odometry_scale: a.odometry_scale,
        odometry_scale_sd: a.odometry_scale_sd,
    }))
}

/// What the daemon's `answers` say of a setup gone wrong or an odometry that jumped, as
/// `lanealign correct` warns of them for a file (the daemon's log says it too, but the person
/// replaying may not read it): from their statuses, and the warnings the session raised in them
/// beyond those.
fn warnings(answers: &[CorrectedPose]) -> Vec<String> {
    let with = |code: StatusCode| answers.iter().filter(move |a| a.status() == Some(code));
    let accepted = with(StatusCode::Accepted).count();
    let attempts = accepted + with(StatusCode::Rejected).count() + with(StatusCode::Reset).count();
    let jumps: Vec<u64> = with(StatusCode::OdometryJump).map(|a| a.seq).collect();
    let no_correction = refusals_warning(
        answers.len() - with(StatusCode::PassThrough).count(),
        attempts,
        accepted,
        "the source's anchor and frame in lanealignd's configuration and that its tile covers \
         the drive",
    );
    let jumped = (!jumps.is_empty()).then(|| {
        format!(
            "the odometry jumped at {} pose{} (sequence number{} {}): farther from the pose \
             before than the source's max_speed_mps allows, so the daemon continued each from \
             where the vehicle was (status odometry_jump); if the poses only paused or come \
             slower than its odometry_rate_hz, give their stamps (--format tum)",
            jumps.len(),
            plural(jumps.len()),
            plural(jumps.len()),
            first_few(jumps.iter().map(u64::to_string), jumps.len()),
        )
    });
    waited_for_place_warning(answers)
        .into_iter()
        .chain(no_correction)
        .chain(jumped)
        .chain(raised_warning(answers))
        .collect()
}

/// The warnings the daemon's watch raised in `answers` ([`CorrectedPose::warnings`]), but for
/// those [`warnings`] tells from the statuses themselves (refusals and jumps), each with the
/// sequence number of the first answer that carries it (the pose before it raised it).
fn raised_warning(answers: &[CorrectedPose]) -> Option<String> {
    let told: Vec<String> = Warning::ALL
        .into_iter()
        .filter(|w| !matches!(w, Warning::Refusals | Warning::Jumped))
        .filter_map(|w| {
            let first = answers.iter().find(|a| a.warnings & w.bit() != 0)?;
            Some(format!(
                "{} from sequence number {} on ({})",
                w.name(),
                first.seq,
                w.meaning()
            ))
        })
        .collect();
    (!told.is_empty()).then(|| {
        format!(
            "the daemon raised in this session's answers: {}; its log says more",
            told.join("; ")
        )
    })
}

/// Runs `lanealign replay`.
pub fn run(args: &ReplayArgs) -> anyhow::Result<()> {
    input::check_outputs_apart(
        &[Some(&args.output), args.status.as_deref()],
        &[Some(&args.input)],
    )?;
    let input = trajectory::read(&args.input, args.format)?;
    let stamps: Vec<i64> = input
        .stamps
        .as_ref()
        .map(|s| s.iter().map(|t| (t * 1e9).round() as i64).collect())
        .unwrap_or_default();
    let mut conn = Connection::connect_in(
        &args.namespace,
        &args.source,
        lanealign_client::connection::new_session_id(),
    )?;
    args.wait.pin_current_thread()?;
    conn.set_wait_strategy(args.wait);
    let result = match replay(
        &mut conn,
        args.source.as_str(),
        &input.poses,
        &stamps,
        args.rate,
        Duration::try_from_secs_f64(args.wait_for_daemon)
            .map_err(|_| anyhow::anyhow!("--wait-for-daemon must be a number of seconds"))?,
        Duration::from_secs(10),
    ) {
        Ok(r) => r,
        Err(e) => {
            // A replay that lost poses: what did come back, and that nothing was written.
            let outcome = e.partial().map(|p| {
                format!(
                    "nothing written ({} poses answered, {} daemon restarts)",
                    p.answers.len(),
                    p.events.daemon_restarts
                )
            });
            let e = anyhow::Error::new(e);
            return Err(match outcome {
                Some(outcome) => e.context(outcome),
                None => e,
            });
        }
    };
    let output = Trajectory {
        stamps: input.stamps.clone(),
        poses: result
            .answers
            .iter()
            .map(|a| Pose3::from_row_major(&a.pose))
            .collect(),
    };
    let status = args
        .status
        .as_deref()
        .map(|path| (path, status_csv(&result.answers)));
    let status = status.as_ref().map(|(path, csv)| (*path, csv.as_str()));
    status_file::write_run(&args.output, &output, args.format, status)?;
    // Every pose is answered: the daemon may forget the session now rather than at its timeout.
    if let Err(e) = conn.close(Duration::ZERO) {
        eprintln!("warning: the session was not closed: {e}");
    }
    let mut rt = result.round_trip_ns.clone();
    rt.sort_unstable();
    let accepted = result
        .answers
        .iter()
        .filter(|a| a.status() == Some(StatusCode::Accepted))
        .count();
    let ev = result.events;
    eprintln!(
        "{} poses replayed, every one answered once, {accepted} accepted; {} daemon restarts, {} poses sent again, {} gaps, {} fresh session starts; round trip p50 {:.1} us, p99 {:.1} us, max {:.1} us",
        result.answers.len(),
        ev.daemon_restarts,
        ev.resent,
        ev.gaps,
        ev.fresh_starts,
        percentile_us(&rt, 0.5),
        percentile_us(&rt, 0.99),
        percentile_us(&rt, 1.0)
    );
    for warning in warnings(&result.answers) {
        eprintln!("WARN {warning}");
    }
    // As `correct` says it, for a source whose session estimates the scale.
    let answers = result.answers.iter();
    let estimates = answers.map(|a| (a.odometry_scale, a.odometry_scale_sd));
    if let Some(line) = status_file::scale_summary(estimates) {
        eprintln!("{line}");
    }
    Ok(())
}
