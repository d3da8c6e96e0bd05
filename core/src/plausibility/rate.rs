//! The rate a source's stamps say it runs at, against the corrector's.

use crate::params::Params;

/// How much faster (or slower) than the corrector's [`Params::odometry_rate_hz`] a source's
/// stamps may say it is before its window is suspect of spanning too short (or too long) a
/// stretch of road.
pub const MAX_RATE_RATIO: f64 = 1.5;

/// Stamps this close (seconds: a nanosecond and a half) or closer are no time: they advance by
/// one a pose, an index (what `lanealign replay` sends without stamps), or not at all.
const INDEX_INTERVAL_S: f64 = 1.5e-9;

/// Below this rate (Hz: poses more than 10 s apart) a source's stamps are more likely in another
/// unit than seconds (milliseconds make 10 Hz read as 0.01 Hz) than an odometry's: the warning
/// asks, instead of naming a setting.
const SLOWEST_PLAUSIBLE_HZ: f64 = 0.1;

/// Above this rate (Hz: poses less than half a millisecond apart) a source's stamps are more
/// likely in a smaller unit than the one they are read in (microseconds sent as the wire's
/// nanoseconds make 10 Hz read as 10 kHz, milliseconds as 10 MHz) than an odometry's: the
/// warning asks, instead of naming a setting.
const FASTEST_PLAUSIBLE_HZ: f64 = 2000.0;

/// The rate (Hz) an odometry's speed is judged at: `stamped_hz`, the rate its stamps say, where
/// they say one an odometry runs at (from 0.1 to 2000 Hz), else `set_hz`, the rate its corrector
/// is set for (stamps in another unit are asked about by [`rate_warning`], not believed).
pub fn judged_rate_hz(stamped_hz: Option<f64>, set_hz: f64) -> f64 {
    stamped_hz
        .filter(|hz| (SLOWEST_PLAUSIBLE_HZ..=FASTEST_PLAUSIBLE_HZ).contains(hz))
        .unwrap_or(set_hz)
}

/// A rate (Hz) as a person reads it: whole hertz from 10 Hz on; below, a tenth matters (2.5 Hz
/// is not 2 or 3).
pub fn rate_text(rate_hz: f64) -> String {
    if rate_hz >= 10.0 {
        format!("{rate_hz:.0}")
    } else {
        format!("{rate_hz:.1}")
    }
}

/// The rate (Hz) consecutive stamps (seconds, in arrival order) say the source runs at: the
/// median interval's; `None` unless at least two intervals, and half of them, move forward by
/// more than a nanosecond (a source whose stamps are constant or an index says nothing). Stamps
/// in a unit too small give a rate no odometry runs at, which [`rate_warning`] asks about and
/// [`judged_rate_hz`] does not believe.
pub fn rate_from_stamps(stamps_s: &[f64]) -> Option<f64> {
    let mut intervals: Vec<f64> = stamps_s
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|dt| dt.is_finite() && *dt > INDEX_INTERVAL_S)
        .collect();
    if intervals.len() < 2 || intervals.len() * 2 < stamps_s.len() {
        return None;
    }
    let mid = intervals.len() / 2;
    let (_, median, _) = intervals.select_nth_unstable_by(mid, f64::total_cmp);
    Some(1.0 / *median)
}

