//! lanealignd: the drift correction daemon. Odometry processes publish poses over iceoryx2 shared
//! memory; one worker per source corrects them against a validated lane tile and publishes
//! the corrected poses back. See [`daemon::run`] and `configs/lanealignd.toml`.

pub mod config;
pub mod daemon;
pub mod metrics;
pub mod worker;
