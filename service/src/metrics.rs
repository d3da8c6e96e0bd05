//! Per-source latency and outcome counts, reported through `tracing` every metrics interval.

use hdrhistogram::Histogram;
use lanealign_core::corrector::{Status, StepTiming};

/// What the daemon did with one input, as the metrics count it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// The corrector ran and said this.
    Corrected(Status),
    /// The input was refused (non-finite pose, duplicate or out-of-order sequence number).
    Flagged,
    /// The input was ahead of the session: answered with a gap status, not used.
    Gap,
    /// The input was already used: its answer was sent again.
    Resent,
    /// The source echoes without correcting.
    PassThrough,
}

/// Counts and latency histograms of one source since the last report.
pub struct SourceMetrics {
    count: u64,
    accepted: u64,
    rejected: u64,
    flagged: u64,
    gaps: u64,
    resent: u64,
    /// Answers no one received in this interval.
    pub undelivered: u64,
    /// Sessions started in this interval.
    pub new_sessions: u64,
    /// Sessions their clients closed in this interval (a goodbye on the wire).
    pub closed_sessions: u64,
    /// Poses not answered in this interval because their session's ports could not be made
    /// (no room in shared memory, too few file descriptors).
    pub unserved: u64,
    /// Poses answered uncorrected in this interval because their session waited for a place
    /// among the source's `max_sessions` (`pass_through`, reason `sessions_full`).
    pub waiting: u64,
    /// Live sessions at the report.
    pub sessions: u64,
    /// Journal writes that failed in this interval.
    pub journal_failures: u64,
    /// On a grid: neighbour queries that reached past a session's loaded cells in this
    /// interval (zero: every answer equals the whole map's).
    pub uncovered_queries: u64,
    /// On a grid: sessions that moved to a newly assembled map in this interval.
    pub map_swaps: u64,
    /// On a grid: poses whose session was behind (poses queued) and waited for the map it
    /// asked for, at most `grid_loader::CATCH_UP` each, in this interval.
    pub map_waits: u64,
    /// Client send to daemon publish (nanoseconds).
    end_to_end: Histogram<u64>,
    /// Daemon receive to daemon publish (nanoseconds).
    in_daemon: Histogram<u64>,
    /// Time in lane matching, in ICP, in the confidence, and in the rest of the source
    /// corrector's call (nanoseconds; bookkeeping: the frame conversions, the continuity and
    /// stall watches, the scale, smoothing and the window's upkeep).
    matching: Histogram<u64>,
    icp: Histogram<u64>,
    confidence: Histogram<u64>,
    bookkeeping: Histogram<u64>,
    /// In the daemon around the source corrector's call (nanoseconds): the sample's copy, the
    /// session's lookup and checks, the answer and its journal record.
    handling: Histogram<u64>,
}

/// p50, p99, p999 and max of a histogram, in microseconds.
fn quantiles(h: &Histogram<u64>) -> [f64; 4] {
    let us = |v: u64| v as f64 / 1e3;
    [
        us(h.value_at_quantile(0.5)),
        us(h.value_at_quantile(0.99)),
        us(h.value_at_quantile(0.999)),
        us(h.max()),
    ]
}

fn histogram() -> Histogram<u64> {
    // 1 ns to 100 s at 3 significant digits; allocated once, reset after each report.
    Histogram::new_with_bounds(1, 100_000_000_000, 3).expect("constant, valid histogram bounds")
}

impl Default for SourceMetrics {
    fn default() -> Self {
        SourceMetrics {
            count: 0,
            accepted: 0,
            rejected: 0,
            flagged: 0,
            gaps: 0,
            resent: 0,
            undelivered: 0,
            new_sessions: 0,
            closed_sessions: 0,
            unserved: 0,
            waiting: 0,
            sessions: 0,
            journal_failures: 0,
            uncovered_queries: 0,
            map_swaps: 0,
            map_waits: 0,
            end_to_end: histogram(),
            in_daemon: histogram(),
            matching: histogram(),
            icp: histogram(),
            confidence: histogram(),
            bookkeeping: histogram(),
            handling: histogram(),
        }
    }
}

impl SourceMetrics {
    /// Records one answered input: what happened, its latencies (nanoseconds) and where the
    /// corrector's time went.
    pub fn record(
        &mut self,
        outcome: &Outcome,
        end_to_end_ns: u64,
        in_daemon_ns: u64,
        timing: &StepTiming,
    ) {
        match outcome {
            Outcome::Corrected(Status::Accepted { .. }) => self.accepted += 1,
            Outcome::Corrected(Status::Rejected { .. } | Status::Reset { .. }) => {
                self.rejected += 1
            }
            Outcome::Flagged => self.flagged += 1,
            Outcome::Gap => self.gaps += 1,
            Outcome::Resent => self.resent += 1,
            Outcome::Corrected(_) | Outcome::PassThrough => {}
        }
        let matching_ns = timing.matching.as_nanos() as u64;
        let icp_ns = timing.icp.as_nanos() as u64;
        let confidence_ns = timing.confidence.as_nanos() as u64;
        let bookkeeping_ns = timing
            .total
            .saturating_sub(timing.matching + timing.icp + timing.confidence)
            .as_nanos() as u64;
        let handling_ns = in_daemon_ns.saturating_sub(timing.total.as_nanos() as u64);
        self.count += 1;
        // Saturating: values beyond the range are clamped, never an error.
        self.end_to_end.saturating_record(end_to_end_ns.max(1));
        self.in_daemon.saturating_record(in_daemon_ns.max(1));
        self.matching.saturating_record(matching_ns.max(1));
        self.icp.saturating_record(icp_ns.max(1));
        self.confidence.saturating_record(confidence_ns.max(1));
        self.bookkeeping.saturating_record(bookkeeping_ns.max(1));
        self.handling.saturating_record(handling_ns.max(1));
    }

