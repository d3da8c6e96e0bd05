//! The building blocks of the `lanealign` command and its examples: where lane maps come from
//! ([`maps`]), streaming a trajectory through the daemon ([`replay`]), running the daemon
//! ([`daemon_process`], [`daemon_config`]), the per-pose status CSV ([`status_file`]), the synthetic town used when there is no data
//! ([`synthetic`]), the KITTI data of `../shared/data` ([`kitti`]), comparing with ground truth
//! ([`evaluation`]), results folders ([`results`]), plots ([`plots`]) and the examples' tables and progress
//! ([`report`]).

pub mod daemon_config;
pub mod daemon_process;
pub mod evaluation;
pub mod kitti;
pub mod maps;
pub mod plots;
pub mod replay;
pub mod report;
pub mod results;
pub mod status_file;
pub mod synthetic;