/// A warning when a source's measured `rate_hz` is well above or below the rate `params` are set
/// for: its window then spans a fraction of the road the preset was chosen for, or a multiple of
/// it (and its first correction comes as many times later).
pub fn rate_warning(rate_hz: f64, params: &Params) -> Option<String> {
    let set_hz = params.odometry_rate_hz;
    let consequence = if rate_hz > MAX_RATE_RATIO * set_hz {
        "only part of the road its preset was chosen for"
    } else if rate_hz * MAX_RATE_RATIO < set_hz {
        "more time and road than its preset was chosen for, and its first correction comes later"
    } else {
        return None;
    };
    if rate_hz > FASTEST_PLAUSIBLE_HZ {
        let apart_us = 1e6 / rate_hz;
        let apart = if apart_us >= 1.0 {
            format!("{apart_us:.0} us")
        } else {
            format!("{:.0} ns", apart_us * 1e3)
        };
        return Some(format!(
            "the poses' stamps are {apart} apart (the median), which is no odometry's rate: are \
             they in the unit they are read in (nanoseconds on the wire, seconds in a TUM file)? \
             (Microseconds sent as nanoseconds make a 10 Hz source read as 10 kHz, milliseconds \
             as 10 MHz.) If they are, set odometry_rate_hz to the rate they give",
        ));
    }
    if rate_hz < SLOWEST_PLAUSIBLE_HZ {
        let apart_s = 1.0 / rate_hz;
        let apart = if apart_s < 1e6 {
            format!("{apart_s:.0}")
        } else {
            format!("{apart_s:.1e}")
        };
        return Some(format!(
            "the poses' stamps are {apart} s apart (the median), which is no odometry's rate: are \
             they in seconds? (Milliseconds make a 10 Hz source read as 0.01 Hz.) If they are, \
             set odometry_rate_hz to the rate they give",
        ));
    }
    let rate = rate_text(rate_hz);
    Some(format!(
        "the poses come at about {rate} Hz (their stamps) but the corrector is set for {set_hz} \
         Hz, so its window spans {consequence}: set odometry_rate_hz = {rate} (--set \
         odometry_rate_hz={rate}, or in the source's overrides)"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_source_faster_or_slower_than_its_preset_is_noticed_and_the_setting_named() {
        let params = crate::params::Preset::KissIcp.robust_params();
        let stamps = |hz: f64| {
            (0..100)
                .map(|i| 1.7e9 + i as f64 / hz)
                .collect::<Vec<f64>>()
        };
        let rate = rate_from_stamps(&stamps(100.0)).unwrap();
        assert!((rate - 100.0).abs() < 1e-3, "{rate}");
        let w = rate_warning(rate, &params).unwrap();
        assert!(w.contains("odometry_rate_hz=100"), "{w}");
        assert!(rate_warning(rate_from_stamps(&stamps(10.0)).unwrap(), &params).is_none());
        assert!(rate_warning(rate_from_stamps(&stamps(14.0)).unwrap(), &params).is_none());
        assert!(rate_warning(rate_from_stamps(&stamps(7.0)).unwrap(), &params).is_none());
        // A slower source too: its window would span twice the time and road.
        let w = rate_warning(rate_from_stamps(&stamps(5.0)).unwrap(), &params).unwrap();
        assert!(
            w.contains("about 5.0 Hz") && w.contains("odometry_rate_hz=5.0"),
            "{w}"
        );
        assert!(w.contains("first correction comes later"), "{w}");
        let mut set = params;
        set.odometry_rate_hz = 100.0;
        assert!(rate_warning(rate, &set).is_none());
        // Stamps far apart are asked about, not turned into a setting: 1e300 s apart printed
        // "set odometry_rate_hz = 0.0", which the corrector refuses.
        for (apart_s, says) in [(100.0, "are 100 s apart"), (1e300, "are 1.0e300 s apart")] {
            let slow: Vec<f64> = (0..100).map(|i| i as f64 * apart_s).collect();
            let w = rate_warning(rate_from_stamps(&slow).unwrap(), &params).unwrap();
            assert!(
                w.contains(says) && w.contains("are they in seconds?"),
                "{w}"
            );
            assert!(!w.contains("= 0"), "{w}");
        }
        // Stamps far too close are asked about too (microseconds sent as nanoseconds), and not
        // believed for the speed; 1 kHz is an odometry's rate.
        let fast: Vec<f64> = (0..100).map(|i| i as f64 * 1e-4).collect();
        let fast_hz = rate_from_stamps(&fast).unwrap();
        let w = rate_warning(fast_hz, &params).unwrap();
        assert!(
            w.contains("are 100 us apart") && w.contains("Microseconds sent as nanoseconds"),
            "{w}"
        );
        assert!(!w.contains("= 10000"), "{w}");
        assert_eq!(judged_rate_hz(Some(fast_hz), 10.0), 10.0);
        assert_eq!(judged_rate_hz(Some(1000.0), 10.0), 1000.0);
        assert_eq!(judged_rate_hz(Some(0.01), 10.0), 10.0);
        assert_eq!(judged_rate_hz(None, 20.0), 20.0);
        assert!(rate_warning(1000.0, &params)
            .unwrap()
            .contains("odometry_rate_hz=1000"));
        // Milliseconds sent as nanoseconds are asked about too, at 10 and 100 Hz (before
        // 2026-12-02 stamps less than 10 us apart told no rate, and nothing was said).
        for (apart_s, says) in [(1e-7, "are 100 ns apart"), (1e-8, "are 10 ns apart")] {
            let close: Vec<f64> = (0..100).map(|i| 1.7e3 + i as f64 * apart_s).collect();
            let hz = rate_from_stamps(&close).unwrap();
            let w = rate_warning(hz, &params).unwrap();
            assert!(
                w.contains(says) && w.contains("milliseconds as 10 MHz"),
                "{w}"
            );
            assert_eq!(judged_rate_hz(Some(hz), 10.0), 10.0);
        }
        // An index (what `replay` sends without stamps, 1 ns apart), a constant (no stamps) or
        // stamps out of order tell no rate.
        let index: Vec<f64> = (0..100).map(|i| i as f64 * 1e-9).collect();
        assert_eq!(rate_from_stamps(&index), None);
        assert_eq!(rate_from_stamps(&[0.0; 100]), None);
        assert_eq!(rate_from_stamps(&[3.0, 2.0, 1.0, 0.0]), None);
    }
}