    /// Emits one INFO event with the counts and latency quantiles, then starts over.
    pub fn report(&mut self, source: &str) {
        if self.count == 0 {
            tracing::info!(
                source,
                count = 0,
                sessions = self.sessions,
                closed_sessions = self.closed_sessions,
                unserved = self.unserved,
                "no poses in this interval"
            );
            self.closed_sessions = 0;
            self.unserved = 0;
            return;
        }
        let [e50, e99, e999, emax] = quantiles(&self.end_to_end);
        let [d50, d99, d999, dmax] = quantiles(&self.in_daemon);
        let [m50, m99, _, mmax] = quantiles(&self.matching);
        let [i50, i99, _, imax] = quantiles(&self.icp);
        let [c50, c99, _, cmax] = quantiles(&self.confidence);
        let [b50, b99, _, bmax] = quantiles(&self.bookkeeping);
        let [h50, h99, _, hmax] = quantiles(&self.handling);
        tracing::info!(
            source,
            count = self.count,
            accepted = self.accepted,
            rejected = self.rejected,
            flagged = self.flagged,
            gaps = self.gaps,
            resent = self.resent,
            undelivered = self.undelivered,
            sessions = self.sessions,
            new_sessions = self.new_sessions,
            closed_sessions = self.closed_sessions,
            unserved = self.unserved,
            waiting_for_place = self.waiting,
            journal_failures = self.journal_failures,
            uncovered_queries = self.uncovered_queries,
            map_swaps = self.map_swaps,
            map_waits = self.map_waits,
            e2e_p50_us = e50,
            e2e_p99_us = e99,
            e2e_p999_us = e999,
            e2e_max_us = emax,
            daemon_p50_us = d50,
            daemon_p99_us = d99,
            daemon_p999_us = d999,
            daemon_max_us = dmax,
            matching_p50_us = m50,
            matching_p99_us = m99,
            matching_max_us = mmax,
            icp_p50_us = i50,
            icp_p99_us = i99,
            icp_max_us = imax,
            confidence_p50_us = c50,
            confidence_p99_us = c99,
            confidence_max_us = cmax,
            bookkeeping_p50_us = b50,
            bookkeeping_p99_us = b99,
            bookkeeping_max_us = bmax,
            handling_p50_us = h50,
            handling_p99_us = h99,
            handling_max_us = hmax,
            "latency"
        );
        self.count = 0;
        self.accepted = 0;
        self.rejected = 0;
        self.flagged = 0;
        self.gaps = 0;
        self.resent = 0;
        self.undelivered = 0;
        self.new_sessions = 0;
        self.closed_sessions = 0;
        self.unserved = 0;
        self.waiting = 0;
        self.journal_failures = 0;
        self.uncovered_queries = 0;
        self.map_swaps = 0;
        self.map_waits = 0;
        for h in [
            &mut self.end_to_end,
            &mut self.in_daemon,
            &mut self.matching,
            &mut self.icp,
            &mut self.confidence,
            &mut self.bookkeeping,
            &mut self.handling,
        ] {
            h.reset();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// A step of `total_us` microseconds, 15 of them in matching, ICP and confidence.
    fn step_of(total_us: u64) -> StepTiming {
        StepTiming {
            matching: Duration::from_micros(5),
            icp: Duration::from_micros(7),
            confidence: Duration::from_micros(3),
            total: Duration::from_micros(total_us),
        }
    }

    #[test]
    fn handling_is_the_daemons_time_around_the_corrector_step() {
        let mut m = SourceMetrics::default();
        m.record(&Outcome::Flagged, 40_000, 26_000, &step_of(20));
        assert_eq!(m.handling.value_at_quantile(0.5) / 1000, 6);
        assert_eq!(m.bookkeeping.value_at_quantile(0.5) / 1000, 5);
    }

    #[test]
    fn every_histogram_starts_over_after_a_report() {
        let mut m = SourceMetrics::default();
        m.record(&Outcome::Flagged, 1000, 500, &step_of(100));
        m.report("test");
        assert_eq!((m.count, m.flagged), (0, 0));
        for h in [
            &m.end_to_end,
            &m.in_daemon,
            &m.matching,
            &m.icp,
            &m.confidence,
            &m.bookkeeping,
            &m.handling,
        ] {
            assert_eq!(h.len(), 0);
        }
    }
}
